# SPDX-License-Identifier: GPL-3.0-or-later
"""``obj.tegument``: the Pyramid Deform settings and status of one object.

These names are Tegument's public interface for scripts; keep them stable.
"""

from __future__ import annotations

import bpy
import tegument
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from . import self_collision

# Defaults come from the core (one source for each); min/max here are UI limits.
_DEFAULTS = tegument.DEFAULTS

MODIFIER_NAME = "Tegument"
REST_ATTRIBUTE = "tegument_rest"


# Blender 4.5 made blend-relative ("//") paths an explicit option of path properties.
_RELATIVE_PATH = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else set()


def _enabled_changed(settings, context):
    obj = settings.id_data
    modifier = obj.modifiers.get(MODIFIER_NAME)
    if modifier is not None:
        modifier.show_viewport = modifier.show_render = settings.enabled


class TEGUMENT_PG_deform(bpy.types.PropertyGroup):
    enabled: BoolProperty(
        name="Enabled", default=True, update=_enabled_changed,
        description="Show Tegument's cached result (the Mesh Cache modifier named Tegument)",
    )
    iterations: IntProperty(
        name="Iterations",
        default=_DEFAULTS.accelerated_iterations if _DEFAULTS.converge else _DEFAULTS.iterations,
        min=1, max=500,
        description="Solver iterations per frame. With Converge (the default) at most this many: a frame stops once "
        "it is within 2% of the converged look, so more only costs time where a frame needs it (a mesh under 4,096 "
        "vertices may take as many as that costs on 4,096: its iterations are cheap). Without Converge "
        "every frame runs this many and more keeps the rest shape better",
    )
    converge: BoolProperty(
        name="Converge", default=_DEFAULTS.converge,
        description="Accelerated solver (on by default): every iteration also corrects the smooth error on coarser "
        "levels, and a frame stops once it is within 2% of the converged look, starting from the previous frame's "
        "result (usually 2-6 iterations, at most Iterations; plain iterations need hundreds at low Closeness). "
        "Off: plain iterations, each frame runs Iterations and gets part of the way",
    )
    closeness: FloatProperty(
        name="Closeness", default=_DEFAULTS.closeness, min=0.0, max=1.0, subtype="FACTOR",
        description="How strongly each vertex is pulled towards the upstream (rig) position; "
        "1 follows the rig exactly, 0 keeps only the rest shape",
    )
    closeness_group: StringProperty(
        name="Closeness Group",
        description="Vertex group whose weights scale Closeness per vertex (empty: the same everywhere)",
    )
    scale_safe: BoolProperty(
        name="Scale Safe", default=_DEFAULTS.scale_safe,
        description="Encode the height of each vertex as angles so the shape survives uniform scaling",
    )
    bind_source: EnumProperty(
        name="Bind Pose",
        items=(
            ("ORIGINAL", "Original", "Bind to the mesh's own vertex positions"),
            ("EVALUATED", "Evaluated", "Bind to the positions the modifier stack produces at the current frame"),
        ),
        default="ORIGINAL",
    )
    collider_collection: PointerProperty(
        name="Colliders", type=bpy.types.Collection,
        description="Mesh objects the skin must not pass through",
    )
    frame_start: IntProperty(name="Start", default=1, description="First frame of the bake")
    frame_end: IntProperty(name="End", default=250, description="Last frame of the bake")
    cache_path: StringProperty(
        name="Cache", subtype="FILE_PATH", default="//tegument/object.pc2", options=_RELATIVE_PATH,
        description="PC2 point cache the bake writes and the Mesh Cache modifier plays back",
    )
    live: BoolProperty(
        name="Live", default=False,
        description="Solve and cache each frame as the timeline advances by one frame",
    )

    # Dynamics (seed 000 §4): projective dynamics on top of the pyramid solve.
    dynamic: BoolProperty(
        name="Dynamics", default=False,
        description="Give the skin inertia: flesh lags, overshoots and settles. Closeness becomes the goal "
        "strength: low values jiggle, 1 follows the rig exactly",
    )
    substeps: IntProperty(
        name="Substeps", default=_DEFAULTS.substeps, min=1, max=64,
        description="Solver steps per frame (the rig and colliders are interpolated between frames): "
        "more follow fast motion and stiff contacts more closely, at a proportional cost",
    )
    damping: FloatProperty(
        name="Damping", default=_DEFAULTS.damping, min=0.0, soft_max=20.0,
        description="How fast motion dies out, per second (0: only the solver's own dissipation)",
    )
    mass: FloatProperty(
        name="Mass", default=_DEFAULTS.mass, min=0.001, soft_max=10.0,
        description="Surface density: each vertex weighs this times the area around it. "
        "Heavier flesh swings slower and further",
    )
    use_gravity: BoolProperty(
        name="Gravity", default=False,
        description="Pull the flesh with the scene's gravity (Scene properties) while it moves",
    )
    # Strain limits (seed 002 §2).
    limit_stretch: BoolProperty(
        name="Limit Stretch", default=False,
        description="Keep every edge no longer than (1 + Max Stretch) times its rest length",
    )
    max_stretch: FloatProperty(
        name="Max Stretch", default=0.1, min=0.0, soft_max=1.0,
        description="ε: how much longer than at rest an edge may get (0.1 = 10%)",
    )
    max_stretch_group: StringProperty(
        name="Max Stretch Group",
        description="Vertex group where the limit applies: weight 1 = Max Stretch, lower weights allow "
        "proportionally more (Max Stretch / weight), 0 or not in the group = no limit (empty: everywhere)",
    )
    strain_mode: EnumProperty(
        name="Strain Mode",
        items=(
            ("UNIFIED", "With Contacts", "Limit stretch in the same loop as the contacts, until both hold"),
            ("POST", "After Contacts", "Limit stretch after the collision passes; can pull skin back "
             "into colliders (kept to show the difference)"),
        ),
        default=_DEFAULTS.strain_mode.upper(),
    )

    self_collision: PointerProperty(type=self_collision.TEGUMENT_PG_self_collision)

    audit: BoolProperty(
        name="Audit", default=True,
        description="After each baked frame, count skin vertices inside colliders and edges crossing "
        "(independent of the solver); the totals show below",
    )
    # Status, written by bind and bake, shown in the panel.
    bound_vertices: IntProperty(
        name="Bound Vertices", default=0, options={"HIDDEN"},
        description="Vertices of the bind: those of the stack above Tegument at bind time",
    )
    source_vertices: IntProperty(
        name="Mesh Vertices at Bind", default=0, options={"HIDDEN"},
        description="Vertices of the object's own mesh at bind time: a later edit of it shows as another count",
    )
    bind_mesh: PointerProperty(
        name="Bind Mesh", type=bpy.types.Mesh, options={"HIDDEN"},
        description="Pyramid Deform's bind: the rest shape and topology of the modifiers above Tegument, a mesh of "
        "its own so that the object's mesh is not changed (empty: not bound, or bound by an earlier version "
        "in the tegument_rest attribute of the object's mesh)",
    )
    last_frame_ms: FloatProperty(name="Time per Frame", default=0.0, options={"HIDDEN"})
    bind_warnings: StringProperty(
        name="Bind Warnings", default="", options={"HIDDEN"},
        description="What the last bind found: vertices that follow the rig (by kind), non-manifold parts",
    )
    warnings: StringProperty(
        name="Warnings", default="", options={"HIDDEN"},
        description="The bind's warnings followed by the last bake's notes (colliders, pinched vertices)",
    )
    # Audit totals of the last bake with colliders, over all its frames.
    audit_vertices_inside: IntProperty(name="Vertices Inside", default=0, options={"HIDDEN"})
    audit_edges_crossing: IntProperty(name="Edges Crossing", default=0, options={"HIDDEN"})
    audit_collider_edges_crossing: IntProperty(name="Collider Edges Crossing", default=0, options={"HIDDEN"})
    worst_stretch: FloatProperty(
        name="Worst Stretch", default=0.0, options={"HIDDEN"},
        description="Largest length / rest length of a limited edge in the last bake",
    )
    max_recession: FloatProperty(
        name="Collider Recession", default=0.0, options={"HIDDEN"},
        description="Farthest a compliant collider vertex receded from its animation in the last bake",
    )
    pinched_vertices: IntProperty(
        name="Pinched", default=0, options={"HIDDEN"},
        description="Most vertices pinched between colliders in one frame of the last bake",
    )


def register() -> None:
    self_collision.register()
    bpy.utils.register_class(TEGUMENT_PG_deform)
    bpy.types.Object.tegument = PointerProperty(type=TEGUMENT_PG_deform)


def unregister() -> None:
    del bpy.types.Object.tegument
    bpy.utils.unregister_class(TEGUMENT_PG_deform)
    self_collision.unregister()
