"""The package's shape: no import cycle between modules, no module past the size where it stops
reading as one idea, no lab-notebook date stamps in the code. (The layers themselves are
import-linter's contract in pyproject.toml, run by .ci/run.)"""

import re
from pathlib import Path

import grimp

PACKAGE = Path(__file__).resolve().parents[1] / "bayescap"
MAX_LINES = 600


def _strongly_connected(graph, modules):
    """Tarjan's algorithm over the direct-import graph; the components of more than one module."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.find_modules_directly_imported_by(v):
            if w not in modules:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for m in sorted(modules):
        if m not in index:
            visit(m)
    return out


def test_no_import_cycle():
    graph = grimp.build_graph("bayescap")
    # packages included: a module that imports its own package (whose __init__ imports it back) is a
    # cycle too
    modules = {m for m in graph.modules if m.startswith("bayescap.")}
    assert _strongly_connected(graph, modules) == []


def test_no_module_over_the_size_limit():
    sizes = {str(p.relative_to(PACKAGE.parent)): len(p.read_text().splitlines()) for p in PACKAGE.rglob("*.py")}
    assert {p: n for p, n in sizes.items() if n > MAX_LINES} == {}


def test_no_date_stamps_in_code():
    stamp = re.compile(r"\b20\d\d-\d\d-\d\d\b")
    hits = [
        f"{p.relative_to(PACKAGE.parent)}:{i}"
        for p in PACKAGE.rglob("*.py")
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if stamp.search(line)
    ]
    assert hits == []
