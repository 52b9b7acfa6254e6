import os

import numpy as np
import pytest
from hypothesis import settings

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("DO_NOT_TRACK", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

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


@pytest.fixture
def setpoint_steps():
    """Set-point steps of 0.5-1.5, alternating in sign, every 25-50 min:
    ``setpoint_steps(rng, n)`` -> array of ``n`` samples at 1 s."""
    def steps(rng, n):
        sp, t, sign = np.zeros(n), 0, 1.0
        while True:
            t += int(rng.uniform(25, 50) * 60)
            if t >= n:
                return sp
            sp[t:] += sign * rng.uniform(0.5, 1.5)
            sign = -sign
    return steps
