# SPDX-License-Identifier: GPL-3.0-or-later
"""Tegument for Blender: the thin Blender layer over the ``tegument`` wheel.

Blender knowledge lives here and only here: reading and writing Blender data
with whole-array ``foreach_get``/``foreach_set``, operators, panels. All
per-vertex work happens in the wheel.
"""

from . import cli, farm, operators, ui
from .deform import colliders, live, properties
from .warp import node as warp_node

_modules = (properties, colliders, warp_node, operators, ui, live, farm, cli)


def register() -> None:
    for module in _modules:
        module.register()


def unregister() -> None:
    for module in reversed(_modules):
        module.unregister()
