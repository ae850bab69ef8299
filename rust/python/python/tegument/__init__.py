"""Tegument: shape-preserving skin deformation and content-aware UV warps.

The numeric core of the Tegument Blender add-on, usable on its own from any
CPython >= 3.11 with numpy. Every function takes and returns numpy arrays:
float32 positions of shape ``(N, 3)``, int32 indices, in Blender's mesh layout
(``corner_verts`` and ``polygon_sizes``). Arrays of other float or integer
dtypes, or not C-contiguous, are converted (one copy); indices must fit int32.
Reports are the frozen classes of :mod:`tegument.results`. Anything refused
raises :class:`TegumentError`, a subclass of :class:`ValueError`, whose message
names what is wrong and where.
"""

from ._native import (
    Collider,
    Dynamics,
    Mesh,
    PyramidDeformer,
    SelfCollision,
    TegumentError,
    UvWarp,
    __version__,
    audit,
    rasterise_corner_values,
    read_exr,
    resample_image,
    stretch_map,
    transform_points,
    write_exr,
)
from ._native import _defaults
from .results import AuditReport, ColliderUpdate, Defaults, MeshReport, StepReport, WarpMetrics

DEFAULTS: Defaults = Defaults(**_defaults())
"""The default of every setting, from the core (the bindings' keyword defaults are these values)."""

__all__ = [
    "DEFAULTS",
    "AuditReport",
    "Collider",
    "ColliderUpdate",
    "Defaults",
    "MeshReport",
    "StepReport",
    "WarpMetrics",
    "Dynamics",
    "Mesh",
    "PyramidDeformer",
    "SelfCollision",
    "TegumentError",
    "UvWarp",
    "__version__",
    "audit",
    "rasterise_corner_values",
    "read_exr",
    "resample_image",
    "stretch_map",
    "transform_points",
    "write_exr",
]
