"""Typed stubs of the native module (kept in step with the Rust docstrings)."""

from typing import Any

import numpy as np
import numpy.typing as npt

__version__: str

class TegumentError(ValueError):
    """Raised for any input Tegument refuses; the message names what is wrong and where."""

class Mesh:
    """The topology of a polygon mesh given in Blender's layout."""

    def __init__(
        self,
        positions: npt.NDArray[np.float32],
        corner_verts: npt.NDArray[np.int32],
        polygon_sizes: npt.NDArray[np.int32],
    ) -> None: ...
    @property
    def vertex_count(self) -> int: ...
    @property
    def polygon_count(self) -> int: ...
    def edges(self) -> npt.NDArray[np.int32]:
        """Unique edges ``(E, 2)``, each ``[low, high]``, sorted."""
    def boundary_vertices(self) -> npt.NDArray[np.int32]:
        """Indices of the vertices on a boundary edge."""
    def one_ring(self, i: int) -> npt.NDArray[np.int32]:
        """Neighbours of vertex ``i``, counter-clockwise around the surface normal."""
    def problem_vertices(self) -> npt.NDArray[np.int32]:
        """Vertices an artist should look at (non-manifold, degenerate, isolated)."""
    def report(self) -> dict[str, Any]:
        """Counts of everything unusual, plus ``is_closed_manifold`` and ``is_clean``."""

class PyramidDeformer:
    """Pyramid-coordinate deformer: keeps the local shape of the rest mesh on top
    of whatever deformation the input positions carry (armature, shape keys).

    Boundary, non-manifold and degenerate vertices cannot be encoded: they follow
    the input and are listed in ``pinned_vertices``.
    """

    def __init__(
        self,
        rest_positions: npt.NDArray[np.float32],
        corner_verts: npt.NDArray[np.int32],
        polygon_sizes: npt.NDArray[np.int32],
        scale_safe: bool = True,
    ) -> None: ...
    @property
    def vertex_count(self) -> int:
        """Number of vertices of the bound mesh."""
    @property
    def pinned_vertices(self) -> npt.NDArray[np.int32]:
        """Vertices the bind could not encode (they follow the input), ascending."""
    def solve(
        self,
        positions: npt.NDArray[np.float32],
        iterations: int = 10,
        closeness: float | npt.NDArray[np.float32] | None = None,
    ) -> npt.NDArray[np.float32]:
        """Solves one frame; ``closeness`` is None (0.1), a float or a float32 ``(N,)`` array in ``[0, 1]``."""
    def residual(self, positions: npt.NDArray[np.float32]) -> float:
        """Mean pyramid residual relative to the mean rest edge length (0 at rest)."""
