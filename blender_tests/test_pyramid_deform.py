"""Pyramid Deform through the installed extension: bind, bake to PC2, Mesh Cache playback."""

from __future__ import annotations

import errno
import math
import os
import pathlib
import re
import signal

import bpy
import numpy as np
import pytest

import scene as demo_scene
from conftest import wheel_bake

PC2_HEADER = 32


def read_pc2(path) -> tuple[np.ndarray, float]:
    data = pathlib.Path(path).read_bytes()
    assert data[:12] == b"POINTCACHE2\0"
    version, vertices, start, sampling, frames = np.frombuffer(data[12:32], dtype="<i4,<i4,<f4,<f4,<i4")[0]
    assert version == 1 and sampling == 1.0
    assert len(data) == PC2_HEADER + 12 * vertices * frames, "cache length does not match its header"
    return np.frombuffer(data, dtype="<f4", offset=PC2_HEADER).reshape(frames, vertices, 3), float(start)


def saved_limb(tmp_path, segments: int = 16, rings: int = 12):
    """An armature-bent tube (90° over frames 1–6) in a saved .blend, so `//` cache paths resolve into tmp_path."""
    limb, rig = demo_scene.build_limb(segments=segments, rings=rings)
    demo_scene.animate_bend(rig, 1, 6, angle_deg=90)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "limb.blend"))
    bpy.context.view_layer.objects.active = limb
    limb.select_set(True)
    return limb, rig


@pytest.fixture
def limb(tmp_path):
    """A small limb (210 vertices)."""
    return saved_limb(tmp_path)


def upstream(obj, frame: int) -> np.ndarray:
    """World-space positions of the stack above Tegument at `frame`, read independently of the add-on."""
    modifier = obj.modifiers["Tegument"]
    modifier.show_viewport = False
    bpy.context.scene.frame_set(frame)
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated.to_mesh()
    local = np.array([v.co[:] for v in mesh.vertices], dtype=np.float64)
    evaluated.to_mesh_clear()
    modifier.show_viewport = True
    m = np.array(evaluated.matrix_world)
    return (local @ m[:3, :3].T + m[:3, 3]).astype(np.float32)


def mesh_arrays(obj):
    mesh = obj.data
    corners = np.array([l.vertex_index for l in mesh.loops], dtype=np.int32)
    sizes = np.array([p.loop_total for p in mesh.polygons], dtype=np.int32)
    rest = np.array([v.co[:] for v in mesh.vertices], dtype=np.float32)
    return rest, corners, sizes


def attribute_names(mesh) -> list[str]:
    return sorted(attribute.name for attribute in mesh.attributes)


def test_round_trip_matches_the_wheel(limb, capfd):
    import tegument

    obj, _ = limb
    attributes = attribute_names(obj.data)
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    modifier = obj.modifiers[-1]
    assert (modifier.name, modifier.type, modifier.cache_format) == ("Tegument", "MESH_CACHE", "PC2")
    assert obj.tegument.cache_path == "//tegument/Limb.pc2"
    # The bind is a mesh of its own, even where the stack keeps the mesh's topology: nothing is
    # added to the user's mesh.
    assert attribute_names(obj.data) == attributes and "tegument_rest" not in obj.data.attributes
    bind = obj.tegument.bind_mesh
    assert bind is not None and bind.name == "Limb · Tegument bind"
    assert obj.tegument.bound_vertices == obj.tegument.source_vertices == len(obj.data.vertices) == len(bind.vertices)
    np.testing.assert_array_equal(np.array([v.co[:] for v in bind.vertices], np.float32), mesh_arrays(obj)[0])
    assert [p.vertices[:] for p in bind.polygons] == [p.vertices[:] for p in obj.data.polygons]

    assert bpy.ops.tegument.bake() == {"FINISHED"}
    out = capfd.readouterr().out
    assert "Tegument: Limb frame 6 (6/6)" in out and "ETA" in out

    path = bpy.path.abspath(obj.tegument.cache_path)
    frames, start = read_pc2(path)
    assert frames.shape == (6, len(obj.data.vertices), 3) and start == 1.0
    assert np.isfinite(frames).all()

    rest, corners, sizes = mesh_arrays(obj)
    deformer = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=True)
    expected = wheel_bake(deformer, [upstream(obj, frame) for frame in range(1, 7)], obj.tegument)
    m_inv = np.linalg.inv(np.array(obj.matrix_world))
    for frame in (1, 4, 6):
        expected_local = expected[frame - 1] @ m_inv[:3, :3].T + m_inv[:3, 3]
        np.testing.assert_allclose(frames[frame - 1], expected_local, atol=1e-5)

    assert bpy.ops.tegument.free_bake() == {"FINISHED"}
    assert not pathlib.Path(path).exists()
    assert bpy.ops.tegument.deform_remove() == {"FINISHED"}
    assert "Tegument" not in obj.modifiers and obj.tegument.bind_mesh is None
    assert not [mesh for mesh in bpy.data.meshes if "Tegument bind" in mesh.name], "Remove deletes the bind mesh"
    assert attribute_names(obj.data) == attributes


@pytest.mark.parametrize("segments, rings", [(64, 96), (12, 16)], ids=["6k vertices", "206 vertices"])
def test_a_converge_bake_is_the_converged_look_and_more_iterations_change_it_little(tmp_path, capfd, segments, rings):
    """Issue 28, through the add-on's operators: a Converge bake (the accelerated solver,
    stopping at its tolerance within ``tegument.DEFAULTS.accelerated_iterations``, bake frames from
    the last one's result) is within 5 % of the converged solve of the same settings at every frame;
    a bake that differs only by four times the iterations differs from it by at most 5 % too; plain
    iterations (Converge off) are much further. Limbs at closeness 0.01: 6k vertices, and 206, where
    the coarse levels do little and the iteration limit counts in work (docs/pyramid-deform.md)."""
    import tegument

    obj, _ = saved_limb(tmp_path, segments=segments, rings=rings)
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    settings = obj.tegument
    # The add-on's defaults follow tegument.DEFAULTS (Converge the default: docs/pyramid-deform.md).
    assert settings.converge == tegument.DEFAULTS.converge
    assert settings.iterations == (tegument.DEFAULTS.accelerated_iterations if tegument.DEFAULTS.converge
                                   else tegument.DEFAULTS.iterations)
    settings.closeness = 0.01
    rest, corners, sizes = mesh_arrays(obj)
    reference = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=settings.scale_safe)
    reference.accelerated = True
    m_inv = np.linalg.inv(np.array(obj.matrix_world))
    to_local = lambda world: world @ m_inv[:3, :3].T + m_inv[:3, 3]  # noqa: E731
    rms = lambda a, b: float(np.sqrt(((a - b) ** 2).sum(1).mean()))  # noqa: E731
    checked = (2, 4, 6)
    converged = {f: to_local(reference.solve(upstream(obj, f), iterations=400, closeness=settings.closeness)) for f in checked}
    displacement = {f: rms(converged[f], to_local(upstream(obj, f))) for f in checked}
    runs = {
        "converge": (True, tegument.DEFAULTS.accelerated_iterations),
        "4x iterations": (True, 4 * tegument.DEFAULTS.accelerated_iterations),
        "plain": (False, tegument.DEFAULTS.iterations),
    }
    baked, errors, taken = {}, {}, {}
    for name, (converge, iterations) in runs.items():
        settings.converge, settings.iterations = converge, iterations
        capfd.readouterr()
        assert bpy.ops.tegument.bake() == {"FINISHED"}
        # The progress lines say how many iterations each frame took.
        taken[name] = [int(k) for k in re.findall(r"ms, (\d+) it\., ETA", capfd.readouterr().out)]
        baked[name], _ = read_pc2(bpy.path.abspath(settings.cache_path))
        errors[name] = max(rms(baked[name][f - 1], converged[f]) / displacement[f] for f in checked)
    assert errors["converge"] <= 0.05, errors
    more = max(rms(baked["converge"][f - 1], baked["4x iterations"][f - 1]) / displacement[f] for f in checked)
    assert more <= 0.05, f"the Converge bake and one with 4x the iterations differ by {more:.3f} of the displacement"
    assert errors["plain"] > 4 * errors["converge"], errors
    # Plain iterations run their count; Converge's warm frames stop at the tolerance, well before its limit.
    assert taken["plain"] == [tegument.DEFAULTS.iterations] * 6, taken
    assert len(taken["converge"]) == 6, taken
    if len(rest) >= 4096:  # smaller meshes count their limit in work: more iterations than the setting
        assert max(taken["converge"][1:]) < tegument.DEFAULTS.accelerated_iterations, taken


def test_a_moved_turned_and_scaled_rig_bakes_in_world_space_and_caches_object_space(limb):
    """The object matrix path (`tegument.transform_points`, both ways) against the wheel and numpy."""
    import tegument

    obj, rig = limb
    rig.location = (3.0, -1.0, 2.0)
    rig.rotation_euler = (0.4, 0.1, 1.2)
    rig.scale = (1.5, 1.5, 1.5)
    bpy.context.view_layer.update()
    assert not np.allclose(np.array(obj.matrix_world), np.eye(4))
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    frames, _ = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    rest, corners, sizes = mesh_arrays(obj)
    deformer = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=True)
    expected = wheel_bake(deformer, [upstream(obj, frame) for frame in range(1, 7)], obj.tegument)
    m_inv = np.linalg.inv(np.array(obj.matrix_world))
    for frame in (1, 6):
        np.testing.assert_allclose(frames[frame - 1], expected[frame - 1] @ m_inv[:3, :3].T + m_inv[:3, 3], atol=1e-5)


def test_pose_changes_result_and_full_closeness_follows_the_rig(limb):
    obj, rig = limb
    bpy.ops.tegument.deform_add()
    bpy.ops.tegument.bake()
    path = bpy.path.abspath(obj.tegument.cache_path)
    bent, _ = read_pc2(path)

    rig.pose.bones["Lower"].rotation_euler.z += math.radians(30)
    rig.pose.bones["Lower"].keyframe_insert("rotation_euler", frame=6)
    bpy.ops.tegument.bake()
    bent_more, _ = read_pc2(path)
    assert np.abs(bent_more[5] - bent[5]).max() > 0.05
    np.testing.assert_allclose(bent_more[0], bent[0], atol=1e-6)  # frame 1 did not change

    group = obj.vertex_groups.new(name="follow")
    group.add(list(range(len(obj.data.vertices))), 1.0, "REPLACE")
    obj.tegument.closeness = 1.0
    obj.tegument.closeness_group = "follow"
    bpy.ops.tegument.bake()
    followed, _ = read_pc2(path)
    m_inv = np.linalg.inv(np.array(obj.matrix_world))
    for frame in (1, 6):
        rig_local = upstream(obj, frame) @ m_inv[:3, :3].T + m_inv[:3, 3]
        np.testing.assert_allclose(followed[frame - 1], rig_local, atol=1e-5)


def test_cancelled_bake_keeps_exactly_the_frames_done(limb):
    obj, _ = limb
    bpy.ops.tegument.deform_add()
    obj.tegument.frame_end = 6
    frames_seen = []

    def interrupt_after_three(scene, depsgraph=None):
        frames_seen.append(scene.frame_current)
        if len(frames_seen) == 3:
            signal.raise_signal(signal.SIGINT)  # what Ctrl-C does to a background bake

    bpy.app.handlers.frame_change_post.append(interrupt_after_three)
    try:
        result = bpy.ops.tegument.bake()
    finally:
        bpy.app.handlers.frame_change_post.remove(interrupt_after_three)
    assert result == {"CANCELLED"}
    frames, start = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    assert frames.shape[0] == 3 and start == 1.0
    assert np.isfinite(frames).all()


def test_save_reload_play_back_and_render(limb, tmp_path):
    obj, _ = limb
    bpy.ops.tegument.deform_add()
    obj.tegument.closeness = 0.01
    bpy.ops.tegument.bake()
    frames, _ = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    blend = tmp_path / "limb.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))

    bpy.ops.wm.open_mainfile(filepath=str(blend))
    obj = bpy.data.objects["Limb"]
    assert obj.tegument.bound_vertices == len(obj.data.vertices)
    # The bind mesh survives the save (the object's pointer to it is a user) with the rest shape.
    bind = obj.tegument.bind_mesh
    assert bind is not None and bind.name == "Limb · Tegument bind" and bind.users == 1
    np.testing.assert_array_equal(np.array([v.co[:] for v in bind.vertices], np.float32), mesh_arrays(obj)[0])
    assert "tegument_rest" not in obj.data.attributes
    scene = bpy.context.scene
    scene.frame_set(5)
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    shown = np.array([v.co[:] for v in evaluated.to_mesh().vertices], dtype=np.float32)
    evaluated.to_mesh_clear()
    np.testing.assert_allclose(shown, frames[4], atol=1e-6)

    # Render the baked frame, the same frame without Tegument, and a plain mesh
    # built from the cached positions: the first must match the third, not the second.

    camera_target = frames[4].mean(axis=0)
    bpy.ops.object.camera_add(location=(camera_target[0], camera_target[1], camera_target[2] + 3.0))
    scene.camera = bpy.context.active_object
    bpy.ops.object.light_add(type="SUN")
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = 48

    def render(name) -> np.ndarray:
        scene.render.filepath = str(tmp_path / f"{name}.png")
        bpy.ops.render.render(write_still=True)
        image = bpy.data.images.load(scene.render.filepath)
        pixels = np.array(image.pixels[:], dtype=np.float32).reshape(48, 48, 4)
        bpy.data.images.remove(image)
        return pixels[..., :3].mean(axis=2) > 0.02  # silhouette

    with_tegument = render("tegument")
    obj.modifiers["Tegument"].show_render = False
    without = render("skinning")
    obj.hide_render = True
    mesh = obj.data.copy()
    mesh.vertices.foreach_set("co", frames[4].ravel())
    copy = bpy.data.objects.new("Baked", mesh)
    copy.matrix_world = obj.matrix_world
    scene.collection.objects.link(copy)
    reference = render("reference")
    assert with_tegument.sum() > 50
    # The bake changes what the camera sees (52 of 2,304 pixels when written): were the cache
    # plain skinning, the reference would render like it and this would fail.
    assert (without != reference).sum() >= 20, "the baked frame renders like plain skinning"
    assert (with_tegument != reference).sum() <= 2


def test_topology_change_upstream_is_refused_and_keeps_the_cache(limb, capfd):
    obj, _ = limb
    bpy.ops.tegument.deform_add()
    bpy.ops.tegument.bake()
    path = pathlib.Path(bpy.path.abspath(obj.tegument.cache_path))
    before = path.read_bytes()
    subdivision = obj.modifiers.new("Subdivision", "SUBSURF")
    bpy.ops.object.modifier_move_to_index(modifier="Subdivision", index=0)
    assert obj.modifiers[0].name == "Subdivision"
    mesh_before = np.array([v.co[:] for v in obj.data.vertices])
    with pytest.raises(RuntimeError, match=r"above Tegument gives \d+ vertices, but the bind has \d+"):
        bpy.ops.tegument.bake()
    assert path.read_bytes() == before
    assert not list(path.parent.glob(".*.tmp")), "a temporary cache file was left behind"
    assert np.array_equal(mesh_before, np.array([v.co[:] for v in obj.data.vertices]))
    assert subdivision.show_viewport, "the user's modifiers must be restored"


@pytest.mark.parametrize("converge", [False, True], ids=["plain", "converge"])
def test_bake_frame_and_live_playback(limb, converge):
    """Bake Frame and live playback write the frames a whole bake writes: each frame is solved
    from the one before it, so the frames they fill in one by one must match the bake's. With
    Converge a frame starts from the frame before it (a warm start): live playback starts from the
    cached one."""
    obj, _ = limb
    bpy.ops.tegument.deform_add()
    obj.tegument.converge = converge
    scene = bpy.context.scene
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    whole = read_pc2(bpy.path.abspath(obj.tegument.cache_path))[0]
    assert whole.shape[0] == 6
    obj.tegument.cache_path = "//frame_by_frame.pc2"
    path = bpy.path.abspath(obj.tegument.cache_path)

    scene.frame_set(3)
    assert bpy.ops.tegument.bake_frame() == {"FINISHED"}
    frames = read_pc2(path)[0]
    assert frames.shape[0] == 3  # frames 1-3: the missing ones before it were solved too
    np.testing.assert_allclose(frames, whole[:3], atol=1e-6)

    obj.tegument.live = True
    scene.frame_set(4)
    frames = read_pc2(path)[0]
    assert frames.shape[0] == 4
    np.testing.assert_allclose(frames[3], whole[3], atol=1e-6)
    shown = np.array([v.co[:] for v in obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data.vertices])
    np.testing.assert_allclose(shown, whole[3], atol=1e-5)  # what the viewport shows is the cache's frame
    scene.frame_set(6)  # a jump: the cache stays as it is
    assert read_pc2(path)[0].shape[0] == 4


def test_headless_command(limb, capfd):
    obj, _ = limb
    bpy.ops.tegument.deform_add()
    from bl_ext.user_default.tegument import cli

    assert cli.main(["bake", "--objects", "Limb", "--frames", "2-4"]) == 0
    frames, start = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    assert frames.shape[0] == 3 and start == 2.0
    assert obj.modifiers["Tegument"].frame_start == 2.0
    assert cli.main(["bake", "--objects", "Nope"]) == 2
    assert "no object named Nope" in capfd.readouterr().err


def test_cache_writer_refuses_nan_and_leaves_nothing_behind(tmp_path):
    from bl_ext.user_default.tegument import pc2

    target = tmp_path / "cache.pc2"
    good = np.zeros((2, 4, 3), np.float32)
    pc2.write(target, good, start=1)
    before = target.read_bytes()
    bad = good.copy()
    bad[1, 3, 0] = np.nan
    with pytest.raises(pc2.CacheError, match="vertex 3 of cache frame 1 is not finite"):
        pc2.write(target, bad, start=1)
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["cache.pc2"]
    frames, start, sampling = pc2.read(target)
    assert frames.shape == (2, 4, 3) and start == 1.0 and sampling == 1.0
    target.write_bytes(before[:-5])
    with pytest.raises(pc2.CacheError, match="truncated"):
        pc2.read(target)


@pytest.mark.parametrize("background", [True, False], ids=["written by a thread", "written in place"])
def test_cache_writer_writes_each_frame_as_appended_while_the_caller_reuses_its_array(tmp_path, monkeypatch, background):
    """Large frames are written in the background: the caller's array is free again as soon as
    append returns, and a write that fails is raised by the next call, the old cache kept."""
    from bl_ext.user_default.tegument import pc2

    # These frames are small: the threshold decides which path they take.
    monkeypatch.setattr(pc2, "BACKGROUND_BYTES", 0 if background else 2**62)

    target = tmp_path / "cache.pc2"
    buffer = np.empty((1000, 3), np.float32)
    writer = pc2.Writer(target, 1000, start=1, expected_frames=5)
    for k in range(5):
        buffer[:] = k  # the bake's reused output array, overwritten frame after frame
        writer.append(buffer)
        buffer[:] = -1
    writer.commit()
    frames, _, _ = pc2.read(target)
    assert [float(f.min()) for f in frames] == [0, 1, 2, 3, 4] and [float(f.max()) for f in frames] == [0, 1, 2, 3, 4]
    before = target.read_bytes()

    real_fdopen = pc2.os.fdopen

    class DiskFullAfterTheHeader:
        def __init__(self, handle, mode):
            self.file, self.written = real_fdopen(handle, mode), 0

        def write(self, data):
            self.written += 1
            if self.written > 1:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return self.file.write(data)

        def __getattr__(self, name):
            return getattr(self.file, name)

    monkeypatch.setattr(pc2.os, "fdopen", DiskFullAfterTheHeader)
    writer = pc2.Writer(target, 1000, start=1)
    with pytest.raises(pc2.CacheError, match="cannot write the cache .*No space left on device"):
        writer.append(buffer)  # in the background, the write fails after append returns...
        writer.append(buffer)  # ...and the next call says so
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["cache.pc2"]
    writer = pc2.Writer(target, 1000, start=1)
    with pytest.raises(pc2.CacheError, match="No space left on device"):
        writer.append(buffer)
        writer.commit()
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["cache.pc2"]


def test_unwritable_cache_path_is_a_clear_error(limb, tmp_path):
    obj, _ = limb
    bpy.ops.tegument.deform_add()
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("a file where the cache folder should be")
    obj.tegument.cache_path = str(blocker / "Limb.pc2")
    mesh_before = np.array([v.co[:] for v in obj.data.vertices])
    with pytest.raises(RuntimeError, match=r"cannot write the cache"):
        bpy.ops.tegument.bake()
    assert blocker.read_text() == "a file where the cache folder should be"
    assert np.array_equal(mesh_before, np.array([v.co[:] for v in obj.data.vertices]))


def test_missing_closeness_group_and_unbound_mesh_are_reported(limb):
    obj, _ = limb
    bpy.ops.tegument.deform_add()
    obj.tegument.closeness_group = "renamed"
    with pytest.raises(RuntimeError, match='closeness vertex group "renamed" does not exist'):
        bpy.ops.tegument.bake()
    obj.tegument.closeness_group = ""
    bpy.data.meshes.remove(obj.tegument.bind_mesh)  # the bind lost (a script, Purge of orphan data…)
    assert obj.tegument.bind_mesh is None
    with pytest.raises(RuntimeError, match=r"Limb is not bound: press Bind"):
        bpy.ops.tegument.bake()
    assert not pathlib.Path(bpy.path.abspath(obj.tegument.cache_path)).exists()


def make_legacy_bind(obj, *, source_vertices: int) -> np.ndarray:
    """Turns the object's bind into one made by Tegument before every bind was a bind mesh: the rest
    positions in the mesh's ``tegument_rest`` point attribute, no bind mesh (files saved before the
    mesh's own count was stored have ``source_vertices`` 0). Returns the attribute's values."""
    rest = mesh_arrays(obj)[0]
    bpy.data.meshes.remove(obj.tegument.bind_mesh)
    attribute = obj.data.attributes.new("tegument_rest", "FLOAT_VECTOR", "POINT")
    attribute.data.foreach_set("vector", rest.ravel())
    obj.tegument.source_vertices = source_vertices
    return rest


@pytest.mark.parametrize("source_vertices", ["stored", 0])
def test_a_legacy_bind_still_bakes_and_a_rebind_leaves_its_attribute_alone(limb, tmp_path, source_vertices):
    """A .blend bound by an earlier version (the ``tegument_rest`` attribute only) bakes the same
    cache as a bind mesh, also after save and reload; Bind moves the bind to a bind mesh and leaves
    the attribute as it was (removing it would change the user's mesh again); so does Remove."""
    obj, _ = limb
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    path = bpy.path.abspath(obj.tegument.cache_path)
    expected, _ = read_pc2(path)
    expected = expected.copy()

    rest = make_legacy_bind(obj, source_vertices=len(obj.data.vertices) if source_vertices == "stored" else 0)
    blend = tmp_path / "legacy.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    obj = bpy.data.objects["Limb"]
    bpy.context.view_layer.objects.active = obj
    assert obj.tegument.bind_mesh is None and "tegument_rest" in obj.data.attributes
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    np.testing.assert_array_equal(read_pc2(path)[0], expected)

    # The legacy bind's checks still hold: an edit of the mesh asks for a rebind.
    if source_vertices == "stored":
        obj.data.vertices.add(1)
        with pytest.raises(RuntimeError, match=r"the mesh has \d+ vertices but was bound with \d+: rebind it"):
            bpy.ops.tegument.bake()
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        obj = bpy.data.objects["Limb"]
        bpy.context.view_layer.objects.active = obj

    snapshot = {a.name: (a.domain, a.data_type) for a in obj.data.attributes}
    assert bpy.ops.tegument.bind() == {"FINISHED"}
    assert obj.tegument.bind_mesh is not None
    assert {a.name: (a.domain, a.data_type) for a in obj.data.attributes} == snapshot
    kept = np.empty(len(rest) * 3, np.float32)
    obj.data.attributes["tegument_rest"].data.foreach_get("vector", kept)
    np.testing.assert_array_equal(kept.reshape(-1, 3), rest)
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    np.testing.assert_array_equal(read_pc2(path)[0], expected)

    assert bpy.ops.tegument.deform_remove() == {"FINISHED"}
    assert obj.tegument.bind_mesh is None and "tegument_rest" in obj.data.attributes
