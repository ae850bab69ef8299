"""Typed stubs of the native module (kept in step with the Rust docstrings)."""

import os
from typing import Literal, Any, Sequence

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

def transform_points(points: npt.NDArray[np.float32], matrix: npt.NDArray[np.float64]) -> npt.NDArray[np.float32]:
    """``matrix @ (x, y, z, 1)`` for float32 ``(N, 3)`` points; ``matrix`` float64 ``(4, 4)``
    row-major (``numpy.array(obj.matrix_world)``), affine part only, in double precision."""

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
    def step(
        self,
        positions: npt.NDArray[np.float32],
        colliders: Sequence[Collider] | None = None,
        iterations: int = 10,
        closeness: float | npt.NDArray[np.float32] | None = None,
        substeps: int = 1,
        dynamics: Dynamics | None = None,
        max_stretch: float | npt.NDArray[np.float32] | None = None,
        strain_mode: Literal["unified", "post"] = "unified",
    ) -> npt.NDArray[np.float32]:
        """Solves the next frame of an animation against ``colliders`` (updated to this frame),
        starting from the last output (history-based, two collision passes); float32 ``(N, 3)``.
        ``substeps`` splits the frame; ``dynamics`` adds inertia; ``max_stretch`` (ε, or per vertex)
        limits edges to (1 + ε)·rest length, with the contacts (``"unified"``) or after them
        (``"post"``); compliant colliders are solved too."""
    @property
    def velocity(self) -> npt.NDArray[np.float32] | None:
        """Velocities at the end of the last dynamic ``step`` ``(N, 3)``, or None."""
    def reset(self, history: npt.NDArray[np.float32] | None = None) -> None:
        """Forgets the last output: the next ``step`` starts from its input, or from ``history``
        (collision-free positions, e.g. the last cached frame of a bake being resumed)."""
    @property
    def last_step(self) -> dict[str, Any] | None:
        """What the last ``step`` did: ``first_pass_contacts``, ``first_pass_moved``,
        ``in_loop_contacts``, ``max_in_loop_correction``, ``pinched`` (int32 array),
        ``kinetic_energy``, ``worst_stretch``, ``compliant_contacts``, ``compliant_skin_vertices``,
        ``max_recession``."""
    def residual(self, positions: npt.NDArray[np.float32]) -> float:
        """Mean pyramid residual relative to the mean rest edge length (0 at rest)."""

class Dynamics:
    """Dynamics settings for ``PyramidDeformer.step``: frame time (s), surface density,
    damping rate (1/s) and gravity (units/s², off by default)."""

    def __init__(
        self,
        frame_time: float = 1.0 / 24.0,
        mass: float = 1.0,
        damping: float = 1.0,
        gravity: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None: ...
    @property
    def frame_time(self) -> float: ...
    @property
    def mass(self) -> float: ...
    @property
    def damping(self) -> float: ...
    @property
    def gravity(self) -> tuple[float, float, float]: ...

class Collider:
    """A kinematic triangle-mesh collider that keeps last frame's positions.

    ``positions`` is float32 ``(N, 3)`` in world space, ``triangles`` int32
    ``(T, 3)``. ``thickness`` is the distance kept between skin and surface;
    ``friction`` the static friction coefficient (and the kinetic one unless
    ``kinetic_friction`` is given). Call :meth:`update` once per frame with the
    new world positions: the collider then moves from the previous positions
    to these over the frame, which is what continuous collision detection sees.
    """

    def __init__(
        self,
        positions: npt.NDArray[np.float32],
        triangles: npt.NDArray[np.int32],
        thickness: float = 0.0,
        friction: float = 0.0,
        kinetic_friction: float | None = None,
    ) -> None: ...
    def update(self, positions: npt.NDArray[np.float32]) -> dict[str, Any]:
        """Next frame: current positions become the previous ones; ``positions`` (same N)
        the current ones. Refits the BVH (rebuilds it when degraded). Returns
        ``{"cost_ratio": float, "rebuilt": bool}``."""
    def place(self, positions: npt.NDArray[np.float32]) -> None:
        """Puts the collider at ``positions`` without motion; a compliant collider keeps its goals."""
    def hold(self) -> None:
        """Forgets the motion (previous = current), e.g. after a jump in time."""
    def set_compliance(self, stiffness: float | npt.NDArray[np.float32] | None) -> None:
        """Makes vertices compliant: a stiffness density per vertex (float32 ``(N,)``), one for all,
        or None (kinematic). 0 = kinematic; 1000 weighs as much as the skin's own shape."""
    @property
    def is_compliant(self) -> bool:
        """Whether any vertex is compliant."""
    @property
    def goal_positions(self) -> npt.NDArray[np.float32]:
        """The animated positions this frame ``(N, 3)`` (for a compliant collider, its goals)."""
    @property
    def vertex_count(self) -> int:
        """Number of vertices."""
    @property
    def triangle_count(self) -> int:
        """Number of triangles."""
    @property
    def thickness(self) -> float:
        """Distance kept between the skin and the surface."""
    @property
    def friction(self) -> float:
        """Static friction coefficient."""
    @property
    def kinetic_friction(self) -> float:
        """Kinetic friction coefficient."""
    @property
    def is_closed(self) -> bool:
        """Whether every edge has exactly two triangles (the audit's inside test needs it)."""
    @property
    def positions(self) -> npt.NDArray[np.float32]:
        """This frame's positions ``(N, 3)``."""
    @property
    def previous_positions(self) -> npt.NDArray[np.float32]:
        """Last frame's positions ``(N, 3)``."""
    @property
    def triangles(self) -> npt.NDArray[np.int32]:
        """Triangles ``(T, 3)``."""
    def edges(self) -> npt.NDArray[np.int32]:
        """Unique edges ``(E, 2)``; rows referred to by the audit's collider edge indices."""
    @property
    def bvh_rebuilds(self) -> int:
        """How many times the BVH was rebuilt because refitting had degraded it."""

def audit(
    positions: npt.NDArray[np.float32],
    corner_verts: npt.NDArray[np.int32],
    polygon_sizes: npt.NDArray[np.int32],
    colliders: Sequence[Collider],
    depth_tolerance: float = 1e-4,
) -> dict[str, Any]:
    """Penetration audit of a mesh against colliders at their current positions.

    Returns counts ``vertices_inside`` (inside a closed collider deeper than
    ``depth_tolerance``), ``edges_crossing`` (mesh edges through collider
    triangles), ``collider_edges_crossing`` (collider edges through mesh polygons),
    the index arrays ``vertices_inside_indices`` ``(K,)``, ``edges_crossing_indices``
    ``(K, 2)``, ``collider_edges_crossing_indices`` ``(K, 2)`` (collider, edge), and
    ``open_colliders`` (skipped by the inside test).
    """

class UvWarp:
    """Content-aware UV warp of one mesh (hierarchical position-based dynamics on a
    UV-space grid, one grid per UDIM tile).

    Images are float32 ``(height, width)`` arrays with row 0 = the lowest v
    (texel ``(row j, column i)`` covers ``u ∈ [i/width, (i+1)/width)``,
    ``v ∈ [j/height, (j+1)/height)``): Blender's ``Image.pixels`` order.
    ``rigidity``/``mask`` may be a dict ``{udim: array}`` for UDIM layouts; then
    the per-tile results are dicts too.
    """

    def __init__(
        self,
        width: int,
        height: int,
        rest_positions: npt.NDArray[np.float32],
        corner_verts: npt.NDArray[np.int32],
        polygon_sizes: npt.NDArray[np.int32],
        corner_uvs: npt.NDArray[np.float32],
        rigidity: npt.NDArray[np.float32] | dict[int, npt.NDArray[np.float32]],
        mask: npt.NDArray[np.float32] | dict[int, npt.NDArray[np.float32]] | None = None,
        iterations: int = 4,
        orientation: float = 0.05,
        smoothing: float = 0.1,
        warm_start: bool = True,
        memory_limit: int | None = None,
        sample_warped: bool = False,
    ) -> None: ...
    def solve(self, deformed_positions: npt.NDArray[np.float32]) -> Any:
        """Solve for this frame; returns the UV redirection ``(height, width, 2)`` float32
        (absolute UVs: sample the texture at ``redirection(t)``), or ``{udim: array}``."""
    def redirection(self) -> Any:
        """The latest redirection, as ``solve`` returns it (identity before the first solve)."""
    def validity(self) -> Any:
        """``(height, width)`` float32: 1 inside UV charts, 0 outside."""
    def displacement(self) -> Any:
        """Forward warp as texel displacements ``(height, width, 2)``."""
    def metrics(self, deformed_positions: npt.NDArray[np.float32]) -> dict[Any, Any]:
        """Stretch error of rigid texels (identity vs warped: mean, p95, max), fold-overs,
        largest masked displacement, round-trip error (texels)."""
    def reset(self) -> None:
        """Forget the previous frame: the next solve starts from the identity."""
    def write_exr(self, path: str | os.PathLike[str], udim: int | None = None) -> None:
        """Write the latest redirection (R, G = UV, B = validity, settings as metadata); atomic."""
    @property
    def tiles(self) -> list[int]:
        """UDIM tiles the UVs touch."""
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def chart_count(self) -> int:
        """Number of UV charts."""
    def settings(self) -> dict[str, str]:
        """The settings, as written into EXR metadata."""

def write_exr(
    path: str | os.PathLike[str],
    array: npt.NDArray[np.float32],
    metadata: dict[str, str] | None = None,
) -> None:
    """Write a float32 ``(height, width[, C])`` image (C ≤ 4; row 0 = lowest v) as OpenEXR;
    metadata is Latin-1 text; refuses NaN/inf; atomic (temporary file, then rename)."""

def read_exr(path: str | os.PathLike[str]) -> tuple[npt.NDArray[np.float32], dict[str, str]]:
    """Read an OpenEXR image: ``(array (height, width, C) float32, metadata)``."""
