# SPDX-License-Identifier: GPL-3.0-or-later
"""The Tegument panel in the Modifier properties tab, beside the real modifiers."""

import json

import bpy

from .. import pc2
from ..deform import evaluate
from .panel import MeshPropertiesPanel, toggled


def warning_lines(settings) -> list[str]:
    """One line per warning: the bind's, then the bake's (``warnings`` holds both once baked)."""
    lines = [part.strip() for part in settings.warnings.split("; ") if part.strip()]
    bind = [part.strip() for part in settings.bind_warnings.split("; ") if part.strip()]
    return bind + [line for line in lines if line not in bind]


class TEGUMENT_PT_modifier(MeshPropertiesPanel, bpy.types.Panel):
    bl_label = "Tegument"
    bl_context = "modifier"

    def draw(self, context):
        layout = self.layout
        obj = context.object
        settings = obj.tegument
        if evaluate.tegument_modifier(obj) is None:
            layout.operator("tegument.deform_add", icon="MOD_MESHDEFORM")
        else:
            header = layout.row(align=True)
            header.prop(settings, "enabled")
            header.operator("tegument.deform_remove", text="", icon="X")
            column = layout.column()
            column.use_property_split = True
            column.prop(settings, "iterations")
            column.prop(settings, "converge")
            column.prop(settings, "closeness")
            column.prop_search(settings, "closeness_group", obj, "vertex_groups")
            column.prop(settings, "scale_safe")
            column.prop(settings, "bind_source")
            column.prop(settings, "collider_collection")
            if settings.collider_collection is not None or settings.self_collision.enabled:
                column.prop(settings, "audit")
            column.prop(settings, "substeps")
            dynamics = toggled(column, settings, "dynamic")
            if dynamics is not None:
                for name in ("mass", "damping", "use_gravity"):
                    dynamics.prop(settings, name)
            strain = toggled(column, settings, "limit_stretch")
            if strain is not None:
                strain.prop(settings, "max_stretch")
                strain.prop_search(settings, "max_stretch_group", obj, "vertex_groups")
                strain.prop(settings, "strain_mode")
            frames = column.column(align=True)
            frames.prop(settings, "frame_start", text="Frame Start")
            frames.prop(settings, "frame_end", text="End")
            column.prop(settings, "cache_path")
            column.prop(settings, "live")
            buttons = layout.row(align=True)
            buttons.operator("tegument.bind")
            buttons.operator("tegument.bake", icon="REC")
            buttons.operator("tegument.bake_frame")
            buttons.operator("tegument.free_bake", icon="TRASH")
            cached = pc2.frame_count(evaluate.cache_file(obj))
            status = layout.column(align=True)
            bind = settings.bind_mesh
            stack = " of the modifier stack" if bind is not None and len(bind.vertices) != len(obj.data.vertices) else ""
            status.label(text=f"Bound: {settings.bound_vertices} vertices{stack} · cached: {cached} frames"
                         + (f" · {settings.last_frame_ms:.1f} ms/frame" if settings.last_frame_ms else ""), icon="INFO")
            if settings.collider_collection is not None and settings.audit and cached:
                status.label(
                    text=f"Audit: {settings.audit_vertices_inside} vertices inside · "
                    f"{settings.audit_edges_crossing} + {settings.audit_collider_edges_crossing} edges crossing · "
                    f"{settings.pinched_vertices} pinched",
                    icon="CHECKMARK" if not (settings.audit_vertices_inside or settings.audit_edges_crossing
                                             or settings.audit_collider_edges_crossing) else "ERROR",
                )
            if cached and (settings.limit_stretch or settings.max_recession):
                extras = []
                if settings.limit_stretch:
                    extras.append(f"worst stretch {100 * (settings.worst_stretch - 1):.1f}%")
                if settings.max_recession:
                    extras.append(f"colliders receded up to {settings.max_recession:.3g}")
                status.label(text=" · ".join(extras), icon="INFO")
            # The bind's warnings (pinned vertices by kind…) first, then the last bake's notes.
            for warning in warning_lines(settings):
                status.label(text=warning, icon="ERROR")
        layout.operator("tegument.check_mesh", icon="CHECKMARK")
        text = context.window_manager.tegument_check_result
        if text:
            result = json.loads(text)
            if result.get("object") == obj.name:
                state = "closed manifold" if result["is_closed_manifold"] else "open" if result["is_clean"] else "has problems"
                layout.label(text=f"Last check: {state}", icon="INFO")
