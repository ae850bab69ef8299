"""The Tegument UV Warp shader node through the installed extension: bake, EXR sequence, Cycles render."""

from __future__ import annotations

import pathlib
import re
import signal

import bpy
import numpy as np
import pytest

GRID = 48  # subdivisions of the 2 × 2 plane
RES = 256  # warp grid
RADIUS = 0.15  # of the round feature, in UV units
RIGID_RADIUS = 1.3 * RADIUS
FRAMES = (1, 5)
SOLVER = {"iterations": 16, "orientation": 0.0, "smoothing": 0.0}


def texel_centres(n=RES):
    c = (np.arange(n) + 0.5) / n
    return np.meshgrid(c, c)  # u, v with row 0 = lowest v


def disc(radius, n=RES) -> np.ndarray:
    u, v = texel_centres(n)
    return (((u - 0.5) ** 2 + (v - 0.5) ** 2) < radius**2).astype(np.float32)


def float_image(name: str, grey: np.ndarray) -> bpy.types.Image:
    h, w = grey.shape
    image = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True, is_data=True)
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., :3] = grey[..., None]
    image.pixels.foreach_set(rgba.ravel())
    image.pack()  # survives save and reload
    return image


def squashed_plane() -> bpy.types.Object:
    """A 2 × 2 UV-mapped grid squashed to half its width (shape key 0 at frame 1, 1 from frame 3)."""
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=GRID, y_subdivisions=GRID, size=2)
    obj = bpy.context.active_object
    obj.name = "Skin"
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
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = FRAMES
    return obj


def warp_material(obj, *, through_node=True, show="texture"):
    """Material: Tegument UV Warp → feature texture → emission (or the warp's UV as the colour)."""
    material = bpy.data.materials.new("Skin")
    obj.data.materials.append(material)
    tree = material.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    emission = tree.nodes.new("ShaderNodeEmission")
    tree.links.new(emission.outputs[0], out.inputs["Surface"])
    node = tree.nodes.new("TegumentUVWarpNode")
    node.object = obj
    node.resolution = RES
    node.frame_start, node.frame_end = FRAMES
    for key, value in SOLVER.items():
        setattr(node, key, value)
    if show == "uv":
        tree.links.new(node.outputs["UV"], emission.inputs["Color"])
    else:
        feature = tree.nodes.new("ShaderNodeTexImage")
        feature.image = bpy.data.images.get("Feature") or float_image("Feature", disc(RADIUS))  # bright feature, dark skin and background
        feature.interpolation = "Linear"
        feature.extension = "EXTEND"
        if through_node:
            tree.links.new(node.outputs["UV"], feature.inputs["Vector"])
        tree.links.new(feature.outputs["Color"], emission.inputs["Color"])
    tree.nodes.active = node
    return material, node


def camera_and_cycles(resolution: int, samples: int) -> bpy.types.Scene:
    scene = bpy.context.scene
    data = bpy.data.cameras.new("Camera")
    data.type = "ORTHO"
    data.ortho_scale = 2.0
    camera = bpy.data.objects.new("Camera", data)
    camera.location = (0.0, 0.0, 5.0)
    scene.collection.objects.link(camera)
    scene.camera = camera
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.render.resolution_x = scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    return scene


def render(scene, frame: int, path: pathlib.Path) -> np.ndarray:
    """Renders one frame; returns RGB ``(h, w, 3)``, row 0 = the bottom of the picture (world −y)."""
    import tegument

    scene.frame_set(frame)
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    pixels, _ = tegument.read_exr(path)
    return pixels[..., :3]


def aspect_ratio(mask: np.ndarray) -> float:
    """Long over short axis of the feature from the second moments of its pixels."""
    rows, cols = np.nonzero(mask)
    assert len(rows) > 50, "the feature is not visible in the render"
    eigen = np.linalg.eigvalsh(np.cov(np.stack([cols, rows]).astype(np.float64)))
    return float(np.sqrt(eigen[1] / eigen[0]))


def mesh_inputs(obj):
    """The wheel's inputs, read independently of the add-on: the rest shape is Pyramid Deform's
    bind mesh where it has the mesh's vertices, else UV Warp's own tegument_rest attribute."""
    mesh = obj.data
    rest = np.empty(len(mesh.vertices) * 3, np.float32)
    bind = obj.tegument.bind_mesh
    if bind is not None and len(bind.vertices) == len(mesh.vertices):
        bind.vertices.foreach_get("co", rest)
    else:
        mesh.attributes["tegument_rest"].data.foreach_get("vector", rest)
    corners = np.array([loop.vertex_index for loop in mesh.loops], np.int32)
    sizes = np.array([p.loop_total for p in mesh.polygons], np.int32)
    uvs = np.array([d.uv[:] for d in mesh.uv_layers.active.data], np.float32)
    return rest.reshape(-1, 3), corners, sizes, uvs


def evaluated(obj, frame: int) -> np.ndarray:
    bpy.context.scene.frame_set(frame)
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    return np.array([v.co[:] for v in ev.data.vertices], np.float32)


@pytest.fixture
def saved(tmp_path):
    """A saved .blend, so the default `//tegument/warp/` directory resolves into tmp_path."""
    obj = squashed_plane()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "warp.blend"))
    return obj


def bind(material, node):
    assert bpy.ops.tegument.warp_bind(material=material.name, node=node.name) == {"FINISHED"}


def test_create_bake_save_reload_matches_the_wheel_and_plays_as_a_sequence(saved, tmp_path, capfd):
    import tegument

    obj = saved
    material, node = warp_material(obj, show="uv")
    group = node.node_tree
    assert group.name.startswith(".Tegument UV Warp") and node.inputs["UV"].name == "UV"
    assert not node.inputs["UV"].is_linked
    assert node.directory == "//tegument/warp/"
    # Before a bake the group passes the UV (here: the active UV map) through.
    assert not [n for n in group.nodes if n.bl_idname == "ShaderNodeTexImage"]
    node.rigidity_image = float_image("Rigidity", disc(RIGID_RADIUS))
    bind(material, node)
    assert bpy.ops.tegument.warp_bake(material="", node="") == {"FINISHED"}  # the active node
    out = capfd.readouterr().out
    assert "frame 5 (5/5)" in out and "rigid stretch" in out and "fold-overs 0" in out and "ms/frame" in out
    assert "→" in node.report

    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "warp.blend"))
    obj = bpy.data.objects["Skin"]
    node = bpy.data.materials["Skin"].node_tree.nodes["Tegument UV Warp"]
    assert node.bl_idname == "TegumentUVWarpNode" and node.baked_frames == 5

    files = sorted((tmp_path / "tegument" / "warp").iterdir())
    assert [f.name for f in files] == [f"Skin_Tegument_UV_Warp_1001_{f:04d}.exr" for f in range(1, 6)]

    rest, corners, sizes, uvs = mesh_inputs(obj)
    warp = tegument.UvWarp(rest, corners, sizes, uvs, disc(RIGID_RADIUS), warm_start=True, **SOLVER)
    expected = {}
    for frame in range(1, 6):
        expected[frame] = warp.solve(evaluated(obj, frame))
        data, meta = tegument.read_exr(files[frame - 1])
        np.testing.assert_allclose(data[..., :2], expected[frame], atol=1e-6)
        np.testing.assert_array_equal(data[..., 2], warp.validity())
        assert meta["iterations"] == "16"
    assert np.abs(expected[5] - expected[1]).max() > 0.05, "the squash must move the warp"

    # The inner tree samples the sequence: Non-Color, one frame per scene frame.
    texture = node.node_tree.nodes["Warp 1001"]
    image = texture.image
    assert image.source == "SEQUENCE" and image.colorspace_settings.name == "Non-Color"
    assert image.filepath == "//tegument/warp/Skin_Tegument_UV_Warp_1001_0001.exr"
    user = texture.image_user
    assert (user.frame_start, user.frame_duration, user.frame_offset) == (1, 5, 0)

    # Render the node's output UV as colour in Cycles at two frames; compare with the files.
    n = 24
    scene = camera_and_cycles(n, samples=1)
    scene.render.filter_size = 0.01  # sample at pixel centres
    centres = -1 + (np.arange(n) + 0.5) * 2 / n
    x, y = np.meshgrid(centres, centres)
    for frame in (2, 5):
        pixels = render(scene, frame, tmp_path / f"uv_{frame}.exr")
        width = 1 - 0.5 * obj.data.shape_keys.key_blocks["Squash"].value  # of the plane at this frame
        inside = np.abs(x) < width - 0.1
        u = (x / width + 1) / 2
        v = (y + 1) / 2
        want = sample(tegument.read_exr(files[frame - 1])[0], u, v)
        got = pixels[..., :2]
        assert np.abs(got[inside] - want[inside]).max() < 2e-3, frame
        for other in {1, 2, 5} - {frame}:
            o = sample(tegument.read_exr(files[other - 1])[0], u, v)
            assert np.abs(got[inside] - o[inside]).max() > 5e-3, f"frame {other} was sampled at frame {frame}"

    # A new bake replaces what renders (no stale image cache): a smaller rigid disc warps differently.
    first = got
    node.rigidity_image = float_image("Smaller", disc(0.6 * RIGID_RADIUS))
    assert bpy.ops.tegument.warp_bake(material="Skin", node=node.name) == {"FINISHED"}
    got = render(scene, 5, tmp_path / "uv_5_again.exr")[..., :2]
    want = sample(tegument.read_exr(files[4])[0], u, v)
    assert np.abs(got[inside] - want[inside]).max() < 2e-3
    assert np.abs(got[inside] - first[inside]).max() > 5e-3


def sample(data: np.ndarray, u: np.ndarray, v: np.ndarray, tile_u: int = 0) -> np.ndarray:
    """What the inner tree computes: bilinear (clamped) redirection and validity, mixed with the UV.

    ``u``, ``v`` are within the tile; the redirection in ``data`` is absolute (tile offset included).
    """
    n = data.shape[0]
    fx = np.clip(u * n - 0.5, 0, n - 1)
    fy = np.clip(v * n - 0.5, 0, n - 1)
    x0 = np.minimum(np.floor(fx).astype(int), n - 2)
    y0 = np.minimum(np.floor(fy).astype(int), n - 2)
    tx, ty = (fx - x0)[..., None], (fy - y0)[..., None]
    c = ((data[y0, x0] * (1 - tx) + data[y0, x0 + 1] * tx) * (1 - ty)
         + (data[y0 + 1, x0] * (1 - tx) + data[y0 + 1, x0 + 1] * tx) * ty)
    uv = np.stack([u + tile_u, v], -1)
    return uv + c[..., 2:3] * (c[..., :2] - uv)


def feature_aspect(tmp_path, scene, name: str) -> float:
    pixels = render(scene, FRAMES[1], tmp_path / f"{name}.exr")
    return aspect_ratio(pixels[..., 0] > 0.5)


def render_setup(obj, material, node):
    bind(material, node)
    scene = camera_and_cycles(128, samples=4)
    return scene


def test_cycles_render_keeps_the_rigid_feature_round(saved, tmp_path):
    obj = saved
    material, node = warp_material(obj)
    node.rigidity_image = float_image("Rigidity", disc(RIGID_RADIUS))
    scene = render_setup(obj, material, node)
    # Not baked yet: the node passes the UV through and the feature squashes with the surface.
    before = feature_aspect(tmp_path, scene, "before")
    assert 1.8 < before < 2.2, before
    assert bpy.ops.tegument.warp_bake(material=material.name, node=node.name) == {"FINISHED"}
    after = feature_aspect(tmp_path, scene, "after")
    print(f"feature aspect ratio: {before:.3f} before the bake, {after:.3f} after")
    assert after < 1.1, f"aspect ratio {after:.3f} with the node (without: {before:.3f})"
    # And the same material without the node squashes it 2:1.
    tree = material.node_tree
    feature = tree.nodes["Image Texture"]
    tree.links.remove(feature.inputs["Vector"].links[0])
    without = feature_aspect(tmp_path, scene, "without")
    assert 1.8 < without < 2.2, without


def test_rigidity_from_a_vertex_group_matches_the_image(saved, tmp_path, capfd):
    obj = saved
    material, node = warp_material(obj)
    group = obj.vertex_groups.new(name="Rigid")
    uv = np.array([d.uv[:] for d in obj.data.uv_layers.active.data], np.float32)
    corner_vert = np.array([loop.vertex_index for loop in obj.data.loops])
    vertex_uv = np.zeros((len(obj.data.vertices), 2), np.float32)
    vertex_uv[corner_vert] = uv
    inside = np.nonzero(np.linalg.norm(vertex_uv - 0.5, axis=1) < RIGID_RADIUS)[0]
    group.add([int(i) for i in inside], 1.0, "REPLACE")
    node.rigidity_group = "Rigid"
    scene = render_setup(obj, material, node)
    assert bpy.ops.tegument.warp_bake(material=material.name, node=node.name) == {"FINISHED"}
    from_group = feature_aspect(tmp_path, scene, "group")
    group_report = node.report
    node.rigidity_group = ""
    node.rigidity_image = float_image("Rigidity", disc(RIGID_RADIUS))
    node.write_heatmap = True
    assert bpy.ops.tegument.warp_bake(material=material.name, node=node.name) == {"FINISHED"}
    # The heat map of the last frame agrees with the wheel's figure for the rigid texels.
    import tegument

    heat, meta = tegument.read_exr(tmp_path / "tegument" / "warp" / "Skin_Tegument_UV_Warp_1001_stretch.exr")
    assert meta["frame"] == "5" and heat.shape == (RES, RES, 1) and np.isfinite(heat).all()
    rigid = disc(RIGID_RADIUS) > 0.5
    last_frame = re.findall(r"frame 5 \(5/5\).*?rigid stretch [\d.]+ → ([\d.]+)", capfd.readouterr().out)
    assert abs(heat[..., 0][rigid].mean() - float(last_frame[-1])) < 0.25 * float(last_frame[-1]) + 0.005
    assert heat[..., 0][~rigid].mean() > 3 * heat[..., 0][rigid].mean()  # the skin took the squash
    from_image = feature_aspect(tmp_path, scene, "image")
    print(f"feature aspect ratio: {from_group:.3f} from the vertex group, {from_image:.3f} from the image")
    assert from_group < 1.1 and from_image < 1.1, (from_group, from_image)
    assert abs(from_group - from_image) < 0.05, (from_group, from_image)
    # The bake reports say the same: rigid stretch cut by a similar factor, no fold-overs.
    print(f"bake reports: group: {group_report}; image: {node.report}")
    assert "fold-overs 0" in group_report and "fold-overs 0" in node.report
    assert group_report != node.report, "the vertex group was not used"
    for report in (group_report, node.report):
        before, after = (float(x) for x in re.search(r"rigid stretch ([\d.]+) → ([\d.]+)", report).groups())
        assert after * 5 < before, report


def assert_refused(match: str, **kwargs):
    with pytest.raises(RuntimeError, match=match):
        bpy.ops.tegument.warp_bake(**kwargs)


def test_bad_input_is_reported_and_writes_nothing(saved, tmp_path):
    obj = saved
    material, node = warp_material(obj)
    names = {"material": material.name, "node": node.name}
    out_dir = tmp_path / "tegument" / "warp"

    assert_refused("no rigidity: set a Rigidity Image or a Rigidity Group", **names)
    node.rigidity_image = float_image("Rigidity", disc(RIGID_RADIUS))
    assert_refused(r"Skin has no bind \(rest shape\): press Bind", **names)
    bind(material, node)
    node.resolution = 300
    assert_refused(r"resolution 300 is not a power of two between 8 and 16384 \(try 256\)", **names)
    node.resolution = RES
    node.frame_end = 0
    assert_refused(r"the frame range 1–0 is empty", **names)
    node.frame_end = FRAMES[1]

    missing = bpy.data.images.new("Scales", 8, 8)
    missing.filepath = str(tmp_path / "scales.png")
    missing.source = "FILE"
    node.rigidity_image = missing
    assert_refused(r'rigidity image "Scales" has no pixels: its file .*scales.png is missing', **names)
    node.rigidity_image = bpy.data.images["Rigidity"]
    node.rigidity_group = ""

    node.mask_image = missing
    assert_refused(r'mask image "Scales" has no pixels', **names)
    node.mask_image = None

    node.rigidity_image = None
    node.rigidity_group = "Nope"
    assert_refused(r'Skin has no vertex group "Nope"', **names)
    node.rigidity_image = bpy.data.images["Rigidity"]

    node.uv_map = "Other"
    assert_refused(r'Skin has no UV map named "Other"', **names)
    node.uv_map = ""
    obj.data.uv_layers.remove(obj.data.uv_layers[0])
    assert_refused(r"Skin has no UV map: add one", **names)

    assert_refused(r'no Tegument UV Warp node named "Nope"', material=material.name, node="Nope")
    assert not out_dir.exists(), f"a refused bake wrote {list(out_dir.iterdir())}"
    assert [p.name for p in tmp_path.iterdir()] == ["warp.blend"]


def test_command_line_bake_and_refusal(saved, tmp_path, capfd):
    from bl_ext.user_default.tegument import cli

    obj = saved
    material, node = warp_material(obj)
    assert cli.main(["warp-bake", "--material", "Nope"]) == 2
    assert "no material named Nope" in capfd.readouterr().err
    assert cli.main(["warp-bake", "--material", "Skin", "--node", "Nope"]) == 2
    assert "error: material Skin has no Tegument UV Warp node named Nope" in capfd.readouterr().err
    node.rigidity_image = float_image("Rigidity", disc(RIGID_RADIUS))
    assert cli.main(["warp-bake", "--frames", "1-2"]) == 1  # not bound: refused, nothing written
    assert "Skin has no bind" in capfd.readouterr().err
    assert not (tmp_path / "tegument").exists()
    bind(material, node)
    assert cli.main(["warp-bake", "--material", "Skin", "--node", node.name, "--frames", "2-3", "--save"]) == 0
    out = capfd.readouterr().out
    assert "frame 2 (1/2)" in out and "frame 3 (2/2)" in out
    names = sorted(p.name for p in (tmp_path / "tegument" / "warp").iterdir())
    assert names == ["Skin_Tegument_UV_Warp_1001_0002.exr", "Skin_Tegument_UV_Warp_1001_0003.exr"]
    # The existing Pyramid Deform command is still there.
    assert cli.main(["bake"]) == 2
    assert "no object has Pyramid Deform" in capfd.readouterr().err
    # --save stored the node's new state.
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "warp.blend"))
    node = bpy.data.materials["Skin"].node_tree.nodes["Tegument UV Warp"]
    assert (node.baked_start, node.baked_frames) == (2, 2)


def warp_groups() -> list[str]:
    return sorted(g.name for g in bpy.data.node_groups if g.name.startswith(".Tegument UV Warp"))


def test_copy_and_delete_leave_no_orphan_group(saved, tmp_path):
    obj = saved
    material, node = warp_material(obj, show="uv")
    node.rigidity_image = float_image("Rigidity", disc(RIGID_RADIUS))
    bind(material, node)
    assert bpy.ops.tegument.warp_bake(material=material.name, node=node.name) == {"FINISHED"}
    assert len(warp_groups()) == 1

    copy = material.copy()  # copies the node: the copy gets its own inner group
    copied = copy.node_tree.nodes["Tegument UV Warp"]
    assert copied.node_tree != node.node_tree and len(warp_groups()) == 2
    assert copied.node_tree.nodes["Warp 1001"].image == node.node_tree.nodes["Warp 1001"].image

    # Re-baking the copy under its own name does not touch the original's sequence.
    copy.node_tree.nodes.active = copied
    assert bpy.ops.tegument.warp_bake(material=copy.name, node=copied.name) == {"FINISHED"}
    assert copied.node_tree.nodes["Warp 1001"].image != node.node_tree.nodes["Warp 1001"].image
    assert node.node_tree.nodes["Warp 1001"].image.filepath.endswith("Skin_Tegument_UV_Warp_1001_0001.exr")

    copy.node_tree.nodes.remove(copied)  # deleting the node frees its group at once
    assert len(warp_groups()) == 1
    material.node_tree.nodes.new("TegumentUVWarpNode")
    assert len(warp_groups()) == 2
    bpy.data.materials.remove(material)  # a whole material: no node callback runs
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "warp.blend"))
    assert warp_groups() == [], "an inner group outlived its node"


def rigid_group(obj, name="Rigid"):
    """Vertex group: weight 1 within RIGID_RADIUS of the plane's centre in the rest UVs."""
    group = obj.vertex_groups.new(name=name)
    co = np.array([v.co[:] for v in obj.data.vertices], np.float32)
    inside = np.nonzero(np.linalg.norm(co[:, :2] / 2, axis=1) < RIGID_RADIUS)[0]  # plane 2 wide = UV 1 wide
    group.add([int(i) for i in inside], 1.0, "REPLACE")
    return name


def test_udim_tiles_get_one_sequence_each_and_the_tree_picks_the_tile(saved, tmp_path):
    import tegument

    obj = saved
    # The right half of the plane moves to tile 1002 (u + 1): two charts, two tiles.
    layer = obj.data.uv_layers.active
    uv = np.empty(len(layer.data) * 2, np.float32)
    layer.uv.foreach_get("vector", uv)
    uv = uv.reshape(-1, 2)
    sizes = np.array([p.loop_total for p in obj.data.polygons])
    owner = np.repeat(np.arange(len(sizes)), sizes)
    centre_u = np.bincount(owner, uv[:, 0]) / sizes
    uv[centre_u[owner] > 0.5, 0] += 1.0
    layer.uv.foreach_set("vector", uv.ravel())
    material, node = warp_material(obj, show="uv")
    node.rigidity_group = rigid_group(obj)
    bind(material, node)
    assert bpy.ops.tegument.warp_bake(material=material.name, node=node.name) == {"FINISHED"}
    assert "fold-overs 0" in node.report
    out = tmp_path / "tegument" / "warp"
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(f"Skin_Tegument_UV_Warp_{t}_{f:04d}.exr" for t in (1001, 1002) for f in range(1, 6))
    assert sorted(n.name for n in node.node_tree.nodes if n.bl_idname == "ShaderNodeTexImage") == ["Warp 1001", "Warp 1002"]
    right = tegument.read_exr(out / "Skin_Tegument_UV_Warp_1002_0005.exr")[0]
    assert right[..., 0][right[..., 2] > 0].min() >= 1.0  # absolute UVs of tile 1002

    n = 24
    scene = camera_and_cycles(n, samples=1)
    scene.render.filter_size = 0.01
    centres = -1 + (np.arange(n) + 0.5) * 2 / n
    x, y = np.meshgrid(centres, centres)
    pixels = render(scene, 5, tmp_path / "udim.exr")
    width = 0.5
    u = (x / width + 1) / 2
    v = (y + 1) / 2
    left = (x < -0.05) & (x > -width + 0.1)
    right_px = (x > 0.05) & (x < width - 0.1)
    want_left = sample(tegument.read_exr(out / "Skin_Tegument_UV_Warp_1001_0005.exr")[0], u, v)
    want_right = sample(right, u, v, tile_u=1)
    assert np.abs(pixels[..., :2][left] - want_left[left]).max() < 2e-3
    assert np.abs(pixels[..., :2][right_px] - want_right[right_px]).max() < 2e-3
    assert pixels[..., 0][right_px].min() > 1.0 and pixels[..., 0][left].max() < 1.0


def staged_leftovers(directory: pathlib.Path) -> list[str]:
    return [p.name for p in directory.iterdir() if p.name.startswith(".tegument-warp-")]


def test_failing_bake_keeps_the_previous_sequence_and_cancel_keeps_frames_done(saved, tmp_path):
    obj = saved
    material, node = warp_material(obj, show="uv")
    node.rigidity_image = float_image("Rigidity", disc(RIGID_RADIUS))
    bind(material, node)
    names = {"material": material.name, "node": node.name}
    assert bpy.ops.tegument.warp_bake(**names) == {"FINISHED"}
    out = tmp_path / "tegument" / "warp"
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert len(before) == 5

    # From frame 3 on a Mirror modifier doubles the vertices: the bake stops there.
    mirror = obj.modifiers.new("Mirror", "MIRROR")
    mirror.use_mirror_merge = False
    for frame, shown in ((1, False), (3, True)):
        mirror.show_viewport = shown
        mirror.keyframe_insert("show_viewport", frame=frame)
    node.iterations = 8
    with pytest.raises(RuntimeError, match=r"at frame 3 Skin evaluates to \d+ vertices but was bound with 2401"):
        bpy.ops.tegument.warp_bake(**names)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before, "a failed bake changed the sequence"
    assert staged_leftovers(out) == []
    assert node.baked_frames == 5
    obj.modifiers.remove(mirror)

    # Ctrl-C after the second frame: the two frames done replace the sequence, the rest is gone.
    seen = []

    def interrupt_after_two(scene, depsgraph=None):
        seen.append(scene.frame_current)
        if len(seen) == 2:
            signal.raise_signal(signal.SIGINT)

    bpy.app.handlers.frame_change_post.append(interrupt_after_two)
    try:
        assert bpy.ops.tegument.warp_bake(**names) == {"CANCELLED"}
    finally:
        bpy.app.handlers.frame_change_post.remove(interrupt_after_two)
    assert sorted(p.name for p in out.iterdir()) == [f"Skin_Tegument_UV_Warp_1001_{f:04d}.exr" for f in (1, 2)]
    assert (node.baked_start, node.baked_frames) == (1, 2)
    assert node.node_tree.nodes["Warp 1001"].image_user.frame_duration == 2


class RecordingLayout:
    """Stands in for a UILayout (none exists without a window): records what the node draws."""

    def __init__(self, log):
        self.log = log

    def __getattr__(self, name):
        def call(*args, **kwargs):
            self.log.append((name, args, kwargs))
            return RecordingLayout(self.log)

        return call


def test_node_is_in_the_add_menu_and_draws_its_settings(saved):
    obj = saved
    menu = bpy.types.NODE_MT_category_shader_vector
    assert any(f.__module__.endswith("warp.node") for f in menu._dyn_ui_initialize())
    _, node = warp_material(obj)
    log = []
    from bl_ext.user_default.tegument.ui import warp_node  # what draw_buttons_ext calls

    warp_node.draw(node, bpy.context, RecordingLayout(log), extended=True)
    drawn = {args[1] for name, args, _ in log if name in ("prop", "prop_search", "template_ID")}
    expected = {"object", "uv_map", "rigidity_image", "rigidity_group", "mask_image", "resolution", "iterations",
                "orientation", "smoothing", "frame_start", "frame_end", "directory", "write_heatmap"}
    assert drawn == expected
    assert all(name in node.bl_rna.properties for name in drawn)
    operators = [args[0] for name, args, _ in log if name == "operator"]
    assert operators == ["tegument.warp_bind", "tegument.warp_bake", "tegument.warp_attach"]
    assert any(name == "label" and "not bound" in kwargs.get("text", "") for name, _, kwargs in log)


def test_a_rigidity_image_of_another_size_or_storage_is_resampled_to_the_grid(saved, tmp_path):
    """Images need not match the warp resolution: a half-size 8-bit image of the
    same disc gives the same kind of result as the full-size float one."""
    obj = saved
    material, node = warp_material(obj)
    bind(material, node)
    reports = {}
    full = float_image("Full", disc(RIGID_RADIUS))
    half = bpy.data.images.new("Half", RES // 2, RES // 2, alpha=False, float_buffer=False)
    rgba = np.ones((RES // 2, RES // 2, 4), np.float32)
    rgba[..., :3] = disc(RIGID_RADIUS, RES // 2)[..., None]
    half.pixels.foreach_set(rgba.ravel())
    for image in (full, half):
        node.rigidity_image = image
        assert bpy.ops.tegument.warp_bake(material=material.name, node=node.name) == {"FINISHED"}
        reports[image.name] = node.report
    stretch = {
        name: [float(x) for x in re.search(r"rigid stretch ([\d.]+) → ([\d.]+)", report).groups()]
        for name, report in reports.items()
    }
    assert all("fold-overs 0" in report for report in reports.values()), reports
    (full_before, full_after), (half_before, half_after) = stretch["Full"], stretch["Half"]
    assert half_after * 5 < half_before, reports
    assert abs(half_after - full_after) < 0.5 * full_after + 0.01, reports


def not_bound_hint(node) -> bool:
    from bl_ext.user_default.tegument.ui import warp_node

    log = []
    warp_node.draw(node, bpy.context, RecordingLayout(log))
    return any(name == "label" and "not bound" in kwargs.get("text", "") for name, _, kwargs in log)


def test_pyramid_deforms_bind_mesh_is_the_warps_rest_shape(saved, tmp_path):
    """With Pyramid Deform bound on the mesh's own vertices, UV Warp reads that bind mesh (the node
    is bound, the mesh gets no attribute) and its Bind renews it; without one, UV Warp's Bind
    stores its own tegument_rest attribute."""
    import tegument

    obj = saved
    material, node = warp_material(obj)
    node.rigidity_image = float_image("Rigidity", disc(RIGID_RADIUS))
    attributes = sorted(a.name for a in obj.data.attributes)
    assert not_bound_hint(node)

    bpy.context.scene.frame_set(1)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.tegument.deform_add() == {"FINISHED"}
    bound = obj.tegument.bind_mesh
    assert bound is not None and len(bound.vertices) == len(obj.data.vertices)
    assert not not_bound_hint(node)
    assert bpy.ops.tegument.warp_bake(material=material.name, node=node.name) == {"FINISHED"}
    assert sorted(a.name for a in obj.data.attributes) == attributes, "the warp's bind is the bind mesh"

    # The node's Bind, squashed (Bind Pose: Evaluated), renews the same bind mesh, not the mesh.
    obj.tegument.bind_source = "EVALUATED"
    bpy.context.scene.frame_set(3)
    bind(material, node)
    assert obj.tegument.bind_mesh == bound and sorted(a.name for a in obj.data.attributes) == attributes
    rest = mesh_inputs(obj)[0]
    np.testing.assert_allclose(rest, evaluated(obj, 3), atol=1e-6)
    assert np.ptp(rest[:, 0]) == pytest.approx(1.0, abs=1e-5), "the squashed pose is the rest shape now"
    assert obj.tegument.bound_vertices == obj.tegument.source_vertices == len(obj.data.vertices)
    assert bpy.ops.tegument.bake() == {"FINISHED"}, "Pyramid Deform bakes from the renewed bind"

    # Without Pyramid Deform, the node's Bind stores UV Warp's own attribute.
    assert bpy.ops.tegument.deform_remove() == {"FINISHED"}
    assert obj.tegument.bind_mesh is None and not_bound_hint(node)
    bind(material, node)
    assert "tegument_rest" in obj.data.attributes and not not_bound_hint(node)
    np.testing.assert_allclose(mesh_inputs(obj)[0], rest, atol=1e-6)
