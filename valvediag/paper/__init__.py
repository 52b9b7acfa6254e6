"""
Farenzena & Trierweiler (2012), reproduced.

* :mod:`~valvediag.paper.tables`: the grids of the paper's Tables 1-3 as
  printed, simulated and classified (:func:`reproduce_paper`).
* :mod:`~valvediag.paper.scenarios`: loops drawn from the paper's parameter
  ranges, recorded as a historian would, for benchmarks and tests.
"""
from .tables import PAPER_RESULTS, PaperReproduction, reproduce_paper

__all__ = ["reproduce_paper", "PaperReproduction", "PAPER_RESULTS"]
