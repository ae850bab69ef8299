# SPDX-License-Identifier: GPL-3.0-or-later
"""Tegument's operators, one module per job."""

import bpy

from . import check_mesh, deform, warp

_classes = (check_mesh.TEGUMENT_OT_check_mesh, *deform.classes, *warp.classes)


def register() -> None:
    for cls in _classes:
        bpy.utils.register_class(cls)
    bpy.types.WindowManager.tegument_check_result = bpy.props.StringProperty(
        name="Last mesh check",
        description="JSON report of the last Check Mesh run (not saved with the file)",
        options={"SKIP_SAVE"},
    )


def unregister() -> None:
    del bpy.types.WindowManager.tegument_check_result
    for cls in reversed(_classes):
        bpy.utils.unregister_class(cls)
