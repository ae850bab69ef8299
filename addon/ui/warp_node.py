# SPDX-License-Identifier: GPL-3.0-or-later
"""Drawing of the Tegument UV Warp node (in the node and in the sidebar's Node tab)."""

from __future__ import annotations

from ..deform.evaluate import is_rest_bound


def _material_of(node):
    import bpy

    for material in bpy.data.materials:
        if material.node_tree == node.id_data:
            return material
    return None


def draw(node, context, layout, *, extended: bool = False) -> None:
    column = layout.column()
    column.prop(node, "object")
    obj = node.object
    if obj is not None and obj.type == "MESH":
        column.prop_search(node, "uv_map", obj.data, "uv_layers", text="UV Map")
        column.prop_search(node, "rigidity_group", obj, "vertex_groups", text="Rigidity Group")
    else:
        column.prop(node, "uv_map")
        column.prop(node, "rigidity_group")
    column.template_ID(node, "rigidity_image", open="image.open")
    column.template_ID(node, "mask_image", open="image.open")
    column.prop(node, "resolution")
    if extended:
        column.prop(node, "iterations")
        column.prop(node, "orientation")
        column.prop(node, "smoothing")
        column.prop(node, "write_heatmap")
    frames = column.row(align=True)
    frames.prop(node, "frame_start")
    frames.prop(node, "frame_end")
    column.prop(node, "directory", text="")
    material = _material_of(node)
    buttons = layout.row(align=True)
    bind = buttons.operator("tegument.warp_bind", icon="PINNED")
    bake = buttons.operator("tegument.warp_bake", text="Bake", icon="REC")
    if material is not None:
        for op in (bind, bake):
            op.material, op.node = material.name, node.name
    if obj is not None and obj.type == "MESH" and not is_rest_bound(obj):
        layout.label(text=f"{obj.name} is not bound", icon="ERROR")
    if node.baked_frames:
        layout.label(text=f"Baked frames {node.baked_start}–{node.baked_start + node.baked_frames - 1}", icon="INFO")
    if node.report:
        layout.label(text=node.report)
