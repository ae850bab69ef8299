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

from . import jobs
from .deform import bake, evaluate
from .warp import bake as warp_bake
from .warp import node as warp_node


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


def _span(text: str | None) -> tuple[int, int] | None:
    """``--frames S-E`` as ``(S, E)``; None when not given (each bake's own range)."""
    if not text:
        return None
    try:
        start, end = (int(part) for part in text.split("-", 1))
    except ValueError:
        raise ValueError(f"error: --frames expects START-END, got {text!r}") from None
    return start, end


def _frames(span: tuple[int, int] | None, settings) -> range:
    start, end = span if span is not None else (settings.frame_start, settings.frame_end)
    return range(start, end + 1)


def main(argv: list[str]) -> int:
    """Runs one command; returns the process exit code."""
    try:
        args = _parser().parse_args(argv)
    except SystemExit as stop:
        return int(stop.code or 0)
    try:
        span = _span(args.frames)
    except ValueError as error:  # checked before anything is baked
        print(error, file=sys.stderr)
        return 2
    targets = _deform_jobs(args, span) if args.command == "bake" else _warp_jobs(args, span)
    if isinstance(targets, int):
        return targets
    failed = 0
    for make_job in targets:
        try:
            cancelled = jobs.run_blocking(bpy.context, make_job())
        except jobs.EXPECTED as error:
            print(f"error: {error}", file=sys.stderr)
            failed += 1
            continue
        if cancelled:
            return 130
    if args.save and bpy.data.filepath:
        bpy.ops.wm.save_mainfile()
    return 1 if failed else 0


def _deform_jobs(args, span):
    """One job factory per object to bake, or the exit code of a usage error."""
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

    def job_of(obj):
        if evaluate.tegument_modifier(obj) is None:
            raise evaluate.DeformError(f"{obj.name} has no Pyramid Deform")
        frames = _frames(span, obj.tegument)
        if frames.start != obj.tegument.frame_start:
            obj.tegument.frame_start = frames.start  # the cache starts where the bake starts
        bpy.context.view_layer.objects.active = obj
        return bake.BakeJob(bpy.context, obj, frames)

    return [lambda obj=obj: job_of(obj) for obj in objects]


def _warp_jobs(args, span):
    """One job factory per node to bake, or the exit code of a usage error."""
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
    return [lambda m=m, n=n: warp_bake.WarpBakeJob(bpy.context, m, n, _frames(span, n)) for m, n in targets]


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
