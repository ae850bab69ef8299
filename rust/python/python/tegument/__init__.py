"""Tegument: shape-preserving skin deformation and content-aware UV warps.

The numeric core of the Tegument Blender add-on, usable on its own from any
CPython >= 3.11 with numpy. Every function takes and returns numpy arrays:
float32 positions of shape ``(N, 3)``, int32 indices, in Blender's mesh layout
(``corner_verts`` and ``polygon_sizes``). Anything refused raises
:class:`TegumentError`, a subclass of :class:`ValueError`, whose message names
what is wrong and where.
"""

from ._native import (
    Collider,
    Dynamics,
    Mesh,
    PyramidDeformer,
    TegumentError,
    UvWarp,
    __version__,
    audit,
    read_exr,
    transform_points,
    write_exr,
)

__all__ = [
    "Collider",
    "Dynamics",
    "Mesh",
    "PyramidDeformer",
    "TegumentError",
    "UvWarp",
    "__version__",
    "audit",
    "read_exr",
    "transform_points",
    "write_exr",
]
