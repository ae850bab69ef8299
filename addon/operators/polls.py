# SPDX-License-Identifier: GPL-3.0-or-later
"""The operators' polls, as ``poll = classmethod(polls.mesh)``: each says in the tooltip why
the operator is greyed out."""

from ..deform import evaluate


def mesh(cls, context) -> bool:
    obj = context.active_object
    if obj is None or obj.type != "MESH":
        cls.poll_message_set("The active object must be a mesh")
        return False
    return True


def deformed(cls, context) -> bool:
    if not mesh(cls, context):
        return False
    if evaluate.tegument_modifier(context.active_object) is None:
        cls.poll_message_set("The active object has no Tegument modifier (Add Pyramid Deform first)")
        return False
    return True
