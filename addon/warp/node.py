# SPDX-License-Identifier: GPL-3.0-or-later
"""The Tegument UV Warp shader node and its inner tree of stock nodes.

The node is a ``ShaderNodeCustomGroup``: what renders is its private node
group, built only from stock nodes so Cycles and EEVEE (and a Blender
without Tegument) render it. Before a bake the group passes the UV through;
after a bake it samples the baked redirection sequence, one Image Texture
per UDIM tile, and falls back to the incoming UV where the texture says the
texel lies outside every UV chart (validity, the blue channel, is 0).

The node owns its group: ``init`` creates it, ``copy`` gives the copy its
own, ``free`` removes it, so deleting the node leaves no orphan group.
"""

from __future__ import annotations

import os

import bpy
import tegument
from bpy.props import (
    BoolProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from . import raster

NODE_IDNAME = "TegumentUVWarpNode"
GROUP_PREFIX = ".Tegument UV Warp"
GROUP_MARK = "tegument_uv_warp_group"  # custom property marking the groups this module owns

# Blender 4.5 made blend-relative ("//") paths an explicit option of path properties.
_RELATIVE_PATH = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else set()


def _is_mesh(node, obj) -> bool:
    return obj.type == "MESH"


def _refresh(node, context) -> None:
    node.update_uv_source()


class TEGUMENT_NT_uv_warp(bpy.types.ShaderNodeCustomGroup):
    """Redirect UVs so rigid texture detail keeps its shape while the surface under it stretches
    (samples the baked Tegument UV warp sequence)"""

    bl_idname = NODE_IDNAME
    bl_label = "Tegument UV Warp"
    bl_width_default = 240

    object: PointerProperty(
        name="Object", type=bpy.types.Object, poll=_is_mesh,
        description="The deforming mesh whose surface this material covers",
    )
    uv_map: StringProperty(
        name="UV Map", update=_refresh,
        description="UV map of the warp (empty: the mesh's active render UV map); also the UV used "
        "when the node's UV input is not connected",
    )
    rigidity_image: PointerProperty(
        name="Rigidity Image", type=bpy.types.Image,
        description="Greyscale image over the UV map: white keeps texture detail rigid, black lets it stretch",
    )
    rigidity_group: StringProperty(
        name="Rigidity Group",
        description="Vertex group used as rigidity when no Rigidity Image is set (weights rasterised into UV space)",
    )
    mask_image: PointerProperty(
        name="Mask Image", type=bpy.types.Image,
        description="Optional greyscale image: black texels never move (UV chart borders are always fixed)",
    )
    resolution: IntProperty(
        name="Resolution", default=1024, min=1, soft_min=8, max=16384,
        description="Warp grid size per side and UDIM tile: a power of two (8 to 16384)",
    )
    iterations: IntProperty(
        name="Iterations", default=tegument.DEFAULTS.warp_iterations, min=1, max=200,
        description="Solver iterations on the finest grid level (coarser levels run more). More bring the warp "
        "closer to its converged shape at a higher cost, most visibly in animation",
    )
    orientation: FloatProperty(
        name="Orientation", default=tegument.DEFAULTS.orientation, min=0.0, max=1.0, subtype="FACTOR",
        description="How strongly rigid detail turns back to its rest direction per iteration "
        "(0 for pure squash and stretch, higher where the surface twists)",
    )
    smoothing: FloatProperty(
        name="Smoothing", default=tegument.DEFAULTS.smoothing, min=0.0, max=1.0, subtype="FACTOR",
        description="Smoothing of the warp inside rigid regions",
    )
    frame_start: IntProperty(name="Start", default=1, min=0, description="First frame of the bake")
    frame_end: IntProperty(name="End", default=250, min=0, description="Last frame of the bake")
    directory: StringProperty(
        name="Directory", subtype="DIR_PATH", default="//tegument/warp/", options=_RELATIVE_PATH,
        description="Folder of the baked OpenEXR sequence (one file per frame and UDIM tile)",
    )
    write_heatmap: BoolProperty(
        name="Stretch Heat Map", default=False,
        description="Also write the remaining stretch error of the last baked frame as an image "
        "(<name>_<tile>_stretch.exr: 0 = undistorted, 0.69 = a factor of 2)",
    )
    # Status, written by the bake and shown on the node.
    report: StringProperty(name="Last Bake", default="", options={"HIDDEN"})
    baked_start: IntProperty(name="Baked Start", default=0, options={"HIDDEN"})
    baked_frames: IntProperty(name="Baked Frames", default=0, options={"HIDDEN"})

    @classmethod
    def poll(cls, ntree):
        return ntree.bl_idname == "ShaderNodeTree"

    def init(self, context):
        self.node_tree = new_group(self.name)
        build_passthrough(self)
        scene = getattr(context, "scene", None) if context is not None else None
        if scene is not None:
            self.frame_start, self.frame_end = scene.frame_start, scene.frame_end
        self.inputs["UV"].hide_value = True

    def copy(self, node):
        # The copy starts from the original's state (same baked images) with a group of its own.
        if node.node_tree is not None:
            self.node_tree = node.node_tree.copy()

    def free(self):
        group = self.node_tree
        if group is None:
            return
        self.node_tree = None
        # Blender's user counts of custom group nodes are not reliable here (adding the
        # node counts its group twice), so ownership is decided by looking at the nodes.
        if not any(other.node_tree == group for other in all_nodes() if other.as_pointer() != self.as_pointer()):
            bpy.data.node_groups.remove(group)

    def update(self):
        # Called when links change: an unconnected UV input means "this node's UV map".
        self.update_uv_source()

    def update_uv_source(self) -> None:
        group = self.node_tree
        if group is None:
            return
        source = group.nodes.get("UV Source")
        group_input = group.nodes.get("Group Input")
        uv_node = group.nodes.get("UV Map")
        if source is None or group_input is None or uv_node is None:
            return
        if uv_node.uv_map != self.uv_map:
            uv_node.uv_map = self.uv_map
        wanted = group_input.outputs[0] if self.inputs["UV"].is_linked else uv_node.outputs["UV"]
        target = source.inputs[0]
        if not (target.is_linked and target.links[0].from_socket == wanted):
            for link in list(target.links):
                group.links.remove(link)
            group.links.new(wanted, target)

    def draw_buttons(self, context, layout):
        from ..ui import warp_node

        warp_node.draw(self, context, layout)

    def draw_buttons_ext(self, context, layout):
        from ..ui import warp_node

        warp_node.draw(self, context, layout, extended=True)


def new_group(name: str) -> bpy.types.ShaderNodeTree:
    group = bpy.data.node_groups.new(f"{GROUP_PREFIX} {name}", "ShaderNodeTree")
    group[GROUP_MARK] = True
    group.interface.new_socket("UV", in_out="INPUT", socket_type="NodeSocketVector")
    group.interface.new_socket("UV", in_out="OUTPUT", socket_type="NodeSocketVector")
    return group


def own_group(node) -> bpy.types.ShaderNodeTree:
    """The node's group, made single-user first (a copied material may share it)."""
    group = node.node_tree
    if group is None:
        group = new_group(node.name)
        node.node_tree = group
    elif any(other.node_tree == group for other in all_nodes() if other.as_pointer() != node.as_pointer()):
        group = group.copy()
        node.node_tree = group
    return group


def _base(group):
    """Clears the group and adds the UV source; returns (group output socket, uv socket)."""
    group.nodes.clear()
    group_input = group.nodes.new("NodeGroupInput")
    group_input.name = "Group Input"
    group_input.location = (-900, 0)
    group_output = group.nodes.new("NodeGroupOutput")
    group_output.name = "Group Output"
    uv_node = group.nodes.new("ShaderNodeUVMap")
    uv_node.name = "UV Map"
    uv_node.location = (-900, -200)
    # One node is the place the UV enters, so switching between the group input
    # and the UV Map node is a single relink. Not a reroute: a reroute rebuilds its
    # sockets when its link's type changes, invalidating references held meanwhile.
    source = group.nodes.new("ShaderNodeVectorMath")
    source.operation = "ADD"
    source.inputs[1].default_value = (0.0, 0.0, 0.0)
    source.name = source.label = "UV Source"
    source.location = (-650, 0)
    return group_output, source


def build_passthrough(node) -> None:
    group = own_group(node)
    group_output, source = _base(group)
    group_output.location = (0, 0)
    group.links.new(source.outputs[0], group_output.inputs[0])
    node.update_uv_source()


def build_sampler(node, images: dict[int, bpy.types.Image]) -> None:
    """Inner tree that samples the baked sequence of each tile at the incoming UV."""
    group = own_group(node)
    group_output, source = _base(group)
    nodes, links = group.nodes, group.links
    uv = source.outputs[0]
    split = nodes.new("ShaderNodeSeparateXYZ")
    split.location = (-450, 300)
    links.new(uv, split.inputs[0])
    current = uv
    x = -450
    for k, (udim, image) in enumerate(sorted(images.items())):
        tu, tv = raster.tile_origin(udim)
        y = -250 * k
        local = uv
        if (tu, tv) != (0, 0):
            shift = nodes.new("ShaderNodeVectorMath")
            shift.operation = "SUBTRACT"
            shift.inputs[1].default_value = (tu, tv, 0.0)
            shift.location = (x, y - 400)
            links.new(uv, shift.inputs[0])
            local = shift.outputs[0]
        texture = nodes.new("ShaderNodeTexImage")
        texture.name = f"Warp {udim}"
        texture.label = f"UV warp {udim}"
        texture.image = image
        # The redirection is a smooth field of absolute UVs: linear between texel centres,
        # clamped at the tile's edge rather than wrapped into the opposite side.
        texture.interpolation = "Linear"
        texture.extension = "EXTEND"
        configure_sequence(texture.image_user, node.baked_start, node.baked_start + node.baked_frames - 1)
        texture.location = (x + 200, y)
        links.new(local, texture.inputs["Vector"])
        colour = nodes.new("ShaderNodeSeparateColor")
        colour.location = (x + 500, y)
        links.new(texture.outputs["Color"], colour.inputs[0])
        redirected = nodes.new("ShaderNodeCombineXYZ")
        redirected.location = (x + 700, y)
        links.new(colour.outputs[0], redirected.inputs[0])
        links.new(colour.outputs[1], redirected.inputs[1])
        links.new(split.outputs[2], redirected.inputs[2])
        # Weight = validity × "this UV lies in this tile" (|u - centre| ≤ 0.5 on both axes).
        factor = colour.outputs[2]
        for axis, origin in ((0, tu), (1, tv)):
            inside = nodes.new("ShaderNodeMath")
            inside.operation = "COMPARE"
            inside.inputs[1].default_value = origin + 0.5
            inside.inputs[2].default_value = 0.5
            inside.location = (x + 500, y - 150 - 60 * axis)
            links.new(split.outputs[axis], inside.inputs[0])
            both = nodes.new("ShaderNodeMath")
            both.operation = "MULTIPLY"
            both.use_clamp = True
            both.location = (x + 700, y - 150 - 60 * axis)
            links.new(factor, both.inputs[0])
            links.new(inside.outputs[0], both.inputs[1])
            factor = both.outputs[0]
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "VECTOR"
        mix.location = (x + 900, y)
        links.new(factor, mix.inputs["Factor"])
        links.new(current, mix.inputs[4])  # A (vector)
        links.new(redirected.outputs[0], mix.inputs[5])  # B (vector)
        current = mix.outputs[1]  # Result (vector)
    group_output.location = (x + 1150, 0)
    links.new(current, group_output.inputs[0])
    node.update_uv_source()


def configure_sequence(image_user, frame_start: int, frame_end: int) -> None:
    """Scene frame f shows file number f; before and after the range, the first and last file."""
    image_user.frame_duration = frame_end - frame_start + 1
    image_user.frame_start = frame_start
    image_user.frame_offset = frame_start - 1
    image_user.use_cyclic = False
    image_user.use_auto_refresh = True


def sequence_image(name: str, first_file: str, stored_path: str, existing=None) -> bpy.types.Image:
    """The image datablock of one tile's sequence, pointing at ``stored_path`` (maybe ``//``-relative)."""
    image = existing
    if image is None:
        image = bpy.data.images.load(first_file, check_existing=False)
        image.name = name
    image.source = "SEQUENCE"
    image.filepath = stored_path
    image.colorspace_settings.is_data = True
    image.colorspace_settings.name = "Non-Color"
    image.alpha_mode = "NONE"
    image.reload()
    return image


def tile_images(node) -> dict[int, bpy.types.Image]:
    """The images the inner tree samples now, by UDIM tile."""
    group = node.node_tree
    if group is None:
        return {}
    out = {}
    for inner in group.nodes:
        if inner.bl_idname == "ShaderNodeTexImage" and inner.name.startswith("Warp ") and inner.image is not None:
            out[int(inner.name.split()[1])] = inner.image
    return out


def heatmap_file(directory: str, stem: str, udim: int) -> str:
    return os.path.join(directory, f"{stem}_{udim}_stretch.exr")


def file_stem(material_name: str, node_name: str) -> str:
    return bpy.path.clean_name(f"{material_name}_{node_name}")


def frame_file(directory: str, stem: str, udim: int, frame: int) -> str:
    # The frame number comes last: that is the number Blender's sequence loader counts.
    return os.path.join(directory, f"{stem}_{udim}_{frame:04d}.exr")


def all_nodes():
    """Every Tegument UV Warp node, in any shader tree (a group used by none is an orphan)."""
    owners = (*bpy.data.materials, *bpy.data.worlds, *bpy.data.lights, *bpy.data.linestyles)
    trees = [o.node_tree for o in owners if getattr(o, "node_tree", None) is not None]
    trees += [g for g in bpy.data.node_groups if g.bl_idname == "ShaderNodeTree"]
    for tree in trees:
        for node in tree.nodes:
            if node.bl_idname == NODE_IDNAME:
                yield node


def purge_orphan_groups() -> int:
    """Removes inner groups no node uses any more (their material was deleted); returns how many.

    Deleting a node frees its group at once, but deleting a whole material
    calls no node callback, so the group would otherwise be saved forever.
    """
    used = {node.node_tree.as_pointer() for node in all_nodes() if node.node_tree is not None}
    orphans = [g for g in bpy.data.node_groups if g.get(GROUP_MARK) and g.as_pointer() not in used]
    for group in orphans:
        bpy.data.node_groups.remove(group)
    return len(orphans)


@bpy.app.handlers.persistent
def _purge_before_save(*_args) -> None:
    purge_orphan_groups()


def find_nodes():
    """Every (material, node) pair of a Tegument UV Warp node."""
    for material in bpy.data.materials:
        tree = material.node_tree
        if tree is None:
            continue
        for node in tree.nodes:
            if node.bl_idname == NODE_IDNAME:
                yield material, node


def menu_func(self, context):
    self.layout.operator("node.add_node", text="Tegument UV Warp").type = NODE_IDNAME


def _uv_warp_menu(self, context):
    if context.space_data is not None and getattr(context.space_data, "tree_type", "") == "ShaderNodeTree":
        self.layout.separator()
        menu_func(self, context)


def register() -> None:
    bpy.utils.register_class(TEGUMENT_NT_uv_warp)
    bpy.types.NODE_MT_category_shader_vector.append(_uv_warp_menu)
    bpy.app.handlers.save_pre.append(_purge_before_save)


def unregister() -> None:
    if _purge_before_save in bpy.app.handlers.save_pre:
        bpy.app.handlers.save_pre.remove(_purge_before_save)
    bpy.types.NODE_MT_category_shader_vector.remove(_uv_warp_menu)
    bpy.utils.unregister_class(TEGUMENT_NT_uv_warp)
