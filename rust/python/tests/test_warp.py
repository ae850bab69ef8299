"""UV warp through the numpy API: tegument.UvWarp, write_exr, read_exr."""

from __future__ import annotations

import math

import numpy as np
import pytest

import tegument
from conftest import shared_data

N = 128


def uv_cylinder(around=64, along=32, radius=1.0, length=2 * math.pi, margin=0.1):
    """Open cylinder along +Z unrolled into one UV chart filling [margin, 1 - margin]²."""
    phi = 2 * math.pi * np.arange(around) / around + math.pi / 2
    z = length * np.arange(along + 1) / along
    pos = np.zeros(((along + 1) * around, 3), np.float32)
    for j in range(along + 1):
        pos[j * around:(j + 1) * around] = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.full(around, z[j])], 1)
    span = 1 - 2 * margin
    cv, uvs = [], []
    for j in range(along):
        for i in range(around):
            for ci, cj in ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)):
                cv.append(cj * around + ci % around)
                uvs.append((margin + span * ci / around, margin + span * cj / along))
    return pos, np.array(cv, np.int32), np.full(along * around, 4, np.int32), np.array(uvs, np.float32)


def bend(pos, amount=1.0, axis=2, side=0, centre=0.0, start=0.0):
    """Bend along `axis`: material at distance o from the neutral line stretches by 1 + kappa·o."""
    kappa = 0.5 * amount
    rho = 1 / kappa
    out = pos.astype(np.float64).copy()
    th = (pos[:, axis] - start) * kappa
    o = pos[:, side] - centre
    out[:, side] = centre - rho + (rho + o) * np.cos(th)
    out[:, axis] = start + (rho + o) * np.sin(th)
    return out.astype(np.float32)


def squares(n=N, s=0.06):
    """Rigid squares on both sides of the cylinder (u = 0.3 and u = 0.7), row 0 = lowest v."""
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c)
    r = np.zeros((n, n), np.float32)
    for uc in (0.3, 0.7):
        r[(abs(u - uc) < s) & (abs(v - 0.5) < s)] = 1.0
    return r


@pytest.fixture(scope="module")
def cylinder():
    return uv_cylinder()


def make(cyl, **kw):
    pos, cv, ps, uvs = cyl
    kw.setdefault("iterations", 8)
    return tegument.UvWarp(pos, cv, ps, uvs, kw.pop("rigidity", squares()), **kw)


def test_rest_equals_deformed_is_the_identity(cylinder):
    warp = make(cylinder, warm_start=False)
    red = warp.solve(cylinder[0])
    assert red.shape == (N, N, 2) and red.dtype == np.float32
    c = (np.arange(N) + 0.5) / N
    u, v = np.meshgrid(c, c)
    # Row 0 is the lowest v: red[j, i] = (u_i, v_j).
    assert np.abs(red[..., 0] - u).max() < 1e-5
    assert np.abs(red[..., 1] - v).max() < 1e-5
    m = warp.metrics(cylinder[0])
    assert m.max_displacement < 0.01


def test_bent_cylinder_rigid_squares_keep_their_size(cylinder):
    warp = make(cylinder, warm_start=False)
    deformed = bend(cylinder[0])
    red = warp.solve(deformed)
    m = warp.metrics(deformed)
    assert m.rigid_texels > 400
    assert m.stretch_identity_mean > 0.3
    assert m.stretch_warped_mean * 3 <= m.stretch_identity_mean, m
    assert m.foldovers == 0
    assert m.max_masked_displacement == 0.0
    assert m.round_trip_max < 0.5
    # Outside the chart the redirection is the identity and validity is 0.
    validity = warp.validity()
    assert validity.shape == (N, N) and validity[0, 0] == 0.0 and validity[N // 2, N // 2] == 1.0
    assert np.allclose(red[0, 0], [0.5 / N, 0.5 / N])
    d = warp.displacement()
    assert np.abs(d).max() > 2.0


def test_user_mask_fixes_texels(cylinder):
    mask = np.ones((N, N), np.float32)
    mask[:, 80:84] = 0.0
    warp = make(cylinder, mask=mask, warm_start=False)
    warp.solve(bend(cylinder[0]))
    d = warp.displacement()
    assert np.all(d[:, 80:84] == 0.0)
    assert np.abs(d).max() > 1.0


def test_warm_start_is_coherent_and_reset_is_deterministic(cylinder):
    warp = make(cylinder)
    for _ in range(5):
        warp.solve(bend(cylinder[0], 1.0))
    base = warp.displacement()
    warp.solve(bend(cylinder[0], 1.01))
    step = np.abs(warp.displacement() - base).max()
    total = np.abs(base).max()
    assert step < 0.05 * total, (step, total)
    # From identity: the same answer whatever came before.
    warp.reset()
    a = warp.solve(bend(cylinder[0], 1.0))
    cold = make(cylinder, warm_start=False)
    cold.solve(bend(cylinder[0], 0.3))
    b = cold.solve(bend(cylinder[0], 1.0))
    assert np.array_equal(a, b)


def test_exr_round_trip_and_blender_reads_it_the_same_way(cylinder, tmp_path):
    warp = make(cylinder, warm_start=False)
    red = warp.solve(bend(cylinder[0]))
    path = tmp_path / "warp.1001.exr"
    warp.write_exr(path)
    data, meta = tegument.read_exr(path)
    assert data.shape == (N, N, 3)
    assert np.array_equal(data[..., :2], red)
    assert np.array_equal(data[..., 2], warp.validity())
    assert meta["iterations"] == "8" and "smoothing" in meta and meta["udim"] == "1001"
    assert [p.name for p in tmp_path.iterdir()] == ["warp.1001.exr"], "no temporary file left behind"
    # Blender's image loader sees the same pixels in the same (bottom-up) order.
    bpy = pytest.importorskip("bpy")
    image = bpy.data.images.load(str(path))
    try:
        px = np.empty(N * N * 4, np.float32)
        image.pixels.foreach_get(px)
        px = px.reshape(N, N, 4)
        assert np.allclose(px[..., 0], red[..., 0], atol=1e-6)
        assert np.allclose(px[..., 1], red[..., 1], atol=1e-6)
    finally:
        bpy.data.images.remove(image)


def test_write_exr_validates_and_is_atomic(tmp_path):
    path = tmp_path / "a.exr"
    img = np.random.default_rng(1).random((4, 8, 2), dtype=np.float32)
    tegument.write_exr(path, img, {"note": "hello"})
    back, meta = tegument.read_exr(path)
    assert np.array_equal(back, img) and meta["note"] == "hello"
    before = path.read_bytes()
    bad = img.copy()
    bad[1, 2, 0] = np.nan
    with pytest.raises(tegument.TegumentError, match=r"row 1, column 2"):
        tegument.write_exr(path, bad)
    assert path.read_bytes() == before
    with pytest.raises(tegument.TegumentError, match="1 to 4 channels"):
        tegument.write_exr(path, np.zeros((4, 4, 5), np.float32))
    with pytest.raises(tegument.TegumentError, match="float32"):
        tegument.write_exr(path, np.zeros((4, 4, 2), np.complex64))


def test_bad_input_names_the_problem(cylinder):
    pos, cv, ps, uvs = cylinder
    r = squares()
    with pytest.raises(tegument.TegumentError, match="power of two"):
        tegument.UvWarp(pos, cv, ps, uvs, np.ones((N, 100), np.float32))
    with pytest.raises(tegument.TegumentError, match=r"rigidity: expected float32 \(128, 128\)"):
        tegument.UvWarp(pos, cv, ps, uvs, squares(64), shape=(N, N))
    with pytest.raises(tegument.TegumentError, match="rigidity"):
        tegument.UvWarp(pos, cv, ps, uvs, np.zeros((N, N, 3), np.float32), shape=(N, N))
    bad = r.copy()
    bad[3, 5] = np.nan
    with pytest.raises(tegument.TegumentError, match=r"row 3, column 5"):
        tegument.UvWarp(pos, cv, ps, uvs, bad)
    with pytest.raises(tegument.TegumentError, match="corner_uvs"):
        tegument.UvWarp(pos, cv, ps, uvs[:-1], r)
    with pytest.raises(tegument.TegumentError, match="mask"):
        tegument.UvWarp(pos, cv, ps, uvs, r, mask=np.ones((N, N + 1), np.float32))
    with pytest.raises(tegument.TegumentError, match=r"16384×16384 would need .* GiB"):
        tegument.UvWarp(pos, cv, ps, uvs, np.zeros((16384, 16384), np.float32))
    warp = make(cylinder)
    with pytest.raises(tegument.TegumentError, match="deformed_positions"):
        warp.solve(pos[:-1])
    p = pos.copy()
    p[7, 1] = np.inf
    with pytest.raises(tegument.TegumentError, match="vertex 7"):
        warp.solve(p)
    assert issubclass(tegument.TegumentError, ValueError)


def test_udim_tiles_are_separate_grids(cylinder):
    pos, cv, ps, uvs = cylinder
    uvs = uvs.copy()
    half = len(ps) // 2
    uvs[4 * half:, 0] += 1.0
    r = np.zeros((64, 64), np.float32)
    r[38:50, 38:50] = 1.0
    with pytest.raises(tegument.TegumentError, match="1002"):
        tegument.UvWarp(pos, cv, ps, uvs, r)
    warp = tegument.UvWarp(pos, cv, ps, uvs, {1001: r, 1002: r}, warm_start=False)
    assert warp.tiles == [1001, 1002]
    red = {udim: warp.solve(bend(pos), udim=udim) for udim in warp.tiles}
    assert set(red) == {1001, 1002}
    assert red[1002][..., 0].min() >= 1.0
    m = {udim: warp.metrics(bend(pos), udim=udim) for udim in warp.tiles}
    assert m[1002].foldovers == 0 and m[1001].max_masked_displacement == 0.0


def read_obj(path):
    v, vt, cv, cuv, sizes = [], [], [], [], []
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            v.append([float(x) for x in parts[1:4]])
        elif parts[0] == "vt":
            vt.append([float(x) for x in parts[1:3]])
        elif parts[0] == "f":
            sizes.append(len(parts) - 1)
            for c in parts[1:]:
                a, b = c.split("/")[:2]
                cv.append(int(a) - 1)
                cuv.append(vt[int(b) - 1])
    return np.array(v, np.float32), np.array(cv, np.int32), np.array(sizes, np.int32), np.array(cuv, np.float32)


def test_spot_bend_with_rigidity_from_its_texture():
    folder = shared_data("meshes", "spot")
    bpy = pytest.importorskip("bpy")
    pos, cv, ps, uvs = read_obj(folder / "spot_triangulated.obj")
    image = bpy.data.images.load(str(folder / "spot_texture.png"))
    try:
        w, h = image.size
        px = np.empty(w * h * 4, np.float32)
        image.pixels.foreach_get(px)  # bottom row first, like our arrays
    finally:
        bpy.data.images.remove(image)
    # Far from the skin colour (in sRGB-ish 0..1 as Blender stores 8-bit PNGs) = rigid feature.
    px = px.reshape(h, w, 4)[..., :3]
    skin = np.array([255, 236, 228], np.float32) / 255
    feature = (np.linalg.norm(px - skin, axis=2) > 60 / 255).astype(np.float32)
    n = 256
    rigidity = feature.reshape(n, h // n, n, w // n).mean(axis=(1, 3)).astype(np.float32)
    warp = tegument.UvWarp(pos, cv, ps, uvs, np.ascontiguousarray(rigidity), iterations=8, warm_start=False)
    assert warp.chart_count == 13
    deformed = bend(pos, amount=1.0, axis=2, side=1, centre=0.0, start=-0.7)
    warp.solve(deformed)
    m = warp.metrics(deformed)
    assert m.stretch_warped_mean < 0.9 * m.stretch_identity_mean, m
    assert m.foldovers == 0
    assert m.max_masked_displacement == 0.0
    assert m.round_trip_max < 0.5
