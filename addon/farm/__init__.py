# SPDX-License-Identifier: GPL-3.0-or-later
"""What a render farm needs to know of a .blend's Tegument bakes, and nothing else.

:func:`scene_bakes` describes every bake the scene holds — each Pyramid Deform
object and each Tegument UV Warp node — as plain data: its frame range, the
files it writes (relative to the .blend, so a worker that opens the file from
shared storage writes them where the artist's Blender reads them), which other
bakes it reads, and the command line that bakes it. ``tegument list-bakes``
prints it as JSON; the Flamenco job type beside this file (``tegument_bake.js``)
compiles it into tasks; any other farm manager can run the command lines as
they are (:func:`chunk_commands`).

The command lines are templates with ``{first}``, ``{last}`` and ``{preroll}``
in them, filled in per task, so that the format of a Tegument command lives
here only: the job type substitutes, it never composes a command itself.

Why a UV Warp node splits into chunks and a Pyramid Deform object does not:
a deformer's frames carry history (collisions, dynamics), so one task bakes
its whole range in order. A warp frame only warm-starts from the frame before;
a chunk solves :data:`DEFAULT_PREROLL` frames before its first one without
writing them, which brings the warm start back within the convergence
tolerance of a bake that ran through (``blender_tests/test_farm.py``).
"""

from __future__ import annotations

import json
import os

import bpy

from .. import mesh_arrays
from ..deform import colliders, evaluate
from ..warp import node as warp_node
from ..warp import raster
from ..warp.inputs import WarpError, corner_uvs, uv_layer_name

# Frames a warp chunk solves before its first frame (not written). Measured in
# blender_tests/test_farm.py: see docs/farm.md for the figures.
DEFAULT_PREROLL = 4

PYRAMID_DEFORM = "pyramid_deform"
UV_WARP = "uv_warp"


class FarmError(ValueError):
    """The scene's bakes cannot be described for a farm; the message says why and what to do."""


def blend_relative(path: str) -> str:
    """``path`` (absolute, or ``//``-relative) relative to the .blend's folder, with ``/`` separators;
    absolute where it lies on another drive."""
    absolute = os.path.abspath(bpy.path.abspath(path))
    try:
        relative = os.path.relpath(absolute, os.path.dirname(bpy.data.filepath))
    except ValueError:  # another drive (Windows)
        return absolute.replace(os.sep, "/")
    return relative.replace(os.sep, "/")


def warp_id(material_name: str, node_name: str) -> str:
    return f"{material_name}/{node_name}"


def _deformers(scene) -> list:
    return [obj for obj in scene.objects if obj.type == "MESH" and evaluate.tegument_modifier(obj) is not None]


def _deform_bake(obj) -> dict:
    settings = obj.tegument
    caches = [blend_relative(settings.cache_path)]
    # Compliant colliders get caches of their own, written by this object's bake.
    compliant = [c for c in colliders.collider_objects(obj) if colliders.is_compliant(c)]
    caches += [blend_relative(colliders.compliance_cache_path(c)) for c in compliant]
    return {
        "kind": PYRAMID_DEFORM,
        "id": obj.name,
        "object": obj.name,
        "frames": [settings.frame_start, settings.frame_end],
        "caches": caches,
        "writes_objects": [c.name for c in compliant],
        "depends_on": [],  # filled in by scene_bakes, which knows every bake
        # Colliders play their own caches when they have Pyramid Deform (or are compliant in another bake).
        "reads_objects": [c.name for c in colliders.collider_objects(obj) if c != obj],
        "args": ["--command", "tegument", "bake", "--objects", obj.name, "--frames", "{first}-{last}"],
        "chunked": False,
    }


def _warp_bake(material, node) -> dict:
    stem = warp_node.file_stem(material.name, node.name)
    obj = node.object
    tiles = [1001]
    problem = None
    if obj is None:
        problem = f"{material.name} › {node.name}: no object: set the node's Object to the deforming mesh"
    elif obj.type == "MESH":
        try:
            layer = uv_layer_name(obj, node.uv_map, f"{material.name} › {node.name}")
        except WarpError as error:
            problem = str(error)
        else:
            tiles = raster.udim_tiles(corner_uvs(obj.data, layer), mesh_arrays.polygon_sizes(obj.data)) or tiles
    directory = blend_relative(node.directory)
    entry = {
        "kind": UV_WARP,
        "id": warp_id(material.name, node.name),
        "material": material.name,
        "node": node.name,
        "object": obj.name if obj is not None else None,
        "frames": [node.frame_start, node.frame_end],
        # One OpenEXR file per frame and UDIM tile; #### is the frame number.
        "caches": [f"{directory.rstrip('/')}/{stem}_{udim}_####.exr" for udim in tiles],
        "depends_on": [],
        "reads_objects": [obj.name] if obj is not None else [],
        "args": ["--command", "tegument", "warp-bake", "--material", material.name, "--node", node.name,
                 "--frames", "{first}-{last}", "--chunk", "--preroll", "{preroll}"],
        "chunked": True,
    }
    if problem:
        entry["problem"] = problem
    return entry


def scene_bakes(scene=None) -> dict:
    """Every Tegument bake of the open .blend as JSON-ready data (see the module docstring)."""
    scene = scene or bpy.context.scene
    if not bpy.data.filepath:
        raise FarmError("no .blend is open: a farm bakes a saved file (blender -b shot.blend --command tegument list-bakes)")
    bakes = [_deform_bake(obj) for obj in _deformers(scene)]
    bakes += [_warp_bake(material, node) for material, node in warp_node.find_nodes()]
    # A bake depends on the deformer whose cache moves an object it reads: the object itself
    # (its Tegument modifier plays the cache) or a compliant collider that deformer writes.
    writer_of = {}
    for bake in bakes:
        if bake["kind"] == PYRAMID_DEFORM:
            writer_of[bake["object"]] = bake["id"]
            for name in bake["writes_objects"]:
                writer_of.setdefault(name, bake["id"])
    for bake in bakes:
        reads = bake["reads_objects"]
        bake["depends_on"] = sorted({writer_of[name] for name in reads if name in writer_of} - {bake["id"]})
    _check_acyclic(bakes)
    return {
        "blendfile": bpy.path.basename(bpy.data.filepath),
        "scene": scene.name,
        "preroll": DEFAULT_PREROLL,
        "bakes": bakes,
    }


def _check_acyclic(bakes: list[dict]) -> None:
    """Two deformers colliding with each other would each wait for the other: say which."""
    depends = {b["id"]: b["depends_on"] for b in bakes}
    state: dict[str, int] = {}

    def visit(name: str, path: list[str]) -> None:
        if state.get(name) == 2:
            return
        if state.get(name) == 1:
            cycle = path[path.index(name):] + [name]
            raise FarmError(
                "these Pyramid Deform objects read each other's caches as colliders: "
                + " → ".join(cycle) + "; a farm cannot order their bakes (bake them together locally, "
                "or take one out of the other's collider collection)"
            )
        state[name] = 1
        for other in depends.get(name, []):
            visit(other, path + [name])
        state[name] = 2

    for name in depends:
        visit(name, [])


def fill(args: list[str], first: int, last: int, preroll: int = 0) -> list[str]:
    """A command template of :func:`scene_bakes` with its frames filled in."""
    values = {"{first}": str(first), "{last}": str(last), "{preroll}": str(preroll)}
    out = []
    for arg in args:
        for key, value in values.items():
            arg = arg.replace(key, value)
        out.append(arg)
    return out


def chunks(first: int, last: int, size: int) -> list[tuple[int, int]]:
    """``first``–``last`` in runs of ``size`` frames (the last run may be shorter)."""
    return [(start, min(start + size - 1, last)) for start in range(first, last + 1, size)]


def chunk_commands(bake: dict, span: tuple[int, int] | None, chunk_size: int, preroll: int) -> list[dict]:
    """The tasks of one bake: ``{"frames": [first, last], "args": [...]}``, one per chunk of a UV Warp
    node (each pre-rolling up to ``preroll`` frames, never before the bake's first frame), one for a
    Pyramid Deform object's whole range. The job type (tegument_bake.js) computes the same."""
    first, last = span if span is not None else bake["frames"]
    if not bake["chunked"]:
        return [{"frames": [first, last], "args": fill(bake["args"], first, last)}]
    return [
        {"frames": [a, b], "args": fill(bake["args"], a, b, min(preroll, a - first))}
        for a, b in chunks(first, last, chunk_size)
    ]


def scene_bakes_json(scene=None) -> str:
    return json.dumps(scene_bakes(scene), ensure_ascii=False)


def _bakes_property(scene) -> str:
    """``C.scene.tegument_farm_bakes``: what the job type's hidden ``scene_bakes`` setting evaluates
    to when Blender's Flamenco add-on submits a job. An error becomes a JSON object whose
    ``error`` the job type reports, instead of an exception inside Flamenco's add-on."""
    try:
        return scene_bakes_json(scene)
    except FarmError as error:
        return json.dumps({"error": str(error)}, ensure_ascii=False)


def register() -> None:
    bpy.types.Scene.tegument_farm_bakes = bpy.props.StringProperty(
        name="Tegument Bakes (farm)", get=_bakes_property, options={"HIDDEN", "SKIP_SAVE"},
        description="Every Tegument bake of this scene as JSON (what `tegument list-bakes` prints)",
    )


def unregister() -> None:
    del bpy.types.Scene.tegument_farm_bakes
