# SPDX-License-Identifier: GPL-3.0-or-later
"""Colliders: the mesh objects of ``obj.tegument.collider_collection``.

Each collider object carries its own settings in ``obj.tegument_collider``
(thickness, friction). A :class:`ColliderRig` reads the colliders' evaluated
world-space triangles frame after frame and keeps one ``tegument.Collider``
per object, whose previous/current positions give the motion over the frame
that continuous collision detection sweeps.
"""

from __future__ import annotations

import bpy
import numpy as np
from bpy.props import FloatProperty, PointerProperty

from .. import mesh_arrays
from .evaluate import DeformError, to_world


class TEGUMENT_PG_collider(bpy.types.PropertyGroup):
    thickness: FloatProperty(
        name="Thickness", default=0.005, min=0.0, soft_max=0.1, subtype="DISTANCE", unit="LENGTH",
        description="Distance kept between the skin and this collider's surface",
    )
    friction: FloatProperty(
        name="Static Friction", default=0.3, min=0.0, soft_max=2.0,
        description="Skin in contact sticks to the surface while its slip stays below this times the contact depth",
    )
    kinetic_friction: FloatProperty(
        name="Kinetic Friction", default=0.2, min=0.0, soft_max=2.0,
        description="Once slipping, the slip is reduced by this times the contact depth",
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


def _world_triangles(collider, depsgraph) -> tuple[np.ndarray, np.ndarray]:
    """``(positions (N, 3) world, triangles (T, 3))`` of the evaluated collider."""
    evaluated = collider.evaluated_get(depsgraph)
    mesh = evaluated.data
    positions = to_world(mesh_arrays.positions(mesh), evaluated.matrix_world)
    triangles = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int32)
    mesh.loop_triangles.foreach_get("vertices", triangles)
    return np.ascontiguousarray(positions, dtype=np.float32), triangles.reshape(-1, 3)


class ColliderRig:
    """The colliders of one skin over a bake, updated frame by frame."""

    def __init__(self, obj):
        self.skin = obj
        self.objects = collider_objects(obj)
        self.colliders: list = []
        self._topology: list[tuple[int, int]] = []
        self.warnings: list[str] = []
        collection = obj.tegument.collider_collection
        if collection is not None and not self.objects:
            self.warnings.append(f"the collider collection \"{collection.name}\" holds no mesh objects")

    def __bool__(self) -> bool:
        return bool(self.objects)

    def update(self, depsgraph, frame: int) -> None:
        """Moves every collider to this frame (the first call places them, without motion)."""
        import tegument

        first = not self.colliders
        for k, collider in enumerate(self.objects):
            positions, triangles = _world_triangles(collider, depsgraph)
            topology = (len(positions), len(triangles))
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
