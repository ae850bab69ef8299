"""`make demo`: install the built extension into an isolated Blender and run every feature headlessly.

The scene (``demo/scene.py``, procedural): an armature bends and twists a limb so that its forearm
presses into a body (a sphere in a collider collection); the limb's skin carries round rigid
scales. The demo then, through the installed extension:

1. checks both meshes (``tegument.check_mesh``);
2. bakes Pyramid Deform with collisions into a PC2 cache (``tegument.deform_add``, ``tegument.bake``);
3. audits every frame independently of the bake (``tegument.audit`` on the skinning-only input and
   on the cached result, against the body at that frame);
4. bakes the Tegument UV Warp node into an OpenEXR sequence (``tegument.warp_bind``, then the bake
   that ``blender --command tegument warp-bake`` runs), with a stretch heat map;
5. renders with Cycles on the CPU: skinning only | Tegument, and the texture without | with the warp;
6. shows the flesh features of Pyramid Deform (``demo/flesh.py``), each in a small scene of its
   own: dynamics (lag, overshoot, settling; 1 vs 4 substeps), a compliant collider that gives way
   where a kinematic one pinches, and strain limits (unified with collisions, or after them).
7. bends a tube 150° and bakes it without and with Self Collision (``demo/self_collision_demo.py``):
   the cut-open fold of skinning, Pyramid Deform and Pyramid Deform with Self Collision.

Writes into ``--out``: the PNG pictures, the PC2 cache, the EXR sequence, ``demo.blend``, the flesh
scenes and their caches in ``flesh/`` and ``report.json`` (time per frame of each stage, audit
counts, rigid stretch errors; the flesh figures under ``"flesh"``). Run through
the Makefile, which builds the extension first.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import shutil
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent

FRAMES = (1, 24)
BEND_DEG, TWIST_DEG = 80.0, 45.0
BODY_RADIUS, LIMB_RADIUS = 0.45, 0.25
PRESS_ALONG = 0.8  # where along the forearm (from the elbow) it presses deepest
PRESS_DEPTH = 0.15  # how far the skinned forearm reaches into the body at the last frame
WARP_RESOLUTION = 1024
TEXTURE_SIZE = 1024
RENDER_SAMPLES = 48
WIDE, CONTACT, CLOSE = (480, 320), (300, 300), (400, 300)  # render sizes of the three cameras


def load_average() -> list[float]:
    try:
        return [float(x) for x in pathlib.Path("/proc/loadavg").read_text().split()[:3]]
    except OSError:
        return []


class Report:
    """``report.json``: what each stage found and how long it took."""

    def __init__(self):
        self.data: dict = {
            "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "load_average_start": load_average()},
            "stages": {},
        }
        self.started = time.perf_counter()

    def stage(self, name: str):
        report = self

        class Timer:
            def __enter__(self):
                self.t = time.perf_counter()
                print(f"[demo] {name} ...", flush=True)
                return report.data["stages"].setdefault(name, {})

            def __exit__(self, kind, *exc):
                seconds = time.perf_counter() - self.t
                report.data["stages"][name]["seconds"] = round(seconds, 3)
                if kind is None:
                    print(f"[demo] {name}: {seconds:.1f} s", flush=True)

        return Timer()


def pixels_of(bpy, path: pathlib.Path):
    import numpy as np

    image = bpy.data.images.load(str(path))
    width, height = image.size
    pixels = np.empty(width * height * 4, np.float32)
    image.pixels.foreach_get(pixels)
    bpy.data.images.remove(image)
    return pixels.reshape(height, width, 4)


def save_png(bpy, pixels, target: pathlib.Path) -> str:
    """Writes RGBA pixels as an 8-bit PNG through Blender's image API.

    A byte image holds and saves its pixel values as they are (no view transform), so pixels read
    from a PNG (:func:`pixels_of`) or display colours (``pictures.heat_colours``) round-trip.
    """
    height, width = pixels.shape[:2]
    image = bpy.data.images.new(target.stem, width, height, alpha=True)
    image.pixels.foreach_set(pixels.astype("float32").ravel())
    image.filepath_raw = str(target)
    image.file_format = "PNG"
    image.save()
    bpy.data.images.remove(image)
    return str(target)


def world_triangles(bpy, np, obj):
    """World positions and triangles of `obj` as evaluated now (read without the add-on)."""
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated.data
    local = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", local)
    triangles = np.empty(len(mesh.loop_triangles) * 3, np.int32)
    mesh.loop_triangles.foreach_get("vertices", triangles)
    m = np.array(evaluated.matrix_world)
    world = local.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    return np.ascontiguousarray(world, np.float32), triangles.reshape(-1, 3)


def independent_audit(bpy, np, tegument, limb, body, cache, frames) -> dict:
    """Per frame, ``tegument.audit`` of the skinning-only input and of the cached result against
    the body at that frame: the check of the bake's own totals, and the "before" figure."""
    from bl_ext.user_default.tegument import mesh_arrays
    from bl_ext.user_default.tegument.deform import evaluate

    corners = mesh_arrays.corner_verts(limb.data)
    sizes = mesh_arrays.polygon_sizes(limb.data)
    keys = ("vertices_inside", "edges_crossing", "collider_edges_crossing")
    per_frame = {"frame": [], "skinning": {k: [] for k in keys}, "tegument": {k: [] for k in keys}}
    scene = bpy.context.scene
    for k, frame in enumerate(frames):
        scene.frame_set(frame)
        collider = tegument.Collider(*world_triangles(bpy, np, body), thickness=0.0, friction=0.0)
        with evaluate.upstream_only(limb):
            skinned, _ = world_triangles(bpy, np, limb)
        m = np.array(limb.matrix_world)
        ours = np.ascontiguousarray(cache[k] @ m[:3, :3].T + m[:3, 3], np.float32)
        per_frame["frame"].append(frame)
        for label, positions in (("skinning", skinned), ("tegument", ours)):
            found = tegument.audit(positions, corners, sizes, [collider])
            for key in keys:
                per_frame[label][key].append(int(getattr(found, key)))
    totals = {label: {key: sum(values) for key, values in per_frame[label].items()} for label in ("skinning", "tegument")}
    return {"totals": totals, "per_frame": per_frame}


def configure_cycles(scene, width: int, height: int) -> None:
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = RENDER_SAMPLES
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False  # a few dozen samples of a diffuse scene are clean enough; no OIDN time
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.film_transparent = False


def render_still(bpy, camera, path: pathlib.Path) -> float:
    scene = bpy.context.scene
    scene.camera = camera
    scene.render.filepath = str(path)
    started = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return time.perf_counter() - started


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "demo")
    parser.add_argument("--zip", type=pathlib.Path, default=os.environ.get("TEGUMENT_EXTENSION_ZIP"))
    args = parser.parse_args()
    if not args.zip or not pathlib.Path(args.zip).is_file():
        sys.exit("error: no extension zip; run `make demo`, which builds it")
    out = args.out.resolve()
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)

    sys.path.insert(0, str(HERE))
    import extension

    user = extension.isolated_user_folder("tegument-demo-user-")
    try:
        return run(args, out, user)
    finally:
        shutil.rmtree(user, ignore_errors=True)


def run(args, out: pathlib.Path, user: str) -> int:
    import bpy
    import numpy as np

    import extension
    import flesh
    import pictures
    import scene as demo_scene

    report = Report()
    stage = report.stage
    first, last = FRAMES
    frames = range(first, last + 1)

    with stage("install"):
        try:
            extension.install(args.zip, user)
        except RuntimeError as error:
            sys.exit(f"error: {error}")

    with stage("scene") as info:
        # Saved first, so the add-on's "//" paths (cache, warp sequence) land in the output folder.
        blend = out / "demo.blend"
        extension.new_blend(blend)
        scene = bpy.context.scene
        scene.frame_start, scene.frame_end = first, last
        limb, rig = demo_scene.build_limb(radius=LIMB_RADIUS)
        demo_scene.animate_bend(rig, first, last, angle_deg=BEND_DEG, twist_deg=TWIST_DEG)
        centre = demo_scene.pressed_body_centre(BEND_DEG, along=PRESS_ALONG, body_radius=BODY_RADIUS,
                                                limb_radius=LIMB_RADIUS, depth=PRESS_DEPTH)
        body = demo_scene.build_body(location=centre, radius=BODY_RADIUS)
        colliders = demo_scene.make_collider(body, thickness=0.01, friction=0.3)
        colour, rigidity = demo_scene.scale_pattern(TEXTURE_SIZE, LIMB_RADIUS, 2.0)
        material, texture = demo_scene.skin_material(limb, demo_scene.image_from_pixels("Scales", colour, is_data=False))
        clay = demo_scene.body_material(body)
        # From above, a little from the front: the bend, and the forearm against the body's outline.
        wide = demo_scene.add_camera_and_light(location=(0.1, -0.9, 3.6), target=(-0.15, 0.4, 0.0))
        # The outside of the elbow, where the skin stretches most.
        close = demo_scene.add_camera("CloseUp", (1.0, -1.15, 0.75), (0.0, 0.0, 0.0), lens=50.0)
        # Straight down onto the contact, close; the body is see-through in its pictures, so the
        # skin inside it (skinning only) or kept outside it (Tegument) shows.
        contact = demo_scene.pressed_contact_point(BEND_DEG, PRESS_ALONG, centre, BODY_RADIUS)
        contact_camera = demo_scene.add_camera("Contact", (contact[0] + 0.15, contact[1] - 0.35, 1.6), contact, lens=55.0)
        import tegument  # the wheel the extension bundles: extension.install made sure

        info.update(limb_vertices=len(limb.data.vertices), body_vertices=len(body.data.vertices),
                    frames=len(frames), bend_degrees=BEND_DEG, twist_degrees=TWIST_DEG,
                    press_depth=PRESS_DEPTH, rigid_texel_fraction=round(float(rigidity.mean()), 3),
                    tegument_module=tegument.__file__)

    with stage("check_mesh") as info:
        for obj in (limb, body):
            bpy.context.view_layer.objects.active = obj
            bpy.ops.tegument.check_mesh()
            info[obj.name] = json.loads(bpy.context.window_manager.tegument_check_result)

    with stage("pyramid_deform") as info:
        bpy.context.view_layer.objects.active = limb
        if bpy.ops.tegument.deform_add() != {"FINISHED"}:
            sys.exit("error: Add Pyramid Deform failed")
        settings = limb.tegument
        settings.cache_path = "//Limb.pc2"
        settings.frame_start, settings.frame_end = first, last
        settings.closeness = 0.01
        settings.iterations = 60
        settings.collider_collection = colliders
        started = time.perf_counter()
        if bpy.ops.tegument.bake() != {"FINISHED"}:
            sys.exit("error: the Pyramid Deform bake failed (its message is above)")
        wall = time.perf_counter() - started
        info.update(
            frames=len(frames), iterations=settings.iterations, closeness=round(settings.closeness, 4),
            collider=body.name, thickness=round(body.tegument_collider.thickness, 4), friction=round(body.tegument_collider.friction, 4),
            ms_per_frame=round(settings.last_frame_ms, 2),
            ms_per_frame_wall=round(1000 * wall / len(frames), 2),
            audit={"vertices_inside": settings.audit_vertices_inside, "edges_crossing": settings.audit_edges_crossing,
                   "collider_edges_crossing": settings.audit_collider_edges_crossing,
                   "pinched_vertices_most_in_a_frame": settings.pinched_vertices},
            warnings=settings.warnings, cache=bpy.path.abspath(settings.cache_path),
        )

    with stage("audit") as info:
        from bl_ext.user_default.tegument import pc2

        cache = pc2.read(bpy.path.abspath(limb.tegument.cache_path))[0]
        found = independent_audit(bpy, np, tegument, limb, body, cache, frames)
        info.update(found)
    audit_stage = report.data["stages"]["audit"]
    audit_stage["ms_per_frame"] = round(1000 * audit_stage["seconds"] / len(frames), 2)  # two audits and a depsgraph per frame

    with stage("uv_warp") as info:
        from bl_ext.user_default.tegument.warp import bake as warp_bake

        tree = material.node_tree
        node = tree.nodes.new("TegumentUVWarpNode")
        node.object = limb
        node.uv_map = "UVMap"
        node.rigidity_image = demo_scene.image_from_pixels("ScalesRigidity", rigidity, is_data=True)
        node.resolution = WARP_RESOLUTION
        node.frame_start, node.frame_end = first, last
        node.directory = "//warp/"
        node.write_heatmap = True
        tree.nodes.active = node
        if bpy.ops.tegument.warp_bind(material=material.name, node=node.name) != {"FINISHED"}:
            sys.exit("error: binding the UV Warp node failed")
        # The bake `blender --command tegument warp-bake` runs; it returns the job with its per-frame figures.
        _, cancelled, job = warp_bake.bake_blocking(bpy.context, material, node, report=print)
        if cancelled:
            sys.exit("error: the UV warp bake was interrupted")
        stats = job.summary.frames
        info.update(
            frames=len(stats), resolution=WARP_RESOLUTION, iterations=node.iterations,
            ms_per_frame=round(1000 * float(np.mean([s.seconds for s in stats])), 2),
            rigid_stretch_before=round(float(np.mean([s.identity_mean for s in stats])), 4),
            rigid_stretch_after=round(float(np.mean([s.warped_mean for s in stats])), 4),
            rigid_stretch_last_frame={"before": round(stats[-1].identity_mean, 4), "after": round(stats[-1].warped_mean, 4)},
            rigid_stretch_worst_after=round(max(s.warped_max for s in stats), 4),
            foldovers=sum(s.foldovers for s in stats),
            per_frame=[{"frame": s.frame, "ms": round(1000 * s.seconds, 1), "before": round(s.identity_mean, 4),
                        "after": round(s.warped_mean, 4), "foldovers": s.foldovers} for s in stats],
            node_report=node.report, directory=str(out / "warp"),
            exr_files=len(list((out / "warp").glob("*_[0-9][0-9][0-9][0-9].exr"))),
        )

    with stage("heat_map") as info:
        # The stretch left on the texture detail at the last frame, without (identity) and with the
        # warp: the measure the add-on's heat map writes (tegument.stretch_map), over the side chart.
        data = job.inputs
        deformed = job.last_positions
        without = tegument.stretch_map(data.rest, deformed, data.corner_verts, data.polygon_sizes, data.corner_uvs,
                                       np.zeros((WARP_RESOLUTION, WARP_RESOLUTION, 2), np.float32), udim=1001)
        with_warp = tegument.read_exr(job.heatmaps[1001])[0][..., 0]
        rigid = demo_scene.scale_pattern(WARP_RESOLUTION, LIMB_RADIUS, 2.0)[1] > 0.5
        chart = demo_scene.tube_side_chart(WARP_RESOLUTION, LIMB_RADIUS, 2.0)
        rows, cols = pictures.crop_to(without, chart, margin=0)
        top = 0.5  # log-stretch 0.5 (a factor of 1.65): the top of the colour scale, the same for both halves
        halves = [pictures.downscale(pictures.heat_colours(m[rows, cols], top, chart[rows, cols]), 2)
                  for m in (without, with_warp)]
        info["picture"] = save_png(bpy, pictures.join_side_by_side(halves), out / "uv_warp_heat_map.png")
        info.update(frame=last, scale_top=top,
                    rigid_mean_without=round(float(without[rigid].mean()), 4),
                    rigid_mean_with=round(float(with_warp[rigid].mean()), 4),
                    skin_mean_without=round(float(without[chart & ~rigid].mean()), 4),
                    skin_mean_with=round(float(with_warp[chart & ~rigid].mean()), 4))

    with stage("render") as info:
        render_scene = bpy.context.scene
        render_scene.frame_set(last)
        modifier = limb.modifiers["Tegument"]
        uv_node = material.node_tree.nodes["UV"]
        links = material.node_tree.links
        seconds = []

        def plain_texture():
            links.new(uv_node.outputs["UV"], texture.inputs["Vector"])

        def warped_texture():
            links.new(node.outputs["UV"], texture.inputs["Vector"])

        configure_cycles(render_scene, *WIDE)
        shots = {}
        # Geometry: the same plain texture on both, so only the deformation differs.
        plain_texture()
        for label, show in (("skinning", False), ("tegument", True)):
            modifier.show_render = show
            path = out / f"{label}_frame{last:03d}.png"
            seconds.append(render_still(bpy, wide, path))
            shots[label] = path
        configure_cycles(render_scene, *CONTACT)
        demo_scene.set_alpha(clay, 0.25)
        for label, show in (("contact_skinning", False), ("contact_tegument", True)):
            modifier.show_render = show
            path = out / f"{label}_frame{last:03d}.png"
            seconds.append(render_still(bpy, contact_camera, path))
            shots[label] = path
        demo_scene.set_alpha(clay, 1.0)
        modifier.show_render = True
        configure_cycles(render_scene, *CLOSE)
        for label, hook in (("texture_without_warp", plain_texture), ("texture_with_warp", warped_texture)):
            hook()
            path = out / f"{label}_frame{last:03d}.png"
            seconds.append(render_still(bpy, close, path))
            shots[label] = path
        render_scene.camera = wide
        info["pictures"] = {
            "collisions_before_after": save_png(
                bpy, pictures.join_side_by_side([pixels_of(bpy, shots["contact_skinning"]), pixels_of(bpy, shots["contact_tegument"])]),
                out / "collisions_before_after.png"),
            "pyramid_deform_before_after": save_png(
                bpy, pictures.join_side_by_side([pixels_of(bpy, shots["skinning"]), pixels_of(bpy, shots["tegument"])]),
                out / "pyramid_deform_before_after.png"),
            "uv_warp_before_after": save_png(
                bpy, pictures.join_side_by_side([pixels_of(bpy, shots["texture_without_warp"]), pixels_of(bpy, shots["texture_with_warp"])]),
                out / "uv_warp_before_after.png"),
        }
        info.update(frame=last, samples=RENDER_SAMPLES, renders=len(seconds),
                    seconds_per_render=round(float(np.mean(seconds)), 2))

    bpy.ops.wm.save_as_mainfile(filepath=str(out / "demo.blend"))
    # Last: each flesh scene replaces the open file with one of its own.
    report.data["flesh"] = flesh.run(out, tegument, stage)
    import character_demo  # the MakeHuman character; also replaces the open file

    report.data["character"] = character_demo.run(out, stage)
    import self_collision_demo  # the bent tube without and with Self Collision; its own file too

    report.data["self_collision"] = self_collision_demo.run(out, stage)
    data = report.data
    data["outputs"] = {
        "blend": str(out / "demo.blend"),
        "pc2": data["stages"]["pyramid_deform"]["cache"],
        "exr_directory": data["stages"]["uv_warp"]["directory"],
        "pictures": sorted(str(p) for p in out.glob("*.png")),
    }
    data["machine"]["load_average_end"] = load_average()
    data["total_seconds"] = round(time.perf_counter() - report.started, 3)
    (out / "report.json").write_text(json.dumps(data, indent=2, ensure_ascii=False))
    print_summary(data, out)
    return 0


def print_summary(data: dict, out: pathlib.Path) -> None:
    s = data["stages"]
    deform, audit, warp = s["pyramid_deform"], s["audit"]["totals"], s["uv_warp"]
    print()
    print(f"[demo] Pyramid Deform with collisions: {deform['frames']} frames, {deform['ms_per_frame']:.1f} ms per frame; "
          f"bake audit: {deform['audit']['vertices_inside']} vertices inside, "
          f"{deform['audit']['edges_crossing']} + {deform['audit']['collider_edges_crossing']} edges crossing, "
          f"{deform['audit']['pinched_vertices_most_in_a_frame']} pinched")
    print(f"[demo] independent audit over all frames: skinning only {audit['skinning']['vertices_inside']} vertices inside, "
          f"{audit['skinning']['edges_crossing'] + audit['skinning']['collider_edges_crossing']} edges crossing; "
          f"Tegument {audit['tegument']['vertices_inside']} and "
          f"{audit['tegument']['edges_crossing'] + audit['tegument']['collider_edges_crossing']}")
    print(f"[demo] UV warp {warp['resolution']}²: {warp['ms_per_frame']:.0f} ms per frame; rigid stretch "
          f"{warp['rigid_stretch_before']:.3f} → {warp['rigid_stretch_after']:.3f}, fold-overs {warp['foldovers']}")
    print(f"[demo] renders: {s['render']['renders']} × {s['render']['seconds_per_render']:.1f} s")
    dynamics, compliance, strain = (data["flesh"][k] for k in ("dynamics", "compliance", "strain"))
    print(f"[demo] dynamics: overshoot {dynamics['peak_overshoot']:.3f} (motion {dynamics['motion']}), settled to "
          f"{dynamics['settle_error']:.4f}; 1 vs 4 substeps {dynamics['substeps_1_vs_4_last_frame_difference']:.4f} apart "
          f"at the last frame ({dynamics['substeps_1_vs_4_max_difference']:.3f} at most) -> {dynamics['picture']}")
    print(f"[demo] compliance: kinematic arm {compliance['kinematic']['bake_audit']['pinched_vertices']} pinched, "
          f"compliant arm {sum(compliance['compliant']['independent_audit'].values())} penetrations, receded "
          f"{compliance['compliant']['played_back_recession']:.3f} -> {compliance['picture']}")
    print("[demo] strain: " + "; ".join(
        f"{mode} worst {strain[mode]['worst_stretch']:.3f}, {sum(strain[mode]['independent_audit'].values())} penetrations"
        for mode in ("no limit", "UNIFIED", "POST")) + f" -> {strain['picture']}")
    print(f"[demo] done in {data['total_seconds']:.1f} s; everything is in {out}:")
    for path in sorted(out.iterdir()):
        suffix = f"  ({len(list(path.iterdir()))} files)" if path.is_dir() else ""
        print(f"  {path}{suffix}")


if __name__ == "__main__":
    sys.exit(main())
