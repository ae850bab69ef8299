"""The demo scene, built procedurally (no downloaded assets).

A limb (a subdivided tube) driven by a two-bone armature that bends it at the elbow, and a body
(a sphere) beside it. Later stages of the demo deform, collide and texture these.
"""

from __future__ import annotations

import math

import bpy
import numpy as np


def clear() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def tube_mesh(name: str, segments: int, rings: int, radius: float, length: float) -> bpy.types.Mesh:
    """A capped tube along +X from -length/2 to +length/2: quads along, triangle fans at the ends."""
    x = np.linspace(-length / 2, length / 2, rings + 1)
    angle = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.zeros(segments), radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    positions = np.concatenate([ring + [xi, 0, 0] for xi in x] + [[[x[0], 0, 0]], [[x[-1], 0, 0]]])
    at = lambda i, j: j * segments + i % segments  # noqa: E731
    quads = [[at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)] for j in range(rings) for i in range(segments)]
    first, last = len(positions) - 2, len(positions) - 1
    fans = [[first, at(i + 1, 0), at(i, 0)] for i in range(segments)]
    fans += [[last, at(i, rings), at(i + 1, rings)] for i in range(segments)]
    polygons = quads + fans
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(positions))
    mesh.vertices.foreach_set("co", positions.astype(np.float32).ravel())
    corners = np.array([v for p in polygons for v in p], dtype=np.int32)
    mesh.loops.add(len(corners))
    mesh.loops.foreach_set("vertex_index", corners)
    sizes = np.array([len(p) for p in polygons], dtype=np.int32)
    mesh.polygons.add(len(sizes))
    mesh.polygons.foreach_set("loop_start", np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int32))
    mesh.update(calc_edges=True)
    mesh.validate()
    return mesh


def build_limb(name: str = "Limb", segments: int = 48, rings: int = 64, radius: float = 0.25, length: float = 2.0):
    """A capped tube along +X with a two-bone armature that bends it at the middle."""
    limb = bpy.data.objects.new(name, tube_mesh(name, segments, rings, radius, length))
    bpy.context.collection.objects.link(limb)
    limb.data.shade_smooth()

    bpy.ops.object.armature_add(location=(-length / 2, 0.0, 0.0))
    rig = bpy.context.active_object
    rig.name = f"{name}Rig"
    bpy.ops.object.mode_set(mode="EDIT")
    upper = rig.data.edit_bones[0]
    upper.name = "Upper"
    upper.head, upper.tail = (0, 0, 0), (length / 2, 0, 0)
    lower = rig.data.edit_bones.new("Lower")
    lower.head, lower.tail = (length / 2, 0, 0), (length, 0, 0)
    lower.parent = upper
    lower.use_connect = True
    bpy.ops.object.mode_set(mode="OBJECT")

    bpy.ops.object.select_all(action="DESELECT")
    limb.select_set(True)
    rig.select_set(True)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.parent_set(type="ARMATURE_AUTO")
    return limb, rig


def animate_bend(rig, frame_start: int = 1, frame_end: int = 24, angle_deg: float = 100.0, twist_deg: float = 0.0) -> None:
    """Bends the lower bone from straight to `angle_deg` (and twists it about its length) over the frame range."""
    bone = rig.pose.bones["Lower"]
    bone.rotation_mode = "YXZ"  # twist about the bone's own axis (Y) first, then bend
    for frame, bend, twist in ((frame_start, 0.0, 0.0), (frame_end, math.radians(angle_deg), math.radians(twist_deg))):
        bone.rotation_euler = (0.0, twist, bend)
        bone.keyframe_insert("rotation_euler", frame=frame)


def build_body(name: str = "Body", location=(0.9, 0.9, 0.0), radius: float = 0.6):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=48, ring_count=24, radius=radius, location=location)
    body = bpy.context.active_object
    body.name = name
    return body


def add_camera_and_light(target=(0.2, 0.3, 0.0)) -> None:
    # Looking down at an angle, so both the bend and the thinning of a twisted joint show.
    bpy.ops.object.camera_add(location=(target[0], target[1] - 3.2, 3.6))
    camera = bpy.context.active_object
    camera.rotation_euler = (math.radians(42), 0.0, 0.0)
    bpy.context.scene.camera = camera
    bpy.ops.object.light_add(type="SUN", location=(0, 0, 5))
    bpy.context.active_object.data.energy = 3.0
    world = bpy.data.worlds.new("DemoWorld")
    world.color = (0.05, 0.05, 0.06)
    bpy.context.scene.world = world
