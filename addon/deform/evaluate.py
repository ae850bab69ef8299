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


def evaluated_positions(obj, depsgraph) -> tuple[np.ndarray, np.ndarray]:
    """``(local (N, 3), world (N, 3))`` positions of the evaluated object."""
    evaluated = obj.evaluated_get(depsgraph)
    local = mesh_arrays.positions(evaluated.data)  # the evaluated mesh; no copy needed to read it
    return local, to_world(local, evaluated.matrix_world)


def _apply(positions: np.ndarray, m: np.ndarray) -> np.ndarray:
    if np.array_equal(m, np.eye(4)):
        return positions  # the common case of an untransformed rig: no pass over the data
    import tegument

    # In Rust, on all cores: numpy's `positions @ m[:3, :3].T` took 1.6 ms for 100k vertices,
    # twice per frame for a transformed object.
    return tegument.transform_points(np.ascontiguousarray(positions, dtype=np.float32), np.ascontiguousarray(m))


def to_world(local: np.ndarray, matrix) -> np.ndarray:
    return _apply(local, np.array(matrix, dtype=np.float64))


def to_local(world: np.ndarray, matrix) -> np.ndarray:
    return _apply(world, np.linalg.inv(np.array(matrix, dtype=np.float64)))


def rest_positions(obj) -> np.ndarray:
    """The bound rest positions (object space), or a DeformError saying to bind."""
    attribute = obj.data.attributes.get(REST_ATTRIBUTE)
    if attribute is None or attribute.data_type != "FLOAT_VECTOR" or attribute.domain != "POINT":
        raise DeformError(f"{obj.name} is not bound: press Bind (tegument.bind) first")
    rest = np.empty((len(attribute.data), 3), dtype=np.float32)
    attribute.data.foreach_get("vector", rest.ravel())
    return rest


def store_rest(obj, rest: np.ndarray) -> None:
    """Stores the rest positions in the mesh so the bind survives save and reload."""
    mesh = obj.data
    attribute = mesh.attributes.get(REST_ATTRIBUTE)
    if attribute is not None:
        mesh.attributes.remove(attribute)
    attribute = mesh.attributes.new(REST_ATTRIBUTE, "FLOAT_VECTOR", "POINT")
    attribute.data.foreach_set("vector", np.ascontiguousarray(rest, dtype=np.float32).ravel())


def closeness_weights(obj) -> float | np.ndarray:
    """Closeness per vertex: the setting, scaled by the closeness group where one is named."""
    settings = obj.tegument
    if not settings.closeness_group:
        return float(settings.closeness)
    group = obj.vertex_groups.get(settings.closeness_group)
    if group is None:
        raise DeformError(f"{obj.name}: the closeness vertex group \"{settings.closeness_group}\" does not exist")
    return (settings.closeness * mesh_arrays.vertex_group_weights(obj.data, group.index)).astype(np.float32)


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
    weights = mesh_arrays.vertex_group_weights(obj.data, group.index)
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
    return options
