"""Benchmarks that need real Blender: Tegument against Blender's own tools, same mesh, same run.

Writes ``<out>/blender.json`` with rows in the format of the Rust benchmarks
(``rust/core/benches/common``); ``bench/collect.py`` merges them all.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import shutil
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()}"


class Rows:
    def __init__(self):
        self.rows = []

    def add(self, case, metric, value, unit, threads, note=""):
        print(f"{case:<40} {metric:<32} {value:>10.3f} {unit:<4} {note}", flush=True)
        self.rows.append(dict(benchmark="blender", case=case, metric=metric, value=value, unit=unit, threads=threads, note=note))


def time_frames(scene, frames, work) -> float:
    """Median milliseconds of `work(frame)` over the frames (alternating so each one re-evaluates)."""
    times = []
    for frame in frames:
        started = time.perf_counter()
        work(frame)
        times.append(1000 * (time.perf_counter() - started))
    times.sort()
    return times[len(times) // 2]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "bench" / "results")
    parser.add_argument("--zip", type=pathlib.Path, default=os.environ.get("TEGUMENT_EXTENSION_ZIP"))
    parser.add_argument("--frames", type=int, default=12)
    args = parser.parse_args()
    user = tempfile.mkdtemp(prefix="tegument-bench-user-")
    os.environ["BLENDER_USER_RESOURCES"] = user
    import bpy
    import numpy as np

    sys.path.insert(0, str(ROOT / "demo"))
    import scene as demo_scene

    bpy.ops.extensions.package_install_files(filepath=str(args.zip.resolve()), repo="user_default", enable_on_install=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.preferences.addon_enable(module="bl_ext.user_default.tegument")
    from bl_ext.user_default.tegument.deform import bake

    rows = Rows()
    threads = os.cpu_count() or 1
    workdir = pathlib.Path(tempfile.mkdtemp(prefix="tegument-bench-"))
    bpy.ops.wm.save_as_mainfile(filepath=str(workdir / "bench.blend"))

    limb, rig = demo_scene.build_limb(segments=256, rings=390, radius=0.25, length=2.0)
    demo_scene.animate_bend(rig, 1, 48, angle_deg=100)
    scene = bpy.context.scene
    vertices = len(limb.data.vertices)
    case = f"armature-bent tube, {vertices // 1000}k vertices"
    frames = [2 + (i * 7) % 46 for i in range(args.frames)]

    def evaluate(frame):
        scene.frame_set(frame)
        evaluated = limb.evaluated_get(bpy.context.evaluated_depsgraph_get())
        positions = np.empty(len(evaluated.data.vertices) * 3, dtype=np.float32)
        evaluated.data.attributes["position"].data.foreach_get("vector", positions)

    armature_only = time_frames(scene, frames, evaluate)
    rows.add(case, "armature only: frame", armature_only, "ms", threads, "frame_set + depsgraph + read positions")

    smooth = limb.modifiers.new("CorrectiveSmooth", "CORRECTIVE_SMOOTH")
    smooth.iterations = 10
    smooth.rest_source = "ORCO"
    corrective = time_frames(scene, frames, evaluate)
    rows.add(case, "Corrective Smooth (10 it.): frame", corrective, "ms", threads, "armature + Corrective Smooth, whole frame")
    rows.add(case, "Corrective Smooth (10 it.): own cost", corrective - armature_only, "ms", threads, "minus the armature-only frame")
    limb.modifiers.remove(smooth)

    bpy.context.view_layer.objects.active = limb
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    limb.tegument.iterations = 10
    job = bake.BakeJob(bpy.context, limb, range(1, 49))
    times = []
    solve_times = []
    deformer = job.deformer
    while not job.finished:
        started = time.perf_counter()
        job.step()
        times.append(1000 * (time.perf_counter() - started))
    job.commit()
    # Solve alone, on the last frame's input, for the split.
    import tegument  # noqa: F401  (the wheel the extension bundles)
    from bl_ext.user_default.tegument.deform import evaluate as deform_evaluate

    with deform_evaluate.upstream_only(limb):
        scene.frame_set(40)
        _, world = deform_evaluate.evaluated_positions(limb, bpy.context.evaluated_depsgraph_get())
    for _ in range(5):
        started = time.perf_counter()
        deformer.solve(world, iterations=10, closeness=limb.tegument.closeness)
        solve_times.append(1000 * (time.perf_counter() - started))
    tegument_frame = sorted(times[1:])[len(times[1:]) // 2]
    solve = sorted(solve_times)[len(solve_times) // 2]
    rows.add(case, "Tegument (10 it.): frame", tegument_frame, "ms", threads, "input evaluation + solve + cache write")
    rows.add(case, "Tegument (10 it.): own cost", tegument_frame - armature_only, "ms", threads, "minus the armature-only frame")
    rows.add(case, "Tegument (10 it.): solve only", solve, "ms", threads, "PyramidDeformer.solve")
    rows.add(case, "Tegument frame / Corrective Smooth frame", tegument_frame / corrective, "x", threads, "target ≤ 0.5")

    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "blender.json").write_text(json.dumps(rows.rows, indent=1))
    (args.out / "machine.txt").write_text(machine() + f"\nBlender {bpy.app.version_string} (PyPI bpy)\n")
    shutil.rmtree(workdir, ignore_errors=True)
    shutil.rmtree(user, ignore_errors=True)
    print(f"wrote {args.out / 'blender.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
