"""JSON Schemas of the dataset root and scene attributes (package ``holodata.schemas``)."""
from __future__ import annotations

import json
from functools import cache
from importlib import resources


@cache
def load_schema(name: str) -> dict:
    """``name``: 'dataset' | 'scene' | 'metrics' -> the parsed ``<name>.schema.json``."""
    return json.loads(resources.files("holodata.schemas").joinpath(f"{name}.schema.json").read_text())


@cache
def _validator(name: str):
    import jsonschema

    schema = load_schema(name)
    cls = jsonschema.validators.validator_for(schema)
    return cls(schema)


def schema_errors(name: str, instance) -> list[str]:
    """One line per violation of schema ``name`` ('path: message'), [] when valid."""
    out = []
    for e in sorted(_validator(name).iter_errors(instance), key=lambda e: list(map(str, e.path))):
        where = "/".join(str(p) for p in e.path) or "(root)"
        out.append(f"{where}: {' '.join(e.message.split())[:200]}")
    return out
