"""The weights holodata ships: a stage-one + stage-two run trained by ``benchmarks/nlos.py --install`` at
the quick demo's settings (32×128 beams, the default range bins) on a synthetic training corpus
(:mod:`holodata.synth.corpus`), stored here as a run directory (``weights/checkpoint.pt``,
``weights/stage2.pt``) without optimiser state. ``checkpoint["pretrained"]`` records the command,
commit, corpora and the scores on held-out corners; ``tests/test_pretrained.py`` rescores the
check set and compares.

``holodata evaluate DS --checkpoint pretrained`` and ``holodata train DS --init pretrained``
name it; :func:`resolve` turns the name (or any run path) into a path.
"""
from __future__ import annotations

from .packaged import CHECK_SET, NAME, SCORE_KEYS, WEIGHTS, install, resolve, scores

__all__ = ["CHECK_SET", "NAME", "SCORE_KEYS", "WEIGHTS", "install", "resolve", "scores"]
