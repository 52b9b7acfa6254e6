import os
import platform
import sys

import pytest
from hypothesis import settings

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("DO_NOT_TRACK", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
# the BLAS kernels the Makefile pins (see there), for a pytest run without make;
# OpenBLAS reads this when numpy first loads it
if platform.machine() == "x86_64" and "numpy" not in sys.modules:
    os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")

# The property-based tests draw new examples on every `make test`, so a developer's
# runs keep exploring. CI (.ci/run sets HYPOTHESIS_PROFILE=ci) draws a fixed set,
# so that whether a commit lands depends on the code, not on the draw.
settings.register_profile("ci", derandomize=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.fixture(scope="session")
def prefect_api():
    """One temporary Prefect server for every flow run of the session; yields its API URL.

    In-process flows use it through Prefect's settings; subprocesses (a
    ``valvediag scan`` started by a test, Dask workers) get it as
    ``PREFECT_API_URL`` in their environment.
    """
    from prefect.settings import PREFECT_API_URL
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=180):
        yield PREFECT_API_URL.value()
