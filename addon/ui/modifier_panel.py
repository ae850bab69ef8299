# SPDX-License-Identifier: GPL-3.0-or-later
"""The Tegument panel in the Modifier properties tab, beside the real modifiers."""

import json

import bpy


class TEGUMENT_PT_modifier(bpy.types.Panel):
    bl_label = "Tegument"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "modifier"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == "MESH"

    def draw(self, context):
        layout = self.layout
        layout.operator("tegument.check_mesh", icon="CHECKMARK")
        text = context.window_manager.tegument_check_result
        if text:
            result = json.loads(text)
            if result.get("object") == context.object.name:
                state = "closed manifold" if result["is_closed_manifold"] else "open" if result["is_clean"] else "has problems"
                layout.label(text=f"Last check: {state}", icon="INFO")
