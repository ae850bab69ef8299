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
