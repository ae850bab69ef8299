"""Renders docs/images/uv-warp-before-after.png: a squashed plane of round scales, without and with the node.

Installs the built extension into an isolated Blender user folder (as the tests do), builds the scene,
bakes the Tegument UV Warp node and renders three Cycles frames side by side: the rest pose, the squash
without the node, the squash through the node. Usage::

    TEGUMENT_EXTENSION_ZIP=dist/tegument-0.1.0-linux_x64.zip .venv/bin/python tools/uv_warp_picture.py
"""

from __future__ import annotations

import argparse
import os
import pathlib
import shutil
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
N = 256  # texture and warp grid


def scales_texture(np, n: int):
    """Round scales, two columns by three rows: (pattern, rigidity), row 0 = bottom.

    Squashing the plane to half its width leaves half the width in rest units: the rigid
    parts across (2 × 0.16) must fit in it with room for the skin between them.
    """
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c)
    pattern = np.full((n, n), 0.15, np.float32)
    rigid = np.zeros((n, n), np.float32)
    for cu in (0.32, 0.68):
        for cv in (0.2, 0.5, 0.8):
            d = np.hypot(u - cu, v - cv)
            pattern[d < 0.065] = 0.9
            pattern[(d < 0.065) & (np.abs(u - cu) < 0.012)] = 0.35  # a stripe shows rotation and shear
            rigid[d < 0.08] = 1.0
    return pattern, rigid


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--zip", type=pathlib.Path, default=os.environ.get("TEGUMENT_EXTENSION_ZIP"))
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "docs" / "images" / "uv-warp-before-after.png")
    args = parser.parse_args()
    if not args.zip or not args.zip.is_file():
        sys.exit("error: no extension zip: run `make extension` and pass --zip or TEGUMENT_EXTENSION_ZIP")
    user = tempfile.mkdtemp(prefix="tegument-picture-user-")
    work = pathlib.Path(tempfile.mkdtemp(prefix="tegument-picture-"))
    os.environ["BLENDER_USER_RESOURCES"] = user  # before bpy starts: the user's own Blender stays untouched
    try:
        import bpy
        import numpy as np

        sys.path.insert(0, str(ROOT / "demo"))
        import extension

        addon = extension.install(args.zip, user)
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.preferences.addon_enable(module=addon)
        bpy.ops.wm.save_as_mainfile(filepath=str(work / "picture.blend"))

        bpy.ops.mesh.primitive_grid_add(x_subdivisions=64, y_subdivisions=64, size=2)
        obj = bpy.context.active_object
        obj.shape_key_add(name="Basis")
        squash = obj.shape_key_add(name="Squash")
        co = np.empty(len(squash.data) * 3, np.float32)
        squash.data.foreach_get("co", co)
        co = co.reshape(-1, 3)
        co[:, 0] *= 0.5
        squash.data.foreach_set("co", co.ravel())
        for frame, value in ((1, 0.0), (3, 1.0)):
            squash.value = value
            squash.keyframe_insert("value", frame=frame)

        def image(name, grey):
            img = bpy.data.images.new(name, N, N, float_buffer=True, is_data=True)
            rgba = np.ones((N, N, 4), np.float32)
            rgba[..., :3] = grey[..., None]
            img.pixels.foreach_set(rgba.ravel())
            return img

        pattern, rigid = scales_texture(np, N)
        material = bpy.data.materials.new("Scales")
        obj.data.materials.append(material)
        tree = material.node_tree
        tree.nodes.clear()
        out = tree.nodes.new("ShaderNodeOutputMaterial")
        emission = tree.nodes.new("ShaderNodeEmission")
        texture = tree.nodes.new("ShaderNodeTexImage")
        texture.image = image("Pattern", pattern)
        warp = tree.nodes.new("TegumentUVWarpNode")
        warp.object = obj
        warp.rigidity_image = image("Rigidity", rigid)
        warp.resolution = N
        warp.iterations, warp.orientation, warp.smoothing = 16, 0.0, 0.0
        warp.frame_start, warp.frame_end = 1, 5
        tree.links.new(texture.outputs["Color"], emission.inputs["Color"])
        tree.links.new(emission.outputs[0], out.inputs["Surface"])

        scene = bpy.context.scene
        camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
        camera.data.type, camera.data.ortho_scale = "ORTHO", 2.1
        camera.location = (0, 0, 5)
        scene.collection.objects.link(camera)
        scene.camera = camera
        scene.render.engine = "CYCLES"
        scene.cycles.samples = 16
        scene.cycles.use_denoising = False
        scene.render.resolution_x, scene.render.resolution_y = 320, 320
        scene.view_settings.view_transform = "Standard"

        assert bpy.ops.tegument.warp_bind(material=material.name, node=warp.name) == {"FINISHED"}
        assert bpy.ops.tegument.warp_bake(material=material.name, node=warp.name) == {"FINISHED"}
        renders = []
        for name, frame, linked in (("rest", 1, False), ("squashed", 5, False), ("warped", 5, True)):
            for link in list(texture.inputs["Vector"].links):
                tree.links.remove(link)
            if linked:
                tree.links.new(warp.outputs["UV"], texture.inputs["Vector"])
            scene.frame_set(frame)
            scene.render.filepath = str(work / f"{name}.png")
            bpy.ops.render.render(write_still=True)
            renders.append(work / f"{name}.png")

        loaded = [bpy.data.images.load(str(p)) for p in renders]
        w, h = loaded[0].size
        pixels = [np.array(img.pixels[:], np.float32).reshape(h, w, 4) for img in loaded]
        gap = np.ones((h, 8, 4), np.float32)
        joined = np.concatenate([pixels[0], gap, pixels[1], gap, pixels[2]], axis=1)
        result = bpy.data.images.new("picture", joined.shape[1], h, alpha=True)
        result.pixels.foreach_set(joined.ravel())
        args.out.parent.mkdir(parents=True, exist_ok=True)
        result.filepath_raw = str(args.out)
        result.file_format = "PNG"
        result.save()
        from docs_pictures import shrink  # a palette PNG: docs/images stays small

        shrink(args.out, args.out, 128)
        print(f"wrote {args.out}: rest | squashed without the node | squashed through the node ({warp.report})")
    finally:
        shutil.rmtree(user, ignore_errors=True)
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
