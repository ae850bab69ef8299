# SPDX-License-Identifier: GPL-3.0-or-later
"""Self Collision of Pyramid Deform: ``obj.tegument.self_collision``.

The skin kept from passing through itself at folds (elbows, knees, armpits), in the same passes as
the colliders. Its settings are a property group of their own inside ``obj.tegument`` (saved in the
.blend with it), with the last bake's figures; :func:`step_option` turns them into the wheel's
``tegument.SelfCollision`` for ``PyramidDeformer.step``.
"""

from __future__ import annotations

import bpy
import tegument
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty

_DEFAULTS = tegument.DEFAULTS


class TEGUMENT_PG_self_collision(bpy.types.PropertyGroup):
    enabled: BoolProperty(
        name="Self Collision", default=False,
        description="Keep the skin from passing through itself: folds at elbows, knees and armpits crease or "
        "bulge instead. Skin that already intersects itself in the rig's input is left to come apart",
    )
    thickness: FloatProperty(
        name="Distance", default=_DEFAULTS.self_thickness, min=0.0, soft_max=0.05, subtype="DISTANCE", unit="LENGTH",
        description="Distance kept between skin that folds onto itself. Skin already closer at rest keeps its rest "
        "distance instead",
    )
    friction: FloatProperty(
        name="Friction", default=_DEFAULTS.self_friction, min=0.0, soft_max=2.0,
        description="How much skin in contact with itself sticks instead of sliding",
    )
    group: StringProperty(
        name="Vertex Group",
        description="Only skin in this vertex group collides with itself (e.g. armpits, elbows and knees: faster "
        "on a large mesh); empty: everywhere",
    )
    rings: IntProperty(
        name="Ignore Rings", default=_DEFAULTS.self_rings, min=0, max=4,
        description="Neighbours never tested against each other besides faces sharing a vertex: faces within this "
        "many edges. 0 is safest; more hides folds sharper than that",
    )
    # The last bake's figures, shown in the panel.
    contacts: IntProperty(name="Self Contacts", default=0, options={"HIDDEN"},
                          description="Contacts between skin and skin in the last bake, over all its frames")
    held: IntProperty(name="Held", default=0, options={"HIDDEN"},
                      description="Times the last bake put skin back where a pass started to keep it from "
                      "passing through itself")
    intersections: IntProperty(
        name="Self-Intersections", default=0, options={"HIDDEN"},
        description="Most pairs of faces intersecting in one frame of the last bake (by the audit with Audit on): "
        "what the rig's input brought in, not yet come apart",
    )


def step_option(obj) -> "tegument.SelfCollision | None":
    """The ``self_collision`` argument of ``PyramidDeformer.step`` for ``obj``, or None when off."""
    # Imported here: evaluate imports properties, which imports this module; and the
    # SelfCollision must come from the same tegument as the deformer (bake.py imports it lazily).
    import tegument

    from . import evaluate

    settings = obj.tegument.self_collision
    if not settings.enabled:
        return None
    weights = None
    if settings.group:
        group = obj.vertex_groups.get(settings.group)
        if group is None:
            raise evaluate.DeformError(f"{obj.name}: the self-collision vertex group \"{settings.group}\" does not exist")
        weights = evaluate.group_weights(obj, group)
    try:
        return tegument.SelfCollision(thickness=settings.thickness, friction=settings.friction,
                                      kinetic_friction=0.75 * settings.friction, rings=settings.rings, weights=weights)
    except tegument.TegumentError as error:
        raise evaluate.DeformError(f"{obj.name}: {error}") from None


class BakeFigures:
    """What a bake gathers of self-collision frame by frame, for the panel and the report."""

    def __init__(self, obj):
        self.enabled = obj.tegument.self_collision.enabled
        self.contacts = 0
        self.held = 0
        self.intersections = 0

    def add(self, step, audited: int | None) -> None:
        """One frame: the step's report, and the audit's count of intersecting face pairs (None without)."""
        if not self.enabled or step is None:
            return
        self.contacts += step.self_contacts
        self.held += step.self_held
        self.intersections = max(self.intersections, step.self_intersections if audited is None else audited)

    def store(self, obj) -> list[str]:
        """Writes the figures into the object's settings; returns the bake's notes about them."""
        settings = obj.tegument.self_collision
        settings.contacts, settings.held, settings.intersections = self.contacts, self.held, self.intersections
        notes = []
        if self.enabled and self.intersections:
            notes.append(f"{self.intersections} face pairs intersect (the input's own, not yet come apart)")
        return notes


def register() -> None:
    bpy.utils.register_class(TEGUMENT_PG_self_collision)


def unregister() -> None:
    bpy.utils.unregister_class(TEGUMENT_PG_self_collision)
