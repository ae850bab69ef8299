"""Benchmarks that need real Blender: Tegument against Blender's own tools, same mesh, same run.

Collisions against Cloth and Shrinkwrap + Corrective Smooth, and the MakeHuman character against
skinning and Corrective Smooth. (Pyramid Deform against Corrective Smooth on armature-bent tubes
from 100k to 5M vertices is ``bench/bake_scaling.py``.)

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
    """The CPU as /proc/cpuinfo names it, with its family and model numbers and
    widest vector extension: a VM's model name ("AMD EPYC") does not tell one
    generation from another, and the figures differ by up to 2× between them."""
    fields: dict[str, str] = {}
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
            if not line.strip():
                break  # the first processor is enough
    except OSError:
        pass
    cpu = fields.get("model name", "unknown CPU")
    if "cpu family" in fields and "model" in fields:
        flags = fields.get("flags", "").split()
        vector = next((name for name in ("avx512f", "avx2", "sse4_2") if name in flags), "")
        cpu += f" (family {fields['cpu family']} model {fields['model']}" + (f", {vector.upper()}" if vector else "") + ")"
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()}"


class Rows:
    def __init__(self):
        self.rows = []

    def add(self, case, metric, value, unit, threads, note=""):
        print(f"{case:<40} {metric:<32} {value:>10.3f} {unit:<4} {note}", flush=True)
        self.rows.append(dict(benchmark="blender", case=case, metric=metric, value=value, unit=unit, threads=threads, note=note))


def frame_times(scene, frames, work) -> list[float]:
    """Milliseconds of `work(frame)` for each of the frames (alternating so each one re-evaluates)."""
    times = []
    for frame in frames:
        started = time.perf_counter()
        work(frame)
        times.append(1000 * (time.perf_counter() - started))
    return times


def time_frames(scene, frames, work) -> float:
    """Median milliseconds of `work(frame)` over the frames."""
    times = sorted(frame_times(scene, frames, work))
    return times[len(times) // 2]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "bench" / "results")
    parser.add_argument("--zip", type=pathlib.Path, default=os.environ.get("TEGUMENT_EXTENSION_ZIP"))
    parser.add_argument("--collide-grid", type=int, default=316, help="skin grid subdivisions of the collision case (316: ~100k vertices)")
    parser.add_argument("--collide-frames", type=int, default=8)
    parser.add_argument("--cases", default="collisions,character,self_collision",
                        help="comma-separated, of collisions, character, self_collision")
    parser.add_argument("--character-both", action="store_true",
                        help="bake the character with Converge on and off, alternating, each against Corrective Smooth in the same run")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "demo"))
    import extension

    user = extension.isolated_user_folder("tegument-bench-user-")
    import bpy
    import numpy as np

    extension.install(args.zip, user)  # Blender runs the wheel the extension bundles

    rows = Rows()
    threads = os.cpu_count() or 1
    workdir = pathlib.Path(tempfile.mkdtemp(prefix="tegument-bench-"))
    bpy.ops.wm.save_as_mainfile(filepath=str(workdir / "bench.blend"))

    cases = args.cases.split(",")
    if "collisions" in cases:
        collisions(bpy, np, rows, threads, workdir, args.collide_grid, args.collide_frames)
    if "character" in cases:
        character(bpy, np, rows, threads, workdir, args.character_both)
    if "self_collision" in cases:
        self_collision(bpy, np, rows, threads, workdir)

    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "blender.json").write_text(json.dumps(rows.rows, indent=1))
    (args.out / "machine.txt").write_text(machine() + f"\nBlender {bpy.app.version_string} (PyPI bpy)\n")
    shutil.rmtree(workdir, ignore_errors=True)
    shutil.rmtree(user, ignore_errors=True)
    print(f"wrote {args.out / 'blender.json'}")
    return 0


def collisions(bpy, np, rows, threads, workdir, grid: int, frame_count: int) -> None:
    """A skin grid against a ~20k-triangle sphere that rises into it and slides:
    Tegument with collisions, Cloth pinned towards the animation (collision
    quality 5), and Shrinkwrap (Outside) + Corrective Smooth, each timed per
    frame and audited with tegument.audit against the sphere at every frame."""
    import extension
    import tegument
    from bl_ext.user_default.tegument.deform import bake

    frames = list(range(1, frame_count + 1))

    def centre(frame):
        k = frame - 1
        rise = min(k, 5)
        return (-0.3 + 0.04 * max(k - 5, 0), 0.05, -0.32 + 0.03 * rise)

    def build():
        extension.new_blend(workdir / "collide.blend")
        scene = bpy.context.scene
        scene.frame_start, scene.frame_end = 1, frame_count
        bpy.ops.mesh.primitive_grid_add(x_subdivisions=grid, y_subdivisions=grid, size=2.0)
        skin = bpy.context.object
        skin.name = "Skin"
        bpy.ops.mesh.primitive_uv_sphere_add(segments=128, ring_count=80, radius=0.3)
        sphere = bpy.context.object
        sphere.name = "Sphere"
        for frame in frames:
            sphere.location = centre(frame)
            sphere.keyframe_insert("location", frame=frame)
        sphere.tegument_collider.thickness = 0.005
        return scene, skin, sphere

    def world(obj):
        evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        mesh = evaluated.data
        positions = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
        mesh.attributes["position"].data.foreach_get("vector", positions)
        m = np.array(evaluated.matrix_world)
        return (positions.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]).astype(np.float32), mesh

    def triangles(mesh):
        tris = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int32)
        mesh.loop_triangles.foreach_get("vertices", tris)
        return tris.reshape(-1, 3)

    def audit_at(scene, skin, sphere, frame, positions=None):
        scene.frame_set(frame)
        body_positions, body_mesh = world(sphere)
        collider = tegument.Collider(body_positions, triangles(body_mesh), thickness=0.0, friction=0.0)
        if positions is None:
            positions, _ = world(skin)
        mesh = skin.data
        corners = np.empty(len(mesh.loops), dtype=np.int32)
        mesh.loops.foreach_get("vertex_index", corners)
        sizes = np.empty(len(mesh.polygons), dtype=np.int32)
        mesh.polygons.foreach_get("loop_total", sizes)
        return tegument.audit(positions, corners, sizes, [collider])

    def play_and_audit(scene, skin, sphere):
        """Per-frame times of evaluating the skin's own stack, and the audit totals."""
        times, totals = [], {"vertices_inside": 0, "edges_crossing": 0, "collider_edges_crossing": 0}
        for frame in frames:
            started = time.perf_counter()
            scene.frame_set(frame)
            positions, _ = world(skin)
            times.append(1000 * (time.perf_counter() - started))
            found = audit_at(scene, skin, sphere, frame, positions)
            for key in totals:
                totals[key] += getattr(found, key)
        return times, totals

    def record(label, times, totals, note):
        median = sorted(times)[len(times) // 2]
        rows.add(case, f"{label}: frame", median, "ms", threads, note)
        rows.add(case, f"{label}: vertices inside (all frames)", totals["vertices_inside"], "", threads)
        rows.add(case, f"{label}: edges crossing (all frames)", totals["edges_crossing"] + totals["collider_edges_crossing"], "", threads, "skin and collider edges")

    # Tegument.
    scene, skin, sphere = build()
    collection = bpy.data.collections.new("Colliders")
    scene.collection.children.link(collection)
    for owner in list(sphere.users_collection):
        owner.objects.unlink(sphere)
    collection.objects.link(sphere)
    case = f"skin {len(skin.data.vertices) // 1000}k vertices vs sphere {len(sphere.data.polygons) * 2 // 1000}k triangles"
    bpy.context.view_layer.objects.active = skin
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    skin.tegument.collider_collection = collection
    skin.tegument.frame_start, skin.tegument.frame_end = 1, frame_count
    job = bake.BakeJob(bpy.context, skin, range(1, frame_count + 1))
    while not job.finished:
        job.step()
    job.commit()
    times = [1000 * t for t in job.times]
    record("Tegument collisions (default it.)", times, job.audit_totals, "input + refit + CCD passes + solve + cache write")
    rows.add(case, "Tegument collisions: pinched (most in a frame)", job.most_pinched, "", threads)

    # Cloth pinned towards the animation (the skin does not move by itself,
    # so the pins hold it where it is, softly).
    scene, skin, sphere = build()
    group = skin.vertex_groups.new(name="pin")
    group.add(range(len(skin.data.vertices)), 0.5, "REPLACE")
    cloth = skin.modifiers.new("Cloth", "CLOTH")
    cloth.settings.vertex_group_mass = "pin"
    cloth.settings.pin_stiffness = 1.0
    cloth.settings.effector_weights.gravity = 0.0
    cloth.collision_settings.collision_quality = 5
    cloth.collision_settings.distance_min = 0.005
    cloth.point_cache.frame_start, cloth.point_cache.frame_end = 1, frame_count
    sphere.modifiers.new("Collision", "COLLISION").settings.thickness_outer = 0.005
    times, totals = play_and_audit(scene, skin, sphere)
    record("Cloth (pinned, collision quality 5)", times[1:] or times, totals, "frame_set + simulation step + read positions")

    # Shrinkwrap (Outside) + Corrective Smooth (10 it.).
    scene, skin, sphere = build()
    wrap = skin.modifiers.new("Shrinkwrap", "SHRINKWRAP")
    wrap.target = sphere
    wrap.wrap_method = "NEAREST_SURFACEPOINT"
    wrap.wrap_mode = "OUTSIDE_SURFACE"
    wrap.offset = 0.005
    smooth = skin.modifiers.new("CorrectiveSmooth", "CORRECTIVE_SMOOTH")
    smooth.iterations = 10
    smooth.rest_source = "ORCO"
    times, totals = play_and_audit(scene, skin, sphere)
    record("Shrinkwrap (Outside) + Corrective Smooth", times, totals, "frame_set + both modifiers + read positions")


CHARACTER_CASES = {
    "obj": "MakeHuman character (OBJ, welded)",
    "gltf": "MakeHuman character (glTF round trip, split seams)",
    "subdivided": "MakeHuman character (Subdivision Surface between Armature and Tegument)",
}


def character(bpy, np, rows, threads, workdir, both_solvers: bool = False) -> None:
    """The hard-posed MakeHuman character (demo/character_demo.py), welded, after a glTF round
    trip and with a Subdivision Surface between the Armature and Tegument: per frame, the armature alone, Corrective Smooth (10 it.) and Tegument's bake; then at the
    pose's last frame what bind pinned, the spike maximum and the self-intersecting face pairs of
    skinning, Corrective Smooth and Pyramid Deform (demo/measures.py, independent of the solver).

    Without the shared MakeHuman data there is one row, "character: shared data" = 0, and
    bench/collect.py says so instead of the character's lines."""
    import character as makehuman
    import character_demo
    import extension
    import measures
    from bl_ext.user_default.tegument.deform import bake

    try:
        makehuman.data_folder()
    except makehuman.CharacterDataMissing as error:
        print(f"character rows skipped: {error}")
        rows.add("MakeHuman character", "character: shared data", 0, "", threads, str(error))
        return
    rows.add("MakeHuman character", "character: shared data", 1, "", threads, "../shared/data/makehuman")
    last = character_demo.POSE_FRAMES[1]
    frames = [2 + (i * 5) % (last - 1) for i in range(2 * (last - 1))]  # each frame twice, never two in a row
    for variant, label in CHARACTER_CASES.items():
        extension.new_blend(workdir / f"character-{variant}.blend")
        obj, _ = character_demo.build(variant, workdir)
        scene = bpy.context.scene
        rest, corners, sizes = character_demo.rest_topology(obj)  # what Tegument deforms
        case = f"{label}, {len(rest) / 1000:.1f}k vertices"
        groups = measures.coincident_groups(rest)

        def evaluate(frame):
            scene.frame_set(frame)
            evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
            positions = np.empty(len(evaluated.data.vertices) * 3, dtype=np.float32)
            evaluated.data.attributes["position"].data.foreach_get("vector", positions)
            return positions.reshape(-1, 3)

        armature_only = time_frames(scene, frames, evaluate)
        rows.add(case, "armature only: frame", armature_only, "ms", threads, "frame_set + depsgraph + read positions")
        skinning = evaluate(last)

        def corrective_smooth():
            """Corrective Smooth's frames and its shape at the pose's last frame."""
            with character_demo.corrective_smooth(obj):
                times = frame_times(scene, frames, evaluate)
                return times, evaluate(last)

        # Corrective Smooth before and after Tegument's bake, so that both are measured over the
        # same minutes (this host's second core comes and goes).
        corrective_times, smoothed = corrective_smooth()
        bpy.context.view_layer.objects.active = obj
        assert bpy.ops.tegument.deform_add() == {"FINISHED"}
        pinned = character_demo.pinned_count(obj)  # the bind's warning (obj.tegument.bind_warnings)
        obj.tegument.frame_start, obj.tegument.frame_end = character_demo.POSE_FRAMES

        import tegument

        default_settings = (obj.tegument.converge, obj.tegument.iterations)
        other_settings = ((False, tegument.DEFAULTS.iterations) if default_settings[0]
                          else (True, tegument.DEFAULTS.accelerated_iterations))

        def tegument_bake(settings):
            """A bake with ``(converge, iterations)``: its frame times (the first left out: it
            factorises), iterations a frame and the job; the default settings are restored."""
            obj.tegument.converge, obj.tegument.iterations = settings
            job = bake.BakeJob(bpy.context, obj, range(character_demo.POSE_FRAMES[0], last + 1))
            while not job.finished:
                job.step()
            job.commit()
            obj.tegument.converge, obj.tegument.iterations = default_settings
            return [1000 * t for t in job.times[1:]], job.iterations_used[1:], job

        # With --character-both the other solver setting is baked too, before and after the
        # default's bake, so that both are measured over the same minutes as Corrective Smooth;
        # the default's last bake leaves the cache the figures below read.
        rounds = [other_settings, default_settings, "corrective", other_settings, default_settings] if both_solvers \
            else [default_settings, "corrective"]
        times, used, other_times, other_iterations = [], [], [], []
        for settings in rounds:
            if settings == "corrective":
                corrective_times += corrective_smooth()[0]
                continue
            frame_times_ms, iterations, job_of_round = tegument_bake(settings)
            if settings == default_settings:
                times += frame_times_ms
                used += iterations
                job = job_of_round
            else:
                other_times += frame_times_ms
                other_iterations += iterations
        times.sort()
        tegument_frame = times[len(times) // 2]
        corrective = sorted(corrective_times)[len(corrective_times) // 2]
        rows.add(case, "Corrective Smooth (10 it.): frame", corrective, "ms", threads,
                 "armature + Corrective Smooth, whole frame, before and after Tegument's bake")
        rows.add(case, f"Tegument ({obj.tegument.iterations} it.): frame", tegument_frame, "ms", threads, "input evaluation + solve + cache write")
        rows.add(case, "Tegument frame / Corrective Smooth frame", tegument_frame / corrective, "x", threads)
        rows.add(case, "Tegument: iterations a frame", sum(used) / len(used), "", threads,
                 f"Converge {'on' if default_settings[0] else 'off'}, mean over the bake's frames after the first")
        if both_solvers:
            label = f"Converge {'on' if other_settings[0] else 'off'}, {other_settings[1]} it."
            other_times.sort()
            other = other_times[len(other_times) // 2]
            rows.add(case, f"Tegument ({label}): frame", other, "ms", threads, "the other solver setting, same minutes")
            rows.add(case, f"Tegument ({label}) frame / Corrective Smooth frame", other / corrective, "x", threads)
            rows.add(case, f"Tegument ({label}): iterations a frame", sum(other_iterations) / len(other_iterations), "", threads)
        rows.add(case, "pinned by bind", pinned, "", threads, "vertices that follow the input")
        rows.add(case, "split vertices", int((groups != np.arange(len(groups))).sum()), "", threads, "coincident with another at rest")
        cache = character_demo.read_cache(obj)
        ours = cache[-1]
        figures = convergence(bpy, np, obj, job, cache, scene)
        default = f"Converge {'on' if obj.tegument.converge else 'off'}, {obj.tegument.iterations} it."
        rows.add(case, "Tegument: convergence error, worst baked frame", figures["baked"], "", threads,
                 f"the bake at the add-on's defaults ({default}); RMS |x − x_inf| / RMS |x_inf − input| (issue 28)")
        rows.add(case, "Tegument Converge: convergence error, worst frame", figures["converge"], "", threads,
                 f"Converge on, at most {figures['converge_iterations']} it., each frame solved from its input (a cold start)")
        rows.add(case, "Tegument: x_inf moves in as many iterations again", figures["drift"], "", threads,
                 f"{REFERENCE_ITERATIONS} against {2 * REFERENCE_ITERATIONS} iterations, the last frame")
        for method, positions in (("skinning", skinning), ("Corrective Smooth", smoothed), ("Tegument", ours)):
            figures = character_demo.frame_figures(positions, rest, corners, sizes, groups)
            rows.add(case, f"{method}: spike max", figures["spike_max"], "", threads, f"frame {last}")
            rows.add(case, f"{method}: self-intersecting pairs", figures["self_intersections"], "", threads, f"frame {last}")
            rows.add(case, f"{method}: seam gap", 1000 * figures["seam_gap"], "mm", threads, f"frame {last}")


def self_collision(bpy, np, rows, threads, workdir) -> None:
    """Issue 30 on the hard-posed MakeHuman character (OBJ, welded): the bake frame without and with
    Self Collision in the same run, and at every frame of the pose the self-intersecting face pairs
    the rest pose does not have (demo/measures.py, Blender's BVHTree), for skinning, Corrective
    Smooth and Pyramid Deform without and with Self Collision."""
    import character as makehuman
    import character_demo
    import extension
    import measures

    try:
        makehuman.data_folder()
    except makehuman.CharacterDataMissing as error:
        print(f"self-collision rows skipped: {error}")
        return
    extension.new_blend(workdir / "self-collision.blend")
    obj, _ = character_demo.build("obj", workdir)
    rest, corners, sizes = character_demo.rest_topology(obj)
    groups = measures.coincident_groups(rest)
    case = f"MakeHuman character (OBJ, welded), {len(rest) / 1000:.1f}k vertices, Self Collision"
    at_rest = measures.self_intersection_pairs(rest, corners, sizes, groups)
    first, last = character_demo.POSE_FRAMES
    pose = range(first, last + 1)
    shapes = {"skinning": [character_demo.upstream_local(obj, frame) for frame in pose]}
    with character_demo.corrective_smooth(obj):
        shapes["Corrective Smooth"] = [character_demo.upstream_local(obj, frame) for frame in pose]
    # Without, then with: the same object, bind and frames; the wall time of the Bake operator.
    times = {}
    bake = character_demo.add_and_bake(obj, "//self-without.pc2")
    times["without"] = bake["ms_per_frame_wall"]
    shapes["Pyramid Deform"] = list(character_demo.read_cache(obj))
    obj.tegument.self_collision.enabled = True
    obj.tegument.cache_path = "//self-with.pc2"
    started = time.perf_counter()
    assert bpy.ops.tegument.bake() == {"FINISHED"}
    times["with"] = 1000 * (time.perf_counter() - started) / len(pose)
    shapes["Pyramid Deform + Self Collision"] = list(character_demo.read_cache(obj))
    rows.add(case, "bake frame without Self Collision", times["without"], "ms", threads, "wall time of the Bake operator per frame")
    rows.add(case, "bake frame with Self Collision", times["with"], "ms", threads, "wall time of the Bake operator per frame")
    rows.add(case, "with / without", times["with"] / times["without"], "x", threads, "target <= 2")
    rows.add(case, "rest: self-intersecting pairs", len(at_rest), "", threads, "overlapping shells of the asset")
    for name, frames in shapes.items():
        found = [measures.self_intersection_pairs(x, corners, sizes, groups) for x in frames]
        rows.add(case, f"{name}: pairs the rest pose does not have", max(len(f - at_rest) for f in found), "", threads, "worst frame of the pose")
        rows.add(case, f"{name}: self-intersecting pairs", len(found[-1]), "", threads, f"frame {last}, the rest pose's included")
    rows.add(case, "Self Collision: contacts (all frames)", obj.tegument.self_collision.contacts, "", threads)
    rows.add(case, "Self Collision: held (all frames)", obj.tegument.self_collision.held, "", threads)


# Iterations of the reference solve (x_inf): the accelerated solver's change per iteration is below
# 1e-7 of the character's size long before (the bench checks it at the last frame, against twice as many).
REFERENCE_ITERATIONS = 1000


def convergence(bpy, np, obj, job, cache, scene) -> dict:
    """Issue 28's convergence error on the posed character: per frame, a solve against the same
    solve continued until it stops moving (x_inf: the accelerated solver at REFERENCE_ITERATIONS),
    relative to how far x_inf is from the frame's input. "baked": the bake's cache (the add-on's
    settings: Converge, each frame from the last one's result); "converge": Converge at its tolerance
    and iteration limit, each frame solved from its input (a still, or the first frame of a bake).
    Each the worst over the frames whose displacement is
    at least a tenth of the last frame's (the first frames of the pose barely move: a ratio of two
    tiny numbers). "drift": how far x_inf moves in twice the iterations at the last frame."""
    import measures
    import tegument
    from bl_ext.user_default.tegument.deform import evaluate

    deformer, closeness = job.deformer, job.closeness
    converge_iterations = tegument.DEFAULTS.accelerated_iterations
    accelerated, tolerance = deformer.accelerated, deformer.tolerance
    modifier = evaluate.tegument_modifier(obj)
    modifier.show_viewport = False  # the input: the stack above Tegument
    baked, converged, scales, last = [], [], [], None
    try:
        deformer.accelerated = True
        for k, frame in enumerate(job.frames):
            scene.frame_set(frame)
            depsgraph = bpy.context.evaluated_depsgraph_get()
            world = np.array(evaluate.evaluated_positions(obj, depsgraph)[1])
            deformer.tolerance = None
            x_inf = deformer.solve(world, iterations=REFERENCE_ITERATIONS, closeness=closeness)
            ours = evaluate.to_world(np.ascontiguousarray(cache[k]), obj.evaluated_get(depsgraph).matrix_world)
            deformer.tolerance = tegument.DEFAULTS.tolerance
            fast = deformer.solve(world, iterations=converge_iterations, closeness=closeness)
            error, scale = measures.convergence_error(ours, x_inf, world)
            baked.append(error)
            converged.append(measures.convergence_error(fast, x_inf, world)[0])
            scales.append(scale)
            last = world, x_inf
        world, x_inf = last
        deformer.tolerance = None
        longer = deformer.solve(world, iterations=2 * REFERENCE_ITERATIONS, closeness=closeness)
        drift = measures.convergence_error(longer, x_inf, world)[0]
    finally:
        deformer.accelerated, deformer.tolerance = accelerated, tolerance
        modifier.show_viewport = True
    return dict(baked=measures.worst_moving(baked, scales), converge=measures.worst_moving(converged, scales),
                converge_iterations=converge_iterations, drift=drift)


if __name__ == "__main__":
    sys.exit(main())
