# SPDX-License-Identifier: GPL-3.0-or-later
"""Bake jobs: solve frames in order and stream them into the PC2 cache.

One job serves every path a bake can take — the blocking operator in
background mode, the modal operator in the UI (one frame per timer event),
``bake_frame``, live playback and the command line — so they cannot drift
apart. A job owns its cache writer: until it commits, the existing cache is
untouched; cancelling commits the frames done, failing discards them.
"""

from __future__ import annotations

import contextlib
import time

import bpy
import numpy as np

from .. import jobs, mesh_arrays, pc2
from . import colliders, evaluate, self_collision
from .evaluate import DeformError

# Deformers are cheap to rebuild but not free (topology + encoding of every
# vertex); live playback reuses them while the bind is unchanged.
_deformers: dict[tuple, object] = {}

# Objects with a bake job in progress (by session_uid). A second bake of the
# same object (the Bake button pressed again during a modal bake, the live
# handler firing on the frame changes of a bake) would interleave frame
# changes and race for the same cache file: it is refused instead.
_baking: set[int] = set()


def is_baking(obj) -> bool:
    return obj.session_uid in _baking


def _bind_key(obj, rest, corners, sizes) -> tuple:
    return (obj.session_uid, obj.tegument.scale_safe, hash(rest.tobytes()), hash(corners.tobytes()), hash(sizes.tobytes()))


def remember_deformer(obj, deformer, rest, corners, sizes) -> None:
    """Keeps the deformer Bind built for the bake that follows: building it again costs as
    much as the bind (seconds at millions of vertices)."""
    _deformers.clear()  # one bind at a time is the common case; keep memory bounded
    _deformers[_bind_key(obj, rest, corners, sizes)] = deformer


def build_deformer(obj):
    """The ``tegument.PyramidDeformer`` for the object's bind (cached per bind)."""
    import tegument

    rest, corners, sizes = evaluate.bound_mesh(obj)
    deformer = _deformers.get(_bind_key(obj, rest, corners, sizes))
    if deformer is None:
        try:
            deformer = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=obj.tegument.scale_safe)
        except tegument.TegumentError as error:
            raise DeformError(f"{obj.name}: {error}") from None
        remember_deformer(obj, deformer, rest, corners, sizes)
    return deformer, rest, corners, sizes


class BakeJob:
    """Solves ``frames`` of ``obj`` into a new cache, one frame per :meth:`step` (a :class:`jobs.Job`)."""

    def __init__(self, context, obj, frames: range, *, keep_existing: bool = False):
        self.scene = context.scene
        self.obj = obj
        self.label = self.title = obj.name
        self.log_prefix = "Tegument"
        self.frames = frames
        self.settings = obj.tegument
        if evaluate.tegument_modifier(obj) is None:
            raise DeformError(f"{obj.name} has no Tegument modifier: use Add Pyramid Deform (tegument.deform_add)")
        if len(frames) == 0:
            raise DeformError(f"{obj.name}: the frame range {frames.start}–{frames.stop - 1} is empty")
        if is_baking(obj):
            raise DeformError(f"{obj.name} is already being baked: wait for that bake to finish, or cancel it (Esc)")
        self.deformer, self.rest, self.corners, self.sizes = build_deformer(obj)
        self.closeness = evaluate.closeness_weights(obj)
        self.buffers = evaluate.FrameBuffers(len(self.rest))
        self.path = evaluate.cache_file(obj)
        self.start_frame = self.settings.frame_start
        self.frame_before = self.scene.frame_current
        self.times: list[float] = []
        self.iterations_used: list[int] = []  # per frame: Converge stops once converged
        self.last_phases: dict[str, float] = {}  # the last frame's time by phase (PhaseClock)
        self._existing = None
        self.done = 0
        self._stack = contextlib.ExitStack()
        self._stack.enter_context(evaluate.upstream_only(obj))
        self.collider_writers: dict[int, pc2.Writer] = {}
        try:
            # Frames kept before the range, then the range.
            self.expected_frames = max(frames.start - self.start_frame, 0) + len(frames)
            self.writer = pc2.Writer(self.path, len(self.rest), start=self.start_frame, expected_frames=self.expected_frames)
            if keep_existing and pc2.frame_count(self.path):
                existing = pc2.read(self.path)[0]
                # A cache of another bind (other vertex count) has nothing to keep.
                self._existing = existing if existing.shape[1] == len(self.rest) else None
            if self._existing is not None:
                self._copy_existing(frames.start - self.start_frame)
            self.rig = colliders.ColliderRig(obj)
            self.options = evaluate.step_options(obj, self.scene)
            # Collisions, dynamics, substeps and strain limits need the history-based step.
            self.uses_step = bool(self.rig) or bool(self.options)
            self.audit_totals = {"vertices_inside": 0, "edges_crossing": 0, "collider_edges_crossing": 0}
            self.most_pinched = 0
            self.worst_stretch = 0.0
            self.max_recession = 0.0
            self.self_figures = self_collision.BakeFigures(obj)
            self._stack.enter_context(self.rig.animated_only())
            self._open_collider_caches(context, keep_existing)
            if self.uses_step:
                self._start_history(frames.start)
            else:
                self._start_warm(frames.start)
        except BaseException:
            for writer in self.collider_writers.values():
                writer.abort()
            if hasattr(self, "writer"):
                self.writer.abort()
            self._stack.close()
            raise
        self._uid = obj.session_uid  # kept: the object may be deleted before the job ends
        _baking.add(self._uid)

    def _copy_existing(self, count: int) -> None:
        """Keeps the first ``count`` frames of the current cache (for partial bakes)."""
        if count <= 0:
            return
        existing = self._existing
        if existing.shape[1] != len(self.rest) or len(existing) < count:
            raise DeformError(f"{self.obj.name}: the cache does not hold the frames before {self.frames.start}")
        for frame in existing[:count]:
            self.writer.append(frame)

    def _open_collider_caches(self, context, keep_existing: bool) -> None:
        """One cache per compliant collider, written beside the skin's, frame for frame."""
        self._collider_existing: dict[int, np.ndarray] = {}
        if not self.rig.compliant:
            return
        depsgraph = context.evaluated_depsgraph_get()
        for k in self.rig.compliant:
            collider = self.rig.objects[k]
            count = len(collider.evaluated_get(depsgraph).data.vertices)
            path = colliders.compliance_cache_path(collider)
            self.collider_writers[k] = pc2.Writer(path, count, start=self.start_frame, expected_frames=self.expected_frames)
            if self._existing is None:
                continue
            keep = self.frames.start - self.start_frame
            existing = pc2.read(path)[0] if pc2.frame_count(path) else None
            if existing is None or existing.shape[1] != count or len(existing) < keep:
                raise DeformError(
                    f"{self.obj.name}: the compliance cache of collider {collider.name} does not hold the frames "
                    f"before {self.frames.start}: bake the whole range (tegument.bake)"
                )
            self._collider_existing[k] = existing
            for frame in existing[:keep]:
                self.collider_writers[k].append(frame)

    def _start_history(self, first: int) -> None:
        """Collisions are history-based: a bake that continues cached frames
        starts from the last of them, with the colliders where they were then."""
        self.deformer.reset()
        before = first - self.start_frame - 1
        if self._existing is None or not 0 <= before < len(self._existing) or first - 1 < self.start_frame:
            return
        if not self.rig:
            # Dynamics alone: resume from the cached shape, at rest.
            self.deformer.reset(np.ascontiguousarray(self._world_of(first - 1, self._existing[before]), dtype=np.float32))
            return
        self.scene.frame_set(first - 1)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        self.rig.update(depsgraph, first - 1)
        matrix = self.obj.evaluated_get(depsgraph).matrix_world
        self.deformer.reset(np.ascontiguousarray(evaluate.to_world(self._existing[before], matrix), dtype=np.float32))
        for k, existing in self._collider_existing.items():
            self.rig.place_local(k, existing[before])

    def _start_warm(self, first: int) -> None:
        """Without the history-based step a bake solves its first frame from the input and, with
        Converge, every later one from the frame before it (a warm start). A bake that continues
        cached frames (live playback, Bake Frame after the cache) starts warm from the last of them,
        with the input it was solved from, so that it writes the frames one bake of the whole range
        writes. Where the cached frame cannot be a start (its input is not finite or no longer has
        the bind's vertices, or the cache itself holds values that are not), the bake starts cold:
        the frame is solved from its own input, and its solve reports what is wrong, naming the
        frame."""
        self.deformer.reset()
        before = first - self.start_frame - 1
        if not self.settings.converge or self._existing is None or not 0 <= before < len(self._existing):
            return
        self.scene.frame_set(first - 1)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        _, input_world = evaluate.evaluated_positions(self.obj, depsgraph)
        if len(input_world) != len(self.rest) or mesh_arrays.first_non_finite(input_world) is not None:
            return
        result = evaluate.to_world(self._existing[before], self.obj.evaluated_get(depsgraph).matrix_world)
        if mesh_arrays.first_non_finite(result) is not None:
            return
        self.deformer.reset(np.ascontiguousarray(result, dtype=np.float32), input=np.ascontiguousarray(input_world, dtype=np.float32))

    def _world_of(self, frame: int, local: np.ndarray) -> np.ndarray:
        self.scene.frame_set(frame)
        matrix = self.obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).matrix_world
        return evaluate.to_world(local, matrix)

    @property
    def finished(self) -> bool:
        return self.done >= len(self.frames)

    @property
    def current_frame(self) -> int:
        return self.frames[min(self.done, len(self.frames) - 1)]

    def step(self) -> int:
        """Solves and writes the next frame; returns it."""
        frame = self.frames[self.done]
        clock = PhaseClock()
        solved, self._world = solve_frame(self.scene, self.obj, frame, self.deformer, self.closeness, self.rig, self.options,
                                          clock=clock, buffers=self.buffers)
        self.writer.append(solved)
        for k, writer in self.collider_writers.items():
            writer.append(self.rig.solved_local(k))
        clock.mark("write")
        self.last_phases = clock.phases
        self.times.append(clock.total)
        self.iterations_used.append(self.deformer.last_iterations)
        step = self.deformer.last_step
        if step is not None and self.uses_step:
            self.worst_stretch = max(self.worst_stretch, step.worst_stretch)
            self.max_recession = max(self.max_recession, step.max_recession)
        if self.rig or self.self_figures.enabled:
            self._audit(frame)
        self.done += 1
        return frame

    def progress_line(self) -> str:
        return (f"{self.log_prefix}: {self.label} frame {self.frames[self.done - 1]} ({self.done}/{len(self.frames)}) "
                f"{1000 * self.times[-1]:.1f} ms, {self.iterations_used[-1]} it., ETA {self.eta_seconds():.1f} s")

    def outcome(self) -> str:
        return f"{self.writer.frames} frames, {self.settings.last_frame_ms:.1f} ms per frame"

    def _audit(self, frame: int) -> None:
        """Counts what the audit finds in this frame's result (not timed: it is a check)."""
        import tegument

        step = self.deformer.last_step
        self.most_pinched = max(self.most_pinched, len(step.pinched) if step else 0)
        if not self.settings.audit:
            self.self_figures.add(step, None)
            return
        found = tegument.audit(self._world, self.corners, self.sizes, self.rig.colliders,
                               self_intersections=self.self_figures.enabled)
        for key in self.audit_totals:
            self.audit_totals[key] += getattr(found, key)
        self.self_figures.add(step, found.self_intersections)

    def eta_seconds(self) -> float:
        if not self.times:
            return float("nan")
        return float(np.mean(self.times)) * (len(self.frames) - self.done)

    def commit(self) -> None:
        """Keeps the frames done as the cache (a cancelled bake is a valid, shorter cache)."""
        try:
            if self.finished and self._existing is not None:
                # A partial re-bake keeps the cached frames after it.
                for frame in self._existing[self.writer.frames:]:
                    self.writer.append(frame)
            for k, writer in self.collider_writers.items():
                existing = self._collider_existing.get(k)
                if self.finished and existing is not None:
                    for frame in existing[writer.frames:]:
                        writer.append(frame)
            if self.writer.frames:
                self.writer.commit()
                for writer in self.collider_writers.values():
                    writer.commit()
            else:
                self.writer.abort()
                for writer in self.collider_writers.values():
                    writer.abort()
        finally:
            self._restore()
        if self.writer.frames:
            self._attach_collider_caches()
        if self.times:
            self.settings.last_frame_ms = 1000.0 * float(np.mean(self.times))
        self._report_contacts()
        modifier = evaluate.tegument_modifier(self.obj)
        modifier.filepath = self.settings.cache_path
        modifier.frame_start = self.start_frame
        self.obj.update_tag()

    def _attach_collider_caches(self) -> None:
        """Each compliant collider plays its solved positions back with its own Mesh Cache modifier;
        a collider no longer compliant loses it (its cache is of an earlier bake)."""
        for k, collider in enumerate(self.rig.objects):
            stale = colliders.compliance_modifier(collider)
            if k not in self.collider_writers and stale is not None:
                collider.modifiers.remove(stale)
                collider.update_tag()
        for k in self.collider_writers:
            collider = self.rig.objects[k]
            modifier = colliders.compliance_modifier(collider)
            if modifier is None:
                modifier = collider.modifiers.new(colliders.COMPLIANCE_MODIFIER_NAME, "MESH_CACHE")
                modifier.cache_format = "PC2"
            modifier.filepath = collider.tegument_collider.cache_path or bpy.path.relpath(
                colliders.compliance_cache_path(collider)
            )
            modifier.frame_start = self.start_frame
            collider.update_tag()

    def _report_contacts(self) -> None:
        settings = self.settings
        settings.worst_stretch = self.worst_stretch
        settings.max_recession = self.max_recession
        settings.audit_vertices_inside = self.audit_totals["vertices_inside"]
        settings.audit_edges_crossing = self.audit_totals["edges_crossing"]
        settings.audit_collider_edges_crossing = self.audit_totals["collider_edges_crossing"]
        settings.pinched_vertices = self.most_pinched
        # The bind's warnings stay: the bake adds its own notes after them.
        notes = [settings.bind_warnings] if settings.bind_warnings else []
        notes += self.rig.warnings
        if self.most_pinched:
            notes.append(f"{self.most_pinched} vertices pinched between colliders")
        notes += self.self_figures.store(self.obj)
        settings.warnings = "; ".join(notes)

    def abort(self) -> None:
        """Discards everything this job wrote; the previous cache stays as it was."""
        self.writer.abort()
        for writer in self.collider_writers.values():
            writer.abort()
        self._restore()

    def _restore(self) -> None:
        _baking.discard(self._uid)
        self._stack.close()
        self.scene.frame_set(self.frame_before)


class PhaseClock:
    """Splits one frame's wall time into phases (``BakeJob.last_phases``, the scaling benchmark):
    each :meth:`mark` books the time since the previous mark to its phase."""

    def __init__(self):
        self._started = self._last = time.perf_counter()
        self.phases = {"evaluate": 0.0, "read": 0.0, "solve": 0.0, "write": 0.0}

    def mark(self, phase: str) -> None:
        now = time.perf_counter()
        self.phases[phase] = self.phases.get(phase, 0.0) + now - self._last
        self._last = now

    @property
    def total(self) -> float:
        return self._last - self._started


def solve_frame(scene, obj, frame: int, deformer, closeness, rig=None, options=None, clock: PhaseClock | None = None,
                buffers: evaluate.FrameBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(object space, world space)`` result of one frame; the caller hides Tegument's modifier.

    With colliders (``rig``), dynamics, substeps or strain limits (``options``,
    from :func:`evaluate.step_options`) the frame is a history-based step from
    the deformer's last output; otherwise a plain solve from the input, or with
    Converge from the last solve's result moved as the input moved (a warm
    start: the solve stops once converged, so frames that follow each other
    take few iterations). With ``buffers`` the arrays are the job's own, valid
    until its next frame.
    """
    options = options or {}
    history = bool(rig) or bool(options)
    clock = clock or PhaseClock()
    import tegument

    scene.frame_set(frame)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    clock.mark("evaluate")
    local, world = evaluate.evaluated_positions(obj, depsgraph, buffers)
    if len(local) != deformer.vertex_count:
        raise DeformError(
            f"{obj.name}: at frame {frame} the modifier stack above Tegument gives {len(local)} vertices, "
            f"but the bind has {deformer.vertex_count}: the topology above Tegument changed since the bind "
            "(rebind, or move the modifier that changes it below Tegument)"
        )
    matrix = obj.evaluated_get(depsgraph).matrix_world
    iterations = obj.tegument.iterations
    converge = obj.tegument.converge
    deformer.accelerated = converge  # a no-op unless it changed
    # Converge stops once converged, and starts each frame from the last one's result.
    deformer.tolerance = tegument.DEFAULTS.tolerance if converge else None
    if rig:
        rig.update(depsgraph, frame)
        clock.mark("colliders")
    clock.mark("read")
    count = deformer.vertex_count
    out = buffers.get("solved", count) if buffers else None
    try:
        if history:
            colliders_now = rig.colliders if rig else None
            solved = deformer.step(world, colliders_now, iterations=iterations, closeness=closeness, out=out, **options)
        else:
            solved = deformer.solve(world, iterations=iterations, closeness=closeness, out=out, warm=converge)
    except tegument.TegumentError as error:
        # The wheel refuses non-finite input too; the search for the culprit costs a pass, so only here.
        vertex = mesh_arrays.first_non_finite(world)
        if vertex is not None:
            raise DeformError(f"{obj.name}: at frame {frame} the input position of vertex {vertex} is not finite") from None
        raise DeformError(f"{obj.name}, frame {frame}: {error}") from None
    clock.mark("solve")
    return evaluate.to_local(solved, matrix, buffers.get("solved_local", count) if buffers else None), solved


def bake_blocking(context, obj, frames: range, *, report=print, keep_existing: bool = False) -> tuple[int, bool]:
    """Bakes in the foreground (:func:`jobs.run_blocking`); returns ``(frames in the cache, cancelled)``."""
    job = BakeJob(context, obj, frames, keep_existing=keep_existing)
    cancelled = jobs.run_blocking(context, job, report=report)
    return job.writer.frames, cancelled
