# SPDX-License-Identifier: GPL-3.0-or-later
"""What Tegument's panels in the Properties editor have in common."""


class MeshPropertiesPanel:
    """Mixin of a Properties-editor panel shown for mesh objects (set ``bl_context`` to the tab)."""

    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == "MESH"


def toggled(layout, settings, toggle: str):
    """Draws the checkbox ``toggle``; returns a sub-column for the settings it enables, or None when off."""
    layout.prop(settings, toggle)
    return layout.column(align=True) if getattr(settings, toggle) else None
