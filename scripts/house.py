"""The house's figures (what a newcomer trips over), measured from the source with ``ast``.

Prints, for ``holodata/`` (its CLI included):

- functions longer than ``--max-lines`` lines (def line to last line, docstring included), and
  functions with more than ``--max-params`` parameters (``self``/``cls`` not counted), except numba
  kernels (decorated ``njit``/``jit``/``vectorize``), click commands (decorated ``click.*``/``*.command``)
  and dataclass-generated constructors (which are not in the source);
- the radar's maximum range typed as a literal (``9.6``) outside ``holodata/conventions.py``;
- lines of code (not docstring, imports, ``__all__`` or constants) in package faces (``__init__.py``);
- function-level imports of a module's own parent package (``from holodata.x import y`` inside a
  function of ``holodata/x/z.py``, or ``from . import``/``from .. import`` reaching it).

``--json`` prints the same as one JSON object; ``--list`` names every offender.
"""
from __future__ import annotations

import argparse
import ast
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KERNEL_DECORATORS = {"njit", "jit", "vectorize", "guvectorize", "stencil"}


def _decorator_names(fn: ast.AST) -> set[str]:
    out = set()
    for d in getattr(fn, "decorator_list", []):
        d = d.func if isinstance(d, ast.Call) else d
        parts = []
        while isinstance(d, ast.Attribute):
            parts.append(d.attr)
            d = d.value
        if isinstance(d, ast.Name):
            parts.append(d.id)
        out.update(parts)
    return out


def _exempt(fn: ast.AST) -> str | None:
    names = _decorator_names(fn)
    if names & KERNEL_DECORATORS:
        return "numba kernel"
    if "click" in names or "command" in names or "group" in names:
        return "click command"
    return None


def _n_params(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = fn.args
    names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
    if names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names) + (a.vararg is not None) + (a.kwarg is not None)


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _face_code_lines(tree: ast.Module) -> int:
    n = 0
    for i, node in enumerate(tree.body):
        if i == 0 and isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            continue   # the docstring
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            continue
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            continue
        if isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None and _constant(node.value):
            continue   # a constant (__version__ = "0.1.0"), as the import-graph test allows
        n += node.end_lineno - node.lineno + 1
    return n


def _constant(node: ast.AST) -> bool:
    """A literal, or a tuple/list/set of literals."""
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return all(_constant(e) for e in node.elts)
    return isinstance(node, ast.Constant)


def _parent_imports(tree: ast.Module, module: str, is_package: bool) -> list[tuple[int, str]]:
    """Imports inside functions of the module's own parent package (the package face)."""
    pkg = module if is_package else module.rpartition(".")[0]
    parent = pkg if not is_package else pkg.rpartition(".")[0]
    owner = module.rpartition(".")[0]   # the package whose face this module sits under
    out = []
    for fn in ast.walk(tree):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(fn):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = module.split(".")[: len(module.split(".")) - node.level + (1 if is_package else 0)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            pkg_dir = ROOT.joinpath(*target.split("."))
            submodules = all((pkg_dir / f"{a.name}.py").is_file() or (pkg_dir / a.name).is_dir() for a in node.names)
            if target in {owner, parent} - {""} and target != module and not submodules:
                out.append((node.lineno, target))
    return out


def measure(max_lines: int = 80, max_params: int = 8) -> dict:
    files = sorted((ROOT / "holodata").rglob("*.py"))
    long_fns, many_params, literals, faces, cycles = [], [], [], [], []
    for path in files:
        rel = str(path.relative_to(ROOT))
        tree = ast.parse(path.read_text(), filename=rel)
        for fn in ast.walk(tree):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)) and not _exempt(fn):
                n = fn.end_lineno - fn.lineno + 1
                if n > max_lines:
                    long_fns.append((rel, fn.lineno, fn.name, n))
                p = _n_params(fn)
                if p > max_params:
                    many_params.append((rel, fn.lineno, fn.name, p))
        if rel != "holodata/conventions.py":
            for node in ast.walk(tree):
                if isinstance(node, ast.Constant) and isinstance(node.value, float) and node.value == 9.6:
                    literals.append((rel, node.lineno))
        if path.name == "__init__.py":
            faces.append((rel, _face_code_lines(tree)))
        for line, target in _parent_imports(tree, _module_name(path), path.name == "__init__.py"):
            cycles.append((rel, line, target))
    return {"functions_over_lines": sorted(long_fns, key=lambda r: -r[3]),
            "functions_over_params": sorted(many_params, key=lambda r: -r[3]),
            "max_range_literals": literals,
            "face_code_lines": sorted([f for f in faces if f[1]], key=lambda r: -r[1]),
            "function_level_parent_imports": cycles,
            "limits": {"lines": max_lines, "params": max_params}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--max-lines", type=int, default=80)
    ap.add_argument("--max-params", type=int, default=8)
    ap.add_argument("--list", action="store_true", help="name every offender")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    m = measure(a.max_lines, a.max_params)
    if a.json:
        print(json.dumps(m, indent=1))
        return
    print(f"functions over {a.max_lines} lines: {len(m['functions_over_lines'])}")
    print(f"functions over {a.max_params} parameters: {len(m['functions_over_params'])}")
    print(f"9.6 literals outside conventions.py: {len(m['max_range_literals'])}")
    print(f"package faces with code beyond docstring/imports/__all__: {len(m['face_code_lines'])} "
          f"({sum(n for _, n in m['face_code_lines'])} lines)")
    print(f"function-level imports of a parent package: {len(m['function_level_parent_imports'])}")
    if a.list:
        for key in ("functions_over_lines", "functions_over_params", "max_range_literals", "face_code_lines",
                    "function_level_parent_imports"):
            print(f"\n{key}:")
            for row in m[key]:
                print("  " + ":".join(str(x) for x in row))


if __name__ == "__main__":
    main()
