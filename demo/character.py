"""The CC0 MakeHuman base character, rigged in Blender from ``../shared/data/makehuman``.

The data (see its README) is an OBJ whose ``body`` group is the skin, a skeleton whose joints are
means of OBJ vertices, and per-bone skin weights over the OBJ's vertices. This module turns them
into what a user would have after importing a rigged character: a mesh object with a UV map, one
vertex group per bone and an Armature modifier, parented to an armature whose bones sit at the
joints with MakeHuman's roll. MakeHuman writes decimetres with Y up; Blender gets metres with Z up,
the character facing -Y.

Used by the tests, the demo and the benchmarks, so all three pose the same character the same way.
Nothing is copied out of the shared data folder.
"""

from __future__ import annotations

import json
import math
import pathlib

import bpy
import numpy as np
from mathutils import Matrix, Vector

BODY_GROUP = "body"
# MakeHuman's units are decimetres: 0.1 gives a 1.7 m character.
METRES_PER_UNIT = 0.1


class CharacterDataMissing(FileNotFoundError):
    """The MakeHuman files are not where they were looked for."""


def data_folder(root: pathlib.Path | None = None) -> pathlib.Path:
    """``../shared/data/makehuman`` beside the checkout (or ``root``), checked for its three files."""
    folder = root or pathlib.Path(__file__).resolve().parents[2] / "shared" / "data" / "makehuman"
    missing = [name for name in ("base.obj", "default.mhskel", "default_weights.mhw") if not (folder / name).is_file()]
    if missing:
        raise CharacterDataMissing(f"{folder}: missing {', '.join(missing)} (the shared MakeHuman data sits beside the checkout)")
    return folder


def _to_blender(points: np.ndarray) -> np.ndarray:
    """MakeHuman (decimetres, Y up, facing +Z) to Blender (metres, Z up, facing -Y)."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    return np.stack([x, -z, y], axis=1) * METRES_PER_UNIT


class ObjBody:
    """The ``body`` group of MakeHuman's ``base.obj``: positions, polygons, corner UVs, and the
    map from the body's vertices back to the OBJ's (weights and joints index the whole file)."""

    def __init__(self, path: pathlib.Path):
        positions, uvs, corners, corner_uvs, sizes = [], [], [], [], []
        group = None
        with open(path, encoding="utf-8") as lines:
            for line in lines:
                tag, _, rest = line.partition(" ")
                if tag == "v":
                    positions.append(rest.split()[:3])
                elif tag == "vt":
                    uvs.append(rest.split()[:2])
                elif tag == "g":
                    group = rest.strip()
                elif tag == "f" and group == BODY_GROUP:
                    refs = [ref.split("/") for ref in rest.split()]
                    corners.extend(int(ref[0]) - 1 for ref in refs)
                    corner_uvs.extend(int(ref[1]) - 1 for ref in refs)
                    sizes.append(len(refs))
        self.all_positions = _to_blender(np.asarray(positions, dtype=np.float64))
        obj_corners = np.asarray(corners, dtype=np.int64)
        # The body's own vertices, in OBJ order: body index -> OBJ index, and back.
        self.obj_index = np.unique(obj_corners)
        to_body = np.full(len(self.all_positions), -1, dtype=np.int64)
        to_body[self.obj_index] = np.arange(len(self.obj_index))
        self.to_body = to_body
        self.positions = self.all_positions[self.obj_index].astype(np.float32)
        self.corner_verts = to_body[obj_corners].astype(np.int32)
        self.polygon_sizes = np.asarray(sizes, dtype=np.int32)
        self.corner_uvs = np.asarray(uvs, dtype=np.float32)[np.asarray(corner_uvs, dtype=np.int64)]


def build_mesh(name: str, body: ObjBody) -> bpy.types.Mesh:
    """A Blender mesh of the body with its UV map "UVMap", built from whole arrays."""
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(body.positions))
    mesh.vertices.foreach_set("co", body.positions.ravel())
    mesh.loops.add(len(body.corner_verts))
    mesh.loops.foreach_set("vertex_index", body.corner_verts)
    mesh.polygons.add(len(body.polygon_sizes))
    starts = np.concatenate(([0], np.cumsum(body.polygon_sizes)[:-1])).astype(np.int32)
    mesh.polygons.foreach_set("loop_start", starts)
    mesh.update(calc_edges=True)
    mesh.validate()
    layer = mesh.uv_layers.new(name="UVMap")
    layer.uv.foreach_set("vector", body.corner_uvs.ravel())
    mesh.shade_smooth()
    return mesh


def _joint_positions(skeleton: dict, body: ObjBody) -> dict[str, np.ndarray]:
    return {name: body.all_positions[np.asarray(indices)].mean(axis=0) for name, indices in skeleton["joints"].items()}


def build_armature(name: str, skeleton: dict, body: ObjBody) -> bpy.types.Object:
    """An armature object with MakeHuman's bones: heads and tails at the joints, parents, and the
    roll that makes each bone's X axis the normal of its rotation plane (MakeHuman's convention)."""
    joints = _joint_positions(skeleton, body)
    armature = bpy.data.armatures.new(name)
    rig = bpy.data.objects.new(name, armature)
    bpy.context.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    bones = skeleton["bones"]
    for bone_name, bone in bones.items():
        edit = armature.edit_bones.new(bone_name)
        edit.head = joints[bone["head"]]
        edit.tail = joints[bone["tail"]]
    for bone_name, bone in bones.items():
        edit = armature.edit_bones[bone_name]
        if bone["parent"]:
            edit.parent = armature.edit_bones[bone["parent"]]
        plane = skeleton["planes"].get(bone["rotation_plane"])
        if plane:
            a, b, c = (Vector(joints[j]) for j in plane)
            normal = (b - a).cross(c - b)
            z_axis = normal.cross(edit.tail - edit.head)
            if normal.length > 1e-9 and z_axis.length > 1e-9:
                edit.align_roll(z_axis.normalized())
    bpy.ops.object.mode_set(mode="OBJECT")
    return rig


def add_weights(obj: bpy.types.Object, weights: dict[str, list], body: ObjBody) -> None:
    """One vertex group per bone, from MakeHuman's weights remapped to the body's vertices
    (weights on helper geometry are dropped with it)."""
    for bone_name, pairs in weights.items():
        if not pairs:
            continue
        table = np.asarray(pairs, dtype=np.float64)
        vertices = body.to_body[table[:, 0].astype(np.int64)]
        keep = vertices >= 0
        if not keep.any():
            continue
        group = obj.vertex_groups.new(name=bone_name)
        vertices, values = vertices[keep], table[keep, 1]
        # vertex_groups.add takes one weight per call: group the vertices by weight.
        order = np.argsort(values, kind="stable")
        values, vertices = values[order], vertices[order]
        cuts = np.flatnonzero(np.diff(values)) + 1
        for chunk_vertices, chunk_values in zip(np.split(vertices, cuts), np.split(values, cuts)):
            group.add(chunk_vertices.tolist(), float(chunk_values[0]), "REPLACE")


def load_character(name: str = "Human", folder: pathlib.Path | None = None) -> tuple[bpy.types.Object, bpy.types.Object]:
    """``(mesh object, armature object)``: the MakeHuman body rigged as a user would have it."""
    folder = data_folder(folder)
    body = ObjBody(folder / "base.obj")
    skeleton = json.loads((folder / "default.mhskel").read_text(encoding="utf-8"))
    weights = json.loads((folder / "default_weights.mhw").read_text(encoding="utf-8"))["weights"]
    obj = bpy.data.objects.new(name, build_mesh(name, body))
    bpy.context.collection.objects.link(obj)
    rig = build_armature(f"{name}Rig", skeleton, body)
    add_weights(obj, weights, body)
    obj.parent = rig
    modifier = obj.modifiers.new("Armature", "ARMATURE")
    modifier.object = rig
    return obj, rig


# ------------------------------------------------------------------------------------- posing

# The hard pose the tests, the demo and the benchmarks use, as (kind, bone, degrees, hint):
# - "flex": the joint at the bone's head closes to ``degrees`` between its parent and it (0 =
#   in line), in the plane it already bends in at rest, or towards the world direction ``hint``
#   where it is nearly straight at rest (MakeHuman's elbows rest at about 46°, its knees at 7°);
# - "bend": the bone turns by ``degrees`` from its rest direction towards the world direction
#   ``hint``;
# - "twist": the bone turns by ``degrees`` about its own length.
# Elbows and knees at 130°, the upper arms raised 60° with a shrug at the shoulders, the left
# forearm twisted 80°, the hips flexed, the spine bent forward 45° over three bones.
FORWARD, BACK, UP = (0.0, -1.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
HARD_POSE = (
    ("bend", "spine03", 15.0, FORWARD),
    ("bend", "spine02", 15.0, FORWARD),
    ("bend", "spine01", 15.0, FORWARD),
    ("bend", "shoulder01.L", 20.0, UP),
    ("bend", "shoulder01.R", 20.0, UP),
    ("bend", "upperarm01.L", 60.0, UP),
    ("bend", "upperarm01.R", 60.0, UP),
    ("flex", "lowerarm01.L", 130.0, FORWARD),
    ("flex", "lowerarm01.R", 130.0, FORWARD),
    ("twist", "lowerarm02.L", 80.0, None),
    ("bend", "upperleg01.L", 70.0, FORWARD),
    ("bend", "upperleg01.R", 40.0, FORWARD),
    ("flex", "lowerleg01.L", 130.0, BACK),
    ("flex", "lowerleg01.R", 130.0, BACK),
)
# Below this rest angle a joint's own bending plane is too ill-defined to follow.
_STRAIGHT_DEGREES = 20.0


def _direction(bone: bpy.types.Bone) -> Vector:
    return (bone.tail_local - bone.head_local).normalized()


def _rest_rotation(bone: bpy.types.Bone, kind: str, degrees: float, hint) -> Matrix:
    """The bone-local rotation (relative to its rest frame) for one entry of a pose."""
    along = _direction(bone)
    if kind == "twist":
        axis, angle = along, degrees
    elif kind == "bend":
        axis, angle = along.cross(Vector(hint)), degrees
    elif kind == "flex":
        parent = _direction(bone.parent)
        rest_angle = math.degrees(parent.angle(along))
        axis = parent.cross(along) if rest_angle > _STRAIGHT_DEGREES else parent.cross(Vector(hint))
        angle = degrees - rest_angle
    else:
        raise ValueError(f"pose entry for {bone.name}: unknown kind {kind!r} (flex, bend or twist)")
    if axis.length < 1e-6:
        raise ValueError(f"pose entry for {bone.name}: the {kind} has no rotation axis (it points along {hint})")
    world = Matrix.Rotation(math.radians(angle), 3, axis.normalized())
    rest = bone.matrix_local.to_3x3()
    return rest.inverted() @ world @ rest


def animate_pose(rig: bpy.types.Object, pose=HARD_POSE, frame_start: int = 1, frame_end: int = 12) -> None:
    """Keys the rest pose at ``frame_start`` and ``pose`` at ``frame_end``; Blender interpolates
    the frames between. Entries on one bone compose in the order given."""
    rotations: dict[str, Matrix] = {}
    for kind, bone_name, degrees, hint in pose:
        turn = _rest_rotation(rig.data.bones[bone_name], kind, degrees, hint)
        rotations[bone_name] = turn @ rotations.get(bone_name, Matrix.Identity(3))
    for bone_name, turn in rotations.items():
        pose_bone = rig.pose.bones[bone_name]
        pose_bone.rotation_mode = "QUATERNION"
        pose_bone.rotation_quaternion = (1.0, 0.0, 0.0, 0.0)
        pose_bone.keyframe_insert("rotation_quaternion", frame=frame_start)
        pose_bone.rotation_quaternion = turn.to_quaternion()
        pose_bone.keyframe_insert("rotation_quaternion", frame=frame_end)


def flexion_degrees(rig: bpy.types.Object, parent_bone: str, child_bone: str) -> float:
    """The angle between two bones' posed directions (0 when they are in line): what the pose
    reached at a joint, measured on the evaluated armature rather than trusted from the keys."""
    bones = rig.pose.bones
    a = (bones[parent_bone].tail - bones[parent_bone].head).normalized()
    b = (bones[child_bone].tail - bones[child_bone].head).normalized()
    return math.degrees(math.acos(max(-1.0, min(1.0, a.dot(b)))))
