# SPDX-License-Identifier: GPL-3.0-or-later
"""Pyramid Deform operators: add, bind, bake, bake one frame, free, remove.

Every failure becomes a ``self.report`` message and ``{'CANCELLED'}``; the
cache and the mesh are left as they were.
"""

from __future__ import annotations

import os

import bpy
import numpy as np

from .. import jobs, mesh_arrays, pc2
from ..deform import bake, colliders, evaluate
from ..deform.evaluate import DeformError
from ..deform.properties import MODIFIER_NAME
from . import polls


def bind_pose(context, obj):
    """The positions UV Warp's bind stores (Bind Pose): the mesh's own, or what the modifiers above
    Tegument make of them, which may have another vertex count (each caller says what to do)."""
    if obj.tegument.bind_source == "EVALUATED":
        with evaluate.upstream_only(obj):
            return evaluate.evaluated_positions(obj, context.evaluated_depsgraph_get())[0]
    return mesh_arrays.positions(obj.data)


# How bind names each kind of pinned vertex (the wheel's `pinned_reasons` keys): (one, several).
PIN_KINDS = {
    "boundary": ("boundary corner", "boundary corners"),
    "non_manifold": ("non-manifold", "non-manifold"),
    "isolated": ("isolated", "isolated"),
    "low_valence": ("with fewer than 3 neighbours", "with fewer than 3 neighbours"),
    "high_valence": ("with too many neighbours", "with too many neighbours"),
    "zero_area": ("with a flat one-ring", "with flat one-rings"),
    "not_star_shaped": ("with a folded one-ring", "with folded one-rings"),
    "inexact": ("not encodable in single precision", "not encodable in single precision"),
}


def pinned_by_kind(deformer) -> str:
    """"12 vertices follow the rig: 8 boundary corners, 4 non-manifold" ("" when none do), most first."""
    reasons = {name: len(vertices) for name, vertices in deformer.pinned_reasons.items() if len(vertices)}
    total = sum(reasons.values())
    if not total:
        return ""
    kinds = ", ".join(
        f"{count} {PIN_KINDS.get(name, (name, name))[count != 1]}"
        for name, count in sorted(reasons.items(), key=lambda item: (-item[1], item[0]))
    )
    return f"{total} {'vertex follows' if total == 1 else 'vertices follow'} the rig: {kinds}"


def bind_shape(context, obj) -> tuple:
    """``(rest, corner_verts, polygon_sizes, keeps_topology)`` of the stack above Tegument's
    modifier now: what Pyramid Deform binds. Bind Pose *Original* takes the mesh's own positions
    (through the generating modifiers, without the deforming ones, when the stack changes the
    topology); *Evaluated* the positions the stack gives at the current frame."""
    depsgraph_of = context.evaluated_depsgraph_get
    evaluated, corners, sizes = evaluate.upstream_topology(obj, depsgraph_of)
    keeps = evaluate.keeps_topology(obj.data, corners, sizes, len(evaluated))
    if obj.tegument.bind_source == "EVALUATED":
        return evaluated, corners, sizes, keeps
    if keeps:
        return mesh_arrays.positions(obj.data), corners, sizes, keeps
    rest, rest_corners, rest_sizes = evaluate.upstream_topology(obj, depsgraph_of, without_deform=True)
    if len(rest) != len(evaluated) or not (np.array_equal(rest_sizes, sizes) and np.array_equal(rest_corners, corners)):
        raise DeformError(
            f"{obj.name}: the modifier stack above Tegument gives {len(evaluated)} vertices posed and {len(rest)} "
            "without its deform modifiers (a modifier whose topology depends on the pose, such as Remesh after "
            "an Armature); set Bind Pose to Evaluated, or move that modifier"
        )
    return rest, corners, sizes, keeps


def bind(context, obj) -> str:
    """Binds the rest shape and topology of the stack above Tegument and checks they can be
    encoded; returns a status message.

    The bind is always a Mesh datablock of its own (``obj.tegument.bind_mesh``: rest positions and
    topology), whether that stack keeps ``obj.data``'s topology or changes it (Subdivision Surface,
    Remesh…): ``obj.data`` is not touched. A ``tegument_rest`` attribute on it (a bind made by an
    earlier version, or UV Warp's own bind) is left alone: the bind mesh takes precedence."""
    import tegument

    rest, corners, sizes, keeps = bind_shape(context, obj)
    try:
        deformer = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=obj.tegument.scale_safe)
        report = tegument.Mesh(rest, corners, sizes).report
    except tegument.TegumentError as error:
        raise DeformError(f"{obj.name}: {error}") from None
    settings = obj.tegument
    evaluate.store_bind_mesh(obj, rest, corners, sizes)
    settings.bound_vertices = len(rest)
    settings.source_vertices = len(obj.data.vertices)
    warnings = []
    pinned = pinned_by_kind(deformer)
    if pinned:
        warnings.append(pinned)
    if not report.is_clean:
        warnings.append("the mesh has non-manifold parts (run Check Mesh)")
    settings.bind_warnings = settings.warnings = "; ".join(warnings)
    where = "" if keeps else f" (the modifier stack's; the mesh has {len(obj.data.vertices)})"
    # Split seams (glTF/FBX/USD imports) are welded for the solver: said, not warned about.
    seams = len(rest) - deformer.welded_vertex_count
    welded = f", {seams} on split seams welded" if seams else ""
    return f"Bound {obj.name}: {len(rest)} vertices{where}{welded}" + (f" ({'; '.join(warnings)})" if warnings else "")


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
        # The bind mesh only: a tegument_rest attribute on obj.data (a legacy bind, or UV Warp's
        # bind) is left alone, so that Remove never changes the user's mesh.
        evaluate.remove_bind_mesh(obj)
        obj.tegument.bound_vertices = obj.tegument.source_vertices = 0
        obj.tegument.warnings = obj.tegument.bind_warnings = ""
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
