# SPDX-License-Identifier: GPL-3.0-or-later
"""UV Warp operators: bake the node's redirection sequence, bind its object.

Every failure becomes a ``self.report`` message and ``{'CANCELLED'}``; the
previous sequence stays as it was and nothing is half-written.
"""

from __future__ import annotations

import bpy
from bpy.props import StringProperty

from .. import jobs, mesh_arrays
from ..deform import evaluate
from ..warp import bake
from ..warp.inputs import WarpError
from .deform import bind_pose


class NodeArguments:
    """Which UV Warp node an operator acts on (the command line and scripts name it)."""

    material: StringProperty(name="Material", description="Material holding the node (empty: the active object's active material)")
    node: StringProperty(name="Node", description="Name of the Tegument UV Warp node (empty: the active node)")


class TEGUMENT_OT_warp_bake(NodeArguments, jobs.BakeOperator, bpy.types.Operator):
    """Bake the Tegument UV Warp node's redirection sequence over its frame range (Esc cancels and keeps the frames done)"""

    bl_idname = "tegument.warp_bake"
    bl_label = "Bake UV Warp"

    def make_job(self, context) -> bake.WarpBakeJob:
        return bake.WarpBakeJob(context, *bake.find_node(context, self.material, self.node))


def bind_rest(context, obj) -> str:
    """Stores the rest shape of the mesh's own vertices: into Pyramid Deform's bind mesh where it
    has those vertices (one rest shape for both; ``obj.data`` untouched), else into the
    ``tegument_rest`` point attribute of ``obj.data`` (UV Warp's own bind).

    Unlike Pyramid Deform's Bind it does not build the pyramid encoding: the
    warp needs only the positions, and a mesh the deformer cannot encode can
    still carry a warped texture.
    """
    rest = bind_pose(context, obj)
    if len(rest) != len(obj.data.vertices):
        raise WarpError(f"{obj.name}: the modifier stack gives {len(rest)} vertices, the mesh has "
                        f"{len(obj.data.vertices)}; bind to the original positions (Bind Pose: Original)")
    vertex = mesh_arrays.first_non_finite(rest)
    if vertex is not None:
        raise WarpError(f"{obj.name}: vertex {vertex} has a non-finite position")
    # Pyramid Deform's bind is renewed where it is the same rest shape: its bind mesh with the
    # mesh's vertices, or a legacy bind (the attribute itself). A bind mesh of another topology
    # (Subdivision Surface above Tegument) is left alone.
    shared = obj.tegument.bind_mesh is None or evaluate.mesh_vertex_bind(obj) is not None
    evaluate.store_rest(obj, rest)
    if shared:
        obj.tegument.bound_vertices = obj.tegument.source_vertices = len(rest)
    return f"Bound {obj.name}: {len(rest)} vertices"


class TEGUMENT_OT_warp_bind(NodeArguments, bpy.types.Operator):
    """Bind the UV Warp node's object: store its current shape as the rest shape whose texture looks right"""

    bl_idname = "tegument.warp_bind"
    bl_label = "Bind"
    bl_options = {"REGISTER", "UNDO"}

    @jobs.reports_errors
    def execute(self, context):
        _, node = bake.find_node(context, self.material, self.node)
        if node.object is None or node.object.type != "MESH":
            raise WarpError(f"{node.name}: set the node's Object to a mesh first")
        self.report({"INFO"}, bind_rest(context, node.object))
        return {"FINISHED"}


class TEGUMENT_OT_warp_attach(NodeArguments, bpy.types.Operator):
    """Play the node's sequence as it is on disk over the node's frame range: frames a farm baked in chunks, which leave the node as it was"""

    bl_idname = "tegument.warp_attach"
    bl_label = "Load Baked"
    bl_options = {"REGISTER", "UNDO"}

    @jobs.reports_errors
    def execute(self, context):
        material, node = bake.find_node(context, self.material, self.node)
        frames = bake.attach(material, node)
        self.report({"INFO"}, f"{material.name} › {node.name} plays frames {frames.start}–{frames.stop - 1}")
        return {"FINISHED"}


classes = (TEGUMENT_OT_warp_bake, TEGUMENT_OT_warp_bind, TEGUMENT_OT_warp_attach)
