"""`make demo`: install the built extension into an isolated Blender and run it headlessly.

Writes into ``--out``: ``report.json`` (what each stage found and how long it took), the
``.blend`` file and PNG renders. Run through the Makefile, which builds the extension first.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import shutil
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent


def side_by_side(bpy, paths, target: pathlib.Path) -> str:
    """Joins renders left to right into one PNG (through Blender's own image I/O)."""
    import numpy as np

    images = [bpy.data.images.load(str(p)) for p in paths]
    width, height = images[0].size
    pixels = [np.array(image.pixels[:], dtype=np.float32).reshape(height, width, 4) for image in images]
    joined = np.concatenate(pixels, axis=1)
    result = bpy.data.images.new(target.stem, width * len(images), height, alpha=True)
    result.pixels.foreach_set(joined.ravel())
    result.filepath_raw = str(target)
    result.file_format = "PNG"
    result.save()
    return str(target)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "out" / "demo")
    parser.add_argument("--zip", type=pathlib.Path, default=os.environ.get("TEGUMENT_EXTENSION_ZIP"))
    args = parser.parse_args()
    if not args.zip or not pathlib.Path(args.zip).is_file():
        sys.exit("error: no extension zip; run `make demo`, which builds it")
    out = args.out.resolve()
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)

    user = tempfile.mkdtemp(prefix="tegument-demo-user-")
    os.environ["BLENDER_USER_RESOURCES"] = user  # before bpy starts: keep the user's Blender untouched
    import bpy

    sys.path.insert(0, str(HERE))
    import scene

    report: dict = {"stages": {}}
    started = time.perf_counter()

    def stage(name: str):
        class Timer:
            def __enter__(self):
                self.t = time.perf_counter()
                print(f"[demo] {name} ...", flush=True)
                return report["stages"].setdefault(name, {})

            def __exit__(self, *exc):
                report["stages"][name]["seconds"] = round(time.perf_counter() - self.t, 3)

        return Timer()

    with stage("install"):
        result = bpy.ops.extensions.package_install_files(filepath=str(pathlib.Path(args.zip).resolve()), repo="user_default", enable_on_install=True)
        if result != {"FINISHED"}:
            sys.exit(f"error: installing {args.zip} failed")

    with stage("scene") as info:
        scene.clear()
        bpy.ops.preferences.addon_enable(module="bl_ext.user_default.tegument")
        limb, rig = scene.build_limb()
        scene.animate_bend(rig, 1, 24, angle_deg=70, twist_deg=160)
        body = scene.build_body()
        scene.add_camera_and_light()
        info.update(limb_vertices=len(limb.data.vertices), body_vertices=len(body.data.vertices))

    with stage("check_mesh") as info:
        for obj in (limb, body):
            bpy.context.view_layer.objects.active = obj
            bpy.ops.tegument.check_mesh()
            info[obj.name] = json.loads(bpy.context.window_manager.tegument_check_result)

    with stage("pyramid_deform") as info:
        bpy.context.view_layer.objects.active = limb
        limb.tegument.cache_path = str(out / "Limb.pc2")
        bpy.ops.tegument.deform_add()
        limb.tegument.frame_start, limb.tegument.frame_end = 1, 24
        limb.tegument.closeness = 0.01
        limb.tegument.iterations = 60
        if bpy.ops.tegument.bake() != {"FINISHED"}:
            sys.exit("error: the Pyramid Deform bake failed")
        info.update(frames=24, ms_per_frame=round(limb.tegument.last_frame_ms, 2), cache=limb.tegument.cache_path,
                    warnings=limb.tegument.warnings)

    with stage("render") as info:
        render = bpy.context.scene.render
        render.engine = "CYCLES"
        bpy.context.scene.cycles.samples = 16
        bpy.context.scene.cycles.device = "CPU"
        render.resolution_x, render.resolution_y = 480, 320
        bpy.context.scene.frame_set(24)
        pictures = []
        for label, show in (("skinning", False), ("tegument", True)):
            limb.modifiers["Tegument"].show_render = show
            render.filepath = str(out / f"{label}_frame024.png")
            bpy.ops.render.render(write_still=True)
            pictures.append(render.filepath)
        limb.modifiers["Tegument"].show_render = True
        info["side_by_side"] = side_by_side(bpy, pictures, out / "pyramid_deform_before_after.png")

    blend = out / "demo.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    report["blend"] = str(blend)
    report["total_seconds"] = round(time.perf_counter() - started, 3)
    (out / "report.json").write_text(json.dumps(report, indent=2))
    shutil.rmtree(user, ignore_errors=True)

    print(json.dumps(report["stages"]["check_mesh"], indent=2))
    print(f"[demo] done in {report['total_seconds']:.1f} s; everything is in {out}:")
    for path in sorted(out.iterdir()):
        print(f"  {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
