"""The bake-job runner (``addon/jobs.py``) that both bakes share: blocking, modal and CLI.

The modal path needs a window, which headless Blender has not: ``jobs.ModalRun``
is driven here directly, with a stand-in for the window manager and the
workspace that records what the runner asks of them, and real bake jobs. A
stand-in job (``ScriptedJob``) covers the runner's own rules without a scene.
"""

from __future__ import annotations

import contextlib
import pathlib
import signal
from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from test_robustness import addon, animate_location, read_pc2, save_scene, sphere
from test_uv_warp_node import RIGID_RADIUS, bind, disc, float_image, squashed_plane, warp_material


class FakeWindow:
    """Records the window manager and workspace calls the modal runner makes."""

    def __init__(self, *, broken: bool = False):
        self.calls: list[tuple] = []
        self.broken = broken  # a closing window: every call fails

    def _record(self, *call):
        if self.broken:
            raise RuntimeError("the window is gone")
        self.calls.append(call)

    def event_timer_add(self, step, window=None):
        self._record("timer_add", step)
        return "timer"

    def event_timer_remove(self, timer):
        self._record("timer_remove", timer)

    def progress_begin(self, low, high):
        self._record("progress_begin", low, high)

    def progress_update(self, value):
        self._record("progress_update", value)

    def progress_end(self):
        self._record("progress_end")

    def status_text_set(self, text):
        self._record("status", text)

    def modal_handler_add(self, operator):
        self._record("modal_handler_add", operator)

    def context(self):
        return SimpleNamespace(window_manager=self, workspace=self, window=object())

    def statuses(self) -> list:
        return [c[1] for c in self.calls if c[0] == "status"]

    def closed(self) -> bool:
        """The timer removed, the progress ended and the status text cleared, in that order, last."""
        return self.calls[-3:] == [("timer_remove", "timer"), ("progress_end",), ("status", None)]


class Reports(list):
    def __call__(self, level, text):
        self.append((next(iter(level)), text))


class ScriptedJob:
    """A job of ``count`` frames; ``fail_at`` raises in that step, ``interrupt_at`` presses Ctrl-C."""

    label = title = "Thing"
    log_prefix = "Test"

    def __init__(self, count=3, *, fail_at=None, interrupt_at=None, commit_error=None):
        self.frames = range(1, count + 1)
        self.done = 0
        self.fail_at, self.interrupt_at, self.commit_error = fail_at, interrupt_at, commit_error
        self.events: list[str] = []

    @property
    def finished(self):
        return self.done >= len(self.frames)

    def step(self):
        frame = self.frames[self.done]
        if frame == self.fail_at:
            raise ZeroDivisionError("simulated bug")
        self.done += 1
        if frame == self.interrupt_at:
            signal.raise_signal(signal.SIGINT)  # what Ctrl-C does to a background bake
        return frame

    def progress_line(self):
        return f"step {self.done}"

    def eta_seconds(self):
        return 1.0 * (len(self.frames) - self.done)

    def commit(self):
        self.events.append("commit")
        if self.commit_error is not None:
            raise self.commit_error

    def abort(self):
        self.events.append("abort")

    def outcome(self):
        return f"{self.done} frames"


# ------------------------------------------------------------ the runner's rules

def test_blocking_run_reports_each_frame_and_commits():
    jobs = addon().jobs
    job, lines, window = ScriptedJob(), [], FakeWindow()
    assert jobs.run_blocking(window.context(), job, report=lines.append) is False
    assert lines == ["step 1", "step 2", "step 3", "Test: Thing: 3 frames"]
    assert job.events == ["commit"]
    assert ("progress_begin", 0, 3) in window.calls and window.calls[-1] == ("progress_end",)


def test_ctrl_c_in_a_blocking_run_commits_the_frames_done():
    jobs = addon().jobs
    job, lines = ScriptedJob(5, interrupt_at=2), []
    handler = signal.getsignal(signal.SIGINT)
    assert jobs.run_blocking(FakeWindow().context(), job, report=lines.append) is True
    assert job.done == 2 and job.events == ["commit"]
    assert lines[-2:] == ["Test: bake of Thing cancelled; keeping the 2 frames done", "Test: Thing: 2 frames"]
    assert signal.getsignal(signal.SIGINT) is handler, "Ctrl-C must get its own handler back after the bake"


def test_an_error_in_a_blocking_run_aborts_and_propagates():
    jobs = addon().jobs
    job, window = ScriptedJob(fail_at=2), FakeWindow()
    with pytest.raises(ZeroDivisionError):
        jobs.run_blocking(window.context(), job, report=lambda line: None)
    assert job.events == ["abort"] and window.calls[-1] == ("progress_end",)


def test_modal_run_steps_on_timer_events_only_and_finishes():
    jobs = addon().jobs
    job, window, reports = ScriptedJob(), FakeWindow(), Reports()
    context = window.context()
    run = jobs.ModalRun(context, job, reports)
    assert window.calls == [("timer_add", 0.001), ("progress_begin", 0, 3)]
    assert run.event(context, "MOUSEMOVE") == {"PASS_THROUGH"} and job.done == 0
    assert run.event(context, "TIMER") == {"RUNNING_MODAL"}
    assert run.event(context, "TIMER") == {"RUNNING_MODAL"}
    assert run.event(context, "TIMER") == {"FINISHED"}
    assert window.statuses()[:2] == ["Tegument: baking Thing, frame 1/3, ETA 2 s (Esc to cancel)",
                                     "Tegument: baking Thing, frame 2/3, ETA 1 s (Esc to cancel)"]
    assert window.closed() and job.events == ["commit"]
    assert reports == [("INFO", "Baked Thing: 3 frames")]


def test_modal_run_esc_commits_the_frames_done():
    jobs = addon().jobs
    job, window, reports = ScriptedJob(), FakeWindow(), Reports()
    context = window.context()
    run = jobs.ModalRun(context, job, reports)
    run.event(context, "TIMER")
    assert run.event(context, "ESC") == {"CANCELLED"}
    assert window.closed() and job.events == ["commit"]
    assert reports == [("WARNING", "Cancelled Thing: 1 frames")]


def test_modal_run_error_aborts_and_reports_a_message_not_a_traceback():
    jobs = addon().jobs
    job, window, reports = ScriptedJob(fail_at=2), FakeWindow(), Reports()
    context = window.context()
    run = jobs.ModalRun(context, job, reports)
    run.event(context, "TIMER")
    assert run.event(context, "TIMER") == {"CANCELLED"}
    assert window.closed() and job.events == ["abort"]
    (level, text), = reports
    assert level == "ERROR" and text.startswith("Tegument internal error (please report it") and "ZeroDivisionError" in text


def test_modal_run_reports_a_failing_commit():
    jobs = addon().jobs
    error = addon().warp.inputs.WarpError("M › N: cannot move the baked frames into /x: No space left on device")
    job, window, reports = ScriptedJob(2, commit_error=error), FakeWindow(), Reports()
    context = window.context()
    run = jobs.ModalRun(context, job, reports)
    run.event(context, "TIMER")
    assert run.event(context, "TIMER") == {"CANCELLED"}
    assert window.closed() and reports == [("ERROR", str(error))]


def test_blender_cancelling_the_modal_run_commits_even_when_the_window_is_gone():
    jobs = addon().jobs
    job, window, reports = ScriptedJob(), FakeWindow(), Reports()
    run = jobs.ModalRun(window.context(), job, reports)
    run.event(window.context(), "TIMER")
    window.broken = True
    run.cancel(window.context())
    assert job.events == ["commit"] and reports == []
    # A commit that fails there (the object freed by a file load) falls back to an abort, silently.
    job = ScriptedJob(commit_error=ReferenceError("StructRNA of type Object has been removed"))
    run = jobs.ModalRun(FakeWindow().context(), job, reports)
    run.cancel(FakeWindow().context())
    assert job.events == ["commit", "abort"] and reports == []


def test_the_operator_mixin_starts_drives_and_cancels_a_modal_run():
    """What invoke() does in the UI (headless Blender always takes the blocking path)."""
    jobs = addon().jobs
    window, reports = FakeWindow(), Reports()
    context = window.context()
    job = ScriptedJob(2)
    operator = SimpleNamespace(make_job=lambda context: job, report=reports)
    assert jobs.BakeOperator._start(operator, context) == {"RUNNING_MODAL"}
    assert ("modal_handler_add", operator) in window.calls
    timer = SimpleNamespace(type="TIMER")
    assert jobs.BakeOperator.modal(operator, context, timer) == {"RUNNING_MODAL"}
    jobs.BakeOperator.cancel(operator, context)
    assert job.done == 1 and job.events == ["commit"] and window.closed()

    def refused(context):
        raise addon().deform.evaluate.DeformError("Ball is already being baked: wait for that bake to finish")

    operator = SimpleNamespace(make_job=refused, report=reports)
    assert jobs.BakeOperator._start(operator, FakeWindow().context()) == {"CANCELLED"}
    assert reports[-1] == ("ERROR", "Ball is already being baked: wait for that bake to finish")


def test_both_bake_operators_are_driven_by_the_one_runner():
    a = addon()
    for operator in (a.operators.deform.TEGUMENT_OT_bake, a.operators.warp.TEGUMENT_OT_warp_bake):
        assert issubclass(operator, a.jobs.BakeOperator)
        for method in ("execute", "invoke", "modal", "cancel"):
            assert getattr(operator, method) is getattr(a.jobs.BakeOperator, method), (operator, method)


# ------------------------------------------------------------ with real jobs

@pytest.fixture
def ball(tmp_path):
    obj = sphere()
    animate_location(obj)
    save_scene(tmp_path)
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    return obj


@pytest.fixture
def warp_node(tmp_path):
    """A bound UV Warp node over 5 frames in a saved .blend, and the sequence folder."""
    obj = squashed_plane()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "warp.blend"))
    material, node = warp_material(obj, show="uv")
    node.rigidity_image = float_image("Rigidity", disc(RIGID_RADIUS))
    bind(material, node)
    return material, node, tmp_path / "tegument" / "warp"


@contextlib.contextmanager
def ctrl_c_at_frame_change(count: int):
    """Presses Ctrl-C (SIGINT, what it does to a background bake) at the ``count``-th frame change."""
    seen = []

    def interrupt(scene, depsgraph=None):
        seen.append(scene.frame_current)
        if len(seen) == count:
            signal.raise_signal(signal.SIGINT)

    bpy.app.handlers.frame_change_post.append(interrupt)
    try:
        yield
    finally:
        bpy.app.handlers.frame_change_post.remove(interrupt)


def sequence(folder: pathlib.Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()} if folder.is_dir() else {}


def test_modal_deform_bake_runs_and_esc_keeps_the_frames_done(ball):
    a = addon()
    window, reports = FakeWindow(), Reports()
    context = window.context()
    run = a.jobs.ModalRun(context, a.deform.bake.BakeJob(bpy.context, ball, range(1, 4)), reports)
    assert run.event(context, "TIMER") == {"RUNNING_MODAL"}
    assert window.statuses()[-1].startswith("Tegument: baking Ball, frame 1/3, ETA ")
    assert run.event(context, "TIMER") == {"RUNNING_MODAL"}
    assert run.event(context, "ESC") == {"CANCELLED"}
    assert window.closed()
    (level, text), = reports
    assert level == "WARNING" and text.startswith("Cancelled Ball: 2 frames, ") and text.endswith(" ms per frame")
    frames = read_pc2(bpy.path.abspath(ball.tegument.cache_path))
    assert frames.shape[0] == 2 and np.isfinite(frames).all()
    assert not a.deform.bake.is_baking(ball) and bpy.context.scene.frame_current == 1


def test_blender_cancelling_a_modal_warp_bake_keeps_the_frames_done(warp_node):
    """The warp operator had no cancel(): a file load during its modal bake left the job holding the scene."""
    a = addon()
    material, node, folder = warp_node
    window = FakeWindow()
    run = a.jobs.ModalRun(window.context(), a.warp.bake.WarpBakeJob(bpy.context, material, node), Reports())
    run.event(window.context(), "TIMER")
    run.event(window.context(), "TIMER")
    run.cancel(window.context())
    assert window.closed()
    assert sorted(sequence(folder)) == [f"Skin_Tegument_UV_Warp_1001_{f:04d}.exr" for f in (1, 2)]
    assert (node.baked_start, node.baked_frames) == (1, 2)
    assert bpy.context.scene.frame_current == 1


def test_a_failing_commit_of_a_modal_warp_bake_is_reported_and_keeps_the_node(warp_node, monkeypatch):
    """The warp operator's commit was unguarded: a failure there escaped as a traceback."""
    a = addon()
    material, node, folder = warp_node
    assert bpy.ops.tegument.warp_bake(material=material.name, node=node.name) == {"FINISHED"}
    before = sequence(folder)
    window, reports = FakeWindow(), Reports()
    run = a.jobs.ModalRun(window.context(), a.warp.bake.WarpBakeJob(bpy.context, material, node, range(1, 3)), reports)
    run.event(window.context(), "TIMER")

    def full_disk(source, target):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(a.warp.bake.os, "replace", full_disk)
    assert run.event(window.context(), "TIMER") == {"CANCELLED"}
    monkeypatch.undo()
    assert window.closed()
    (level, text), = reports
    assert level == "ERROR" and text.startswith(f"Skin › {node.name}: cannot move the baked frames into ")
    assert text.endswith(": No space left on device"), text
    assert sequence(folder) == before, "no frame was moved: the previous sequence stays"
    assert (node.baked_start, node.baked_frames) == (1, 5)
    assert bpy.context.scene.frame_current == 1


def test_an_unexpected_error_in_a_warp_bake_is_a_message_not_a_traceback(warp_node, monkeypatch, capfd):
    a = addon()
    material, node, folder = warp_node

    def broken(self):
        raise ZeroDivisionError("simulated bug")

    monkeypatch.setattr(a.warp.bake.WarpBakeJob, "step", broken)
    with pytest.raises(RuntimeError, match=r"Tegument internal error \(please report it.*ZeroDivisionError: simulated bug"):
        bpy.ops.tegument.warp_bake(material=material.name, node=node.name)
    assert sequence(folder) == {}


def test_ctrl_c_in_a_command_line_warp_bake_keeps_the_frames_done(warp_node, capfd):
    a = addon()
    material, node, folder = warp_node
    with ctrl_c_at_frame_change(2):
        code = a.cli.main(["warp-bake", "--material", material.name, "--node", node.name])
    assert code == 130
    assert sorted(sequence(folder)) == [f"Skin_Tegument_UV_Warp_1001_{f:04d}.exr" for f in (1, 2)]
    assert (node.baked_start, node.baked_frames) == (1, 2)
    assert f"Tegument UV Warp: bake of Skin › {node.name} cancelled; keeping the 2 frames done" in capfd.readouterr().out


def test_a_bad_frame_range_on_the_command_line_is_a_usage_error_for_both_bakes(warp_node, capfd):
    """warp-bake let `--frames` errors out of main() as SystemExit."""
    cli = addon().cli
    for command in ("bake", "warp-bake"):
        assert cli.main([command, "--frames", "1-x"]) == 2
        assert "error: --frames expects START-END, got '1-x'" in capfd.readouterr().err
    assert sequence(warp_node[2]) == {}


# ------------------------------------------------------------ the panels (their shared base and toggles)

def test_panels_draw_the_same_settings_in_the_same_order(ball):
    from test_uv_warp_node import RecordingLayout

    ui = addon().ui
    settings = ball.tegument

    def drawn():
        log = []
        panel = SimpleNamespace(layout=RecordingLayout(log))
        context = SimpleNamespace(object=ball, window_manager=bpy.context.window_manager)
        ui.modifier_panel.TEGUMENT_PT_modifier.draw(panel, context)
        return [args[1] for name, args, _ in log if name in ("prop", "prop_search")]

    common = ["enabled", "iterations", "converge", "closeness", "closeness_group", "scale_safe", "bind_source",
              "collider_collection", "substeps", "dynamic"]
    tail = ["frame_start", "frame_end", "cache_path", "live"]
    assert drawn() == common + ["limit_stretch"] + tail
    settings.dynamic = settings.limit_stretch = True
    assert drawn() == common + ["mass", "damping", "use_gravity", "limit_stretch", "max_stretch",
                                "max_stretch_group", "strain_mode"] + tail
    for panel in (ui.modifier_panel.TEGUMENT_PT_modifier, ui.collider_panel.TEGUMENT_PT_collider):
        assert (panel.bl_space_type, panel.bl_region_type) == ("PROPERTIES", "WINDOW")
        assert panel.poll(SimpleNamespace(object=ball)) and not panel.poll(SimpleNamespace(object=None))
