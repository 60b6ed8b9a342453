"""No import cycles in holodata/ (issue 25, point 3): every import, at module level or inside a
function, is an edge; a strongly connected component of more than one module is a cycle.

KNOWN lists cycles tolerated for a while (none now: the Dask executor called back into the stages it
ran until each stage owned its task function). Imports under ``if TYPE_CHECKING:`` (annotations only) never
run and are left out. The test fails on any other cycle, and on a listed one that is gone (delete it here)."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "holodata"
KNOWN: set[frozenset] = set()


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """{module: modules of the package it imports} (relative imports resolved; ``from pkg import
    sub`` is an edge to ``pkg.sub`` when that is a module; a module's own parent packages left out)."""
    mods = {}
    for p in root.rglob("*.py"):
        parts = ("holodata",) + p.relative_to(root).with_suffix("").parts
        mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    edges: dict[str, set[str]] = {m: set() for m in mods}
    for m, p in mods.items():
        pkg = m.split(".") if p.name == "__init__.py" else m.split(".")[:-1]
        tree = ast.parse(p.read_text())
        typing_only = {id(x) for b in ast.walk(tree) if isinstance(b, ast.If) and "TYPE_CHECKING" in ast.unparse(b.test)
                       for x in ast.walk(b)}              # imports for annotations only never run
        for n in ast.walk(tree):
            if id(n) in typing_only:
                continue
            if isinstance(n, ast.ImportFrom):
                base = ".".join((pkg[:len(pkg) - n.level + 1] if n.level else []) + ([n.module] if n.module else []))
                subs = [f"{base}.{a.name}" for a in n.names if f"{base}.{a.name}" in mods]
                targets = subs or [base]
            elif isinstance(n, ast.Import):
                targets = [a.name for a in n.names]
            else:
                continue
            edges[m] |= {t for t in targets if t in mods and t != m and not m.startswith(t + ".")}
    return edges


def cycles(edges: dict[str, set[str]]) -> list[frozenset]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]
    for start in edges:
        if start in index:
            continue
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = counter[0]
        counter[0] += 1
        stack.append(start)
        on.add(start)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(edges[w]))))
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
    return out


def test_cycle_finder_finds_a_cycle_and_no_false_one():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [frozenset("abc")]
    assert cycles({"a": {"b"}, "b": set(), "c": {"a", "b"}}) == []


def test_no_import_cycle_but_the_known_ones():
    found = set(cycles(import_graph()))
    assert found - KNOWN == set(), f"new import cycle(s): {[sorted(c) for c in found - KNOWN]}"
    assert KNOWN - found == set(), f"gone (delete from KNOWN): {[sorted(c) for c in KNOWN - found]}"
