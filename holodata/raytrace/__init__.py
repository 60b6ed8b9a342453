"""raytrace stage: multi-bounce specular ray tracing through a static mesh plus a per-frame
dynamic (human) mesh, with LOS/NLOS x human/structure labels and semantic classes."""
from .backends import BACKENDS, DEFAULT_BACKEND, available_backends, make_backend, register_backend
from .labels import GEOMETRIC_CLASS_NAMES, geometric_classes
from .trace import SELF_HIT_OFFSET_M, CastResult, FixedRays, RayScene, TraceResult, trace

__all__ = [
    "BACKENDS", "DEFAULT_BACKEND", "available_backends", "make_backend", "register_backend",
    "GEOMETRIC_CLASS_NAMES", "geometric_classes", "SELF_HIT_OFFSET_M", "CastResult", "FixedRays", "RayScene",
    "TraceResult", "trace",
]
