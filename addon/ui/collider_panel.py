# SPDX-License-Identifier: GPL-3.0-or-later
"""Collider settings in the Physics tab, where Blender keeps its own collision settings."""

import bpy

from .panel import MeshPropertiesPanel


class TEGUMENT_PT_collider(MeshPropertiesPanel, bpy.types.Panel):
    bl_label = "Tegument Collider"
    bl_context = "physics"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        settings = context.object.tegument_collider
        layout.label(text="Used when this object is in a skin's Tegument collider collection")
        layout.prop(settings, "thickness")
        layout.prop(settings, "friction")
        layout.prop(settings, "kinetic_friction")
        layout.prop_search(settings, "compliant_group", context.object, "vertex_groups")
        if settings.compliant_group:
            layout.prop(settings, "stiffness")
            layout.prop(settings, "cache_path")
