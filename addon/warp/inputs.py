# SPDX-License-Identifier: GPL-3.0-or-later
"""What a UV Warp bake reads from Blender, checked before anything is written.

Every problem becomes a :class:`WarpError` whose message names the node,
the object and the setting to fix.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass

import bpy
import numpy as np

from .. import mesh_arrays
from ..deform import evaluate
from ..deform.evaluate import DeformError
from . import raster

MIN_RESOLUTION, MAX_RESOLUTION = 8, 16384


class WarpError(ValueError):
    """Something about the node, its object or its images that stops a warp bake."""


@dataclass
class WarpInputs:
    """Everything the wheel's ``UvWarp`` needs, read once per bake."""

    obj: bpy.types.Object
    uv_map: str
    rest: np.ndarray
    corner_verts: np.ndarray
    polygon_sizes: np.ndarray
    corner_uvs: np.ndarray
    tiles: list[int]
    rigidity: dict[int, np.ndarray]
    mask: dict[int, np.ndarray] | None
    resolution: int
    directory: str  # absolute, with a trailing separator


def is_power_of_two(n: int) -> bool:
    return n > 0 and n & (n - 1) == 0


def uv_layer_name(obj, requested: str, label: str = "") -> str:
    """The UV map the node uses: the named one, or the mesh's active render UV map."""
    layers = obj.data.uv_layers
    prefix = f"{label}: " if label else ""
    if not len(layers):
        raise WarpError(f"{prefix}{obj.name} has no UV map: add one (Object Data properties → UV Maps) and unwrap it")
    if requested:
        if requested not in layers:
            raise WarpError(f"{prefix}{obj.name} has no UV map named \"{requested}\" (it has: {', '.join(l.name for l in layers)})")
        return requested
    for layer in layers:
        if layer.active_render:
            return layer.name
    return layers.active.name if layers.active else layers[0].name


def corner_uvs(mesh, name: str) -> np.ndarray:
    out = np.empty((len(mesh.loops), 2), dtype=np.float32)
    mesh.uv_layers[name].uv.foreach_get("vector", out.ravel())
    return out


def output_directory(directory: str, label: str) -> str:
    if not directory:
        raise WarpError(f"{label}: the output directory is empty")
    if directory.startswith("//") and not bpy.data.filepath:
        raise WarpError(f"{label}: the directory {directory} is relative to the .blend file: save the file first "
                        "or choose an absolute directory")
    path = os.path.abspath(bpy.path.abspath(directory))
    return os.path.join(path, "")


def image_pixels(image, what: str, label: str) -> np.ndarray:
    """Greyscale pixels ``(h, w)`` (row 0 = bottom) of an image, or a WarpError saying why not."""
    if image.source == "TILED":
        raise WarpError(f"{label}: the {what} image \"{image.name}\" is a UDIM image: use a single image for one tile, "
                        "or a vertex group for several")
    width, height = image.size
    if width == 0 or height == 0 or not image.has_data:
        where = bpy.path.abspath(image.filepath) if image.filepath else "(no file)"
        raise WarpError(f"{label}: the {what} image \"{image.name}\" has no pixels: its file {where} is missing "
                        "or unreadable")
    pixels = np.empty(width * height * image.channels, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    pixels = pixels.reshape(height, width, image.channels)
    grey = pixels[..., :3].mean(axis=2) if image.channels >= 3 else pixels[..., 0]
    if not np.isfinite(grey).all():
        raise WarpError(f"{label}: the {what} image \"{image.name}\" contains NaN or infinite pixels")
    return np.clip(grey, 0.0, 1.0)


@contextlib.contextmanager
def without_trailing_subdivision(obj):
    """Hides Subdivision and Multires modifiers at the end of the stack while the block runs.

    The warp is solved on the mesh's own vertices; subdividing last only
    smooths what they describe, so the bake reads the cage and the render
    subdivides as usual.
    """
    trailing = []
    for modifier in reversed(obj.modifiers):
        if modifier.type not in {"SUBSURF", "MULTIRES"}:
            break
        trailing.append(modifier)
    with evaluate.hidden_in_viewport(trailing):
        yield


def read(node, label: str) -> WarpInputs:
    """Reads and checks the node's inputs; raises WarpError before any file is touched."""
    import tegument

    obj = node.object
    if obj is None:
        raise WarpError(f"{label}: no object: set the node's Object to the deforming mesh")
    if obj.type != "MESH":
        raise WarpError(f"{label}: {obj.name} is a {obj.type.lower()}, not a mesh")
    resolution = int(node.resolution)
    if not is_power_of_two(resolution) or not MIN_RESOLUTION <= resolution <= MAX_RESOLUTION:
        raise WarpError(f"{label}: resolution {resolution} is not a power of two between {MIN_RESOLUTION} and "
                        f"{MAX_RESOLUTION} (try {1 << max(3, min(14, round(np.log2(max(resolution, 1)))))})")
    mesh = obj.data
    uv_map = uv_layer_name(obj, node.uv_map, label)
    if node.rigidity_image is None and not node.rigidity_group:
        raise WarpError(f"{label}: no rigidity: set a Rigidity Image or a Rigidity Group (white/1 = keep rigid)")
    try:
        rest = evaluate.rest_positions(obj)
    except DeformError:
        raise WarpError(f"{label}: {obj.name} has no bind (rest shape): press Bind on the node "
                        "(or Bind in Tegument's modifier panel) in the pose whose texture looks right") from None
    if len(rest) != len(mesh.vertices):
        raise WarpError(f"{label}: {obj.name} has {len(mesh.vertices)} vertices but was bound with {len(rest)}: bind again")
    corners = mesh_arrays.corner_verts(mesh)
    sizes = mesh_arrays.polygon_sizes(mesh)
    if len(sizes) == 0:
        raise WarpError(f"{label}: {obj.name} has no faces")
    uvs = corner_uvs(mesh, uv_map)
    if not np.isfinite(uvs).all():
        raise WarpError(f"{label}: the UV map \"{uv_map}\" of {obj.name} has non-finite coordinates")
    tiles = raster.udim_tiles(uvs, sizes)
    shape = (resolution, resolution)
    if node.rigidity_image is not None:
        if len(tiles) > 1:
            raise WarpError(f"{label}: the UVs span UDIM tiles {', '.join(map(str, tiles))}: a rigidity image covers "
                            "one tile; use a Rigidity Group for several")
        grey = image_pixels(node.rigidity_image, "rigidity", label)
        rigidity = {tiles[0]: tegument.resample_image(grey, shape)}
    else:
        group = obj.vertex_groups.get(node.rigidity_group)
        if group is None:
            raise WarpError(f"{label}: {obj.name} has no vertex group \"{node.rigidity_group}\"")
        weights = mesh_arrays.vertex_group_weights(mesh, group.index)
        rigidity = {t: tegument.rasterise_corner_values(uvs, sizes, weights[corners], t, shape) for t in tiles}
    mask = None
    if node.mask_image is not None:
        if len(tiles) > 1:
            raise WarpError(f"{label}: the UVs span UDIM tiles {', '.join(map(str, tiles))}: a mask image covers one tile")
        mask = {tiles[0]: tegument.resample_image(image_pixels(node.mask_image, "mask", label), shape)}
    directory = output_directory(node.directory, label)
    return WarpInputs(obj, uv_map, rest, corners, sizes, uvs, tiles, rigidity, mask, resolution, directory)
