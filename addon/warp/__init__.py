# SPDX-License-Identifier: GPL-3.0-or-later
"""The Tegument UV Warp shader node: settings, inputs, bake, inner node tree.

``node`` is the ShaderNodeCustomGroup and its inner tree of stock nodes,
``inputs`` reads and checks what one bake needs from Blender (its UV-space
grids come from the wheel), ``raster`` keeps the UDIM bookkeeping, ``bake``
runs the frames and writes the OpenEXR sequence and the heat map.
"""
