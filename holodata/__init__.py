"""holodata: multi-bounce radar ground truth datasets.

Public API (docs/format.md §6): :func:`open_dataset`, :mod:`holodata.metrics`,
:func:`holodata.raytrace.trace`, :mod:`holodata.torch`. Subpackages are imported on first use
(``holodata.raytrace`` works after a plain ``import holodata``; :mod:`holodata._lazy`), so ``import
holodata`` stays fast and ``holodata.torch`` needs the ``train`` extra only when it is touched.
"""
from __future__ import annotations

from ._lazy import SUBMODULES, open_dataset
from ._lazy import __dir__ as __dir__  # PEP 562: the module's own dir() and attribute hook
from ._lazy import __getattr__ as __getattr__

__version__ = "0.1.0"

__all__ = ["open_dataset", "__version__", "SUBMODULES"]
