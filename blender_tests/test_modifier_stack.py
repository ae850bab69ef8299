"""Pyramid Deform binds the stack *above* its modifier (issue 26: a Subdivision Surface between the
Armature and Tegument), through the installed extension; plus what bind reports (pinned vertices
by kind) and that its warning survives a bake.

The bind is a Mesh datablock of its own (``obj.tegument.bind_mesh``), whether or not the stack
above Tegument changes the topology, and the user's mesh is not touched at all.
"""

from __future__ import annotations

import pathlib

import bpy
import numpy as np
import pytest

import scene as demo_scene
from conftest import wheel_bake
from test_pyramid_deform import read_pc2
from test_real_character import mesh_snapshot

BIND_MESH = "Limb · Tegument bind"


@pytest.fixture
def subdivided(tmp_path):
    """A small armature-bent tube with Armature, then Subdivision Surface (level 1), in a saved .blend."""
    limb, rig = demo_scene.build_limb(segments=12, rings=10)
    demo_scene.animate_bend(rig, 1, 4, angle_deg=90)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 4
    assert [m.type for m in limb.modifiers] == ["ARMATURE"]
    subdivision = limb.modifiers.new("Subdivision", "SUBSURF")
    subdivision.levels = subdivision.render_levels = 1
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "subdivided.blend"))
    bpy.ops.object.select_all(action="DESELECT")
    bpy.context.view_layer.objects.active = limb
    limb.select_set(True)
    return limb, rig


def evaluated(obj, frame: int, *, upstream: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Object-space ``(positions, corners, sizes)`` of the evaluated object at ``frame``, with or
    without Tegument's modifier: read here, independently of the add-on."""
    modifier = obj.modifiers.get("Tegument")
    shown = modifier.show_viewport if modifier else False
    if modifier and upstream:
        modifier.show_viewport = False
    try:
        bpy.context.scene.frame_set(frame)
        mesh = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
        positions = np.empty(len(mesh.vertices) * 3, np.float32)
        mesh.vertices.foreach_get("co", positions)
        corners = np.empty(len(mesh.loops), np.int32)
        mesh.loops.foreach_get("vertex_index", corners)
        sizes = np.empty(len(mesh.polygons), np.int32)
        mesh.polygons.foreach_get("loop_total", sizes)
    finally:
        if modifier:
            modifier.show_viewport = shown
    return positions.reshape(-1, 3), corners, sizes


def bind_meshes() -> list[str]:
    return [mesh.name for mesh in bpy.data.meshes if "Tegument bind" in mesh.name]


def test_a_subdivided_stack_binds_bakes_and_plays_back(subdivided):
    import tegument

    obj, _ = subdivided
    own_vertices = len(obj.data.vertices)
    before = mesh_snapshot(obj.data)
    rest, corners, sizes = evaluated(obj, 1, upstream=True)
    assert len(rest) > 3 * own_vertices, "the Subdivision Surface above Tegument should multiply the vertices"

    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    assert [m.type for m in obj.modifiers] == ["ARMATURE", "SUBSURF", "MESH_CACHE"]
    settings = obj.tegument
    assert settings.bind_mesh is not None and settings.bind_mesh.name == BIND_MESH
    assert settings.bound_vertices == len(rest) and settings.source_vertices == own_vertices
    bound = np.empty(len(rest) * 3, np.float32)
    settings.bind_mesh.vertices.foreach_get("co", bound)
    np.testing.assert_allclose(bound.reshape(-1, 3), rest, atol=1e-6)
    assert mesh_snapshot(obj.data) == before, "bind must not touch the user's mesh (not even add an attribute)"

    assert bpy.ops.tegument.bake() == {"FINISHED"}
    frames, start = read_pc2(bpy.path.abspath(settings.cache_path))
    assert frames.shape == (4, len(rest), 3) and start == 1.0
    assert np.isfinite(frames).all()
    assert mesh_snapshot(obj.data) == before, "the bake must not touch the user's mesh"

    # The cache is the wheel's solve of the subdivided input on the subdivided rest ...
    deformer = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=settings.scale_safe)
    m = np.array(obj.matrix_world)
    upstreams = [evaluated(obj, frame, upstream=True)[0] for frame in range(1, 5)]
    expected = wheel_bake(deformer, [(u @ m[:3, :3].T + m[:3, 3]).astype(np.float32) for u in upstreams], settings)
    m_inv = np.linalg.inv(m)
    for frame in (2, 4):
        np.testing.assert_allclose(frames[frame - 1], expected[frame - 1] @ m_inv[:3, :3].T + m_inv[:3, 3], atol=1e-5)
        assert np.abs(frames[frame - 1] - upstreams[frame - 1]).max() > 1e-4 or frame == 1
    # ... and the Mesh Cache modifier plays it back at its place in the stack.
    for frame in (1, 3, 4):
        shown = evaluated(obj, frame, upstream=False)[0]
        np.testing.assert_allclose(shown, frames[frame - 1], atol=1e-6)


def test_rebind_after_changing_the_levels_and_remove(subdivided):
    obj, _ = subdivided
    before = mesh_snapshot(obj.data)
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    first = len(obj.tegument.bind_mesh.vertices)
    obj.modifiers["Subdivision"].levels = 2
    with pytest.raises(RuntimeError, match=r"above Tegument gives \d+ vertices, but the bind has \d+: .*rebind"):
        bpy.ops.tegument.bake()

    assert bpy.ops.tegument.bind() == {"FINISHED"}
    count = len(evaluated(obj, 1, upstream=True)[0])
    assert count > first and len(obj.tegument.bind_mesh.vertices) == count
    assert bind_meshes() == [BIND_MESH], "the rebind replaces the bind mesh, it does not add one"
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    frames, _ = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    assert frames.shape == (4, count, 3)

    # Without the Subdivision Surface the bind is still a bind mesh, now of the mesh's own
    # vertices and faces: the user's mesh gets no attribute.
    obj.modifiers.remove(obj.modifiers["Subdivision"])
    assert bpy.ops.tegument.bind() == {"FINISHED"}
    assert bind_meshes() == [BIND_MESH] and len(obj.tegument.bind_mesh.vertices) == len(obj.data.vertices)
    assert [p.vertices[:] for p in obj.tegument.bind_mesh.polygons] == [p.vertices[:] for p in obj.data.polygons]
    assert "tegument_rest" not in obj.data.attributes and mesh_snapshot(obj.data) == before
    obj.modifiers.new("Subdivision", "SUBSURF")
    bpy.ops.object.modifier_move_to_index(modifier="Subdivision", index=1)
    assert bpy.ops.tegument.bind() == {"FINISHED"} and bind_meshes() == [BIND_MESH]

    assert bpy.ops.tegument.deform_remove() == {"FINISHED"}
    assert obj.tegument.bind_mesh is None and bind_meshes() == []
    assert "Tegument" not in obj.modifiers
    after = mesh_snapshot(obj.data)
    assert after == before, "Remove leaves the user's mesh as it was before the first bind"


def test_save_and_reload_keep_the_bind(subdivided, tmp_path):
    obj, _ = subdivided
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    bound = np.empty(len(obj.tegument.bind_mesh.vertices) * 3, np.float32)
    obj.tegument.bind_mesh.vertices.foreach_get("co", bound)
    blend = tmp_path / "subdivided.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))

    bpy.ops.wm.open_mainfile(filepath=str(blend))
    obj = bpy.data.objects["Limb"]
    mesh = obj.tegument.bind_mesh
    assert mesh is not None and mesh.name == BIND_MESH
    reloaded = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", reloaded)
    np.testing.assert_array_equal(reloaded, bound)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    frames, _ = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    assert frames.shape == (4, len(mesh.vertices), 3) and np.isfinite(frames).all()


def test_original_bind_pose_is_the_unposed_subdivided_mesh(subdivided):
    """Bind Pose Original at a posed frame binds the mesh's own shape through the Subdivision
    Surface (the Armature left out); Evaluated binds the pose."""
    obj, _ = subdivided
    rest = evaluated(obj, 1, upstream=True)[0]
    posed = evaluated(obj, 4, upstream=True)[0]
    assert np.abs(posed - rest).max() > 0.1
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}  # at frame 4, Bind Pose Original

    def bound():
        values = np.empty(len(obj.tegument.bind_mesh.vertices) * 3, np.float32)
        obj.tegument.bind_mesh.vertices.foreach_get("co", values)
        return values.reshape(-1, 3)

    np.testing.assert_allclose(bound(), rest, atol=1e-5)
    assert obj.modifiers["Armature"].show_viewport, "the user's modifiers must be restored"
    obj.tegument.bind_source = "EVALUATED"
    assert bpy.ops.tegument.bind() == {"FINISHED"}
    np.testing.assert_allclose(bound(), posed, atol=1e-5)


def test_an_edit_of_the_mesh_and_a_closeness_group_on_a_subdivided_stack(subdivided):
    obj, _ = subdivided
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    # A vertex group on the mesh reaches the subdivided vertices (Subdivision Surface carries it over).
    group = obj.vertex_groups.new(name="follow")
    group.add(list(range(len(obj.data.vertices))), 1.0, "REPLACE")
    obj.tegument.closeness, obj.tegument.closeness_group = 1.0, "follow"
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    frames, _ = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    np.testing.assert_allclose(frames[3], evaluated(obj, 4, upstream=True)[0], atol=1e-5)

    obj.data.vertices.add(1)
    obj.data.update()
    with pytest.raises(RuntimeError, match=r"the mesh has \d+ vertices but was bound with \d+: rebind it"):
        bpy.ops.tegument.bake()


# ---------------------------------------------------------------------------- bind reports


def grid_with_a_fin(name: str = "Grid") -> bpy.types.Object:
    """A 5 × 4 quad grid (its corners ring-fitted: two neighbours, no ring to encode) plus, for
    "Fin", a third face on one inner edge, whose ends are non-manifold, or for "Loose", two loose
    vertices (the only kind that follows the rig)."""
    rows, columns = 4, 5
    positions = [(float(c), float(r), 0.0) for r in range(rows) for c in range(columns)]
    faces = [(r * columns + c, r * columns + c + 1, (r + 1) * columns + c + 1, (r + 1) * columns + c)
             for r in range(rows - 1) for c in range(columns - 1)]
    if name == "Fin":
        positions += [(1.0, 1.0, 1.0), (2.0, 1.0, 1.0)]
        a, b = 1 * columns + 1, 1 * columns + 2
        faces.append((a, b, len(positions) - 1, len(positions) - 2))
    if name == "Loose":
        positions += [(9.0, 9.0, 0.0), (9.0, 9.0, 1.0)]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(positions, [], faces)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    return obj


def test_bind_lists_the_pinned_vertices_by_kind(tmp_path):
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "grids.blend"))
    grid = grid_with_a_fin("Grid")
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    assert grid.tegument.bind_warnings == "", "border corners are ring-fitted, not pinned"

    loose = grid_with_a_fin("Loose")
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    # Loose vertices also make the mesh unclean for Check Mesh.
    assert loose.tegument.bind_warnings == "2 vertices follow the rig: 2 isolated; the mesh has non-manifold parts (run Check Mesh)"

    fin = grid_with_a_fin("Fin")
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    # The fin's non-manifold ends are ring-fitted: nothing follows the rig, Check Mesh is suggested.
    assert fin.tegument.bind_warnings == "the mesh has non-manifold parts (run Check Mesh)"


def test_the_bind_warning_survives_a_bake(tmp_path):
    from bl_ext.user_default.tegument.ui import modifier_panel

    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "grid.blend"))
    grid = grid_with_a_fin("Loose")
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    settings = grid.tegument
    settings.frame_start, settings.frame_end = 1, 2
    settings.collider_collection = bpy.data.collections.new("Colliders")  # empty: the bake notes it
    bind_warning = "2 vertices follow the rig: 2 isolated; the mesh has non-manifold parts (run Check Mesh)"
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    assert settings.bind_warnings == bind_warning
    assert settings.warnings == f'{bind_warning}; the collider collection "Colliders" holds no mesh objects'
    assert modifier_panel.warning_lines(settings) == [*bind_warning.split("; "), 'the collider collection "Colliders" holds no mesh objects']
    assert pathlib.Path(bpy.path.abspath(settings.cache_path)).is_file()

    settings.collider_collection = None
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    assert settings.warnings == bind_warning and modifier_panel.warning_lines(settings) == bind_warning.split("; ")
    assert bpy.ops.tegument.deform_remove() == {"FINISHED"}
    assert settings.warnings == settings.bind_warnings == ""


def test_a_uv_warp_bind_leaves_a_subdivided_bind_alone(subdivided):
    """UV Warp binds the mesh's own vertices: beside a bind mesh of another vertex count (the
    subdivided stack's) that is UV Warp's own tegument_rest attribute, at the user's request, and it
    must not change what Pyramid Deform bound."""
    from bl_ext.user_default.tegument.operators.warp import bind_rest

    obj, _ = subdivided
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    bound, source = obj.tegument.bound_vertices, obj.tegument.source_vertices
    bind_rest(bpy.context, obj)
    assert "tegument_rest" in obj.data.attributes
    assert obj.tegument.bind_mesh is not None
    assert (obj.tegument.bound_vertices, obj.tegument.source_vertices) == (bound, source)
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    frames, _ = read_pc2(bpy.path.abspath(obj.tegument.cache_path))
    assert frames.shape == (4, bound, 3)
