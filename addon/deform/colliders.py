# SPDX-License-Identifier: GPL-3.0-or-later
"""Colliders: the mesh objects of ``obj.tegument.collider_collection``.

Each collider object carries its own settings in ``obj.tegument_collider``
(thickness, friction, and a compliant region: a vertex group and a
stiffness). A :class:`ColliderRig` reads the colliders' evaluated
world-space triangles frame after frame and keeps one ``tegument.Collider``
per object, whose previous/current positions give the motion over the frame
that continuous collision detection sweeps.
"""

from __future__ import annotations

import contextlib

import bpy
import numpy as np
import tegument
from bpy.props import FloatProperty, PointerProperty, StringProperty

from .. import mesh_arrays
from .evaluate import DeformError, hidden_in_viewport, to_local, to_world

# One source for every default: the core's (see tegument.DEFAULTS).
_DEFAULTS = tegument.DEFAULTS

# The Mesh Cache modifier that plays a compliant collider's solved positions back.
COMPLIANCE_MODIFIER_NAME = "Tegument Compliance"


# Blender 4.5 made blend-relative ("//") paths an explicit option of path properties.
_RELATIVE_PATH = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else set()


def is_compliant(collider) -> bool:
    settings = collider.tegument_collider
    return bool(settings.compliant_group) and settings.stiffness > 0.0


def compliance_cache_path(collider) -> str:
    """Absolute path of a compliant collider's PC2 cache."""
    path = collider.tegument_collider.cache_path or f"//tegument/{bpy.path.clean_name(collider.name)}.compliant.pc2"
    return bpy.path.abspath(path)


def compliance_modifier(collider):
    modifier = collider.modifiers.get(COMPLIANCE_MODIFIER_NAME)
    return modifier if modifier is not None and modifier.type == "MESH_CACHE" else None


def compliant_stiffness(collider, vertex_count: int) -> np.ndarray:
    """Stiffness per vertex of the evaluated collider: the setting divided by the group weight (0, kinematic,
    where the weight is 0)."""
    settings = collider.tegument_collider
    group = collider.vertex_groups.get(settings.compliant_group)
    if group is None:
        raise DeformError(f"collider {collider.name}: the compliant vertex group \"{settings.compliant_group}\" does not exist")
    if len(collider.data.vertices) != vertex_count:
        raise DeformError(
            f"collider {collider.name}: its modifiers give {vertex_count} vertices but the mesh has "
            f"{len(collider.data.vertices)}; a compliant collider must keep its vertex count (the group "
            "weights belong to the mesh's vertices): apply or remove the modifier that changes it"
        )
    # Weight = how compliant: 1 gives Stiffness, lower weights stiffer springs, and 0 none at all
    # (kinematic), so painting fades continuously into the rigid part.
    weights = mesh_arrays.vertex_group_weights(collider.data, group.index)
    with np.errstate(divide="ignore"):
        return np.where(weights > 0, settings.stiffness / np.maximum(weights, 1e-30), 0.0).astype(np.float32)


class TEGUMENT_PG_collider(bpy.types.PropertyGroup):
    thickness: FloatProperty(
        name="Thickness", default=_DEFAULTS.thickness, min=0.0, soft_max=0.1, subtype="DISTANCE", unit="LENGTH",
        description="Distance kept between the skin and this collider's surface",
    )
    friction: FloatProperty(
        name="Static Friction", default=_DEFAULTS.friction, min=0.0, soft_max=2.0,
        description="Skin in contact sticks to the surface while its slip stays below this times the contact depth",
    )
    kinetic_friction: FloatProperty(
        name="Kinetic Friction", default=_DEFAULTS.kinetic_friction, min=0.0, soft_max=2.0,
        description="Once slipping, the slip is reduced by this times the contact depth",
    )
    compliant_group: StringProperty(
        name="Compliant Group",
        description="Vertex group of the region that gives way where it meets the skin: weight 1 springs "
        "with Stiffness, lower weights stiffer (Stiffness / weight), 0 or not in the group follows its "
        "animation exactly. Empty: fully kinematic",
    )
    stiffness: FloatProperty(
        name="Stiffness", default=200.0, min=0.0, soft_max=10000.0,
        description="How hard the compliant region holds its animated shape, against the skin's own "
        "stiffness of 1000: lower values recede more. Does not depend on substeps",
    )
    cache_path: StringProperty(
        name="Compliance Cache", subtype="FILE_PATH", default="", options=_RELATIVE_PATH,
        description="PC2 cache of where the compliant region receded, played back by this collider's "
        "Tegument Compliance modifier (empty: //tegument/<collider>.compliant.pc2)",
    )


def collider_objects(obj) -> list:
    """Mesh objects of the skin's collider collection (never the skin itself), by name."""
    collection = obj.tegument.collider_collection
    if collection is None:
        return []
    return sorted(
        (o for o in collection.all_objects if o.type == "MESH" and o != obj),
        key=lambda o: o.name,
    )


def _world_positions(collider, depsgraph) -> tuple[np.ndarray, int]:
    """``(positions (N, 3) world, triangle count)`` of the evaluated collider."""
    evaluated = collider.evaluated_get(depsgraph)
    mesh = evaluated.data
    positions = to_world(mesh_arrays.positions(mesh), evaluated.matrix_world)
    return np.ascontiguousarray(positions, dtype=np.float32), len(mesh.loop_triangles)


def _world_triangles(collider, depsgraph) -> tuple[np.ndarray, np.ndarray]:
    """``(positions (N, 3) world, triangles (T, 3))`` of the evaluated collider, the triangles
    in a canonical order (:func:`canonical_triangles`)."""
    positions, count = _world_positions(collider, depsgraph)
    triangles = np.empty(count * 3, dtype=np.int32)
    collider.evaluated_get(depsgraph).data.loop_triangles.foreach_get("vertices", triangles)
    return positions, canonical_triangles(triangles.reshape(-1, 3))


def canonical_triangles(triangles: np.ndarray) -> np.ndarray:
    """``triangles`` (T, 3) in an order that depends only on which triangles there are: each
    starts at its lowest vertex (its winding kept), and they are sorted by their vertices.

    The order of a mesh's faces and corners can differ where its vertices and triangles do not
    (two UV spheres made by the same operator call listed their faces differently), and the order
    of the triangles decides ties in the collision response: without this, two bakes of the same
    scene differed in the fifth digit.
    """
    first = np.argmin(triangles, axis=1)
    turn = (first[:, None] + np.arange(3)) % 3
    triangles = np.take_along_axis(triangles, turn, axis=1)
    order = np.lexsort((triangles[:, 2], triangles[:, 1], triangles[:, 0]))
    return np.ascontiguousarray(triangles[order], dtype=np.int32)


class ColliderRig:
    """The colliders of one skin over a bake, updated frame by frame."""

    def __init__(self, obj):
        self.skin = obj
        self.objects = collider_objects(obj)
        self.colliders: list = []
        self._topology: list[tuple[int, int]] = []
        self._matrices: list = []
        self.warnings: list[str] = []
        # Indices (into objects) of the compliant colliders.
        self.compliant = [k for k, o in enumerate(self.objects) if is_compliant(o)]
        collection = obj.tegument.collider_collection
        if collection is not None and not self.objects:
            self.warnings.append(f"the collider collection \"{collection.name}\" holds no mesh objects")

    def __bool__(self) -> bool:
        return bool(self.objects)

    @contextlib.contextmanager
    def animated_only(self):
        """Within the block, colliders evaluate to their animation: a Tegument Compliance
        modifier (and everything below it) is left out, also on a collider no longer compliant."""
        hide = []
        for collider in self.objects:
            modifiers = list(collider.modifiers)
            names = [m.name for m in modifiers]
            if COMPLIANCE_MODIFIER_NAME in names:
                hide.extend(modifiers[names.index(COMPLIANCE_MODIFIER_NAME):])
        with hidden_in_viewport(hide):
            yield

    def solved_local(self, k: int) -> np.ndarray:
        """Where compliant collider ``k`` was solved this frame, in its object space."""
        return np.ascontiguousarray(to_local(self.colliders[k].positions, self._matrices[k]), dtype=np.float32)

    def place_local(self, k: int, local: np.ndarray) -> None:
        """Puts compliant collider ``k`` where a cached frame solved it (object space)."""
        self.colliders[k].place(np.ascontiguousarray(to_world(local, self._matrices[k]), dtype=np.float32))

    def update(self, depsgraph, frame: int) -> None:
        """Moves every collider to this frame (the first call places them, without motion)."""
        import tegument

        first = not self.colliders
        for k, collider in enumerate(self.objects):
            # The triangles are read once: later frames only check their count.
            if first:
                positions, triangles = _world_triangles(collider, depsgraph)
                count = len(triangles)
            else:
                positions, count = _world_positions(collider, depsgraph)
            topology = (len(positions), count)
            matrix = collider.evaluated_get(depsgraph).matrix_world.copy()
            if first:
                self._matrices.append(matrix)
            else:
                self._matrices[k] = matrix
            if first:
                if not len(triangles):
                    raise DeformError(f"collider {collider.name} has no faces")
                settings = collider.tegument_collider
                try:
                    self.colliders.append(
                        tegument.Collider(
                            positions, triangles, thickness=settings.thickness,
                            friction=settings.friction, kinetic_friction=settings.kinetic_friction,
                        )
                    )
                except tegument.TegumentError as error:
                    raise DeformError(f"collider {collider.name}, frame {frame}: {error}") from None
                self._topology.append(topology)
                if k in self.compliant:
                    try:
                        self.colliders[-1].set_compliance(compliant_stiffness(collider, len(positions)))
                    except tegument.TegumentError as error:
                        raise DeformError(f"collider {collider.name}: {error}") from None
                if not self.colliders[-1].is_closed:
                    self.warnings.append(f"collider {collider.name} is open: the audit cannot tell inside from outside")
                continue
            if topology != self._topology[k]:
                raise DeformError(
                    f"collider {collider.name} had {self._topology[k][0]} vertices and {self._topology[k][1]} "
                    f"triangles when the bake started, and {topology[0]} and {topology[1]} at frame {frame}: "
                    "a collider must keep its topology over a bake (apply or remove the modifier that changes it)"
                )
            try:
                self.colliders[k].update(positions)
            except tegument.TegumentError as error:
                raise DeformError(f"collider {collider.name}, frame {frame}: {error}") from None


def register() -> None:
    bpy.utils.register_class(TEGUMENT_PG_collider)
    bpy.types.Object.tegument_collider = PointerProperty(type=TEGUMENT_PG_collider)


def unregister() -> None:
    del bpy.types.Object.tegument_collider
    bpy.utils.unregister_class(TEGUMENT_PG_collider)
