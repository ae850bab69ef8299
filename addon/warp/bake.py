# SPDX-License-Identifier: GPL-3.0-or-later
"""UV Warp bakes: solve frames in order and write the OpenEXR redirection sequence.

One job serves the modal operator (one frame per timer event), the blocking
operator in background mode and the command line. Frames are written into a
hidden staging folder beside the sequence; :meth:`WarpBakeJob.commit` moves
them into place (each move atomic) and points the node at them, so until
then the previous bake stays exactly as it was, and a failed bake leaves
nothing behind. Cancelling keeps the frames done.

A farm splits a node's frames into chunks (``chunk=True``), baked at once on
several workers into the one sequence: a chunk moves each frame into place as
soon as it is solved (atomically, so a worker that dies leaves whole frames),
and leaves the sequence's other frames, the node and the .blend alone. A chunk
that does not begin the bake first solves ``preroll`` frames before its first
one without writing them: the warm start a bake that ran through would have
had, to within the convergence tolerance (``farm`` says how many).
"""

from __future__ import annotations

import contextlib
import glob
import os
import re
import shutil
import tempfile
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from .. import jobs, mesh_arrays
from . import inputs, raster
from . import node as warp_node
from .inputs import WarpError


@dataclass
class FrameStats:
    frame: int
    seconds: float
    identity_mean: float
    warped_mean: float
    warped_max: float
    foldovers: int


@dataclass
class BakeSummary:
    frames: list[FrameStats] = field(default_factory=list)

    def text(self) -> str:
        if not self.frames:
            return "no frames baked"
        f = self.frames
        ms = 1000 * float(np.mean([s.seconds for s in f]))
        before = float(np.mean([s.identity_mean for s in f]))
        after = float(np.mean([s.warped_mean for s in f]))
        worst = max(s.warped_max for s in f)
        folds = sum(s.foldovers for s in f)
        return (f"{len(f)} frames, {ms:.0f} ms/frame; rigid stretch {before:.3f} → {after:.3f} "
                f"(worst {worst:.3f}); fold-overs {folds}")


def _combine(per_tile: list) -> tuple[float, float, float, int]:
    """Rigid-texel-weighted means over the tiles of one frame's metrics (``tegument.WarpMetrics``)."""
    weights = np.array([m.rigid_texels for m in per_tile], dtype=np.float64)
    total = weights.sum()
    w = weights / total if total else np.full(len(per_tile), 1 / len(per_tile))
    identity = float(sum(wi * m.stretch_identity_mean for wi, m in zip(w, per_tile)))
    warped = float(sum(wi * m.stretch_warped_mean for wi, m in zip(w, per_tile)))
    worst = float(max(m.stretch_warped_max for m in per_tile))
    folds = int(sum(m.foldovers for m in per_tile))
    return identity, warped, worst, folds


def _stored_path(directory_setting: str, filename: str) -> str:
    """Keeps a ``//``-relative directory relative in the image path, so the .blend can move."""
    if directory_setting.startswith("//"):
        return directory_setting.rstrip("/\\") + "/" + filename
    return os.path.join(os.path.abspath(bpy.path.abspath(directory_setting)), filename)


class WarpBakeJob:
    """Bakes ``frames`` of one UV Warp node, one frame per :meth:`step` (a :class:`jobs.Job`)."""

    def __init__(self, context, material, node, frames: range | None = None, *, preroll: int = 0, chunk: bool = False):
        import tegument

        self.scene = context.scene
        self.material = material
        self.node = node
        self.label = f"{material.name} › {node.name}"
        self.title = f"UV warp of {self.label}"
        self.log_prefix = "Tegument UV Warp"
        self.frames = frames if frames is not None else range(node.frame_start, node.frame_end + 1)
        if len(self.frames) == 0:
            raise WarpError(f"{self.label}: the frame range {self.frames.start}–{self.frames.stop - 1} is empty")
        if self.frames.start < 0:
            raise WarpError(f"{self.label}: frame {self.frames.start} is negative: image sequences number frames from 0")
        if preroll < 0:
            raise WarpError(f"{self.label}: a pre-roll of {preroll} frames is negative")
        self.chunk = chunk
        # Solved before the first frame, not written; never before frame 0 (where sequences start).
        self.preroll = range(max(self.frames.start - preroll, 0), self.frames.start)
        self.inputs = data = inputs.read(node, self.label)
        single = len(data.tiles) == 1
        # The wheel takes a plain array for tile 1001 alone and a dict otherwise.
        rigidity = data.rigidity[1001] if single and data.tiles == [1001] else data.rigidity
        mask = data.mask
        if mask is not None and single and data.tiles == [1001]:
            mask = mask[1001]
        try:
            self.warp = tegument.UvWarp(
                data.rest, data.corner_verts, data.polygon_sizes,
                data.corner_uvs, rigidity, mask=mask, iterations=node.iterations,
                orientation=node.orientation, smoothing=node.smoothing, warm_start=True,
            )
        except tegument.TegumentError as error:
            raise WarpError(f"{self.label}: {error}") from None
        self.stem = warp_node.file_stem(material.name, node.name)
        self.summary = BakeSummary()
        self.frame_before = self.scene.frame_current
        self.done = 0
        try:
            os.makedirs(data.directory, exist_ok=True)
            self.staging = tempfile.mkdtemp(prefix=".tegument-warp-", dir=data.directory)
        except OSError as error:
            raise WarpError(f"{self.label}: cannot write into {data.directory}: {error.strerror}") from None
        self._stack = contextlib.ExitStack()
        self._stack.enter_context(inputs.without_trailing_subdivision(data.obj))

    @property
    def finished(self) -> bool:
        return self.done >= len(self.frames)

    @property
    def times(self) -> list[float]:
        return [s.seconds for s in self.summary.frames]

    def eta_seconds(self) -> float:
        if not self.summary.frames:
            return float("nan")
        return float(np.mean(self.times)) * (len(self.frames) - self.done)

    def _positions(self, frame: int) -> np.ndarray:
        """The node's object at ``frame``, checked against the bind."""
        obj = self.inputs.obj
        self.scene.frame_set(frame)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        positions = mesh_arrays.positions(obj.evaluated_get(depsgraph).data)
        if len(positions) != len(self.inputs.rest):
            raise WarpError(
                f"{self.label}: at frame {frame} {obj.name} evaluates to {len(positions)} vertices but was bound "
                f"with {len(self.inputs.rest)}: a modifier changes the topology (move it to the end of the stack, "
                "or disable it in the viewport while baking)"
            )
        vertex = mesh_arrays.first_non_finite(positions)
        if vertex is not None:
            raise WarpError(f"{self.label}: at frame {frame} the position of vertex {vertex} of {obj.name} is not finite")
        return positions

    def _solve(self, frame: int, positions: np.ndarray) -> None:
        import tegument

        try:
            # One solve moves every tile; each tile's result and figures are read by its UDIM.
            self.warp.solve(positions, udim=self.inputs.tiles[0])
        except tegument.TegumentError as error:
            raise WarpError(f"{self.label}, frame {frame}: {error}") from None

    def step(self) -> FrameStats:
        """Solves and stages the next frame (in a chunk: moves it into place)."""
        import tegument

        started = time.perf_counter()
        if self.done == 0:
            # The pre-roll: the warm start of the first frame, counted in its time.
            for frame in self.preroll:
                self._solve(frame, self._positions(frame))
        frame = self.frames[self.done]
        positions = self._positions(frame)
        self._solve(frame, positions)
        try:
            metrics = [self.warp.metrics(positions, udim=udim) for udim in self.inputs.tiles]
            for udim in self.inputs.tiles:
                self.warp.write_exr(self._staged(udim, frame), udim=udim)
        except tegument.TegumentError as error:
            raise WarpError(f"{self.label}, frame {frame}: {error}") from None
        if self.chunk:
            self._move_into_place([frame])
        self.last_positions = positions
        identity, warped, worst, folds = _combine(metrics)
        stats = FrameStats(frame, time.perf_counter() - started, identity, warped, worst, folds)
        self.summary.frames.append(stats)
        self.done += 1
        return stats

    def progress_line(self) -> str:
        stats = self.summary.frames[-1]
        return (f"{self.log_prefix}: {self.label} frame {stats.frame} ({self.done}/{len(self.frames)}) "
                f"{1000 * stats.seconds:.1f} ms, rigid stretch {stats.identity_mean:.3f} → {stats.warped_mean:.3f}, "
                f"fold-overs {stats.foldovers}, ETA {self.eta_seconds():.1f} s")

    def outcome(self) -> str:
        text = self.summary.text()
        if self.preroll:
            text += f"; pre-roll of {len(self.preroll)} frames ({self.preroll.start}–{self.preroll.stop - 1})"
        return text

    def _staged(self, udim: int, frame: int) -> str:
        return warp_node.frame_file(self.staging, self.stem, udim, frame)

    def _move_into_place(self, frames) -> None:
        directory = self.inputs.directory
        try:
            for udim in self.inputs.tiles:
                for frame in frames:
                    os.replace(self._staged(udim, frame), warp_node.frame_file(directory, self.stem, udim, frame))
        except OSError as error:
            raise WarpError(f"{self.label}: cannot move the baked frames into {directory}: {error.strerror}") from None

    def commit(self) -> None:
        """Moves the frames done into place and points the node's inner tree at them (a chunk's
        frames are in place already, and a chunk leaves the node as it is)."""
        try:
            if self.done == 0 or self.chunk:
                return
            baked = self.frames[: self.done]
            self._move_into_place(baked)
            self._remove_stale(baked)
            if self.node.write_heatmap:
                self._write_heatmaps(baked.stop - 1)
            self._point_node_at(baked)
        finally:
            self._restore()

    def abort(self) -> None:
        """Discards what this job staged; the previous bake stays as it was."""
        self._restore()

    def _restore(self) -> None:
        shutil.rmtree(self.staging, ignore_errors=True)
        self._stack.close()
        self.scene.frame_set(self.frame_before)

    def _write_heatmaps(self, frame: int) -> None:
        """The remaining stretch of the last frame done, one single-channel EXR per tile."""
        import tegument

        data = self.inputs
        self.heatmaps = {}
        for udim in data.tiles:
            d = self.warp.displacement(udim=udim)
            error = tegument.stretch_map(data.rest, self.last_positions, data.corner_verts, data.polygon_sizes,
                                         data.corner_uvs, d, udim=udim)
            path = warp_node.heatmap_file(data.directory, self.stem, udim)
            staged = warp_node.heatmap_file(self.staging, self.stem, udim)
            tegument.write_exr(staged, np.ascontiguousarray(error), {
                "frame": str(frame), "udim": str(udim),
                "measure": "max(|log s1|, |log s2|) of the texture detail's deformation gradient",
            })
            os.replace(staged, path)
            self.heatmaps[udim] = path
            image = bpy.data.images.get(os.path.basename(path))
            if image is None:
                image = bpy.data.images.load(path, check_existing=True)
            image.colorspace_settings.name = "Non-Color"
            image.reload()

    def _remove_stale(self, baked: range) -> None:
        """Frames and tiles of an earlier bake of this node that the new sequence does not cover."""
        pattern = re.compile(re.escape(self.stem) + r"_(\d{4})_(\d+)\.exr")
        for path in glob.glob(os.path.join(glob.escape(self.inputs.directory), f"{glob.escape(self.stem)}_*.exr")):
            match = pattern.fullmatch(os.path.basename(path))
            if match is None:
                continue
            udim, frame = int(match.group(1)), int(match.group(2))
            if udim not in self.inputs.tiles or frame not in baked:
                with contextlib.suppress(OSError):
                    os.remove(path)

    def _point_node_at(self, baked: range) -> None:
        point_node_at(self.node, self.stem, self.inputs.tiles, self.inputs.directory, baked)
        self.node.report = self.summary.text()
        if getattr(self, "heatmaps", None):
            self.node.report += f"; heat map of frame {baked.stop - 1}: {', '.join(os.path.basename(p) for p in self.heatmaps.values())}"


def point_node_at(node, stem: str, tiles: list[int], directory: str, baked: range) -> None:
    """Makes the node's inner tree sample the sequence ``stem`` of ``tiles`` in ``directory`` over ``baked``."""
    node.baked_start = baked.start
    node.baked_frames = len(baked)
    current = warp_node.tile_images(node)
    images = {}
    for udim in tiles:
        filename = os.path.basename(warp_node.frame_file("", stem, udim, baked.start))
        stored = _stored_path(node.directory, filename)
        existing = current.get(udim)
        if existing is not None and existing.filepath != stored:
            existing = None  # another node's sequence (a copy of this node): leave it alone
        images[udim] = warp_node.sequence_image(
            f"{stem}_{udim}", warp_node.frame_file(directory, stem, udim, baked.start), stored, existing,
        )
    warp_node.build_sampler(node, images)


def attach(material, node, frames: range | None = None) -> range:
    """Points the node at a sequence baked elsewhere — a farm's chunks, which leave the node and the
    .blend alone — once every frame of every tile is there; returns the frames. A WarpError names
    the first missing file, and the node stays as it was."""
    label = f"{material.name} › {node.name}"
    frames = frames if frames is not None else range(node.frame_start, node.frame_end + 1)
    if len(frames) == 0:
        raise WarpError(f"{label}: the frame range {frames.start}–{frames.stop - 1} is empty")
    obj = node.object
    if obj is None or obj.type != "MESH":
        raise WarpError(f"{label}: no object: set the node's Object to the deforming mesh")
    layer = inputs.uv_layer_name(obj, node.uv_map, label)
    tiles = raster.udim_tiles(inputs.corner_uvs(obj.data, layer), mesh_arrays.polygon_sizes(obj.data))
    directory = inputs.output_directory(node.directory, label)
    stem = warp_node.file_stem(material.name, node.name)
    for udim in tiles:
        for frame in frames:
            path = warp_node.frame_file(directory, stem, udim, frame)
            if not os.path.isfile(path):
                raise WarpError(f"{label}: frame {frame} of the sequence is missing ({path}): bake it first")
    point_node_at(node, stem, tiles, directory, frames)
    node.report = f"{len(frames)} frames baked elsewhere (frames {frames.start}–{frames.stop - 1})"
    return frames


def bake_blocking(context, material, node, frames: range | None = None, *, report=print,
                  preroll: int = 0, chunk: bool = False) -> tuple[int, bool, WarpBakeJob]:
    """Bakes in the foreground (:func:`jobs.run_blocking`); returns ``(frames written, cancelled, job)``."""
    job = WarpBakeJob(context, material, node, frames, preroll=preroll, chunk=chunk)
    cancelled = jobs.run_blocking(context, job, report=report)
    return job.done, cancelled, job


def find_node(context, material_name: str = "", node_name: str = ""):
    """``(material, node)`` named, or the active ones; WarpError saying what is missing."""
    if material_name:
        material = bpy.data.materials.get(material_name)
        if material is None:
            raise WarpError(f"no material named \"{material_name}\"")
    else:
        obj = getattr(context, "active_object", None) or getattr(context, "object", None)
        material = obj.active_material if obj is not None else None
        if material is None:
            found = list(warp_node.find_nodes())
            if len(found) == 1 and not node_name:
                return found[0]
            raise WarpError("no material given and the active object has no active material")
    tree = material.node_tree
    if tree is None:
        raise WarpError(f"material \"{material.name}\" has no node tree")
    if node_name:
        node = tree.nodes.get(node_name)
        if node is None or node.bl_idname != warp_node.NODE_IDNAME:
            raise WarpError(f"material \"{material.name}\" has no Tegument UV Warp node named \"{node_name}\"")
        return material, node
    active = tree.nodes.active
    if active is not None and active.bl_idname == warp_node.NODE_IDNAME:
        return material, active
    nodes = [n for n in tree.nodes if n.bl_idname == warp_node.NODE_IDNAME]
    if len(nodes) == 1:
        return material, nodes[0]
    if not nodes:
        raise WarpError(f"material \"{material.name}\" has no Tegument UV Warp node")
    raise WarpError(f"material \"{material.name}\" has {len(nodes)} Tegument UV Warp nodes: name one "
                    f"({', '.join(n.name for n in nodes)})")
