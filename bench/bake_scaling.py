"""The bake loop at scale (issue 27): whole frames of an armature-bent tube from 100k to 5M vertices.

For each size, in a fresh Blender process (so that peak memory is that size's own):

- *armature only*: ``frame_set`` + depsgraph + reading the positions, what every method starts from;
- *bind*: Add Pyramid Deform (``tegument.deform_add``), its wall time and the process's peak
  memory above what it held before;
- then three rounds, each of *Corrective Smooth* (10 iterations) on top of the armature, the same
  frames, whole frame, with Tegument's modifier left out; and 16 frames of *Tegument*'s bake job
  (``BakeJob.step``: evaluate the stack above Tegument, read, solve at the add-on's default settings
  (``--converge``: the accelerated solver, at most ``tegument.DEFAULTS.accelerated_iterations``, warm
  frames; ``--plain``: 10 plain iterations), write the PC2 frame), whole frame, with its breakdown by phase as the job records it
  (``BakeJob.phase_seconds``). The medians over all rounds are compared, and each round's ratio
  is reported beside them: both deformers are measured in the same minutes.

Frames alternate over the animation so each one re-evaluates. Weights are a smooth blend (bone
heat on millions of vertices takes minutes), the same at every size.

    python bench/bake_scaling.py --zip dist/tegument-0.1.0-linux_x64.zip --out bench/results
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import resource
import shutil
import subprocess
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent

# (segments around, rings along): vertices = segments · (rings + 1) + 2.
SIZES = {
    "100k": (256, 390),
    "500k": (512, 945),
    "2.5M": (1024, 2440),
    "5M": (1448, 3452),
}
FRAMES = 8  # frames per pass of the armature alone or Corrective Smooth (medians)
ROUNDS = 3  # alternations of Corrective Smooth and Tegument passes
JOB_FRAMES = 16  # Tegument bake frames per round


def rss_mib() -> float:
    """Resident memory now (MiB)."""
    pages = int(pathlib.Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def peak_mib() -> float:
    """Peak resident memory of this process so far (MiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def one_size(name: str, zip_path: str, solver: str | None = None) -> dict:
    sys.path.insert(0, str(ROOT / "demo"))
    import extension

    user = extension.isolated_user_folder("tegument-scaling-user-")
    import bpy
    import numpy as np
    import scene as demo_scene

    extension.install(zip_path, user)
    from bl_ext.user_default.tegument.deform import bake
    import tegument  # the wheel the extension bundles

    workdir = pathlib.Path(tempfile.mkdtemp(prefix="tegument-scaling-"))
    extension.new_blend(workdir / "scaling.blend")
    segments, rings = SIZES[name]
    started = time.perf_counter()
    limb, rig = demo_scene.build_limb(segments=segments, rings=rings, radius=0.25, length=2.0, heat_weights=False)
    demo_scene.animate_bend(rig, 1, 48, angle_deg=100)
    build_s = time.perf_counter() - started
    scene = bpy.context.scene
    vertices = len(limb.data.vertices)
    frames = [2 + (i * 7) % 46 for i in range(FRAMES)]

    def median(values):
        values = sorted(values)
        return values[len(values) // 2]

    def play_times(frames=frames):
        times = []
        for frame in frames:
            started = time.perf_counter()
            scene.frame_set(frame)
            evaluated = limb.evaluated_get(bpy.context.evaluated_depsgraph_get())
            positions = np.empty(len(evaluated.data.vertices) * 3, dtype=np.float32)
            evaluated.data.attributes["position"].data.foreach_get("vector", positions)
            times.append(time.perf_counter() - started)
        return times

    armature = median(play_times())

    bpy.context.view_layer.objects.active = limb
    scene.frame_set(1)
    before_mib, before_peak = rss_mib(), peak_mib()
    started = time.perf_counter()
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    if solver == "plain":
        limb.tegument.converge, limb.tegument.iterations = False, tegument.DEFAULTS.iterations
    elif solver == "converge":
        limb.tegument.converge, limb.tegument.iterations = True, tegument.DEFAULTS.accelerated_iterations
    converge = limb.tegument.converge
    job = bake.BakeJob(bpy.context, limb, range(1, 1 + ROUNDS * JOB_FRAMES))
    bind_s = time.perf_counter() - started
    bind_peak = max(peak_mib() - before_mib, 0.0)
    tegument_modifier = bake.evaluate.tegument_modifier(limb)

    def corrective_smooth_frames():
        """Corrective Smooth's frames, with Tegument's modifier left out of the stack."""
        tegument_modifier.show_viewport = False
        smooth = limb.modifiers.new("CorrectiveSmooth", "CORRECTIVE_SMOOTH")
        smooth.iterations = 10
        smooth.rest_source = "ORCO"
        play_times(frames[:2])  # the first frames after adding a modifier rebuild the depsgraph's relations
        times = play_times()
        limb.modifiers.remove(smooth)
        tegument_modifier.show_viewport = True
        return times

    # Rounds of Corrective Smooth frames and Tegument bake frames (the job's own
    # loop, whole), so that both are measured in the same minutes: on a
    # virtual machine the second core comes and goes, and a comparison made
    # minutes apart measures the machine as much as the deformers.
    corrective_times, times, phases, round_ratios = [], [], [], []  # the Tegument lists hold whole rounds
    for _ in range(ROUNDS):
        corrective = corrective_smooth_frames()
        corrective_times += corrective
        round_times = []
        for _ in range(JOB_FRAMES):
            started = time.perf_counter()
            job.step()
            round_times.append(time.perf_counter() - started)
            phases.append(dict(job.last_phases))
        times += round_times
        round_ratios.append(median(round_times[1:]) / median(corrective))
    job.commit()
    # The cache is 48 frames of the whole mesh (2.9 GB at 5M vertices): not kept.
    shutil.rmtree(workdir, ignore_errors=True)
    shutil.rmtree(user, ignore_errors=True)
    # A round's first frame re-evaluates the stack Corrective Smooth left (and the
    # first of all pays for first-touch allocations).
    keep = [k for k in range(len(times)) if k % JOB_FRAMES]
    corrective = median(corrective_times)
    tegument_frame = median([times[k] for k in keep])
    breakdown = {key: median([phases[k][key] for k in keep]) for key in phases[0]}
    return dict(
        size=name, vertices=vertices, build_s=build_s, armature_s=armature, corrective_s=corrective,
        tegument_s=tegument_frame, round_ratios=round_ratios, breakdown_s=breakdown, bind_s=bind_s, bind_peak_mib=bind_peak,
        peak_mib=peak_mib(), baseline_peak_mib=before_peak, threads=os.cpu_count() or 1, converge=converge,
        iterations=limb.tegument.iterations,
        iterations_used=sum(job.iterations_used) / len(job.iterations_used),
    )


def rows_of(result: dict) -> list[dict]:
    case = f"armature-bent tube, {result['vertices'] / 1e6:.2f}M vertices" if result["vertices"] >= 1e6 else \
        f"armature-bent tube, {result['vertices'] // 1000}k vertices"
    threads = result["threads"]
    ms = lambda seconds: 1000 * seconds  # noqa: E731
    rows = [
        ("vertices", result["vertices"], "", ""),
        ("armature only: frame", ms(result["armature_s"]), "ms", "frame_set + depsgraph + read positions"),
        ("Corrective Smooth (10 it.): frame", ms(result["corrective_s"]), "ms", "armature + Corrective Smooth"),
        ("Tegument (default it.): frame", ms(result["tegument_s"]), "ms",
         "BakeJob.step, whole" + (f" (Converge, at most {result['iterations']} iterations, {result.get('iterations_used', 0):.1f} per frame)"
                                  if result.get("converge") else f" ({result['iterations']} plain iterations)")),
        ("Tegument frame / Corrective Smooth frame", result["tegument_s"] / result["corrective_s"], "x",
         "target ≤ 0.5; per round " + ", ".join(f"{r:.2f}" for r in result["round_ratios"])),
        ("Tegument frame per vertex", 1e9 * result["tegument_s"] / result["vertices"], "ns", ""),
        ("bind", result["bind_s"], "s", "Add Pyramid Deform + the bake job's setup"),
        ("bind: peak memory", result["bind_peak_mib"], "MiB", "peak resident memory above the scene's before bind"),
        ("bind: peak memory per vertex", 2**20 * result["bind_peak_mib"] / result["vertices"], "B", ""),
        ("process peak memory", result["peak_mib"], "MiB", "the whole Blender process"),
    ]
    rows += [(f"Tegument frame: {phase}", ms(value), "ms", "median over the frames") for phase, value in result["breakdown_s"].items()]
    return [dict(benchmark="scaling", case=case, metric=m, value=v, unit=u, threads=threads, note=n) for m, v, u, n in rows]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--zip", default=os.environ.get("TEGUMENT_EXTENSION_ZIP"))
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "bench" / "results")
    parser.add_argument("--sizes", default=",".join(SIZES), help=f"comma-separated, of {', '.join(SIZES)}")
    solver = parser.add_mutually_exclusive_group()
    solver.add_argument("--plain", action="store_const", dest="solver", const="plain",
                        help="bake with Converge off (10 plain iterations) instead of the add-on's defaults")
    solver.add_argument("--converge", action="store_const", dest="solver", const="converge",
                        help="bake with Converge on (at most tegument.DEFAULTS.accelerated_iterations)")
    parser.add_argument("--one", help=argparse.SUPPRESS)  # internal: measure one size, print JSON
    args = parser.parse_args()
    if args.one:
        print("RESULT " + json.dumps(one_size(args.one, args.zip, args.solver)), flush=True)
        return 0
    rows = []
    for name in args.sizes.split(","):
        if name not in SIZES:
            parser.error(f"unknown size {name!r}; known: {', '.join(SIZES)}")
        command = [sys.executable, __file__, "--one", name, "--zip", str(args.zip)] + ([f"--{args.solver}"] if args.solver else [])
        done = subprocess.run(command, capture_output=True, text=True)
        lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
        if done.returncode != 0 or not lines:
            sys.stderr.write(done.stdout[-4000:] + done.stderr[-4000:])
            print(f"bake_scaling: size {name} failed (exit {done.returncode})", file=sys.stderr)
            return 1
        result = json.loads(lines[-1][len("RESULT "):])
        for row in rows_of(result):
            print(f"{row['case']:<36} {row['metric']:<44} {row['value']:>10.3f} {row['unit']:<4} {row['note']}", flush=True)
            rows.append(row)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "scaling.json").write_text(json.dumps(rows, indent=1))
    print(f"wrote {args.out / 'scaling.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
