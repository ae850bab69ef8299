"""The demo's procedural scene and picture helpers (``demo/scene.py``, ``demo/pictures.py``).

`make demo` runs them end to end; these tests pin the properties its figures rely on: UVs laid
out like the faces with one scale in both directions, a rigidity image that covers every scale,
a body placed where the bend drives the forearm into it, and pixel helpers that do what they say.
"""

from __future__ import annotations

import math
import pathlib
import sys

import bpy
import numpy as np
import pytest

import flesh
import pictures
import scene as demo_scene

RADIUS, LENGTH = 0.25, 2.0


def triangle_uvs_and_positions(mesh):
    mesh.calc_loop_triangles()
    loops = np.array([t.loops[:] for t in mesh.loop_triangles])
    uv = np.array([d.uv[:] for d in mesh.uv_layers["UVMap"].data])[loops]
    corner_vertex = np.array([loop.vertex_index for loop in mesh.loops])
    co = np.array([v.co[:] for v in mesh.vertices])[corner_vertex[loops]]
    return uv, co


def test_tube_uvs_are_counter_clockwise_in_one_tile_and_keep_the_rest_scale():
    mesh = demo_scene.tube_mesh("Tube", 24, 16, RADIUS, LENGTH)
    uv, co = triangle_uvs_and_positions(mesh)
    assert uv.min() > 0 and uv.max() < 1, "the UVs must stay inside tile 1001"
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    area_uv = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert (area_uv > 0).all(), "every triangle must be counter-clockwise in UV, as its face is seen from outside"
    # Faces point outwards: the normal of each side triangle points away from the tube's axis.
    normal = np.cross(co[:, 1] - co[:, 0], co[:, 2] - co[:, 0])
    centre = co.mean(axis=1)
    side = np.abs(centre[:, 0]) < LENGTH / 2 - 1e-6
    radial = centre[side] * [0, 1, 1]
    assert ((normal[side] * radial).sum(axis=1) > 0).all()
    # One scale in both directions: UV area over rest area is the square of the UV scale.
    area_3d = 0.5 * np.linalg.norm(normal, axis=1)
    s = demo_scene.tube_uv_scale(RADIUS, LENGTH)
    np.testing.assert_allclose(area_uv[side] / area_3d[side], s * s, rtol=0.05)


def test_scale_pattern_rigidity_covers_every_scale_and_no_scale_crosses_the_seam():
    size = 512
    colour, rigidity = demo_scene.scale_pattern(size, RADIUS, LENGTH)
    assert colour.shape == (size, size, 4) and rigidity.shape == (size, size)
    skin = np.all(np.isclose(colour[..., :3], (0.80, 0.58, 0.46)), axis=2)
    scales = ~skin
    assert scales.any()
    assert (rigidity[scales] == 1).all(), "every scale texel must be rigid"
    assert 0.05 < rigidity.mean() < 0.5, "the skin between the scales must be able to take the stretch"
    side = demo_scene.tube_side_chart(size, RADIUS, LENGTH)
    assert not (rigidity.astype(bool) & ~side).any(), "rigidity only on the side chart"
    columns = np.flatnonzero(side.any(axis=0))
    for column in (columns[0], columns[-1]):  # the two sides of the seam
        assert not scales[:, column].any(), "a scale is cut by the seam"


def test_the_body_sits_where_the_bend_presses_the_forearm_into_it():
    angle, along, body, depth = 80.0, 0.8, 0.45, 0.15
    centre = np.array(demo_scene.pressed_body_centre(angle, along, body, RADIUS, depth))
    a = math.radians(angle)
    axis = np.array([math.cos(a), math.sin(a), 0.0])
    # Closest point of the forearm's axis to the centre is at `along`, at distance body + limb − depth.
    assert np.dot(centre, axis) == pytest.approx(along)
    assert np.linalg.norm(centre - along * axis) == pytest.approx(body + RADIUS - depth)
    # Straight (frame 1) the forearm lies along +X: clear of the body.
    assert abs(centre[1]) - body - RADIUS > 0
    contact = np.array(demo_scene.pressed_contact_point(angle, along, centre, body))
    assert np.linalg.norm(contact - centre) == pytest.approx(body)
    assert np.linalg.norm(contact - along * axis) == pytest.approx(RADIUS - depth)


def test_limb_with_body_collider_and_materials():
    limb, rig = demo_scene.build_limb(segments=12, rings=8)
    body = demo_scene.build_body(location=(0.0, 2.0, 0.0), radius=0.5)
    collection = demo_scene.make_collider(body, thickness=0.02, friction=0.4)
    assert list(collection.objects) == [body] and collection.name in bpy.context.scene.collection.children
    assert body.tegument_collider.thickness == pytest.approx(0.02)
    assert body.tegument_collider.friction == pytest.approx(0.4)
    colour, _ = demo_scene.scale_pattern(64, 0.25, 2.0)
    material, texture = demo_scene.skin_material(limb, demo_scene.image_from_pixels("Scales", colour, is_data=False))
    assert texture.inputs["Vector"].links[0].from_node.uv_map == "UVMap"
    assert texture.image.packed_file is not None, "the generated image must be saved inside the .blend"
    clay = demo_scene.body_material(body)
    demo_scene.set_alpha(clay, 0.25)
    assert clay.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value == pytest.approx(0.25)


def test_plane_section_of_a_sphere_is_its_great_circle():
    # The compliance picture draws the arm and torso as these sections: they must lie on the outline.
    bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=0.3, location=(0.1, 0.0, -0.2))
    sphere = bpy.context.object
    positions, triangles = flesh.world_mesh(sphere, 1)
    segments = flesh.plane_section(positions, triangles, y=0.0)
    assert segments.shape[1:] == (2, 2) and len(segments) >= 32
    radius = np.linalg.norm(segments.reshape(-1, 2) - (0.1, -0.2), axis=1)
    assert radius.max() <= 0.3 + 1e-5 and radius.min() > 0.29  # chords of the faceted sphere, near its circle
    assert len(flesh.plane_section(positions, triangles, y=0.5)) == 0


def rgba(height, width, value):
    return np.full((height, width, 4), value, np.float32)


def test_join_side_by_side_puts_an_opaque_gap_between_pictures():
    joined = pictures.join_side_by_side([rgba(3, 2, 0.2), rgba(3, 5, 0.7)], gap=2, gap_value=1.0)
    assert joined.shape == (3, 9, 4)
    assert (joined[:, :2, 0] == np.float32(0.2)).all() and (joined[:, 2:4] == 1.0).all()
    assert (joined[:, 4:, 0] == np.float32(0.7)).all()
    with pytest.raises(ValueError, match="height 3"):
        pictures.join_side_by_side([rgba(3, 2, 0), rgba(4, 2, 0)])


def test_heat_colours_run_from_black_to_pale_yellow_and_mark_what_is_outside():
    values = np.array([[0.0, 0.25, 0.5, 2.0]], np.float32)
    valid = np.array([[True, True, True, False]])
    out = pictures.heat_colours(values, top=0.5, valid=valid, background=(0.1, 0.2, 0.3))
    assert out.shape == (1, 4, 4) and (out[..., 3] == 1).all()
    assert out[0, 0, :3].max() < 0.02  # 0: near black
    np.testing.assert_allclose(out[0, 2, :3], (0.988, 0.998, 0.645), atol=1e-6)  # top: pale yellow
    assert 0.02 < out[0, 1, :3].mean() < out[0, 2, :3].mean()
    np.testing.assert_allclose(out[0, 3, :3], (0.1, 0.2, 0.3))
    with pytest.raises(ValueError):
        pictures.heat_colours(values, top=0.0)


def test_crop_and_downscale():
    mask = np.zeros((10, 12), bool)
    mask[3:5, 4:9] = True
    rows, cols = pictures.crop_to(mask, mask, margin=1)
    assert (rows, cols) == (slice(2, 6), slice(3, 10))
    assert pictures.crop_to(mask, np.zeros_like(mask)) == (slice(0, 10), slice(0, 12))
    picture = np.arange(6 * 8 * 4, dtype=np.float32).reshape(6, 8, 4)
    window = pictures.crop_around(picture, (7.5, 0.0), 4, 2)  # pushed back inside the picture
    np.testing.assert_array_equal(window, picture[0:2, 4:8])
    with pytest.raises(ValueError):
        pictures.crop_around(picture, (0, 0), 9, 2)
    small = pictures.downscale(picture, 2)
    assert small.shape == (3, 4, 4)
    np.testing.assert_allclose(small[0, 0], picture[:2, :2].mean(axis=(0, 1)))


def test_docs_pictures_stores_the_demo_pictures_as_small_palette_pngs(tmp_path):
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "tools"))
    import docs_pictures
    from PIL import Image

    demo, out = tmp_path / "demo", tmp_path / "images"
    demo.mkdir()
    assert docs_pictures.main(["--demo", str(demo), "--out", str(out)]) == 1  # nothing rendered yet
    gradient = np.linspace(0, 255, 64 * 48 * 3).reshape(48, 64, 3).astype(np.uint8)
    for name in docs_pictures.PICTURES:
        Image.fromarray(gradient).save(demo / name)
    assert docs_pictures.main(["--demo", str(demo), "--out", str(out)]) == 0
    for target, colours in docs_pictures.PICTURES.values():
        with Image.open(out / target) as picture:
            assert picture.mode == "P" and picture.size == (64, 48)
            assert len(picture.getcolors()) <= colours
