"""No import cycle in holodata/ (issue 25 point 3, issue 44 point 4).

Every module under holodata/ is parsed with ``ast`` and every import in it is an edge of the module
graph: module level, inside a function (a lazy import is still a dependency; it only moves the
failure to the first call), and under ``if TYPE_CHECKING:`` (annotations are part of the module's
interface: two modules that name each other's types depend on each other, and mypy reads them as
imports). Relative imports are resolved against the importing module's package; ``from pkg import
name`` is an edge to ``pkg.name`` when that is a module, else to ``pkg``; ``import a.b`` is an edge to
``a.b``. A module's own parent packages are left out: importing ``holodata.x.y`` runs
``holodata/__init__.py`` and ``holodata/x/__init__.py`` first whoever imports it, so counting those
would make every package ``__init__`` that re-exports its modules a cycle. Except where the module
imports a *name* from one of them (``from holodata.x import f`` or ``from . import f`` in
``holodata/x/y.py``, not a submodule): then it needs that package's code, which its ``__init__``
usually re-exports from the module's siblings or from the module itself, so that is an edge like any
other (issue 25: three such lazy imports hid the cycles ``synth`` <-> ``synth.data_pass``,
``mapping.slam`` <-> ``mapping.slam.localise`` and ``mapping.register`` <-> ``mapping.register.steps``).
:func:`parent_package_imports` lists every import of a module's own (direct) parent package,
which :func:`test_no_module_imports_its_own_parent_package` forbids outright, cycle or not: a package
face holds no code of its own (:func:`test_package_faces_hold_no_code`), so what a module wants from
it lives in a sibling module, to be imported from there.

A strongly connected component of more than one module is a cycle; the test fails naming each, with
one concrete loop through it (edges marked ``[function]`` / ``[TYPE_CHECKING]`` when that is how the
import is written). No cycle is tolerated: fix it by moving what both sides need into the module
below them.

Some arrows must not exist even without a cycle (issue 44, "arrows that run back up"):
:data:`FORBIDDEN_IMPORTS` lists (importer, imported) package prefixes, checked over the same graph by
:func:`test_no_import_runs_back_up` (holodata.torch never imports holodata.evaluate, the geometry
core neither of them, holodata.distributed no stage package).
"""
from __future__ import annotations

import ast
from collections import deque
from pathlib import Path

from _paths import REPO

ROOT = REPO / "holodata"


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
                # a parent package counts when a name is imported from it (``plain``: its code), not when
                # it is only run first (``import holodata.x.y``, ``from holodata.x import y`` of a module)
                parent_code = isinstance(n, ast.ImportFrom) and t == base and bool(plain)
                if t in mods and t != m and (parent_code or not m.startswith(t + ".")):
                    edges[m].setdefault(t, how)
    return edges


def parent_package_imports(root: Path = ROOT) -> list[str]:
    """``"module:line [how]: statement"`` for every import of a module's own parent package, at
    module level, in a function or under ``TYPE_CHECKING``: a name from it (``from . import f``,
    ``from holodata.x import f`` in ``holodata/x/y.py``) or the package itself (``import holodata.x``,
    ``from holodata import x``). A package's ``__init__`` is the module of the package itself: its
    parent is the package above."""
    mods = modules(root)
    out = []
    for m, p in mods.items():
        if "." not in m:
            continue
        parent = m.rsplit(".", 1)[0]
        pkg = m.split(".") if p.name == "__init__.py" else m.split(".")[:-1]
        tree = ast.parse(p.read_text(), filename=str(p))
        typing_only, in_function = _typing_only(tree), _in_function(tree)
        for n in ast.walk(tree):
            if isinstance(n, ast.ImportFrom):
                prefix = pkg[:len(pkg) - n.level + 1] if n.level else []
                base = ".".join(prefix + ([n.module] if n.module else []))
                hit = any(f"{base}.{a.name}" == parent or (base == parent and f"{base}.{a.name}" not in mods)
                          for a in n.names)
            elif isinstance(n, ast.Import):
                hit = any(a.name == parent for a in n.names)
            else:
                continue
            if hit:
                how = "TYPE_CHECKING" if id(n) in typing_only else "function" if id(n) in in_function else "module"
                out.append(f"{m}:{n.lineno} [{how}]: {ast.unparse(n)}")
    return out


# Package faces (``__init__.py``) that still hold code, and why. Every other face holds only its
# docstring, imports, ``__all__`` and constants (test_package_faces_hold_no_code).
FACES_WITH_CODE: set[str] = set()   # none (holodata's lazy PEP 562 hooks live in holodata/_lazy.py)


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


def _package(tmp_path, files: dict):
    """A toy ``holodata`` package under ``tmp_path``: {path relative to it: source text}."""
    pkg = tmp_path / "holodata"
    for rel, text in files.items():
        (pkg / rel).parent.mkdir(parents=True, exist_ok=True)
        (pkg / rel).write_text(text)
    return pkg


def test_import_graph_resolves_relative_submodule_and_typing_imports(tmp_path):
    pkg = _package(tmp_path, {"__init__.py": "from .sub import leaf\n", "sub/__init__.py": "",
                              "sub/leaf.py": "from .. import top\n",
                              "top.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                        "    from holodata.sub.leaf import X\n"
                                        "def f():\n    import holodata.sub\n    from holodata.sub import nothing\n"})
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


# Arrows that must not run back up (issue 44 "arrows that run back up"): (importer, imported) module
# prefixes; no edge of the import graph, of any kind (module level, lazy in a function, TYPE_CHECKING),
# may run from a module under the first to one under the second. A cycle test alone misses these: one
# direction of such a pair is enough to invert the layering.
STAGES = ("synth", "ingest", "mapping", "raytrace", "torch", "evaluate")
FORBIDDEN_IMPORTS = [
    # the model package: evaluate runs it, so it never reaches into evaluate (shared code lives below both,
    # e.g. holodata.geometry.unmirror)
    ("holodata.torch", "holodata.evaluate"),
    # the geometry core is arrays in, arrays out, below every stage
    ("holodata.geometry", "holodata.torch"),
    ("holodata.geometry", "holodata.evaluate"),
    # the Dask runner knows no stage: each stage owns its task function and imports the runner
    *[("holodata.distributed", f"holodata.{stage}") for stage in STAGES],
]


def _under(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def forbidden_imports(edges, rules=FORBIDDEN_IMPORTS) -> list[str]:
    """``"importer -> imported [how]"`` for every edge of ``edges`` that a rule of ``rules`` forbids."""
    return [f"{a} -> {b} [{how}]" for a in sorted(edges) for b, how in sorted(edges[a].items())
            if any(_under(a, hi) and _under(b, lo) for hi, lo in rules)]


def test_forbidden_import_finder(tmp_path):
    pkg = _package(tmp_path, {"__init__.py": "", "torch/__init__.py": "",
                              "torch/train.py": "def f():\n    from holodata.evaluate.frames import X\n",
                              "evaluate/__init__.py": "", "evaluate/frames.py": "from holodata.torch import train\n",
                              "distributed.py": "from holodata import evaluate\n",
                              "torchvision_like.py": "import holodata.evaluate\n"})   # a prefix, not a package
    assert forbidden_imports(import_graph(pkg)) == ["holodata.distributed -> holodata.evaluate [module]",
                                                    "holodata.torch.train -> holodata.evaluate.frames [function]"]


def test_no_import_runs_back_up():
    g = import_graph()
    assert "holodata.distributed" in g and "holodata.torch.stage2" in g and "holodata.geometry.unmirror" in g
    found = forbidden_imports(g)
    assert not found, ("import(s) against the layering (FORBIDDEN_IMPORTS; move what both sides need below "
                       "them):\n" + "\n".join(found))


def test_import_graph_counts_names_imported_from_a_parent_package(tmp_path):
    pkg = _package(tmp_path, {"__init__.py": "VERSION = '1'\n",
                              "sub/__init__.py": "from .core import run\nfrom .leaf import thing\n",
                              "sub/core.py": "def run():\n    from . import thing\n    from .. import VERSION\n",
                              "sub/leaf.py": "import holodata.sub\nfrom holodata import sub\nthing = 1\n"})
    g = import_graph(pkg)
    assert g["holodata.sub.core"] == {"holodata.sub": "function", "holodata": "function"}
    assert g["holodata.sub.leaf"] == {}      # the package only run first (or bound), no name taken from it
    assert cycles(g) == [frozenset({"holodata.sub", "holodata.sub.core"})]
    assert describe(g, cycles(g)[0]) == ("2 modules ['holodata.sub', 'holodata.sub.core']: "
                                         "holodata.sub -> holodata.sub.core -> holodata.sub [function]")
    assert parent_package_imports(pkg) == [
        "holodata.sub.core:2 [function]: from . import thing",
        "holodata.sub.leaf:1 [module]: import holodata.sub",
        "holodata.sub.leaf:2 [module]: from holodata import sub",
    ]                                         # ``from .. import VERSION``: the grandparent, a graph edge only


def test_no_module_imports_its_own_parent_package():
    found = parent_package_imports()
    assert not found, ("module(s) importing their own parent package (import from the sibling module that "
                       "holds the code instead):\n" + "\n".join(found))


def _face_code(path: Path) -> list[str]:
    """What a package ``__init__`` holds besides its docstring, imports, ``__all__`` and constants
    (names bound to a literal: ``ast.literal_eval`` reads it): ``"line: statement"`` each."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out = []
    for i, stmt in enumerate(tree.body):
        if i == 0 and isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant) \
                and isinstance(stmt.value.value, str):
            continue
        if isinstance(stmt, (ast.Import, ast.ImportFrom)):
            continue
        if isinstance(stmt, (ast.Assign, ast.AnnAssign)) and stmt.value is not None:
            names = stmt.targets if isinstance(stmt, ast.Assign) else [stmt.target]
            if all(isinstance(t, ast.Name) for t in names):
                try:
                    ast.literal_eval(stmt.value)
                    continue
                except ValueError:
                    pass
        out.append(f"{stmt.lineno}: {ast.unparse(stmt).splitlines()[0][:80]}")
    return out


def test_face_code_finder(tmp_path):
    f = tmp_path / "__init__.py"
    f.write_text('"""Doc."""\nfrom __future__ import annotations\nimport os\nfrom .a import b as b\n'
                 'X = (1, "a")\nY: dict = {"k": [1.0, None]}\n__all__ = ["b", "X"]\n')
    assert _face_code(f) == []
    f.write_text('"""Doc."""\nZ = {t: 1 for t in "ab"}\ndef f():\n    pass\nclass C:\n    pass\n'
                 'for _x in ():\n    pass\n"""not the docstring"""\n')
    assert _face_code(f) == ["2: Z = {t: 1 for t in 'ab'}", "3: def f():", "5: class C:", "7: for _x in ():",
                             "9: 'not the docstring'"]


def test_package_faces_hold_no_code():
    """Every ``__init__.py`` under holodata/ is its package's face: the docstring (the package's
    documentation), imports from its modules, ``__all__`` and constants; the code lives in named
    modules (issue 25: register, segment, ingest, slam, synth and readers held their stage code
    there). The few faces that still hold code are :data:`FACES_WITH_CODE`, each with its reason; one
    that no longer does leaves that list."""
    faces = {p.relative_to(ROOT.parent).as_posix(): p for p in sorted(ROOT.rglob("__init__.py"))}
    assert "holodata/mapping/register/__init__.py" in faces
    assert set(faces) >= FACES_WITH_CODE, f"allowed faces that are gone: {sorted(FACES_WITH_CODE - set(faces))}"
    code = {name: _face_code(p) for name, p in faces.items()}
    bad = {name: c for name, c in code.items() if c and name not in FACES_WITH_CODE}
    assert not bad, "package __init__.py holding code (move it into a named module of the package):\n" + \
        "\n".join(f"{name}: {'; '.join(c)}" for name, c in bad.items())
    stale = sorted(name for name in FACES_WITH_CODE if not code[name])
    assert not stale, f"faces in FACES_WITH_CODE that hold no code any more (remove them from it): {stale}"
