# SPDX-License-Identifier: GPL-3.0-or-later
"""Check Mesh: what Tegument sees in the active mesh, before anything is bound."""

from __future__ import annotations

import json

import bpy

from .. import mesh_arrays
from . import polls


def describe(report: dict) -> tuple[str, str]:
    """The status-bar message and its level for ``tegument.Mesh.report.to_dict()``."""
    size = f"{report['vertex_count']} vertices, {report['edge_count']} edges, {report['polygon_count']} faces"
    problems = [
        f"{report[key]} {label}"
        for key, label in (
            ("non_manifold_edges", "non-manifold edges"),
            ("flipped_edges", "edges between faces of opposite orientation"),
            ("non_manifold_vertices", "non-manifold vertices"),
            ("degenerate_polygons", "degenerate faces"),
            ("isolated_vertices", "loose vertices"),
        )
        if report[key]
    ]
    if problems:
        return "WARNING", f"{size}: " + ", ".join(problems) + " (selected)"
    if report["is_closed_manifold"]:
        return "INFO", f"Closed manifold mesh: {size}"
    return "INFO", f"Manifold mesh with a boundary: {size}, {report['boundary_vertices']} boundary vertices"


class TEGUMENT_OT_check_mesh(bpy.types.Operator):
    """Check the active mesh for what Tegument cannot deform cleanly (non-manifold edges, degenerate faces, loose vertices) and select it"""

    bl_idname = "tegument.check_mesh"
    bl_label = "Check Mesh"
    bl_options = {"REGISTER", "UNDO"}

    poll = classmethod(polls.mesh)

    def execute(self, context):
        import tegument

        obj = context.active_object
        was_edit = obj.mode == "EDIT"
        if was_edit:
            bpy.ops.object.mode_set(mode="OBJECT")
        try:
            mesh = obj.data
            try:
                checked = tegument.Mesh(
                    mesh_arrays.positions(mesh), mesh_arrays.corner_verts(mesh), mesh_arrays.polygon_sizes(mesh)
                )
            except tegument.TegumentError as error:
                self.report({"ERROR"}, f"{obj.name}: {error}")
                return {"CANCELLED"}
            report = checked.report.to_dict()
            problems = checked.problem_vertices()
            if len(problems):
                mesh_arrays.set_vertex_selection(mesh, problems)
            context.window_manager.tegument_check_result = json.dumps({"object": obj.name, **report})
            level, message = describe(report)
            self.report({level}, message)
            return {"FINISHED"}
        finally:
            if was_edit:
                bpy.ops.object.mode_set(mode="EDIT")
