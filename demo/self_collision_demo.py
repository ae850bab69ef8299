"""The Self Collision picture of ``docs/self-collision.md``: an armature-bent tube at 150°, cut open
along its bending plane, as skinning, Pyramid Deform without and with Self Collision leave it.

A capped tube (32 around, 48 along) bent from straight to 150° over 12 frames by a two-bone
armature (``demo/scene.py``, the scene of ``blender_tests/test_self_collision.py``), baked twice
through the installed extension, without and with Self Collision. At the last frame each of the
three shapes is copied with the faces above the bending plane left out (the tube cut open along
it) and rendered by Cycles on the CPU (few samples) from above through an orthographic camera: the
section shows whether the inner side of the fold passes through itself. The pictures are
joined left to right (``demo/pictures.py``) into ``self_collision_before_after.png``; the
independent counts of self-intersecting face pairs (``demo/measures.py``) go into the report.

Part of ``make demo`` (``run``); on its own::

    .venv/bin/python demo/self_collision_demo.py --zip dist/tegument-0.1.0-linux_x64.zip --out out/self_collision
"""

from __future__ import annotations

import argparse
import math
import os
import pathlib
import shutil
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent
FRAMES = 12
BEND_DEGREES = 150.0
RENDER_SAMPLES = 16
SIZE = (360, 300)  # each of the three pictures, pixels


def _scene(folder: pathlib.Path):
    import bpy

    import extension
    import scene as demo_scene

    extension.new_blend(folder / "self_collision.blend")
    limb, rig = demo_scene.build_limb("Limb", segments=32, rings=48, radius=0.25, length=2.0, heat_weights=False)
    demo_scene.animate_bend(rig, 1, FRAMES, angle_deg=BEND_DEGREES)
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = 1, FRAMES
    return limb


def _bake(limb, *, self_collision: bool, cache: str) -> float:
    """Bakes the tube through the Bake operator; returns the wall milliseconds per frame."""
    import bpy

    bpy.context.view_layer.objects.active = limb
    if limb.modifiers.get("Tegument") is None and bpy.ops.tegument.deform_add() != {"FINISHED"}:
        raise RuntimeError(f"Add Pyramid Deform failed: {limb.tegument.warnings}")
    settings = limb.tegument
    settings.self_collision.enabled = self_collision
    settings.cache_path = cache
    settings.frame_start, settings.frame_end = 1, FRAMES
    started = time.perf_counter()
    if bpy.ops.tegument.bake() != {"FINISHED"}:
        raise RuntimeError("the bake failed (its message is above)")
    return 1000 * (time.perf_counter() - started) / FRAMES


def _positions(limb):
    import bpy
    import numpy as np

    bpy.context.scene.frame_set(FRAMES)
    evaluated = limb.evaluated_get(bpy.context.evaluated_depsgraph_get())
    positions = np.empty(len(evaluated.data.vertices) * 3, np.float32)
    evaluated.data.vertices.foreach_get("co", positions)
    return positions.reshape(-1, 3)


def _look():
    """Cycles on the CPU, a light from above, an orthographic camera above the elbow (at the
    origin) looking down -Z, and a two-sided skin material (outside warm, inside dark: where the
    tube is cut open its inside shows)."""
    import bpy

    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = RENDER_SAMPLES
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.resolution_x, scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.8, 0.8, 0.82, 1.0)
    scene.world = world
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 2.5
    sun.rotation_euler = (math.radians(15), math.radians(-10), 0.0)
    bpy.context.collection.objects.link(sun)

    camera_data = bpy.data.cameras.new("Section")
    camera_data.type = "ORTHO"
    camera_data.ortho_scale = 1.5
    camera = bpy.data.objects.new("Section", camera_data)
    bpy.context.collection.objects.link(camera)
    camera.location = (0.0, 0.3, 3.0)
    scene.camera = camera

    material = bpy.data.materials.new("Skin")
    material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    shader = nodes["Principled BSDF"]
    shader.inputs["Roughness"].default_value = 0.6
    facing = nodes.new("ShaderNodeNewGeometry")
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.inputs["A"].default_value = (0.72, 0.50, 0.40, 1.0)  # outside
    mix.inputs["B"].default_value = (0.30, 0.10, 0.10, 1.0)  # inside
    links.new(facing.outputs["Backfacing"], mix.inputs["Factor"])
    links.new(mix.outputs["Result"], shader.inputs["Base Color"])
    return material


def _cut_copy(name: str, positions, corners, sizes, material):
    """A mesh object of ``positions`` without the faces whose corners are all above z = 0."""
    import bpy
    import numpy as np

    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    faces = [corners[s:s + k].tolist() for s, k in zip(starts, sizes) if (positions[corners[s:s + k], 2] <= 1e-6).any()]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(positions.tolist(), [], faces)
    mesh.shade_smooth()
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.collection.objects.link(obj)
    return obj


def _render(path: pathlib.Path) -> pathlib.Path:
    import bpy

    bpy.context.scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    return path


def run(out: pathlib.Path, stage) -> dict:
    """The picture and its counts, in a fresh file of its own in ``out/self_collision/``."""
    import bpy
    import numpy as np

    import measures
    import pictures

    folder = out / "self_collision"
    with stage("self_collision") as info:
        limb = _scene(folder)
        corners = np.array([l.vertex_index for l in limb.data.loops], np.int64)
        sizes = np.array([p.loop_total for p in limb.data.polygons], np.int64)
        times = {"without": _bake(limb, self_collision=False, cache="//without.pc2")}
        modifier = limb.modifiers["Tegument"]
        modifier.show_viewport = modifier.show_render = False
        shapes = {"skinning": _positions(limb)}
        modifier.show_viewport = modifier.show_render = True
        shapes["without"] = _positions(limb)
        times["with"] = _bake(limb, self_collision=True, cache="//with.pc2")
        shapes["with"] = _positions(limb)
        limb.hide_render = True
        material = _look()
        copies = {label: _cut_copy(f"Cut_{label}", x, corners, sizes, material) for label, x in shapes.items()}
        shots = []
        for label, copy in copies.items():
            for other in copies.values():
                other.hide_render = other is not copy
            shots.append(_render(folder / f"{label}.png"))
        joined = pictures.join_side_by_side([_pixels(path) for path in shots])
        target = out / "self_collision_before_after.png"
        _save(joined, target)
        info.update(frame=FRAMES, bend_degrees=BEND_DEGREES, samples=RENDER_SAMPLES, picture=str(target),
                    ms_per_frame={k: round(v, 1) for k, v in times.items()},
                    self_intersecting_pairs={k: measures.self_intersections(x, corners, sizes) for k, x in shapes.items()},
                    contacts=limb.tegument.self_collision.contacts, held=limb.tegument.self_collision.held)
        bpy.ops.wm.save_as_mainfile(filepath=str(folder / "self_collision.blend"))
    return info


def _pixels(path: pathlib.Path):
    import bpy
    import numpy as np

    image = bpy.data.images.load(str(path))
    try:
        width, height = image.size
        pixels = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(pixels)
        return pixels.reshape(height, width, 4)
    finally:
        bpy.data.images.remove(image)


def _save(pixels, target: pathlib.Path) -> None:
    import bpy

    height, width = pixels.shape[:2]
    image = bpy.data.images.new(target.stem, width, height, alpha=True)
    try:
        image.pixels.foreach_set(pixels.ravel())
        image.filepath_raw = str(target)
        image.file_format = "PNG"
        image.save()
    finally:
        bpy.data.images.remove(image)


class _Stage:
    """``run_demo.py``'s stage context, for a run of this file alone: prints the stage's time."""

    def __call__(self, name: str):
        info: dict = {}

        class Timed:
            def __enter__(self):
                self.started = time.perf_counter()
                return info

            def __exit__(self, *exc):
                info["seconds"] = round(time.perf_counter() - self.started, 2)
                print(f"[{name}] {info}")
                return False

        return Timed()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=pathlib.Path, default=HERE.parent / "out" / "self_collision")
    parser.add_argument("--zip", type=pathlib.Path, default=os.environ.get("TEGUMENT_EXTENSION_ZIP"))
    args = parser.parse_args()
    if not args.zip or not args.zip.is_file():
        sys.exit("error: no extension zip: `make extension`, then --zip dist/tegument-<version>-linux_x64.zip")
    sys.path.insert(0, str(HERE))
    import extension

    user = extension.isolated_user_folder("tegument-demo-user-")
    try:
        extension.install(args.zip, user)
        out = args.out.resolve()
        out.mkdir(parents=True, exist_ok=True)
        run(out, _Stage())
        return 0
    finally:
        shutil.rmtree(user, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
