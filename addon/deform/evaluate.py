# SPDX-License-Identifier: GPL-3.0-or-later
"""What one frame of Pyramid Deform reads from Blender: rest, input, weights."""

from __future__ import annotations

import contextlib

import bpy
import numpy as np

from .. import mesh_arrays
from .properties import MODIFIER_NAME, REST_ATTRIBUTE


class DeformError(ValueError):
    """Something about the object or its settings that stops a bind or bake."""


def tegument_modifier(obj) -> bpy.types.Modifier | None:
    modifier = obj.modifiers.get(MODIFIER_NAME)
    return modifier if modifier is not None and modifier.type == "MESH_CACHE" else None


@contextlib.contextmanager
def hidden_in_viewport(modifiers):
    """Within the block, these modifiers are left out of the viewport evaluation;
    afterwards each is shown again exactly if it was shown before."""
    hidden = [modifier for modifier in modifiers if modifier.show_viewport]
    try:
        for modifier in hidden:
            modifier.show_viewport = False
        yield
    finally:
        for modifier in hidden:
            modifier.show_viewport = True


@contextlib.contextmanager
def upstream_only(obj):
    """Within the block, the object evaluates to the stack *above* Tegument's modifier.

    The Tegument Mesh Cache modifier and every modifier below it are hidden.
    """
    names = [modifier.name for modifier in obj.modifiers]
    below = names.index(MODIFIER_NAME) if MODIFIER_NAME in names else len(names)
    with hidden_in_viewport(list(obj.modifiers)[below:]):
        yield


class FrameBuffers:
    """The arrays a bake fills every frame, allocated once per job.

    At millions of vertices a fresh array costs more than filling it: each
    one is new memory from the kernel, faulted in page by page (at 5M vertices
    they took a fifth of the frame). Each array is only valid until the next
    frame overwrites it.
    """

    def __init__(self, count: int):
        self.count = count
        self._arrays: dict[str, np.ndarray] = {}

    def get(self, name: str, count: int) -> np.ndarray | None:
        """The array called ``name`` for ``count`` vertices; None for another count
        (the caller then makes a new one and reports the mismatch)."""
        if count != self.count:
            return None
        if name not in self._arrays:
            self._arrays[name] = np.empty((count, 3), dtype=np.float32)
        return self._arrays[name]


def evaluated_positions(obj, depsgraph, buffers: FrameBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(local (N, 3), world (N, 3))`` positions of the evaluated object."""
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.data  # the evaluated mesh; no copy needed to read it
    count = len(mesh.vertices)
    local = mesh_arrays.positions(mesh, buffers.get("local", count) if buffers else None)
    return local, to_world(local, evaluated.matrix_world, buffers.get("world", count) if buffers else None)


def _apply(positions: np.ndarray, m: np.ndarray, out: np.ndarray | None) -> np.ndarray:
    if np.array_equal(m, np.eye(4)):
        return positions  # the common case of an untransformed rig: no pass over the data
    import tegument

    # In Rust, on all cores: numpy's `positions @ m[:3, :3].T` took 1.6 ms for 100k vertices,
    # twice per frame for a transformed object.
    return tegument.transform_points(np.ascontiguousarray(positions, dtype=np.float32), np.ascontiguousarray(m), out=out)


def to_world(local: np.ndarray, matrix, out: np.ndarray | None = None) -> np.ndarray:
    return _apply(local, np.array(matrix, dtype=np.float64), out)


def to_local(world: np.ndarray, matrix, out: np.ndarray | None = None) -> np.ndarray:
    return _apply(world, np.linalg.inv(np.array(matrix, dtype=np.float64)), out)


def _rest_layer(obj):
    attribute = obj.data.attributes.get(REST_ATTRIBUTE)
    if attribute is None or attribute.data_type != "FLOAT_VECTOR" or attribute.domain != "POINT":
        return None
    return attribute


def rest_attribute(obj) -> np.ndarray | None:
    """The rest positions in the ``tegument_rest`` point attribute of ``obj.data`` (object space),
    or None. UV Warp's own bind where Pyramid Deform has none of the mesh's vertices, and the bind
    of files bound by Tegument before every bind was a bind mesh (a legacy bind)."""
    attribute = _rest_layer(obj)
    if attribute is None:
        return None
    rest = np.empty((len(attribute.data), 3), dtype=np.float32)
    attribute.data.foreach_get("vector", rest.ravel())
    return rest


def mesh_vertex_bind(obj) -> bpy.types.Mesh | None:
    """Pyramid Deform's bind mesh where it has the vertices of ``obj.data`` (the stack above
    Tegument keeps the mesh's vertex count), else None: the bind UV Warp shares."""
    mesh = obj.tegument.bind_mesh
    return mesh if mesh is not None and len(mesh.vertices) == len(obj.data.vertices) else None


def rest_positions(obj) -> np.ndarray:
    """The rest shape UV Warp reads (object space): Pyramid Deform's bind mesh where it has the
    mesh's vertex count, else the ``tegument_rest`` attribute UV Warp's Bind wrote; a DeformError
    saying to bind when there is neither. Pyramid Deform reads :func:`bound_mesh`."""
    mesh = mesh_vertex_bind(obj)
    if mesh is not None:
        return mesh_arrays.positions(mesh)
    rest = rest_attribute(obj)
    if rest is None:
        raise DeformError(f"{obj.name} is not bound: press Bind (tegument.bind) first")
    return rest


def is_rest_bound(obj) -> bool:
    """Whether :func:`rest_positions` has a rest shape to give (UV Warp's "not bound" hint)."""
    return mesh_vertex_bind(obj) is not None or _rest_layer(obj) is not None


def store_rest(obj, rest: np.ndarray) -> None:
    """UV Warp's Bind: the rest positions of the mesh's own vertices. Into Pyramid Deform's bind
    mesh where it has those vertices (one rest shape for both, ``obj.data`` untouched), else into
    the ``tegument_rest`` point attribute of ``obj.data`` (saved with the file)."""
    bound = mesh_vertex_bind(obj)
    if bound is not None and len(rest) == len(bound.vertices):
        if bound.users > 1:  # shared with a duplicate of the object: that one's bind stays as it is
            bound = bound.copy()
            bound.name = bind_mesh_name(obj)
            obj.tegument.bind_mesh = bound
        bound.vertices.foreach_set("co", np.ascontiguousarray(rest, dtype=np.float32).ravel())
        bound.update()
        return
    mesh = obj.data
    attribute = mesh.attributes.get(REST_ATTRIBUTE)
    if attribute is not None:
        mesh.attributes.remove(attribute)
    attribute = mesh.attributes.new(REST_ATTRIBUTE, "FLOAT_VECTOR", "POINT")
    attribute.data.foreach_set("vector", np.ascontiguousarray(rest, dtype=np.float32).ravel())


# Modifiers that only move vertices. With Bind Pose "Original" and a stack above Tegument that
# changes the topology, the rest shape is that stack evaluated with these left out: the mesh's own
# positions through the generating modifiers (Subdivision Surface, Remesh…), not the current pose.
DEFORM_ONLY = frozenset({
    "ARMATURE", "CAST", "CLOTH", "CORRECTIVE_SMOOTH", "CURVE", "DISPLACE", "HOOK", "LAPLACIANDEFORM",
    "LAPLACIANSMOOTH", "LATTICE", "MESH_CACHE", "MESH_DEFORM", "SHRINKWRAP", "SIMPLE_DEFORM", "SMOOTH",
    "SOFT_BODY", "SURFACE_DEFORM", "WARP", "WAVE",
})


def mesh_topology(mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(positions, corner_verts, polygon_sizes)`` of a mesh datablock (original or evaluated)."""
    return mesh_arrays.positions(mesh), mesh_arrays.corner_verts(mesh), mesh_arrays.polygon_sizes(mesh)


def upstream_topology(obj, depsgraph_of, *, without_deform: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`mesh_topology` of the stack above Tegument's modifier, now; ``without_deform`` also
    leaves out the deform-only modifiers above it (:data:`DEFORM_ONLY`). ``depsgraph_of()`` gives the
    evaluated depsgraph (called inside, once the modifiers are hidden)."""
    with upstream_only(obj), hidden_in_viewport(
        [m for m in obj.modifiers if m.type in DEFORM_ONLY] if without_deform else []
    ):
        return mesh_topology(obj.evaluated_get(depsgraph_of()).data)


def keeps_topology(mesh, corners: np.ndarray, sizes: np.ndarray, vertex_count: int) -> bool:
    """Whether ``(vertex_count, corners, sizes)`` is the topology of ``mesh`` (same order)."""
    return (vertex_count == len(mesh.vertices) and np.array_equal(sizes, mesh_arrays.polygon_sizes(mesh))
            and np.array_equal(corners, mesh_arrays.corner_verts(mesh)))


def bind_mesh_name(obj) -> str:
    return f"{obj.name} · Tegument bind"


def store_bind_mesh(obj, rest: np.ndarray, corners: np.ndarray, sizes: np.ndarray) -> bpy.types.Mesh:
    """Stores Pyramid Deform's bind (rest positions and topology of the stack above Tegument,
    whether or not it is ``obj.data``'s) in a Mesh datablock of its own, referenced by
    ``obj.tegument.bind_mesh`` (a user of it: it is saved with the file); ``obj.data`` is not
    touched. Replaces an earlier bind mesh."""
    remove_bind_mesh(obj)  # first: the new one takes its name
    mesh = bpy.data.meshes.new(bind_mesh_name(obj))
    mesh.vertices.add(len(rest))
    # Through the generic attributes (block copies), as mesh_arrays reads them: the older
    # `vertices.foreach_set("co")` and `loops.foreach_set("vertex_index")` go element by element
    # (seconds at millions of vertices).
    mesh.attributes["position"].data.foreach_set("vector", np.ascontiguousarray(rest, dtype=np.float32).ravel())
    mesh.loops.add(len(corners))
    mesh.attributes[".corner_vert"].data.foreach_set("value", np.ascontiguousarray(corners, dtype=np.int32))
    mesh.polygons.add(len(sizes))
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int32)
    mesh.polygons.foreach_set("loop_start", starts)
    mesh.update(calc_edges=True)
    obj.tegument.bind_mesh = mesh
    return mesh


def remove_bind_mesh(obj) -> None:
    """Forgets (and deletes, unless something else uses it) the object's bind mesh."""
    mesh = obj.tegument.bind_mesh
    if mesh is None:
        return
    obj.tegument.bind_mesh = None
    if mesh.users == 0:
        bpy.data.meshes.remove(mesh)


def bound_mesh(obj) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(rest positions, corner_verts, polygon_sizes)`` of the object's bind: the bind mesh, or for
    a file bound before every bind was one (a legacy bind) ``obj.data`` with its ``tegument_rest``
    attribute. A DeformError says to bind, or to rebind after an edit of ``obj.data``."""
    settings = obj.tegument
    mesh = obj.data
    # What the bind saw of obj.data (files bound before it was stored: the bind's own count).
    source = settings.source_vertices or settings.bound_vertices
    if settings.bind_mesh is not None:
        rest, corners, sizes = mesh_topology(settings.bind_mesh)
        source = source or len(rest)
        if source != len(mesh.vertices):
            raise DeformError(
                f"{obj.name}: the mesh has {len(mesh.vertices)} vertices but was bound with {source}: rebind it"
            )
        return rest, corners, sizes
    rest = rest_attribute(obj)
    if rest is None:
        raise DeformError(f"{obj.name} is not bound: press Bind (tegument.bind) first")
    # Edit Mode carries the rest attribute over to added vertices (with zeros),
    # so its length alone does not show an edit: the count stored at bind does.
    bound = source or len(rest)
    if len(rest) != len(mesh.vertices) or bound != len(mesh.vertices):
        raise DeformError(
            f"{obj.name}: the mesh has {len(mesh.vertices)} vertices but was bound with {bound}: rebind it"
        )
    return rest, mesh_arrays.corner_verts(mesh), mesh_arrays.polygon_sizes(mesh)


def group_weights(obj, group) -> np.ndarray:
    """Weights of a vertex group per bound vertex: on ``obj.data`` where the bind has its vertices
    (a legacy bind, or a stack above Tegument that keeps them), else on the stack above Tegument
    (which carries the weights over, interpolated by Subdivision Surface)."""
    bind = obj.tegument.bind_mesh
    if bind is None or len(bind.vertices) == len(obj.data.vertices):
        return mesh_arrays.vertex_group_weights(obj.data, group.index)
    with upstream_only(obj):
        evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
        weights = mesh_arrays.vertex_group_weights(evaluated, group.index)
    if len(weights) != len(bind.vertices):
        raise DeformError(f"{obj.name}: the modifier stack above Tegument gives {len(weights)} vertices, "
                          f"the bind has {len(bind.vertices)}: rebind it")
    return weights


def closeness_weights(obj) -> float | np.ndarray:
    """Closeness per vertex: the setting, scaled by the closeness group where one is named."""
    settings = obj.tegument
    if not settings.closeness_group:
        return float(settings.closeness)
    group = obj.vertex_groups.get(settings.closeness_group)
    if group is None:
        raise DeformError(f"{obj.name}: the closeness vertex group \"{settings.closeness_group}\" does not exist")
    return (settings.closeness * group_weights(obj, group)).astype(np.float32)


def cache_file(obj) -> str:
    return bpy.path.abspath(obj.tegument.cache_path)


def max_stretch(obj) -> float | np.ndarray | None:
    """ε for ``PyramidDeformer.step``: None without limits, a float, or per vertex from the group
    (Max Stretch / weight; no limit where the weight is 0)."""
    settings = obj.tegument
    if not settings.limit_stretch:
        return None
    if not settings.max_stretch_group:
        return float(settings.max_stretch)
    group = obj.vertex_groups.get(settings.max_stretch_group)
    if group is None:
        raise DeformError(f"{obj.name}: the max stretch vertex group \"{settings.max_stretch_group}\" does not exist")
    weights = group_weights(obj, group)
    with np.errstate(divide="ignore"):
        return np.where(weights > 0, settings.max_stretch / np.maximum(weights, 1e-30), np.inf).astype(np.float32)


def step_options(obj, scene) -> dict:
    """The keyword arguments of ``PyramidDeformer.step`` from the object's settings (beyond
    iterations and closeness); empty when a plain frame-by-frame solve will do."""
    import tegument

    settings = obj.tegument
    options: dict = {}
    if settings.substeps > 1:
        options["substeps"] = settings.substeps
    if settings.dynamic:
        fps = scene.render.fps / scene.render.fps_base
        gravity = tuple(scene.gravity) if settings.use_gravity and scene.use_gravity else (0.0, 0.0, 0.0)
        try:
            options["dynamics"] = tegument.Dynamics(
                frame_time=1.0 / fps, mass=settings.mass, damping=settings.damping, gravity=gravity
            )
        except tegument.TegumentError as error:
            raise DeformError(f"{obj.name}: {error}") from None
    stretch = max_stretch(obj)
    if stretch is not None:
        options["max_stretch"] = stretch
        options["strain_mode"] = settings.strain_mode.lower()
    from .self_collision import step_option

    skin = step_option(obj)
    if skin is not None:
        options["self_collision"] = skin
    return options
