# SPDX-License-Identifier: GPL-3.0-or-later
"""Self Collision: a sub-panel of Tegument's panel on the Modifier tab."""

import bpy

from ..deform import evaluate
from .panel import MeshPropertiesPanel


class TEGUMENT_PT_self_collision(MeshPropertiesPanel, bpy.types.Panel):
    bl_label = "Self Collision"
    bl_context = "modifier"
    bl_parent_id = "TEGUMENT_PT_modifier"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        return super().poll(context) and evaluate.tegument_modifier(context.object) is not None

    def draw_header(self, context):
        self.layout.prop(context.object.tegument.self_collision, "enabled", text="")

    def draw(self, context):
        obj = context.object
        settings = obj.tegument.self_collision
        layout = self.layout
        layout.use_property_split = True
        layout.active = settings.enabled
        layout.prop(settings, "thickness")
        layout.prop(settings, "friction")
        layout.prop_search(settings, "group", obj, "vertex_groups")
        layout.prop(settings, "rings")
        if settings.enabled and (settings.contacts or settings.intersections or settings.held):
            layout.label(text=f"Last bake: {settings.contacts} contacts · {settings.intersections} intersecting face "
                         f"pairs · {settings.held} held", icon="ERROR" if settings.intersections else "CHECKMARK")
