"""valvediag: find sticky and loose control valves from historian data."""
from . import closedloop, valves
from .closedloop import LoopSimulation, simulate_loop

__version__ = "0.1.0"
__all__ = ["valves", "closedloop", "simulate_loop", "LoopSimulation", "__version__"]
