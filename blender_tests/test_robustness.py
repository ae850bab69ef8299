"""Robustness battery in real Blender: every bad input or interruption gets a clear
message, and nothing is lost.

Each case checks the message the user sees AND a snapshot taken before the
action: the mesh (positions, corners, polygon sizes, edges, shape keys,
vertex groups), the modifier stack (order and visibility), the bind, the
cache file (its bytes, or its absence) and the cache folder (no temporary
files left behind).

Table rows: ``TOPOLOGY_CASES`` (meshes Tegument must cope with),
``BAKE_REFUSALS`` (setups a bake must refuse). Cases for features built
elsewhere (collider collections, the UV Warp node) are added as rows of the
same tables: a row is a setup function, the action, the expected message and
what must be preserved.
"""

from __future__ import annotations

import errno
import math
import os
import pathlib
import signal
from dataclasses import dataclass
from typing import Callable

import bpy
import numpy as np
import pytest

PC2_HEADER = 32


def addon():
    import importlib

    return importlib.import_module("bl_ext.user_default.tegument")


def read_pc2(path) -> np.ndarray:
    data = pathlib.Path(path).read_bytes()
    assert data[:12] == b"POINTCACHE2\0"
    version, vertices, start, sampling, frames = np.frombuffer(data[12:32], dtype="<i4,<i4,<f4,<f4,<i4")[0]
    assert version == 1 and len(data) == PC2_HEADER + 12 * vertices * frames, "cache length does not match its header"
    return np.frombuffer(data, dtype="<f4", offset=PC2_HEADER).reshape(frames, vertices, 3)


# ------------------------------------------------------------------ snapshots

@dataclass
class Snapshot:
    """Everything of the user's that a failed action must leave as it was."""

    positions: np.ndarray
    corners: np.ndarray
    sizes: np.ndarray
    edges: np.ndarray
    shape_keys: list
    groups: list
    modifiers: list
    rest: np.ndarray | None
    attributes: list
    cache: bytes | None
    folder: list

    @classmethod
    def take(cls, obj) -> "Snapshot":
        mesh = obj.data
        positions = np.empty(len(mesh.vertices) * 3, np.float32)
        mesh.vertices.foreach_get("co", positions)
        corners = np.empty(len(mesh.loops), np.int32)
        mesh.loops.foreach_get("vertex_index", corners)
        sizes = np.empty(len(mesh.polygons), np.int32)
        mesh.polygons.foreach_get("loop_total", sizes)
        edges = np.empty(len(mesh.edges) * 2, np.int32)
        mesh.edges.foreach_get("vertices", edges)
        keys = []
        if mesh.shape_keys:
            for block in mesh.shape_keys.key_blocks:
                data = np.empty(len(block.data) * 3, np.float32)
                block.data.foreach_get("co", data)
                keys.append((block.name, block.value, data))
        # The bind: the bind mesh's rest positions, or a legacy bind's tegument_rest attribute.
        rest = None
        bind = obj.tegument.bind_mesh
        if bind is not None:
            rest = np.empty(len(bind.vertices) * 3, np.float32)
            bind.vertices.foreach_get("co", rest)
        elif "tegument_rest" in mesh.attributes:
            attribute = mesh.attributes["tegument_rest"]
            rest = np.empty(len(attribute.data) * 3, np.float32)
            attribute.data.foreach_get("vector", rest)
        # Named attributes (Blender's internal ".…" ones are the selection, which Check Mesh changes
        # on purpose, or the topology, compared above): bind and bake add none.
        attributes = sorted((a.name, a.domain, a.data_type) for a in mesh.attributes if not a.name.startswith("."))
        path = pathlib.Path(bpy.path.abspath(obj.tegument.cache_path))
        cache = path.read_bytes() if path.is_file() else None
        folder = sorted(p.name for p in path.parent.iterdir()) if path.parent.is_dir() else []
        return cls(
            positions, corners, sizes, edges, keys,
            [(g.name, g.index) for g in obj.vertex_groups],
            [(m.name, m.type, m.show_viewport, m.show_render) for m in obj.modifiers],
            rest, attributes, cache, folder,
        )

    def assert_same(self, other: "Snapshot", *, cache: bool = True) -> None:
        for name in ("positions", "corners", "sizes", "edges"):
            np.testing.assert_array_equal(getattr(other, name), getattr(self, name), err_msg=f"the mesh's {name} changed")
        assert len(other.shape_keys) == len(self.shape_keys)
        for (n0, v0, d0), (n1, v1, d1) in zip(self.shape_keys, other.shape_keys):
            assert (n0, v0) == (n1, v1)
            np.testing.assert_array_equal(d0, d1, err_msg=f"shape key {n0} changed")
        assert other.groups == self.groups, "vertex groups changed"
        assert other.modifiers == self.modifiers, "the modifier stack changed"
        if self.rest is None:
            assert other.rest is None
        else:
            np.testing.assert_array_equal(other.rest, self.rest, err_msg="the bind changed")
        assert other.attributes == self.attributes, "the mesh's attributes changed"
        if cache:
            assert other.cache == self.cache, "the cache file changed"
            assert other.folder == self.folder, f"the cache folder changed: {self.folder} -> {other.folder}"


def run_operator(op, capfd, **kwargs) -> tuple[str, str]:
    """Runs an operator; returns (outcome, everything it reported).

    In background mode an ERROR report makes ``bpy.ops`` raise RuntimeError
    with the message (the UI shows it in the status bar instead): the
    outcome is then ``"ERROR"``. An operator must never let another exception
    (a traceback) escape.
    """
    capfd.readouterr()
    try:
        result = op(**kwargs)
    except RuntimeError as error:
        return "ERROR", str(error) + capfd.readouterr().out
    return next(iter(result)), capfd.readouterr().out


# -------------------------------------------------------------------- scenes

def save_scene(tmp_path) -> None:
    """Saves the .blend so that `//` cache paths resolve into tmp_path."""
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))


def mesh_object(name, vertices, faces, edges=()):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(map(float, v)) for v in vertices], list(edges), [tuple(f) for f in faces])
    mesh.validate(clean_customdata=False)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.collection.objects.link(obj)
    for other in bpy.context.view_layer.objects:
        other.select_set(False)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    return obj


def animate_location(obj, frames=3):
    """Rigid motion over the frames: a bake has something to solve."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, frames
    obj.location = (0, 0, 0)
    obj.keyframe_insert("location", frame=1)
    obj.location = (0.5, 0.2, 0.1)
    obj.keyframe_insert("location", frame=frames)
    scene.frame_set(1)


CUBE_VERTS = [(x, y, z) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)]
CUBE_FACES = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]


def sphere(name="Ball"):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8, radius=1)
    obj = bpy.context.active_object
    obj.name = name
    return obj


@dataclass
class TopologyCase:
    name: str
    build: Callable[[], object]
    check_level: str          # outcome of Check Mesh: "FINISHED" with this text in the report
    check_text: str
    bind_text: str            # in the Bind / Add report


TOPOLOGY_CASES = [
    TopologyCase(
        "non-manifold edge",
        lambda: mesh_object("Fin", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (1, 0, 1), (0, 0, 1), (0, -1, 0), (1, -1, 0)],
                            [(0, 1, 2, 3), (1, 0, 5, 4), (0, 1, 7, 6)]),
        "FINISHED", "1 non-manifold edges", "non-manifold parts"),  # ring-fitted, not pinned
    TopologyCase(
        "loose vertices and edges",
        lambda: mesh_object("Loose", CUBE_VERTS + [(5, 5, 5), (6, 6, 6), (7, 6, 6)], CUBE_FACES, edges=[(9, 10)]),
        "FINISHED", "3 loose vertices", "follow the rig"),
    TopologyCase(
        "n-gons",
        lambda: mesh_object("Prism", [(math.cos(a), math.sin(a), z) for z in (0, 1) for a in np.linspace(0, 2 * math.pi, 7)[:-1]],
                            [tuple(range(5, -1, -1)), tuple(range(6, 12))] + [(i, (i + 1) % 6, 6 + (i + 1) % 6, 6 + i) for i in range(6)]),
        "FINISHED", "Closed manifold mesh: 12 vertices, 18 edges, 8 faces", "Bound Prism: 12 vertices"),
    TopologyCase(
        "zero-area faces",
        lambda: mesh_object("Sliver", [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (2, 1, 0)], [(0, 1, 2), (0, 1, 3), (1, 2, 4)]),
        "FINISHED", "1 degenerate faces", "non-manifold parts"),
    TopologyCase(
        "duplicate vertices",
        lambda: mesh_object("Seam", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (1, 0, 0), (2, 0, 0), (2, 1, 0), (1, 1, 0)],
                            [(0, 1, 2, 3), (4, 5, 6, 7)]),
        "FINISHED", "Manifold mesh with a boundary: 8 vertices", "2 on split seams welded"),
    TopologyCase(
        "flipped face",
        lambda: mesh_object("Flipped", CUBE_VERTS, CUBE_FACES[:-1] + [tuple(reversed(CUBE_FACES[-1]))]),
        "FINISHED", "4 edges between faces of opposite orientation", "non-manifold parts"),
]


@pytest.mark.parametrize("case", TOPOLOGY_CASES, ids=lambda c: c.name)
def test_unusual_topology_checks_binds_and_bakes_without_touching_the_mesh(case, tmp_path, capfd):
    obj = case.build()
    animate_location(obj)
    save_scene(tmp_path)
    before = Snapshot.take(obj)

    outcome, text = run_operator(bpy.ops.tegument.check_mesh, capfd)
    assert outcome == case.check_level and case.check_text in text, (outcome, text)
    after_check = Snapshot.take(obj)
    before.assert_same(after_check)  # Check Mesh only changes the selection

    outcome, text = run_operator(bpy.ops.tegument.deform_add, capfd)
    assert outcome == "FINISHED" and case.bind_text in text, (outcome, text)
    outcome, text = run_operator(bpy.ops.tegument.bake, capfd)
    assert outcome == "FINISHED" and "Baked" in text, (outcome, text)
    frames = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    assert frames.shape == (3, len(obj.data.vertices), 3) and np.isfinite(frames).all()
    after = Snapshot.take(obj)
    for name in ("positions", "corners", "sizes", "edges"):
        np.testing.assert_array_equal(getattr(after, name), getattr(before, name))
    assert after.attributes == before.attributes, "bind and bake add nothing to the mesh (the bind is a mesh of its own)"


# ------------------------------------------------------------- bake refusals

@dataclass
class Refusal:
    name: str
    setup: Callable  # (obj, tmp_path) -> None: breaks something after a good bake
    message: str     # regex of the message the user sees
    action: str = "bake"


def add_subsurf_above(obj, tmp_path):
    obj.modifiers.new("Subdivision", "SUBSURF")
    bpy.ops.object.modifier_move_to_index(modifier="Subdivision", index=0)


def add_remesh_after_a_deform(obj, tmp_path):
    """A Displace (a deform modifier) that swells the ball, then a voxel Remesh: the remeshed
    topology depends on the displaced shape."""
    displace = obj.modifiers.new("Swell", "DISPLACE")
    displace.strength = 0.6
    remesh = obj.modifiers.new("Remesh", "REMESH")
    remesh.mode, remesh.voxel_size = "VOXEL", 0.15
    for index, name in enumerate(("Swell", "Remesh")):
        bpy.ops.object.modifier_move_to_index(modifier=name, index=index)


def add_vertex_to_mesh(obj, tmp_path):
    import bmesh

    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bm.verts.new((3, 3, 3))
    bm.to_mesh(obj.data)
    bm.free()


def rename_closeness_group(obj, tmp_path):
    group = obj.vertex_groups.new(name="follow")
    group.add(list(range(len(obj.data.vertices))), 1.0, "REPLACE")
    obj.tegument.closeness_group = "follow"
    group.name = "follow_renamed"


def nan_shape_key(obj, tmp_path):
    obj.shape_key_add(name="Basis")
    key = obj.shape_key_add(name="Broken")
    key.data[5].co = (math.nan, 0.0, 0.0)
    key.value = 1.0


def inf_shape_key(obj, tmp_path):
    obj.shape_key_add(name="Basis")
    key = obj.shape_key_add(name="Huge")
    co = np.empty(len(key.data) * 3, np.float32)
    key.data.foreach_get("co", co)
    key.data.foreach_set("co", co * np.float32(3e38))
    key.value = 1.0


def huge_displace(obj, tmp_path):
    displace = obj.modifiers.new("Displace", "DISPLACE")
    displace.strength = 1e38
    bpy.ops.object.modifier_move_to_index(modifier="Displace", index=0)


def cache_parent_is_a_file(obj, tmp_path):
    (tmp_path / "blocker").write_text("a file where the cache folder should be")
    obj.tegument.cache_path = str(tmp_path / "blocker" / "Ball.pc2")


def cache_path_is_a_folder(obj, tmp_path):
    (tmp_path / "folder.pc2").mkdir()
    obj.tegument.cache_path = str(tmp_path / "folder.pc2")


# Undone after each test (autouse fixture below): a folder left unwritable would
# break the cleanup of pytest's temporary folders.
_UNDO: list[Callable[[], None]] = []


@pytest.fixture(autouse=True)
def _undo_after_test():
    yield
    while _UNDO:
        _UNDO.pop()()


def cache_folder_read_only(obj, tmp_path):
    """The cache folder made unwritable. Root ignores permission bits, and CI runs as root: there
    the folder is made immutable (``chattr +i``: not even root may create, rename or delete in
    it), or failing that bind-mounted read-only over itself."""
    folder = pathlib.Path(bpy.path.abspath(obj.tegument.cache_path)).parent
    if os.geteuid() != 0:
        folder.chmod(0o555)
        _UNDO.append(lambda: folder.chmod(0o755))
        return
    import subprocess

    def run(*command) -> bool:
        return subprocess.run(command, capture_output=True).returncode == 0

    if run("chattr", "+i", str(folder)):
        _UNDO.append(lambda: run("chattr", "-i", str(folder)))
    elif run("mount", "--bind", str(folder), str(folder)):
        _UNDO.append(lambda: run("umount", str(folder)))
        assert run("mount", "-o", "remount,ro,bind", str(folder)), f"cannot remount {folder} read-only"
    else:
        message = f"as root, neither chattr +i nor a read-only bind mount could make {folder} unwritable"
        if os.environ.get("CI") == "true":
            pytest.fail(message + " (required under CI)")
        pytest.skip(message)
    # The folder really is unwritable now, even for root.
    probe = folder / "probe"
    with pytest.raises(OSError):
        probe.write_bytes(b"")


def unbind(obj, tmp_path):
    """The bind lost: its bind mesh deleted (by a script, or Purge of orphan data after an unlink)."""
    bpy.data.meshes.remove(obj.tegument.bind_mesh)


def legacy_unbind(obj, tmp_path):
    """A bind of an earlier version (the tegument_rest attribute, no bind mesh) whose attribute was
    then removed (by a script, or by applying modifiers)."""
    bpy.data.meshes.remove(obj.tegument.bind_mesh)
    obj.data.attributes.new("tegument_rest", "FLOAT_VECTOR", "POINT")
    obj.data.attributes.remove(obj.data.attributes["tegument_rest"])


def legacy_edited(obj, tmp_path):
    """A legacy bind (the tegument_rest attribute) of a mesh edited since: Edit Mode carries the
    attribute over to the new vertex, so only the count stored at bind time shows the edit."""
    rest = np.empty(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", rest)
    bpy.data.meshes.remove(obj.tegument.bind_mesh)
    attribute = obj.data.attributes.new("tegument_rest", "FLOAT_VECTOR", "POINT")
    attribute.data.foreach_set("vector", rest)
    add_vertex_to_mesh(obj, tmp_path)
    assert len(obj.data.attributes["tegument_rest"].data) == len(obj.data.vertices)


def empty_range(obj, tmp_path):
    obj.tegument.frame_end = obj.tegument.frame_start - 1


# Rows for features still being built go here too, e.g. (with the operator
# names those features define):
#   Refusal("empty collider collection", lambda obj, tmp: setattr(obj.tegument, "collider_collection",
#           bpy.data.collections.new("Empty")), r"<the message the collider code gives>"),
#   Refusal("UV warp image missing", <setup>, r"<message>", action="<warp bake operator>"),
BAKE_REFUSALS = [
    Refusal("upstream modifier changes the vertex count", add_subsurf_above,
            r"at frame 1 the modifier stack above Tegument gives \d+ vertices, but the bind has 114"),
    Refusal("mesh edited after binding", add_vertex_to_mesh, r"Ball: the mesh has 115 vertices but was bound with 114: rebind it"),
    Refusal("renamed vertex group", rename_closeness_group, r'Ball: the closeness vertex group "follow" does not exist'),
    Refusal("NaN upstream (shape key)", nan_shape_key, r"Ball: at frame 1 the input position of vertex 5 is not finite"),
    Refusal("cache folder is a file", cache_parent_is_a_file, r"cannot write the cache in .*blocker: .*blocker is a file, not a folder"),
    Refusal("cache path is a folder", cache_path_is_a_folder, r"cannot write the cache .*folder\.pc2: Is a directory"),
    Refusal("read-only cache folder", cache_folder_read_only,
            r"cannot write the cache in .*: (Permission denied|Operation not permitted|Read-only file system)"),
    Refusal("mesh not bound", unbind, r"Ball is not bound: press Bind"),
    Refusal("legacy bind lost", legacy_unbind, r"Ball is not bound: press Bind"),
    Refusal("legacy bind, mesh edited after binding", legacy_edited,
            r"Ball: the mesh has 115 vertices but was bound with 114: rebind it"),
    Refusal("empty frame range", empty_range, r"Ball: the frame range 1–0 is empty"),
    Refusal("Bake Frame outside the range", lambda obj, tmp: bpy.context.scene.frame_set(9),
            r"frame 9 is outside the bake range 1–3", action="bake_frame"),
    Refusal("Bake Frame with NaN upstream", nan_shape_key, r"vertex 5 is not finite", action="bake_frame"),
    Refusal("Add Pyramid Deform twice", lambda obj, tmp: None, r"Ball already has Pyramid Deform", action="deform_add"),
    # A topology-changing stack above Tegument is bound as it is (test_modifier_stack.py); what
    # Bind Pose Original cannot bind is one whose topology depends on the pose.
    Refusal("rebind Original through a pose-dependent topology", add_remesh_after_a_deform,
            r"Ball: the modifier stack above Tegument gives \d+ vertices posed and \d+ without its deform modifiers",
            action="bind"),
]


@pytest.fixture
def baked_ball(tmp_path, capfd):
    """A sphere with Pyramid Deform and a good 3-frame cache."""
    obj = sphere()
    animate_location(obj)
    save_scene(tmp_path)
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    assert read_pc2(bpy.path.abspath(obj.tegument.cache_path)).shape[0] == 3
    capfd.readouterr()
    return obj


@pytest.mark.parametrize("case", BAKE_REFUSALS, ids=lambda c: c.name)
def test_refused_actions_report_and_keep_everything(case, baked_ball, tmp_path, capfd):
    obj = baked_ball
    case.setup(obj, tmp_path)
    before = Snapshot.take(obj)
    frame_before = bpy.context.scene.frame_current
    try:
        outcome, text = run_operator(getattr(bpy.ops.tegument, case.action), capfd)
    finally:
        while _UNDO:  # a folder made unwritable by the setup becomes writable again
            _UNDO.pop()()
    assert outcome in ("ERROR", "CANCELLED"), (outcome, text)
    import re

    assert re.search(case.message, text), f"expected /{case.message}/ in: {text}"
    assert "Traceback" not in text
    before.assert_same(Snapshot.take(obj))
    assert bpy.context.scene.frame_current == frame_before


# Blender clamps a Displace strength of 1e38 to 10000: the cache holds ~1e4.
@pytest.mark.parametrize("setup, magnitude", [(inf_shape_key, 1e30), (huge_displace, 1e3)],
                         ids=["shape key x 3e38", "Displace strength 1e38"])
def test_extreme_finite_upstream_positions_bake_to_a_finite_cache_or_are_refused(setup, magnitude, baked_ball, capfd):
    """Coordinates near the float32 limit: either a finite cache or a clear refusal, never NaN in a cache."""
    obj = baked_ball
    setup(obj, None)
    before = Snapshot.take(obj)
    outcome, text = run_operator(bpy.ops.tegument.bake, capfd)
    if outcome == "ERROR":
        assert "not finite" in text or "non-finite" in text, text
        before.assert_same(Snapshot.take(obj))
        return
    assert outcome == "FINISHED", text
    frames = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    assert frames.shape[0] == 3 and np.isfinite(frames).all()
    assert np.abs(frames).max() > magnitude, "the cache must hold the extreme positions the rig produced"
    before.assert_same(Snapshot.take(obj), cache=False)


# -------------------------------------------------- interruption and re-entrancy

def test_full_disk_is_a_clear_error_and_keeps_the_old_cache(baked_ball, capfd, monkeypatch):
    obj = baked_ball
    pc2 = addon().pc2
    real_fdopen = pc2.os.fdopen

    class FullDisk:
        """A file whose disk fills up after the header and one frame."""

        def __init__(self, handle, mode):
            self.file = real_fdopen(handle, mode)
            self.budget = PC2_HEADER + 12 * len(obj.data.vertices)

        def write(self, data):
            if len(data) > self.budget:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            self.budget -= len(data)
            return self.file.write(data)

        def __getattr__(self, name):
            return getattr(self.file, name)

    monkeypatch.setattr(pc2.os, "fdopen", FullDisk)
    before = Snapshot.take(obj)
    outcome, text = run_operator(bpy.ops.tegument.bake, capfd)
    monkeypatch.undo()
    assert outcome == "ERROR" and "No space left on device" in text and "cannot write the cache" in text, text
    before.assert_same(Snapshot.take(obj))


def test_a_bug_during_a_bake_is_a_message_and_restores_everything(baked_ball, capfd, monkeypatch):
    obj = baked_ball
    obj.modifiers.new("Smooth", "SMOOTH")  # below Tegument: hidden during the bake, must come back
    bake = addon().deform.bake
    calls = []

    def broken(scene, o, frame, *args, **kwargs):
        calls.append(frame)
        if len(calls) == 2:
            raise ZeroDivisionError("simulated bug")
        return real(scene, o, frame, *args, **kwargs)

    real = bake.solve_frame
    monkeypatch.setattr(bake, "solve_frame", broken)
    before = Snapshot.take(obj)
    outcome, text = run_operator(bpy.ops.tegument.bake, capfd)
    assert outcome == "ERROR" and "Tegument internal error (please report it" in text and "ZeroDivisionError: simulated bug" in text, text
    before.assert_same(Snapshot.take(obj))
    assert not bake.is_baking(obj)


def test_second_bake_of_the_same_object_is_refused_while_one_runs(baked_ball, capfd):
    """What the modal bake does between timer events, with the user pressing Bake again."""
    obj = baked_ball
    bake = addon().deform.bake
    path = pathlib.Path(bpy.path.abspath(obj.tegument.cache_path))
    old = path.read_bytes()
    job = bake.BakeJob(bpy.context, obj, range(1, 4))
    job.step()
    for op in (bpy.ops.tegument.bake, bpy.ops.tegument.bake_frame):
        outcome, text = run_operator(op, capfd)
        assert outcome == "ERROR" and "Ball is already being baked: wait for that bake to finish" in text, text
        assert path.read_bytes() == old, "the refused bake touched the cache"
    while not job.finished:
        job.step()
    job.commit()
    frames = read_pc2(path)
    assert frames.shape[0] == 3 and np.isfinite(frames).all()
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]
    assert run_operator(bpy.ops.tegument.bake, capfd)[0] == "FINISHED", "the refusal must end with the job"


def test_failed_job_releases_the_object(baked_ball, capfd):
    obj = baked_ball
    nan_shape_key(obj, None)
    assert run_operator(bpy.ops.tegument.bake, capfd)[0] == "ERROR"
    obj.shape_key_clear()
    assert run_operator(bpy.ops.tegument.bake, capfd)[0] == "FINISHED"


def test_live_playback_does_not_re_solve_the_frames_of_a_bake(baked_ball, capfd, monkeypatch):
    obj = baked_ball
    obj.tegument.live = True
    bake = addon().deform.bake
    solved = []
    real = bake.solve_frame

    def counting(scene, o, frame, *args, **kwargs):
        solved.append(frame)
        return real(scene, o, frame, *args, **kwargs)

    monkeypatch.setattr(bake, "solve_frame", counting)
    assert run_operator(bpy.ops.tegument.bake, capfd)[0] == "FINISHED"
    assert solved == [1, 2, 3], f"frames solved during one bake: {solved}"
    assert "live" not in obj.tegument.warnings


def test_esc_in_a_modal_bake_keeps_a_valid_cache_of_the_frames_done(baked_ball):
    """The modal operator's Esc path: a job stepped twice, then committed as cancelled."""
    obj = baked_ball
    bake = addon().deform.bake
    job = bake.BakeJob(bpy.context, obj, range(1, 4))
    job.step()
    job.step()
    job.commit()
    frames = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    assert frames.shape[0] == 2 and np.isfinite(frames).all()
    assert not bake.is_baking(obj)


def test_sigint_during_a_command_line_bake_keeps_the_frames_done(baked_ball, capfd):
    obj = baked_ball
    cli = addon().cli
    seen = []

    def interrupt(scene, depsgraph=None):
        seen.append(scene.frame_current)
        if len(seen) == 2:
            signal.raise_signal(signal.SIGINT)

    bpy.app.handlers.frame_change_post.append(interrupt)
    try:
        code = cli.main(["bake", "--objects", "Ball"])
    finally:
        bpy.app.handlers.frame_change_post.remove(interrupt)
    assert code == 130
    frames = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    assert frames.shape[0] == 2 and np.isfinite(frames).all()
    assert "cancelled; keeping the 2 frames done" in capfd.readouterr().out


def test_live_playback_error_goes_to_the_status_and_keeps_the_cache(baked_ball):
    obj = baked_ball
    obj.tegument.live = True
    bpy.context.scene.frame_set(1)
    nan_shape_key(obj, None)
    before = Snapshot.take(obj)
    bpy.context.scene.frame_set(2)
    assert "live:" in obj.tegument.warnings and "vertex 5 is not finite" in obj.tegument.warnings
    before.assert_same(Snapshot.take(obj))


def test_live_playback_after_the_topology_changed_says_so(baked_ball, capfd):
    """A cached frame whose input no longer has the bind's vertices (a Subdivision added above
    Tegument after the bake) is no warm start: the frame is solved from its own input, whose solve
    names what changed, in the modifier's status line rather than as an error in Blender's
    frame-change handler."""
    obj = baked_ball
    bpy.context.scene.frame_set(1)
    add_subsurf_above(obj, None)
    obj.tegument.live = True
    capfd.readouterr()
    bpy.context.scene.frame_set(2)
    err = capfd.readouterr().err
    assert "Traceback" not in err, err
    assert "live:" in obj.tegument.warnings and "the topology above Tegument changed" in obj.tegument.warnings


def test_command_line_errors(baked_ball, capfd):
    obj = baked_ball
    cli = addon().cli
    before = Snapshot.take(obj)
    assert cli.main(["bake", "--frames", "1-x"]) == 2
    assert "--frames expects START-END, got '1-x'" in capfd.readouterr().err
    assert cli.main(["bake", "--objects", "Nope"]) == 2
    assert "no object named Nope" in capfd.readouterr().err
    nan_shape_key(obj, None)
    before = Snapshot.take(obj)
    assert cli.main(["bake", "--objects", "Ball"]) == 1
    assert "error: Ball: at frame 1 the input position of vertex 5 is not finite" in capfd.readouterr().err
    before.assert_same(Snapshot.take(obj))


def test_free_bake_and_remove(baked_ball, tmp_path, capfd):
    obj = baked_ball
    path = pathlib.Path(bpy.path.abspath(obj.tegument.cache_path))
    assert run_operator(bpy.ops.tegument.free_bake, capfd)[0] == "FINISHED" and not path.exists()
    outcome, text = run_operator(bpy.ops.tegument.free_bake, capfd)
    assert outcome == "CANCELLED" and "Ball has no cache to free" in text
    (tmp_path / "dir.pc2").mkdir()
    obj.tegument.cache_path = str(tmp_path / "dir.pc2")
    outcome, text = run_operator(bpy.ops.tegument.free_bake, capfd)
    assert outcome == "ERROR" and "cannot delete" in text and (tmp_path / "dir.pc2").is_dir()
    before = Snapshot.take(obj)
    assert run_operator(bpy.ops.tegument.deform_remove, capfd)[0] == "FINISHED"
    after = Snapshot.take(obj)
    for name in ("positions", "corners", "sizes", "edges"):
        np.testing.assert_array_equal(getattr(after, name), getattr(before, name))
    assert after.rest is None and "Tegument" not in obj.modifiers


def test_operators_on_a_non_mesh_say_why(capfd):
    bpy.ops.object.empty_add()
    for op in (bpy.ops.tegument.check_mesh, bpy.ops.tegument.deform_add, bpy.ops.tegument.bake):
        outcome, text = run_operator(op, capfd)
        assert outcome == "ERROR" and "The active object must be a mesh" in text, text
