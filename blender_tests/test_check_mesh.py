"""Check Mesh through the installed extension: UI operator → numpy → Rust → UI."""

from __future__ import annotations

import json

import addon_utils
import bmesh
import bpy
import numpy as np
import pytest

from conftest import ADDON_MODULE, shared_data


def last_check() -> dict:
    return json.loads(bpy.context.window_manager.tegument_check_result)


def selected_vertices(obj) -> np.ndarray:
    selected = np.zeros(len(obj.data.vertices), dtype=bool)
    obj.data.vertices.foreach_get("select", selected)
    return np.flatnonzero(selected)


def test_default_cube_is_a_closed_manifold(capfd):
    bpy.ops.mesh.primitive_cube_add()
    assert bpy.ops.tegument.check_mesh() == {"FINISHED"}
    report = last_check()
    assert report["object"] == "Cube"
    assert report["is_closed_manifold"] is True
    assert (report["vertex_count"], report["edge_count"], report["polygon_count"]) == (8, 12, 6)
    assert report["boundary_vertices"] == 0
    assert "Closed manifold mesh: 8 vertices, 12 edges, 6 faces" in capfd.readouterr().out


def test_grid_reports_its_boundary(capfd):
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=5, y_subdivisions=4)
    assert bpy.ops.tegument.check_mesh() == {"FINISHED"}
    report = last_check()
    assert report["is_closed_manifold"] is False
    assert report["is_clean"] is True
    bm = bmesh.new()
    bm.from_mesh(bpy.context.active_object.data)
    assert report["boundary_vertices"] == sum(v.is_boundary for v in bm.verts) > 0
    bm.free()
    assert "Manifold mesh with a boundary" in capfd.readouterr().out


def test_non_manifold_edge_is_reported_and_selected(capfd):
    mesh = bpy.data.meshes.new("Fin")
    verts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (1, 0, 1), (0, 0, 1), (0, -1, 0), (1, -1, 0), (5, 5, 5)]
    faces = [(0, 1, 2, 3), (1, 0, 5, 4), (0, 1, 7, 6)]  # three faces on edge 0-1, vertex 8 loose
    mesh.from_pydata(verts, [], faces)
    obj = bpy.data.objects.new("Fin", mesh)
    bpy.context.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    positions_before = np.array([v.co[:] for v in mesh.vertices])

    assert bpy.ops.tegument.check_mesh() == {"FINISHED"}
    report = last_check()
    assert report["non_manifold_edges"] == 1
    assert report["isolated_vertices"] == 1
    assert set(selected_vertices(obj)) == {0, 1, 8}
    assert "1 non-manifold edges" in capfd.readouterr().out
    assert np.array_equal(positions_before, np.array([v.co[:] for v in mesh.vertices])), "positions changed"


def test_check_in_edit_mode_sees_unsaved_edits():
    bpy.ops.mesh.primitive_cube_add()
    obj = bpy.context.active_object
    bpy.ops.object.mode_set(mode="EDIT")
    bm = bmesh.from_edit_mesh(obj.data)
    bm.faces.ensure_lookup_table()
    bm.faces.remove(bm.faces[0])  # open the cube
    bmesh.update_edit_mesh(obj.data)
    assert bpy.ops.tegument.check_mesh() == {"FINISHED"}
    assert obj.mode == "EDIT"
    assert last_check()["boundary_vertices"] == 4


def test_spot_imported_with_blenders_obj_importer():
    path = shared_data("meshes", "spot", "spot_triangulated.obj")
    assert bpy.ops.wm.obj_import(filepath=str(path)) == {"FINISHED"}
    obj = bpy.context.selected_objects[0]
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.tegument.check_mesh() == {"FINISHED"}
    report = last_check()
    assert report["vertex_count"] == len(obj.data.vertices)
    assert report["polygon_count"] == len(obj.data.polygons)
    # Spot is a closed genus-0 surface: V − E + F = 2.
    assert report["vertex_count"] - report["edge_count"] + report["polygon_count"] == 2
    assert report["is_closed_manifold"] is True


def test_operator_needs_a_mesh():
    bpy.ops.object.empty_add()
    assert not bpy.ops.tegument.check_mesh.poll()
    with pytest.raises(RuntimeError, match="active object must be a mesh"):
        bpy.ops.tegument.check_mesh()


def test_registers_and_unregisters_repeatedly():
    for _ in range(3):
        addon_utils.disable(ADDON_MODULE, default_set=True)
        assert not hasattr(bpy.types, "TEGUMENT_OT_check_mesh")
        assert not hasattr(bpy.types.WindowManager, "tegument_check_result")
        addon_utils.enable(ADDON_MODULE, default_set=True)
        assert hasattr(bpy.types, "TEGUMENT_OT_check_mesh")
    bpy.ops.mesh.primitive_cube_add()
    assert bpy.ops.tegument.check_mesh() == {"FINISHED"}


def test_panel_is_in_the_modifier_tab():
    panel = bpy.types.TEGUMENT_PT_modifier
    assert (panel.bl_space_type, panel.bl_context) == ("PROPERTIES", "modifier")
