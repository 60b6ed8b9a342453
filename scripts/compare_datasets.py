"""Compare two holodata datasets array by array: which arrays hold different bytes, which attributes differ.

The check behind "outputs stay byte-identical" (issue 25): run the same command (e.g. ``holodata demo
--quick``) from two source trees, then

    .venv/bin/python scripts/compare_datasets.py BEFORE/dataset.zarr AFTER/dataset.zarr [--timings]

Every array of every scene is read whole and hashed (SHA-256 of dtype, shape and C-order bytes), so a
re-chunked or re-compressed array with the same values counts as identical. Attributes are compared
key by key after flattening nested dicts (``register.params.search_m``); keys that are run times
(``seconds``, ``timings``, ``*_s`` under a ``timings`` dict) are left out unless ``--timings``.
Exit code 0 when every array is identical, 1 otherwise.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import warnings

import numpy as np
import zarr


def array_digests(group, prefix: str = "") -> tuple[dict[str, str], dict[str, dict]]:
    """``{path: sha256 hex}`` of every array under ``group`` and ``{path: attrs}`` of every node."""
    digests: dict[str, str] = {}
    attrs: dict[str, dict] = {prefix or "/": dict(group.attrs)}
    for name, arr in group.arrays():
        data = np.ascontiguousarray(arr[...])
        h = hashlib.sha256(f"{data.dtype.str} {data.shape}".encode())
        h.update(data.tobytes())
        digests[prefix + name] = h.hexdigest()
        attrs[prefix + name] = dict(arr.attrs)
    for name, sub in group.groups():
        d, a = array_digests(sub, prefix + name + "/")
        digests.update(d)
        attrs.update(a)
    return digests, attrs


def flatten(value, key: str = "") -> dict[str, str]:
    """Nested dicts as ``{"a.b.c": json}``; lists and scalars are leaves."""
    if isinstance(value, dict):
        out: dict[str, str] = {}
        for k, v in value.items():
            out.update(flatten(v, f"{key}.{k}" if key else str(k)))
        return out
    return {key: json.dumps(value, sort_keys=True, default=str)}


def is_timing(key: str) -> bool:
    parts = key.split(".")
    return "timings" in parts or parts[-1] == "seconds"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--timings", action="store_true", help="also report differing run times")
    args = ap.parse_args(argv)
    with warnings.catch_warnings():  # the manifest/ folder beside the hierarchy is not a zarr node
        warnings.simplefilter("ignore")
        da, aa = array_digests(zarr.open_group(args.before, mode="r"))
        db, ab = array_digests(zarr.open_group(args.after, mode="r"))
    differ = 0
    for path in sorted(set(da) | set(db)):
        if da.get(path) != db.get(path):
            differ += 1
            state = "only in before" if path not in db else "only in after" if path not in da else "values differ"
            print(f"array {path}: {state}")
    for path in sorted(set(aa) | set(ab)):
        fa, fb = flatten(aa.get(path, {})), flatten(ab.get(path, {}))
        keys = [k for k in sorted(set(fa) | set(fb)) if fa.get(k) != fb.get(k) and (args.timings or not is_timing(k))]
        if keys:
            print(f"attrs {path}: {', '.join(keys)}")
    print(f"{len(set(da) | set(db)) - differ} arrays identical, {differ} differ")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
