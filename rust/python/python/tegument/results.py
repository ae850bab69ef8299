"""What Tegument's calls report: small frozen classes with attributes.

Every report (``PyramidDeformer.last_step``, ``audit()``, ``UvWarp.metrics()``,
``Mesh.report``, ``Collider.update()``) is one of these classes: read its
fields as attributes (``tegument.audit(...).vertices_inside``), or take them all
with ``to_dict()``. In 0.1.0 they were plain dicts; the dict spellings
(``report["key"]``, ``.get``, ``in``, ``keys()``, ``items()``, ``values()``)
still work for one release and warn with a ``DeprecationWarning``.

Arrays in reports are numpy arrays owned by the report (int32 indices).
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any, Iterator

import numpy as np
import numpy.typing as npt

__all__ = [
    "AuditReport",
    "ColliderUpdate",
    "Defaults",
    "MeshReport",
    "StepReport",
    "WarpMetrics",
]


def _deprecated(what: str, instead: str) -> None:
    # stacklevel 3: the caller of the dict-style method, not this helper.
    warnings.warn(f"{what} is deprecated and goes away in the next release: use {instead}", DeprecationWarning, stacklevel=3)


class _Report:
    """Shared behaviour: ``to_dict()``, a readable ``repr``, and the old dict
    spellings, deprecated."""

    __slots__ = ()

    def to_dict(self) -> dict[str, Any]:
        """Every field as a plain dict (arrays are the same objects, not copies)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}  # type: ignore[arg-type]

    def _field_names(self) -> list[str]:
        return [f.name for f in dataclasses.fields(self)]  # type: ignore[arg-type]

    def __repr__(self) -> str:
        def short(value: Any) -> str:
            if isinstance(value, np.ndarray):
                return f"array({value.dtype}, shape={value.shape})"
            return repr(value)

        inner = ", ".join(f"{name}={short(getattr(self, name))}" for name in self._field_names())
        return f"tegument.{type(self).__name__}({inner})"

    # The dict spellings of releases up to 0.2, deprecated.
    def __getitem__(self, key: str) -> Any:
        _deprecated(f"{type(self).__name__}[{key!r}]", f"the attribute .{key}")
        if key not in self._field_names():
            raise KeyError(key)
        return getattr(self, key)

    def get(self, key: str, default: Any = None) -> Any:
        _deprecated(f"{type(self).__name__}.get({key!r})", f"the attribute .{key}")
        return getattr(self, key) if key in self._field_names() else default

    def __contains__(self, key: object) -> bool:
        _deprecated(f"`key in {type(self).__name__}`", "hasattr() or .to_dict()")
        return key in self._field_names()

    def keys(self) -> list[str]:
        _deprecated(f"{type(self).__name__}.keys()", ".to_dict().keys()")
        return self._field_names()

    def values(self) -> list[Any]:
        _deprecated(f"{type(self).__name__}.values()", ".to_dict().values()")
        return [getattr(self, k) for k in self._field_names()]

    def items(self) -> list[tuple[str, Any]]:
        _deprecated(f"{type(self).__name__}.items()", ".to_dict().items()")
        return [(k, getattr(self, k)) for k in self._field_names()]

    def __iter__(self) -> Iterator[str]:
        _deprecated(f"iterating over a {type(self).__name__}", ".to_dict()")
        return iter(self._field_names())

    def __len__(self) -> int:
        return len(self._field_names())


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class StepReport(_Report):
    """What the last :meth:`PyramidDeformer.step` did (its ``last_step``)."""

    first_pass_contacts: int
    """Vertex, edge and collider-vertex contacts of the first pass."""
    first_pass_moved: int
    """Vertices the first pass moved."""
    in_loop_contacts: int
    """Contacts resolved after the solve's iterations, over all of them."""
    max_in_loop_correction: float
    """Largest correction of one of those contacts."""
    pinched: npt.NDArray[np.int32]
    """int32 ``(K,)``: vertices left pinched between colliders."""
    kinetic_energy: float
    """Kinetic energy at the end of the step (0 without dynamics)."""
    worst_stretch: float
    """Largest length / rest length of a limited edge (0 without limits)."""
    compliant_contacts: int
    """Contacts that stopped compliant collider vertices."""
    compliant_skin_vertices: int
    """Skin vertices giving way to compliant colliders."""
    max_recession: float
    """Largest distance of a compliant collider vertex from its animated position."""
    held: int
    """Times a pass put a vertex it could not clear of colliders standing still back where the
    pass started (a contact that holds rather than a pinch), over all passes."""
    self_contacts: int
    """Contacts between skin and skin projected (self-collision), over all passes."""
    self_held: int
    """Times the self-collision fail-safe put a vertex back where its pass started, over all passes."""
    self_pinched: npt.NDArray[np.int32]
    """int32 ``(K,)``: vertices left crossing skin where a sweeping collider had the last word."""
    self_intersections: int
    """Pairs of the skin's triangles intersecting in the output (neighbours not counted): what the
    input brought in that has not come apart yet."""
    self_tangled: int
    """Vertices exempt at the start of the frame because their triangles intersected there."""


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class AuditReport(_Report):
    """What :func:`audit` found."""

    vertices_inside: int
    """Vertices inside a closed collider, deeper than the tolerance."""
    edges_crossing: int
    """Mesh edges (and fan diagonals) crossing a collider triangle."""
    collider_edges_crossing: int
    """Collider edges crossing a mesh polygon."""
    vertices_inside_indices: npt.NDArray[np.int32]
    """int32 ``(K,)``."""
    edges_crossing_indices: npt.NDArray[np.int32]
    """int32 ``(K, 2)``: vertex pairs."""
    collider_edges_crossing_indices: npt.NDArray[np.int32]
    """int32 ``(K, 2)``: (collider, row of :attr:`Collider.edges`)."""
    open_colliders: list[int]
    """Colliders the inside test skipped because they are not closed."""
    self_intersections: int
    """With ``self_intersections=True``: pairs of polygons sharing no vertex that intersect."""
    self_intersection_indices: npt.NDArray[np.int32]
    """int32 ``(K, 2)``: those polygon pairs, ascending."""


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class WarpMetrics(_Report):
    """Quality figures of one UDIM tile of a :class:`UvWarp` (``UvWarp.metrics``).

    Stretch errors are ``max(|log σ1|, |log σ2|)`` over texels with rigidity
    ≥ 0.5; displacements and round trips in texels.
    """

    udim: int
    rigid_texels: int
    stretch_identity_mean: float
    stretch_identity_p95: float
    stretch_identity_max: float
    stretch_warped_mean: float
    stretch_warped_p95: float
    stretch_warped_max: float
    foldovers: int
    max_masked_displacement: float
    max_displacement: float
    round_trip_max: float
    round_trip_mean: float


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class MeshReport(_Report):
    """Counts of everything unusual in a :class:`Mesh` (``Mesh.report``)."""

    vertex_count: int
    edge_count: int
    polygon_count: int
    boundary_edges: int
    boundary_vertices: int
    non_manifold_edges: int
    flipped_edges: int
    non_manifold_vertices: int
    degenerate_polygons: int
    isolated_vertices: int
    is_closed_manifold: bool
    is_clean: bool

    def __call__(self) -> MeshReport:
        # ``Mesh.report`` was a method in 0.1.0.
        _deprecated("Mesh.report()", "the property Mesh.report (no parentheses)")
        return self


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class ColliderUpdate(_Report):
    """What :meth:`Collider.update` did to the collider's BVH."""

    cost_ratio: float
    """Cost of the refitted tree relative to a fresh build."""
    rebuilt: bool
    """Whether the tree was rebuilt because refitting had degraded it."""


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class Defaults(_Report):
    """The default of every setting, as the core defines it (``tegument.DEFAULTS``).

    The bindings' keyword defaults and the add-on's property defaults are
    read from here, so that there is one source for each.
    """

    iterations: int
    """``PyramidDeformer.solve``/``step``: solver iterations per frame (plain iterations)."""
    converge: bool
    """Whether the add-on's Pyramid Deform bakes use the accelerated solver (its Converge setting):
    ``PyramidDeformer.accelerated`` with :attr:`tolerance`, at most :attr:`accelerated_iterations`,
    each bake frame warm-started from the last. ``PyramidDeformer`` itself stays plain until asked."""
    accelerated_iterations: int
    """The add-on's Converge iteration limit: the accelerated solver (``PyramidDeformer.accelerated``)
    with :attr:`tolerance` stops before it once converged."""
    tolerance: float
    """``PyramidDeformer.tolerance`` of the add-on's Converge: a solve stops once its estimated
    convergence error is at most this fraction of the displacement."""
    closeness: float
    """Pull of each vertex towards its input when ``closeness`` is None."""
    substeps: int
    scale_safe: bool
    strain_mode: str
    frame_time: float
    """``Dynamics``: seconds per frame."""
    mass: float
    damping: float
    gravity: tuple[float, float, float]
    thickness: float
    """``Collider``: distance kept between skin and surface."""
    friction: float
    kinetic_friction: float
    depth_tolerance: float
    """``audit``: vertices inside but closer than this are not counted."""
    self_thickness: float
    """``SelfCollision``: distance kept between skin that folds onto itself."""
    self_friction: float
    self_kinetic_friction: float
    self_rings: int
    """``SelfCollision``: rings of neighbours left out besides elements sharing a vertex."""
    warp_iterations: int
    """``UvWarp``: PBD iterations on the finest level."""
    orientation: float
    smoothing: float
    warm_start: bool
    memory_limit: int
    sample_warped: bool


class PropertyArray(np.ndarray):
    """A numpy array returned by a property that was a method in 0.1.0:
    calling it (``mesh.edges()``) still works, with a ``DeprecationWarning``,
    and returns the plain array."""

    _spelling: str = "this property"

    def __array_finalize__(self, obj: Any) -> None:
        self._spelling = getattr(obj, "_spelling", "this property")

    def __call__(self) -> np.ndarray:
        _deprecated(f"{self._spelling}()", f"the property {self._spelling} (no parentheses)")
        return self.view(np.ndarray)


def _property_array(array: np.ndarray, spelling: str) -> PropertyArray:
    out = array.view(PropertyArray)
    out._spelling = spelling
    return out
