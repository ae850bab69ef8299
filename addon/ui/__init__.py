# SPDX-License-Identifier: GPL-3.0-or-later
"""Tegument's panels."""

import bpy

from . import collider_panel, modifier_panel, self_collision_panel

_classes = (modifier_panel.TEGUMENT_PT_modifier, self_collision_panel.TEGUMENT_PT_self_collision, collider_panel.TEGUMENT_PT_collider)


def register() -> None:
    for cls in _classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(_classes):
        bpy.utils.unregister_class(cls)
