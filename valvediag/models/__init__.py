"""
Physical models: control valves and the closed loop.

* :mod:`~valvediag.models.valves`: OP to valve position (linear, backlash,
  Kano, Choudhury, He), with the compiled step shared by every simulator and
  by the workbench's fitted valve.
* :mod:`~valvediag.models.closedloop`: PI control of an integrating or
  self-regulating process, thousands of scenarios at once.
"""
from . import closedloop, valves
from .closedloop import LoopSimulation, simulate_loop

__all__ = ["valves", "closedloop", "simulate_loop", "LoopSimulation"]
