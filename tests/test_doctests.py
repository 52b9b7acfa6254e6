"""The ``>>>`` examples in the docstrings of the core modules run, and print what they show."""
from __future__ import annotations

import contextlib
import doctest
import importlib
import io
import inspect
import pkgutil

import pytest

import valvediag.analysis
import valvediag.paper

# every module of these packages, and these modules
MODULES = sorted(
    [f"valvediag.analysis.{m.name}" for m in pkgutil.iter_modules(valvediag.analysis.__path__)]
    + [f"valvediag.paper.{m.name}" for m in pkgutil.iter_modules(valvediag.paper.__path__)]
    + ["valvediag.analysis", "valvediag.paper", "valvediag.verdicts",
       "valvediag.models.valves", "valvediag.models.closedloop",
       "valvediag.workbench", "valvediag.workbench.model"])

FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    report = io.StringIO()
    with contextlib.redirect_stdout(report):
        result = doctest.testmod(module, optionflags=FLAGS, report=False)
    try:
        import matplotlib.pyplot as plt
    except ImportError:   # pragma: no cover
        pass
    else:
        plt.close("all")   # the workbench's examples plot
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed:\n" \
                               f"{report.getvalue()}"
    if ">>>" in inspect.getsource(module):
        assert result.attempted > 0, f"{name} shows examples but none ran"
