# SPDX-License-Identifier: GPL-3.0-or-later
"""The Tegument UV Warp shader node: settings, inputs, bake, inner node tree.

``node`` is the ShaderNodeCustomGroup and its inner tree of stock nodes,
``inputs`` reads and checks what one bake needs from Blender, ``raster``
turns per-vertex values and images into UV-space grids, ``bake`` runs the
frames and writes the OpenEXR sequence.
"""
