"""valvediag: find sticky and loose control valves from historian data."""
from . import _numba_cache

_numba_cache.configure()

from .analysis.bi import BacklashIndex, backlash_index  # noqa: E402
from .analysis.classify import LoopDiagnosis, classify_loop  # noqa: E402
from .models import closedloop, valves  # noqa: E402
from .models.closedloop import LoopSimulation, simulate_loop  # noqa: E402
from .verdicts import VERDICTS  # noqa: E402

__version__ = "0.1.0"
__all__ = ["backlash_index", "BacklashIndex", "classify_loop", "LoopDiagnosis", "VERDICTS",
           "simulate_loop", "LoopSimulation", "valves", "closedloop", "__version__"]
