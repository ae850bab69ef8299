# SPDX-License-Identifier: GPL-3.0-or-later
"""Headless bakes: ``blender -b scene.blend --command tegument bake [--objects A,B] [--frames S-E]``,
``... --command tegument warp-bake [--material M] [--node N] [--frames S-E] [--chunk] [--preroll N]``,
``... --command tegument list-bakes`` (every bake of the file as JSON, for farms: see ``farm``) and
``... --command tegument warp-attach [--save]`` (nodes play sequences a farm baked in chunks).

The same entry point serves the PyPI ``bpy`` module, which has no ``--command``::

    import bpy, sys
    bpy.ops.wm.open_mainfile(filepath="scene.blend")
    from bl_ext.user_default.tegument import cli
    sys.exit(cli.main(["bake", "--frames", "1-24"]))
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import bpy

from . import farm, jobs
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
    warping = _node_arguments(commands.add_parser(
        "warp-bake", help="bake Tegument UV Warp nodes into their OpenEXR sequences"))
    warping.add_argument("--save", action="store_true",
                         help="save the .blend afterwards (so the nodes point at the new sequences)")
    warping.add_argument("--chunk", action="store_true",
                         help="farm chunk: write only these frames into the sequence, each as soon as it is solved; "
                         "leave the node, the .blend and the sequence's other frames alone")
    warping.add_argument("--preroll", type=_count, default=0, metavar="N",
                         help="first solve up to N frames before the range without writing them (a warm start "
                         "for a chunk that does not begin the bake); never before frame 0")
    attaching = _node_arguments(commands.add_parser(
        "warp-attach", help="point Tegument UV Warp nodes at sequences baked elsewhere (a farm's chunks)"))
    attaching.add_argument("--save", action="store_true", help="save the .blend afterwards (unless a node failed)")
    listing = commands.add_parser("list-bakes", help="print every Tegument bake of the .blend as JSON (for farms)")
    listing.add_argument("--output", help="write the JSON to this file instead of stdout")
    listing.add_argument("--frames", help="frame range S-E of every bake in the tasks (default: each bake's own)")
    listing.add_argument("--chunk-size", type=_positive, metavar="N",
                         help="also list each bake's tasks: UV Warp nodes in chunks of N frames")
    listing.add_argument("--preroll", type=_count, default=None, metavar="N",
                         help=f"frames a UV Warp chunk solves before its first one (default {farm.DEFAULT_PREROLL})")
    return parser


def _node_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The arguments that pick UV Warp nodes and their frames (``warp-bake``, ``warp-attach``)."""
    parser.add_argument("--material", help="material holding the node (default: every material with one)")
    parser.add_argument("--node", help="node name (default: every Tegument UV Warp node of the material)")
    parser.add_argument("--frames", help="frame range S-E (default: each node's own range)")
    return parser


def _count(text: str) -> int:
    """An argparse type: a whole number of frames, 0 or more."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expects a whole number of frames, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expects 0 or more frames, got {value}")
    return value


def _positive(text: str) -> int:
    value = _count(text)
    if value == 0:
        raise argparse.ArgumentTypeError("expects at least 1 frame, got 0")
    return value


def _span(text: str | None) -> tuple[int, int] | None:
    """``--frames S-E`` as ``(S, E)``; None when not given (each bake's own range)."""
    if not text:
        return None
    try:
        start, end = (int(part) for part in text.split("-", 1))
    except ValueError:
        raise ValueError(f"error: --frames expects START-END, got {text!r}") from None
    if end < start:
        raise ValueError(f"error: --frames {text}: the last frame {end} comes before the first {start}")
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
    if args.command == "list-bakes":
        return _list_bakes(args, span)
    if args.command == "warp-attach":
        return _warp_attach(args, span)
    if args.command == "warp-bake" and args.chunk and args.save:
        # Chunks of one node run at once on several workers: none may save the shared .blend.
        print("error: --chunk leaves the .blend as it is (chunks run at once on a farm): drop --save", file=sys.stderr)
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


def _no_file_hint() -> str:
    """Blender runs the command on its empty start-up scene when the .blend it was given is missing:
    "nothing to bake" alone would hide that."""
    return "" if bpy.data.filepath else " (no .blend is open: was the file given to Blender found?)"


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
        print("error: nothing to bake: no object has Pyramid Deform" + _no_file_hint(), file=sys.stderr)
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
    targets = _warp_targets(args)
    if isinstance(targets, int):
        return targets
    return [
        lambda m=m, n=n: warp_bake.WarpBakeJob(bpy.context, m, n, _frames(span, n), preroll=args.preroll, chunk=args.chunk)
        for m, n in targets
    ]


def _warp_targets(args):
    """The (material, node) pairs ``--material`` and ``--node`` name, or the exit code of a usage error."""
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
                  + (f" named {args.node}" if args.node else "") + _no_file_hint(), file=sys.stderr)
            return 2
    return targets


def _warp_attach(args, span) -> int:
    """``warp-attach``: points each node at its sequence baked elsewhere (a farm's chunks)."""
    targets = _warp_targets(args)
    if isinstance(targets, int):
        return targets
    failed = 0
    for material, node in targets:
        try:
            frames = warp_bake.attach(material, node, _frames(span, node))
        except warp_bake.WarpError as error:
            print(f"error: {error}", file=sys.stderr)
            failed += 1
            continue
        print(f"Tegument UV Warp: {material.name} › {node.name} plays frames {frames.start}–{frames.stop - 1}")
    if args.save and bpy.data.filepath and not failed:
        bpy.ops.wm.save_mainfile()
    return 1 if failed else 0


def _list_bakes(args, span) -> int:
    """``list-bakes``: the JSON of :func:`farm.scene_bakes`, on one line of stdout (Blender prints
    its own lines around it) or into ``--output``, replaced whole."""
    try:
        described = farm.scene_bakes()
    except farm.FarmError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.chunk_size is not None:
        preroll = farm.DEFAULT_PREROLL if args.preroll is None else args.preroll
        for bake_entry in described["bakes"]:
            bake_entry["tasks"] = farm.chunk_commands(bake_entry, span, args.chunk_size, preroll)
    text = json.dumps(described, ensure_ascii=False)
    if not args.output:
        print(text, flush=True)
        return 0
    temporary = f"{args.output}.tmp"
    try:
        with open(temporary, "w", encoding="utf-8") as file:
            file.write(text + "\n")
        os.replace(temporary, args.output)
    except OSError as error:
        print(f"error: cannot write {args.output}: {error.strerror or error}", file=sys.stderr)
        return 1
    return 0


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
