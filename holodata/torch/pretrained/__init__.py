"""The weights holodata ships: stage-one + stage-two runs trained by ``benchmarks/nlos.py --install`` on a
synthetic training corpus (:mod:`holodata.synth.corpus`), one per beam grid (:data:`GRID_DIRS`:
``weights/`` at the quick demo's 32×128, ``weights_64x512/`` at the paper's grid when shipped), each a run
directory (``checkpoint.pt``, ``stage2.pt``) without optimiser state. ``checkpoint["pretrained"]``
records the command, commit, corpora and the scores on held-out corners; ``tests/torch_/test_pretrained.py``
rescores the check set and compares.

``holodata evaluate DS --checkpoint pretrained`` and ``holodata train DS --init pretrained`` name it;
:func:`resolve` turns the name (or any run path) into a path, the run trained for the dataset's grid.
"""
from __future__ import annotations

from .packaged import CHECK_SET, GRID_DIRS, NAME, SCORE_KEYS, WEIGHTS, grid_key, install, installed, resolve, scores

__all__ = ["CHECK_SET", "GRID_DIRS", "NAME", "SCORE_KEYS", "WEIGHTS", "grid_key", "install", "installed", "resolve", "scores"]
