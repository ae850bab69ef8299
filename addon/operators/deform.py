# SPDX-License-Identifier: GPL-3.0-or-later
"""Pyramid Deform operators: add, bind, bake, bake one frame, free, remove.

Every failure becomes a ``self.report`` message and ``{'CANCELLED'}``; the
cache and the mesh are left as they were.
"""

from __future__ import annotations

import os

import bpy

from .. import jobs, mesh_arrays, pc2
from ..deform import bake, colliders, evaluate
from ..deform.evaluate import DeformError
from ..deform.properties import MODIFIER_NAME
from . import polls


def bind_pose(context, obj):
    """The positions a bind stores (Bind Pose): the mesh's own, or what the modifiers above
    Tegument make of them, which may have another vertex count (each caller says what to do)."""
    if obj.tegument.bind_source == "EVALUATED":
        with evaluate.upstream_only(obj):
            return evaluate.evaluated_positions(obj, context.evaluated_depsgraph_get())[0]
    return mesh_arrays.positions(obj.data)


def bind(context, obj) -> str:
    """Stores the rest pose and checks it can be encoded; returns a status message."""
    import tegument

    rest = bind_pose(context, obj)
    if len(rest) != len(obj.data.vertices):
        raise DeformError(
            f"{obj.name}: the modifier stack gives {len(rest)} vertices, the mesh has {len(obj.data.vertices)}; "
            "bind to the original positions or move topology-changing modifiers below Tegument"
        )
    corners = mesh_arrays.corner_verts(obj.data)
    sizes = mesh_arrays.polygon_sizes(obj.data)
    try:
        deformer = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=obj.tegument.scale_safe)
        report = tegument.Mesh(rest, corners, sizes).report
    except tegument.TegumentError as error:
        raise DeformError(f"{obj.name}: {error}") from None
    evaluate.store_rest(obj, rest)
    obj.tegument.bound_vertices = len(rest)
    pinned = len(deformer.pinned_vertices)
    warnings = []
    if pinned:
        warnings.append(f"{pinned} vertices follow the rig (a border corner, a non-manifold spot or a one-ring that cannot be encoded)")
    if not report.is_clean:
        warnings.append("the mesh has non-manifold parts (run Check Mesh)")
    obj.tegument.warnings = "; ".join(warnings)
    return f"Bound {obj.name}: {len(rest)} vertices" + (f" ({'; '.join(warnings)})" if warnings else "")


class TEGUMENT_OT_deform_add(bpy.types.Operator):
    """Add Pyramid Deform to the active mesh: bind its rest shape and add the Mesh Cache modifier that plays the bake back"""

    bl_idname = "tegument.deform_add"
    bl_label = "Add Pyramid Deform"
    bl_options = {"REGISTER", "UNDO"}

    poll = classmethod(polls.mesh)

    @jobs.reports_errors
    def execute(self, context):
        obj = context.active_object
        if evaluate.tegument_modifier(obj) is not None:
            self.report({"WARNING"}, f"{obj.name} already has Pyramid Deform")
            return {"CANCELLED"}
        settings = obj.tegument
        if settings.cache_path in ("", "//tegument/object.pc2"):
            settings.cache_path = f"//tegument/{bpy.path.clean_name(obj.name)}.pc2"
        settings.frame_start, settings.frame_end = context.scene.frame_start, context.scene.frame_end
        message = bind(context, obj)
        modifier = obj.modifiers.new(MODIFIER_NAME, "MESH_CACHE")
        modifier.cache_format = "PC2"
        modifier.filepath = settings.cache_path
        modifier.frame_start = settings.frame_start
        self.report({"INFO"}, message)
        return {"FINISHED"}


class TEGUMENT_OT_deform_remove(bpy.types.Operator):
    """Remove Pyramid Deform from the active mesh: its modifier and its bind (the cache file stays on disk)"""

    bl_idname = "tegument.deform_remove"
    bl_label = "Remove Pyramid Deform"
    bl_options = {"REGISTER", "UNDO"}

    poll = classmethod(polls.deformed)

    def execute(self, context):
        obj = context.active_object
        obj.modifiers.remove(evaluate.tegument_modifier(obj))
        attribute = obj.data.attributes.get(evaluate.REST_ATTRIBUTE)
        if attribute is not None:
            obj.data.attributes.remove(attribute)
        obj.tegument.bound_vertices = 0
        obj.tegument.warnings = ""
        self.report({"INFO"}, f"Removed Pyramid Deform from {obj.name}")
        return {"FINISHED"}


class TEGUMENT_OT_bind(bpy.types.Operator):
    """Bind: store the current rest shape that Pyramid Deform preserves (rebinding replaces it)"""

    bl_idname = "tegument.bind"
    bl_label = "Bind"
    bl_options = {"REGISTER", "UNDO"}

    poll = classmethod(polls.mesh)

    @jobs.reports_errors
    def execute(self, context):
        self.report({"INFO"}, bind(context, context.active_object))
        return {"FINISHED"}


class TEGUMENT_OT_bake(jobs.BakeOperator, bpy.types.Operator):
    """Bake Pyramid Deform over the frame range into the point cache (Esc cancels and keeps the frames done)"""

    bl_idname = "tegument.bake"
    bl_label = "Bake"

    poll = classmethod(polls.deformed)

    def make_job(self, context) -> bake.BakeJob:
        obj = context.active_object
        return bake.BakeJob(context, obj, range(obj.tegument.frame_start, obj.tegument.frame_end + 1))


class TEGUMENT_OT_bake_frame(bpy.types.Operator):
    """Solve the current frame into the cache (and any frames missing before it)"""

    bl_idname = "tegument.bake_frame"
    bl_label = "Bake Frame"

    poll = classmethod(polls.deformed)

    @jobs.reports_errors
    def execute(self, context):
        obj = context.active_object
        settings = obj.tegument
        frame = context.scene.frame_current
        if not settings.frame_start <= frame <= settings.frame_end:
            self.report({"ERROR"}, f"frame {frame} is outside the bake range {settings.frame_start}–{settings.frame_end}")
            return {"CANCELLED"}
        cached = pc2.frame_count(evaluate.cache_file(obj))
        first = min(settings.frame_start + cached, frame)
        bake.bake_blocking(context, obj, range(first, frame + 1), keep_existing=True, report=lambda line: None)
        self.report({"INFO"}, f"Baked frame {frame} of {obj.name}")
        return {"FINISHED"}


class TEGUMENT_OT_free_bake(bpy.types.Operator):
    """Delete the point cache of the active object"""

    bl_idname = "tegument.free_bake"
    bl_label = "Free Bake"
    bl_options = {"REGISTER", "UNDO"}

    poll = classmethod(polls.deformed)

    def execute(self, context):
        obj = context.active_object
        path = evaluate.cache_file(obj)
        # The compliant colliders' caches belong to this bake too.
        for collider in colliders.collider_objects(obj):
            if colliders.is_compliant(collider):
                compliance_path = colliders.compliance_cache_path(collider)
                try:
                    os.remove(compliance_path)
                except FileNotFoundError:
                    pass
                except OSError as error:
                    self.report({"ERROR"}, f"cannot delete {compliance_path}: {error.strerror}")
                    return {"CANCELLED"}
                collider.update_tag()
        try:
            os.remove(path)
        except FileNotFoundError:
            self.report({"INFO"}, f"{obj.name} has no cache to free")
            return {"CANCELLED"}
        except OSError as error:
            self.report({"ERROR"}, f"cannot delete {path}: {error.strerror}")
            return {"CANCELLED"}
        obj.update_tag()
        self.report({"INFO"}, f"Freed the cache of {obj.name}")
        return {"FINISHED"}


classes = (
    TEGUMENT_OT_deform_add,
    TEGUMENT_OT_deform_remove,
    TEGUMENT_OT_bind,
    TEGUMENT_OT_bake,
    TEGUMENT_OT_bake_frame,
    TEGUMENT_OT_free_bake,
)
