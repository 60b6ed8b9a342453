"""The house stays readable (the architecture issue's figures, measured by scripts/house.py): no function
over 80 lines or over 8 parameters outside numba kernels and click commands, the radar's maximum range
typed only in conventions.py, no package face with code, no function-level import of a module's own parent package."""
import importlib.util

from _paths import REPO


def _house():
    spec = importlib.util.spec_from_file_location("house", REPO / "scripts" / "house.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_house_figures():
    m = _house().measure()
    assert m["functions_over_lines"] == [], m["functions_over_lines"]
    assert m["functions_over_params"] == [], m["functions_over_params"]
    assert m["max_range_literals"] == [], m["max_range_literals"]
    assert m["face_code_lines"] == [], m["face_code_lines"]
    assert m["function_level_parent_imports"] == [], m["function_level_parent_imports"]


def test_house_counts_what_it_says(tmp_path, monkeypatch):
    """The counter itself: a long function, a many-parameter one, a kernel and a face with code are seen."""
    house = _house()
    pkg = tmp_path / "holodata"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text('"""doc"""\nimport os\n__all__ = ["os"]\n')
    (pkg / "sub" / "__init__.py").write_text('"""doc"""\nX = 9.6\n\n\ndef f():\n    return X\n')
    body = "\n".join(f"    x{i} = {i}" for i in range(81))
    (pkg / "sub" / "mod.py").write_text(
        f"def long():\n{body}\n\n\ndef many(a, b, c, d, e, f, g, h, i):\n    pass\n\n\n"
        f"@njit\ndef kernel(a, b, c, d, e, f, g, h, i):\n{body}\n\n\n"
        "def lazy():\n    from holodata.sub import X\n    return X\n")
    monkeypatch.setattr(house, "ROOT", tmp_path)
    m = house.measure()
    assert [r[2] for r in m["functions_over_lines"]] == ["long"]
    assert [r[2] for r in m["functions_over_params"]] == ["many"]
    assert m["max_range_literals"] == [("holodata/sub/__init__.py", 2)]
    assert m["face_code_lines"] == [("holodata/sub/__init__.py", 2)]   # the function, not the constant
    assert [(f, t) for f, _, t in m["function_level_parent_imports"]] == [("holodata/sub/mod.py", "holodata.sub")]
