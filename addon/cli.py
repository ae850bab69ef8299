# SPDX-License-Identifier: GPL-3.0-or-later
"""Headless bakes: ``blender -b scene.blend --command tegument bake [--objects A,B] [--frames S-E]``
and ``... --command tegument warp-bake [--material M] [--node N] [--frames S-E]``.

The same entry point serves the PyPI ``bpy`` module, which has no ``--command``::

    import bpy, sys
    bpy.ops.wm.open_mainfile(filepath="scene.blend")
    from bl_ext.user_default.tegument import cli
    sys.exit(cli.main(["bake", "--frames", "1-24"]))
"""

from __future__ import annotations

import argparse
import sys

import bpy

from . import pc2
from .deform import bake, evaluate


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="blender -b FILE --command tegument", description="Tegument headless bakes")
    commands = parser.add_subparsers(dest="command", required=True)
    baking = commands.add_parser("bake", help="bake Pyramid Deform into each object's point cache")
    baking.add_argument("--objects", help="comma-separated object names (default: every object with Pyramid Deform)")
    baking.add_argument("--frames", help="frame range S-E (default: each object's own range)")
    baking.add_argument("--save", action="store_true", help="save the .blend afterwards (status fields)")
    warping = commands.add_parser("warp-bake", help="bake Tegument UV Warp nodes into their OpenEXR sequences")
    warping.add_argument("--material", help="material holding the node (default: every material with one)")
    warping.add_argument("--node", help="node name (default: every Tegument UV Warp node of the material)")
    warping.add_argument("--frames", help="frame range S-E (default: each node's own range)")
    warping.add_argument("--save", action="store_true",
                         help="save the .blend afterwards (so the nodes point at the new sequences)")
    return parser


def _frames(text: str | None, settings) -> range:
    if not text:
        return range(settings.frame_start, settings.frame_end + 1)
    try:
        start, end = (int(part) for part in text.split("-", 1))
    except ValueError:
        raise SystemExit(f"error: --frames expects START-END, got {text!r}") from None
    return range(start, end + 1)


def main(argv: list[str]) -> int:
    """Runs one command; returns the process exit code."""
    try:
        args = _parser().parse_args(argv)
    except SystemExit as stop:
        return int(stop.code or 0)
    if args.command == "warp-bake":
        return warp_bake(args)
    scene = bpy.context.scene
    if args.objects:
        names = [name.strip() for name in args.objects.split(",") if name.strip()]
        missing = [name for name in names if name not in scene.objects]
        if missing:
            print(f"error: no object named {', '.join(missing)} in scene {scene.name}", file=sys.stderr)
            return 2
        objects = [scene.objects[name] for name in names]
    else:
        objects = [obj for obj in scene.objects if obj.type == "MESH" and evaluate.tegument_modifier(obj)]
    if not objects:
        print("error: nothing to bake: no object has Pyramid Deform", file=sys.stderr)
        return 2
    failed = 0
    for obj in objects:
        if evaluate.tegument_modifier(obj) is None:
            print(f"error: {obj.name} has no Pyramid Deform", file=sys.stderr)
            failed += 1
            continue
        try:
            frames = _frames(args.frames, obj.tegument)
        except SystemExit as stop:  # a bad --frames is a usage error, not a reason to leave main()
            print(stop.code, file=sys.stderr)
            return 2
        if frames.start != obj.tegument.frame_start:
            obj.tegument.frame_start = frames.start  # the cache starts where the bake starts
        bpy.context.view_layer.objects.active = obj
        try:
            written, cancelled = bake.bake_blocking(bpy.context, obj, frames, report=print)
        except (evaluate.DeformError, pc2.CacheError) as error:
            print(f"error: {error}", file=sys.stderr)
            failed += 1
            continue
        print(f"Tegument: {obj.name}: {written} frames in {evaluate.cache_file(obj)}")
        if cancelled:
            return 130
    if args.save and bpy.data.filepath:
        bpy.ops.wm.save_mainfile()
    return 1 if failed else 0


def warp_bake(args) -> int:
    from .warp import bake as warp_bake_module
    from .warp import node as warp_node
    from .warp.inputs import WarpError

    if args.material:
        material = bpy.data.materials.get(args.material)
        if material is None:
            print(f"error: no material named {args.material}", file=sys.stderr)
            return 2
        targets = [(m, n) for m, n in warp_node.find_nodes() if m == material and (not args.node or n.name == args.node)]
        if not targets:
            what = f"Tegument UV Warp node named {args.node}" if args.node else "Tegument UV Warp node"
            print(f"error: material {material.name} has no {what}", file=sys.stderr)
            return 2
    else:
        targets = [(m, n) for m, n in warp_node.find_nodes() if not args.node or n.name == args.node]
        if not targets:
            print("error: nothing to bake: no material has a Tegument UV Warp node"
                  + (f" named {args.node}" if args.node else ""), file=sys.stderr)
            return 2
    failed = 0
    for material, node in targets:
        frames = _frames(args.frames, node)
        try:
            _, cancelled, _ = warp_bake_module.bake_blocking(bpy.context, material, node, frames, report=print)
        except WarpError as error:
            print(f"error: {error}", file=sys.stderr)
            failed += 1
            continue
        if cancelled:
            return 130
    if args.save and bpy.data.filepath:
        bpy.ops.wm.save_mainfile()
    return 1 if failed else 0


def _command(argv: list[str]) -> int:
    return main(argv)


_registered = []


def register() -> None:
    try:
        _registered.append(bpy.utils.register_cli_command("tegument", _command))
    except (AttributeError, RuntimeError):
        pass  # Blender < 4.2, or a build without command-line commands


def unregister() -> None:
    while _registered:
        bpy.utils.unregister_cli_command(_registered.pop())
