"""The package's imports point one way: no module imports one that imports it back.

Every ``import`` and ``from ... import`` of ``valvediag`` (and of the flows in
``pipelines/``, installed as ``valvediag.pipelines``) is read from the source,
at module level and inside functions alike; only imports under
``if TYPE_CHECKING:`` are left out (they never run). A cycle in that graph
fails the test with the modules on it.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = {"valvediag": ROOT / "valvediag", "valvediag.pipelines": ROOT / "pipelines"}


def _modules() -> dict[str, Path]:
    mods = {}
    for prefix, base in SOURCES.items():
        for p in base.rglob("*.py"):
            parts = list(p.relative_to(base).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join([prefix, *parts])] = p
    return mods


MODULES = _modules()


def _type_checking_lines(tree: ast.AST) -> set[int]:
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for sub in node.body:
                skip.update(range(sub.lineno, (sub.end_lineno or sub.lineno) + 1))
    return skip


def imports_of(module: str) -> set[str]:
    """The project modules ``module`` imports (explicit edges only)."""
    path = MODULES[module]
    tree = ast.parse(path.read_text())
    skip = _type_checking_lines(tree)
    is_pkg = path.name == "__init__.py"
    out = set()
    for node in ast.walk(tree):
        if getattr(node, "lineno", None) in skip:
            continue
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_pkg else module.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                src = ".".join(base + ([node.module] if node.module else []))
            else:
                src = node.module or ""
            names = [f"{src}.{a.name}" if f"{src}.{a.name}" in MODULES else src
                     for a in node.names]
        else:
            continue
        for name in names:
            while name and name not in MODULES:
                name = name.rpartition(".")[0]
            if name and name != module:
                out.add(name)
    return out


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of ``graph`` as a list of nodes (first == last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                found = visit(m)
                if found:
                    return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            found = visit(n)
            if found:
                return found
    return None


def test_the_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_no_import_cycle():
    graph = {m: imports_of(m) for m in MODULES}
    assert sum(len(v) for v in graph.values()) > 100       # the walk saw the imports
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


@pytest.mark.parametrize("low, high", [
    ("valvediag.analysis", "valvediag.scan"), ("valvediag.analysis", "valvediag.store"),
    ("valvediag.analysis", "valvediag.report"), ("valvediag.models", "valvediag.analysis"),
    ("valvediag.io", "valvediag.store"), ("valvediag.store", "valvediag.scan"),
    ("valvediag.store", "valvediag.report"), ("valvediag", "valvediag.pipelines")])
def test_lower_layers_do_not_import_higher_ones(low, high):
    """Readers -> store -> analysis -> results -> report: the arrows point down."""
    offenders = sorted(f"{m} imports {d}" for m in MODULES
                       if (m == low or m.startswith(low + ".")) and not m.startswith(high)
                       and not (low == "valvediag" and m.startswith("valvediag.cli"))
                       for d in imports_of(m) if d == high or d.startswith(high + "."))
    assert not offenders, offenders


def test_the_library_never_imports_prefect():
    """valvediag/ is numerics and I/O; only the flows (and the scan command, which runs
    them) import Prefect."""
    users = []
    for m, p in MODULES.items():
        if m.startswith(("valvediag.pipelines", "valvediag.cli")):
            continue
        tree = ast.parse(p.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "prefect"
                                                    for a in node.names):
                users.append(m)
            elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "prefect":
                users.append(m)
    assert not users, users
