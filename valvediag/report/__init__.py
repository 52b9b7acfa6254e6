"""
The morning report of a plant scan: HTML page, figures, history across runs.

* :mod:`~valvediag.report.html`: :func:`render_report`, the self-contained
  ``report.html`` (jinja2 templates in ``reports/``, CSS and script inlined).
* :mod:`~valvediag.report.figures`: one reproducible inline SVG of evidence
  per loop needing action (matplotlib).
* :mod:`~valvediag.report.svg`: sparklines and history strips, drawn by hand.
* :mod:`~valvediag.report.history`: new, repeat and resolved loops from the
  store's earlier runs.
* :mod:`~valvediag.report.explain`: the verdicts in plain words.
* :mod:`~valvediag.report.browser`: open a report in headless Chromium,
  check it and take a screenshot (tests and docs).

:func:`valvediag.report.outputs.write_outputs` writes the report with the other
output files.
"""
from .explain import ACTIONS, explain
from .history import PlantHistory, plant_history, read_history
from .html import loop_anchor, render_report

__all__ = ["render_report", "loop_anchor", "explain", "ACTIONS", "PlantHistory",
           "plant_history", "read_history"]
