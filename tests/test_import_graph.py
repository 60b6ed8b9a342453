"""No import cycle in holodata/ (issue 25 point 3, issue 44 point 4).

Every module under holodata/ is parsed with ``ast`` and every import in it is an edge of the module
graph: module level, inside a function (a lazy import is still a dependency; it only moves the
failure to the first call), and under ``if TYPE_CHECKING:`` (annotations are part of the module's
interface: two modules that name each other's types depend on each other, and mypy reads them as
imports). Relative imports are resolved against the importing module's package; ``from pkg import
name`` is an edge to ``pkg.name`` when that is a module, else to ``pkg``; ``import a.b`` is an edge to
``a.b``. A module's own parent packages are left out: importing ``holodata.x.y`` runs
``holodata/__init__.py`` and ``holodata/x/__init__.py`` first whoever imports it, so counting those
would make every package ``__init__`` that re-exports its modules a cycle.

A strongly connected component of more than one module is a cycle; the test fails naming each, with
one concrete loop through it (edges marked ``[function]`` / ``[TYPE_CHECKING]`` when that is how the
import is written). No cycle is tolerated: fix it by moving what both sides need into the module
below them.
"""
from __future__ import annotations

import ast
from collections import deque
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "holodata"


def modules(root: Path = ROOT) -> dict[str, Path]:
    """{dotted name: file} for every module and package of ``root`` (a package is its ``__init__``)."""
    out = {}
    for p in sorted(root.rglob("*.py")):
        parts = (root.name,) + p.relative_to(root).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def _typing_only(tree: ast.AST) -> set[int]:
    """ids of the nodes under an ``if TYPE_CHECKING:`` (or ``typing.TYPE_CHECKING``) body."""
    ids: set[int] = set()
    for b in ast.walk(tree):
        if isinstance(b, ast.If) and "TYPE_CHECKING" in ast.unparse(b.test):
            for stmt in b.body:
                ids |= {id(x) for x in ast.walk(stmt)}
    return ids


def _in_function(tree: ast.AST) -> set[int]:
    ids: set[int] = set()
    for f in ast.walk(tree):
        if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            ids |= {id(x) for x in ast.walk(f) if x is not f}
    return ids


def import_graph(root: Path = ROOT) -> dict[str, dict[str, str]]:
    """{module: {imported module of the package: how}} with ``how`` ``"module"``, ``"function"`` or
    ``"TYPE_CHECKING"`` (the first import statement found that makes the edge)."""
    mods = modules(root)
    edges: dict[str, dict[str, str]] = {m: {} for m in mods}
    for m, p in mods.items():
        pkg = m.split(".") if p.name == "__init__.py" else m.split(".")[:-1]
        tree = ast.parse(p.read_text(), filename=str(p))
        typing_only, in_function = _typing_only(tree), _in_function(tree)
        for n in ast.walk(tree):
            if isinstance(n, ast.ImportFrom):
                if n.level:
                    if n.level - 1 > len(pkg) - 1:
                        raise AssertionError(f"{p}:{n.lineno}: relative import beyond the top package")
                    prefix = pkg[:len(pkg) - n.level + 1]
                else:
                    prefix = []
                base = ".".join(prefix + ([n.module] if n.module else []))
                subs = [f"{base}.{a.name}" for a in n.names if f"{base}.{a.name}" in mods]
                plain = [a.name for a in n.names if f"{base}.{a.name}" not in mods]
                targets = subs + ([base] if plain or not subs else [])
            elif isinstance(n, ast.Import):
                targets = [a.name for a in n.names]
            else:
                continue
            how = "TYPE_CHECKING" if id(n) in typing_only else "function" if id(n) in in_function else "module"
            for t in targets:
                if t in mods and t != m and not m.startswith(t + "."):
                    edges[m].setdefault(t, how)
    return edges


def cycles(edges) -> list[frozenset]:
    """Strongly connected components with more than one module (Tarjan, iterative), in a stable order."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on: set[str] = set()
    stack: list[str] = []
    out: list[frozenset] = []
    for start in sorted(edges):
        if start in index:
            continue
        index[start] = low[start] = len(index)
        stack.append(start)
        on.add(start)
        work = [(start, iter(sorted(edges[start])))]
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = set()
                while True:
                    x = stack.pop()
                    on.discard(x)
                    comp.add(x)
                    if x == v:
                        break
                if len(comp) > 1:
                    out.append(frozenset(comp))
    return sorted(out, key=lambda c: sorted(c))


def loop_through(edges, comp: frozenset) -> list[str]:
    """A shortest loop from the component's first module back to itself, inside the component."""
    start = min(comp)
    prev: dict[str, str] = {}
    todo = deque([start])
    while todo:
        v = todo.popleft()
        for w in sorted(edges[v]):
            if w not in comp:
                continue
            if w == start:
                path = [v]
                while path[-1] != start:
                    path.append(prev[path[-1]])
                return [start] + path[::-1][1:] + [start] if len(path) > 1 else [start, start]
            if w not in prev:
                prev[w] = v
                todo.append(w)
    raise AssertionError(f"{sorted(comp)} is not strongly connected")


def describe(edges, comp: frozenset) -> str:
    loop = loop_through(edges, comp)
    steps = " -> ".join(loop[:1] + [f"{b}" + (f" [{edges[a][b]}]" if edges[a][b] != "module" else "")
                                    for a, b in zip(loop, loop[1:])])
    return f"{len(comp)} modules {sorted(comp)}: {steps}"


def test_cycle_finder_finds_a_cycle_and_no_false_one():
    g = {"a": {"b": "module"}, "b": {"c": "function"}, "c": {"a": "TYPE_CHECKING"}, "d": {"a": "module"}}
    assert cycles(g) == [frozenset("abc")]
    assert describe(g, frozenset("abc")) == "3 modules ['a', 'b', 'c']: a -> b -> c [function] -> a [TYPE_CHECKING]"
    assert cycles({"a": {"b": "module"}, "b": {}, "c": {"a": "module", "b": "module"}}) == []


def test_import_graph_resolves_relative_submodule_and_typing_imports(tmp_path):
    pkg = tmp_path / "holodata"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from .sub import leaf\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "leaf.py").write_text("from .. import top\n")
    (pkg / "top.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                "    from holodata.sub.leaf import X\n"
                                "def f():\n    import holodata.sub\n    from holodata.sub import nothing\n")
    g = import_graph(pkg)
    assert g["holodata"] == {"holodata.sub.leaf": "module"}
    assert g["holodata.sub.leaf"] == {"holodata.top": "module"}     # parents holodata, holodata.sub left out
    assert g["holodata.top"] == {"holodata.sub.leaf": "TYPE_CHECKING", "holodata.sub": "function"}
    assert cycles(g) == [frozenset({"holodata.sub.leaf", "holodata.top"})]


def test_no_import_cycle_in_holodata():
    g = import_graph()
    assert "holodata.radar.beamform" in g and "holodata.evaluate.pipeline" in g     # the walk saw the package
    found = cycles(g)
    assert not found, "import cycle(s) in holodata/:\n" + "\n".join(describe(g, c) for c in found)
