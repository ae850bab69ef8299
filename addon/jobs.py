# SPDX-License-Identifier: GPL-3.0-or-later
"""One runner for every bake: blocking (background, scripts, the CLI), modal (the UI), both bakes.

A bake is a *job* (``deform.bake.BakeJob``, ``warp.bake.WarpBakeJob``) that
solves one frame per :meth:`Job.step` into a staging place and replaces the
old result only on :meth:`Job.commit`. Everything around the stepping —
progress, Ctrl-C, Esc, Blender cancelling a modal operator, the messages, what
happens to the frames done when it stops — is here, once, so the two bakes
cannot drift apart again. The rule for stopping is the same everywhere:
cancelling (Esc, Ctrl-C, Blender ending the operator) commits the frames
done; an error aborts, and the previous result stays as it was.
"""

from __future__ import annotations

import contextlib
import functools
import traceback
from typing import Callable, Protocol

import bpy

from . import pc2
from .deform.evaluate import DeformError
from .warp.inputs import WarpError

# Errors that are about the user's data or files: their text is the message.
EXPECTED = (DeformError, WarpError, pc2.CacheError)

Report = Callable[[set, str], None]


class Job(Protocol):
    """What the runner needs of a bake."""

    frames: range
    done: int  # frames stepped so far
    label: str  # what is baked, in console lines: "Ball", "Skin › Tegument UV Warp"
    log_prefix: str  # what bakes it, first on console lines: "Tegument", "Tegument UV Warp"
    title: str  # what is baked, in operator messages: "Ball", "UV warp of Skin › Tegument UV Warp"

    @property
    def finished(self) -> bool: ...

    def step(self) -> object:
        """Solves the next frame; raises on failure (the runner then aborts)."""

    def progress_line(self) -> str:
        """The console line of the frame just stepped."""

    def eta_seconds(self) -> float: ...

    def commit(self) -> None:
        """Makes the frames done the result; releases the job's hold on Blender."""

    def abort(self) -> None:
        """Discards what the job wrote; releases the job's hold on Blender."""

    def outcome(self) -> str:
        """After a commit, what was baked: "6 frames, 12.0 ms per frame"."""


def message(error: Exception) -> str:
    """The status-bar text of a failure; anything unexpected is a bug, reported as one.

    Operators catch every ``Exception`` so that a bug shows a message instead of
    a traceback dialog, after the bake job has restored the scene and removed
    its staged files; the traceback still goes to the console.
    """
    if isinstance(error, EXPECTED):
        return str(error)
    traceback.print_exception(error)
    return f"Tegument internal error (please report it, the console has the details): {type(error).__name__}: {error}"


def reports_errors(method):
    """Decorates an operator method: any exception becomes a ``self.report`` error and
    ``{'CANCELLED'}``, never a traceback dialog (see :func:`message`)."""

    @functools.wraps(method)
    def reporting(self, context):
        try:
            return method(self, context)
        except Exception as error:
            self.report({"ERROR"}, message(error))
            return {"CANCELLED"}

    return reporting


@contextlib.contextmanager
def sigint_requests_cancel():
    """Ctrl-C (SIGINT) during the block sets the returned flag instead of raising.

    A KeyboardInterrupt raised in the middle of Blender's frame evaluation
    could land inside a handler, where Blender swallows it; a flag checked
    between frames always stops the bake cleanly after the current frame.
    """
    import signal
    import threading

    requested = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield requested
        return
    previous = signal.signal(signal.SIGINT, lambda signum, frame: requested.set())
    try:
        yield requested
    finally:
        signal.signal(signal.SIGINT, previous)


def run_blocking(context, job: Job, *, report=print) -> bool:
    """Steps ``job`` to its end in the foreground, one ``report`` line per frame, then commits.

    Ctrl-C stops after the current frame and keeps the frames done; an error
    aborts the job and propagates. Returns whether the bake was cancelled.
    """
    wm = context.window_manager
    wm.progress_begin(0, len(job.frames))
    try:
        with sigint_requests_cancel() as cancel:
            while not job.finished and not cancel.is_set():
                job.step()
                wm.progress_update(job.done)
                report(job.progress_line())
            cancelled = not job.finished
    except BaseException:
        job.abort()
        raise
    finally:
        wm.progress_end()
    if cancelled:
        report(f"{job.log_prefix}: bake of {job.label} cancelled; keeping the {job.done} frames done")
    job.commit()
    report(f"{job.log_prefix}: {job.label}: {job.outcome()}")
    return cancelled


def finish(report: Report, job: Job, cancelled: bool) -> set[str]:
    """Reports a committed job and returns the operator's result."""
    report({"WARNING" if cancelled else "INFO"}, f"{'Cancelled' if cancelled else 'Baked'} {job.title}: {job.outcome()}")
    return {"CANCELLED"} if cancelled else {"FINISHED"}


class ModalRun:
    """Drives a job from a modal operator's events: one frame per timer event, Esc cancels.

    A plain class (not an operator) so that its logic can be tested without a
    window; ``report`` is the operator's ``self.report``.
    """

    def __init__(self, context, job: Job, report: Report):
        self.job = job
        self.report = report
        wm = context.window_manager
        self.timer = wm.event_timer_add(0.001, window=context.window)
        wm.progress_begin(0, len(job.frames))

    def event(self, context, event_type: str) -> set[str]:
        """Handles one event; returns what ``modal()`` returns."""
        job = self.job
        if event_type == "ESC":
            return self._end(context, cancelled=True)
        if event_type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            job.step()
        except Exception as error:
            job.abort()
            self._end(context, cancelled=True, failed=True)
            self.report({"ERROR"}, message(error))
            return {"CANCELLED"}
        context.window_manager.progress_update(job.done)
        context.workspace.status_text_set(
            f"Tegument: baking {job.title}, frame {job.done}/{len(job.frames)}, "
            f"ETA {job.eta_seconds():.0f} s (Esc to cancel)"
        )
        if job.finished:
            return self._end(context, cancelled=False)
        return {"RUNNING_MODAL"}

    def cancel(self, context) -> None:
        """Blender ended the operator itself (a file load, the window closing): keep the
        frames done as a valid result, or failing that leave the old one."""
        try:
            context.window_manager.event_timer_remove(self.timer)
            context.window_manager.progress_end()
            context.workspace.status_text_set(None)
        except Exception:  # noqa: BLE001 - the window may already be gone
            pass
        try:
            self.job.commit()
        except Exception:  # noqa: BLE001 - e.g. the object was freed by a file load
            with contextlib.suppress(Exception):
                self.job.abort()

    def _end(self, context, *, cancelled: bool, failed: bool = False) -> set[str]:
        wm = context.window_manager
        wm.event_timer_remove(self.timer)
        wm.progress_end()
        context.workspace.status_text_set(None)
        if failed:
            return {"CANCELLED"}
        try:
            self.job.commit()
        except Exception as error:  # e.g. the disk filled up while finishing the result
            self.report({"ERROR"}, message(error))
            return {"CANCELLED"}
        return finish(self.report, self.job, cancelled)


class BakeOperator:
    """Mixin of a bake operator: blocking in ``execute`` (background mode, scripts), modal
    in ``invoke`` (the UI). Subclasses say which job with :meth:`make_job`.

    Every failure becomes a ``self.report`` message and ``{'CANCELLED'}``.
    """

    def make_job(self, context) -> Job:
        raise NotImplementedError

    @reports_errors
    def execute(self, context):
        job = self.make_job(context)
        return finish(self.report, job, run_blocking(context, job))

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        return self._start(context)

    @reports_errors
    def _start(self, context):
        self._run = ModalRun(context, self.make_job(context), self.report)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        return self._run.event(context, event.type)

    def cancel(self, context):
        self._run.cancel(context)
