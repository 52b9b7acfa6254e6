"""Every public function and class of the core modules documents its parameters
(numpydoc), in the manner of python-control's docstring tests."""
import importlib
import inspect
import re

import pytest

CORE = ["models.valves", "models.closedloop", "analysis.oscillation", "analysis.bi",
        "analysis.linearity", "analysis.classify", "paper.tables", "paper.scenarios",
        "io.loopfile", "verdicts"]


def _public(modname):
    mod = importlib.import_module(f"valvediag.{modname}")
    for name in getattr(mod, "__all__", []):
        obj = getattr(mod, name)
        if inspect.isfunction(obj):
            yield f"{modname}.{name}", obj


@pytest.mark.parametrize("qual,func", [x for m in CORE for x in _public(m)], ids=lambda x: x if isinstance(x, str) else "")
def test_every_parameter_is_documented(qual, func):
    doc = inspect.getdoc(func) or ""
    assert doc, f"{qual} has no docstring"
    params = [p for p in inspect.signature(func).parameters.values()
              if p.kind not in (p.VAR_POSITIONAL,) and p.name not in ("self", "cls")]
    if not params:
        return
    assert "Parameters\n----------" in doc, f"{qual} has no Parameters section"
    section = doc.split("Parameters\n----------", 1)[1].split("\n\n" + "Returns", 1)[0]
    documented = set()
    for line in section.splitlines():
        m = re.match(r"^(\*{0,2}[\w, *]+?)\s*:", line)
        if m and not line.startswith(" "):
            documented.update(n.strip().lstrip("*") for n in m.group(1).split(","))
    missing = [p.name for p in params if p.name not in documented]
    assert not missing, f"{qual}: undocumented parameters {missing}"
