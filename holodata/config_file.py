"""Stage settings from one YAML (or JSON) file: ``holodata slam|register|raytrace-gt|train --config FILE``.

The file is a mapping of sections to fields of the stages' config dataclasses::

    slam:      {voxel: 0.3, max_range: 60.0}        # holodata.mapping.slam.SlamConfig
    mesh:      {voxel: 0.04}                        # holodata.mapping.mesh.MeshConfig
    segment:   {...}                                # holodata.mapping.segment.SegmentConfig
    register:  {guess_std_m: 0.05}                  # holodata.mapping.register.RegisterConfig
    gt:        {max_bounces: 3, max_range: 9.6}     # holodata.groundtruth.GTConfig
    train:     {epochs: 30}                         # holodata.torch.TrainConfig

``examples/holodata.yaml`` is a commented one. Precedence: a flag given on the command line, then
the file, then the dataclass's default (the commands' flags default to None, "not given", and
:func:`build` takes only the given ones; the dataclass is the one place of every default). Unknown
sections or fields are a one-line error naming the file. The resolved configs are what the stages
record in the scene attributes, as without a file.
"""
from __future__ import annotations

import dataclasses
import importlib
import json
from pathlib import Path

from .errors import InputError

SECTIONS = {
    "slam": "holodata.mapping.slam.config:SlamConfig",
    "mesh": "holodata.mapping.mesh:MeshConfig",
    "segment": "holodata.mapping.segment.config:SegmentConfig",
    "register": "holodata.mapping.register.config:RegisterConfig",
    "gt": "holodata.groundtruth:GTConfig",
    "train": "holodata.torch.train:TrainConfig",
}


def config_class(section: str):
    mod, _, name = SECTIONS[section].partition(":")
    return getattr(importlib.import_module(mod), name)


def read(path) -> dict:
    """The file's sections {name: {field: value}}, every section and field checked (one-line
    :class:`InputError` naming the file otherwise)."""
    import yaml

    p = Path(path)
    try:
        text = p.read_text()
    except OSError as err:
        raise InputError(f"{p}: cannot read the config file ({err.strerror or err})") from err
    try:
        data = json.loads(text) if p.suffix == ".json" else yaml.safe_load(text)
    except (ValueError, yaml.YAMLError) as err:
        raise InputError(f"{p}: not a YAML/JSON mapping ({' '.join(str(err).split())[:120]})") from err
    data = data or {}
    if not isinstance(data, dict):
        raise InputError(f"{p}: a config file is a mapping of sections ({', '.join(SECTIONS)})")
    unknown = sorted(set(data) - set(SECTIONS))
    if unknown:
        raise InputError(f"{p}: unknown section(s) {', '.join(unknown)} (sections: {', '.join(SECTIONS)})")
    for name, body in data.items():
        if not isinstance(body, dict):
            raise InputError(f"{p}: section {name!r} must be a mapping of field: value")
        names = {f.name for f in dataclasses.fields(config_class(name))}
        bad = sorted(set(body) - names)
        if bad:
            raise InputError(f"{p}: unknown {name} field(s) {', '.join(bad)}")
    return data


def _convert(cls, values: dict) -> dict:
    """YAML values → the dataclass's field types where YAML has no such type: tuples (lists in
    YAML), the beam grid ("64x512"), a beam-origin model (its attrs mapping)."""
    out = dict(values)
    defaults = cls()
    for f in dataclasses.fields(cls):
        if f.name not in out:
            continue
        cur, v = getattr(defaults, f.name), out[f.name]
        if isinstance(cur, tuple) and isinstance(v, list):
            out[f.name] = tuple(v)
        elif f.name == "grid" and isinstance(v, str):
            from .conventions import Grid

            out[f.name] = Grid.parse(v)
        elif f.name == "origin" and isinstance(v, dict):
            from .beams import OriginModel

            out[f.name] = OriginModel.from_attrs(v)
    return out


def build(section: str, path=None, flags: dict | None = None):
    """The ``section`` config: the dataclass's defaults, overridden by the file's section (``path``;
    None: no file), overridden by the ``flags`` {field: value} that are not None (the flags given on
    the command line; a flag not given is None)."""
    cls = config_class(section)
    given = {k: v for k, v in (flags or {}).items() if v is not None}
    if path is None:
        return cls(**given)
    body = read(path).get(section, {})
    try:
        return cls(**{**_convert(cls, body), **given})
    except (TypeError, ValueError) as err:
        raise InputError(f"{path}: section {section!r}: {' '.join(str(err).split())[:160]}") from err


__all__ = ["SECTIONS", "read", "build", "config_class"]
