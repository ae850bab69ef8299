"""Per-texel images for the add-on: tegument.rasterise_corner_values, resample_image, stretch_map.

Each is checked against a straightforward numpy reference: the add-on's own
numpy code before the numerics moved into the core (issue 25), kept here
as the old behaviour (its rasteriser unbatched: one triangle at a time).
"""

from __future__ import annotations

import numpy as np
import pytest

import tegument

N = 64


def jittered_sheet(n=12, margin=0.1, seed=3):
    """A bumpy sheet of n × n quads, one UV chart filling [margin, 1 - margin]² with jittered inner vertices."""
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1))
    uv = np.stack([i, j], -1).reshape(-1, 2).astype(np.float64) / n
    inner = ((i > 0) & (i < n) & (j > 0) & (j < n)).ravel()
    uv[inner] += rng.uniform(-0.3, 0.3, (inner.sum(), 2)) / n
    uv = margin + (1 - 2 * margin) * uv
    pos = np.column_stack([uv * 2.0, 0.2 * np.sin(6 * uv[:, 0]) * np.cos(4 * uv[:, 1])]).astype(np.float32)
    quads = [(jj * (n + 1) + ii, jj * (n + 1) + ii + 1, (jj + 1) * (n + 1) + ii + 1, (jj + 1) * (n + 1) + ii)
             for jj in range(n) for ii in range(n)]
    corner_verts = np.array(quads, np.int32).ravel()
    sizes = np.full(len(quads), 4, np.int32)
    return pos, corner_verts, sizes, uv[corner_verts].astype(np.float32)


# --- the reference: the add-on's numpy code before issue 25 -----------------------------------------

def ref_tile_origin(udim):
    index = udim - 1001
    return index % 10, index // 10


def ref_resample(pixels, width, height):
    h, w = pixels.shape
    if (h, w) == (height, width):
        return np.ascontiguousarray(pixels, dtype=np.float32)
    x = np.clip((np.arange(width) + 0.5) * w / width - 0.5, 0, w - 1)
    y = np.clip((np.arange(height) + 0.5) * h / height - 0.5, 0, h - 1)
    x0 = np.minimum(np.floor(x).astype(np.intp), w - 2) if w > 1 else np.zeros(width, np.intp)
    y0 = np.minimum(np.floor(y).astype(np.intp), h - 2) if h > 1 else np.zeros(height, np.intp)
    fx = (x - x0) if w > 1 else np.zeros(width)
    fy = (y - y0) if h > 1 else np.zeros(height)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    p = pixels.astype(np.float64)
    top = p[y0][:, x0] * (1 - fx) + p[y0][:, x1] * fx
    bottom = p[y1][:, x0] * (1 - fx) + p[y1][:, x1] * fx
    return np.ascontiguousarray(top * (1 - fy)[:, None] + bottom * fy[:, None], dtype=np.float32)


def ref_triangulate(polygon_sizes):
    sizes = polygon_sizes.astype(np.intp)
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.intp)
    fans = sizes - 2
    owner = np.repeat(np.arange(len(sizes)), fans)
    k = np.arange(fans.sum()) - np.repeat(np.cumsum(fans) - fans, fans)
    first = starts[owner]
    return np.stack([first, first + k + 1, first + k + 2], axis=1)


def ref_rasterise(corner_uvs, polygon_sizes, corner_values, udim, width, height):
    tris = ref_triangulate(polygon_sizes)
    return ref_rasterise_triangles(corner_uvs[tris], corner_values[tris], udim, width, height)


def ref_triangle_ids(corner_uvs, polygon_sizes, udim, width, height):
    tris = ref_triangulate(polygon_sizes)
    ids = np.repeat(np.arange(1, len(tris) + 1, dtype=np.float64)[:, None], 3, axis=1)
    grid = ref_rasterise_triangles(corner_uvs[tris], ids, udim, width, height, dtype=np.float64)
    return np.rint(grid).astype(np.int64) - 1


def ref_rasterise_triangles(uv, values, udim, width, height, *, dtype=np.float32):
    """One triangle at a time (the add-on batched them; the result is the same)."""
    out = np.zeros((height, width), dtype)
    tu, tv = ref_tile_origin(udim)
    p = uv.astype(np.float64)
    p[..., 0] = (p[..., 0] - tu) * width - 0.5
    p[..., 1] = (p[..., 1] - tv) * height - 0.5
    values = values.astype(np.float64)
    lo = np.maximum(np.ceil(p.min(axis=1)).astype(np.int64), 0)
    hi = np.floor(p.max(axis=1)).astype(np.int64)
    hi[:, 0] = np.minimum(hi[:, 0], width - 1)
    hi[:, 1] = np.minimum(hi[:, 1], height - 1)
    for t in range(len(p)):
        if (hi[t] < lo[t]).any():
            continue
        y, x = np.mgrid[lo[t, 1]:hi[t, 1] + 1, lo[t, 0]:hi[t, 0] + 1]
        a, b, c = p[t]
        det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])
        if abs(det) <= 1e-12:
            continue
        w1 = ((x - a[0]) * (c[1] - a[1]) - (y - a[1]) * (c[0] - a[0])) / det
        w2 = ((y - a[1]) * (b[0] - a[0]) - (x - a[0]) * (b[1] - a[1])) / det
        w0 = 1 - w1 - w2
        inside = (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9)
        out[y[inside], x[inside]] = (w0 * values[t, 0] + w1 * values[t, 1] + w2 * values[t, 2])[inside]
    return out


def ref_triangle_jacobians(positions, corner_verts, tris, uv):
    x = positions[corner_verts[tris]].astype(np.float64)
    p = uv[tris].astype(np.float64)
    edges = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]], axis=2)
    t = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=2)
    det = t[:, 0, 0] * t[:, 1, 1] - t[:, 0, 1] * t[:, 1, 0]
    ok = np.abs(det) > 1e-14
    safe = np.where(ok, det, 1.0)
    inverse = np.stack([np.stack([t[:, 1, 1], -t[:, 0, 1]], 1), np.stack([-t[:, 1, 0], t[:, 0, 0]], 1)], 1) / safe[:, None, None]
    return edges @ inverse, ok


def ref_stretch_map(rest, deformed, corner_verts, polygon_sizes, corner_uvs, udim, displacement):
    height, width = displacement.shape[:2]
    tris = ref_triangulate(polygon_sizes)
    j_rest, ok_rest = ref_triangle_jacobians(rest, corner_verts, tris, corner_uvs)
    j_def, _ = ref_triangle_jacobians(deformed, corner_verts, tris, corner_uvs)
    ids = ref_triangle_ids(corner_uvs, polygon_sizes, udim, width, height)
    jj, ii = np.mgrid[0:height, 0:width].astype(np.float64)
    wx = ii + displacement[..., 0]
    wy = jj + displacement[..., 1]
    grad = np.empty((height, width, 2, 2))
    grad[..., 0, 0], grad[..., 0, 1] = np.gradient(wx, axis=1), np.gradient(wx, axis=0)
    grad[..., 1, 0], grad[..., 1, 1] = np.gradient(wy, axis=1), np.gradient(wy, axis=0)
    landed = ids[np.clip(np.rint(wy).astype(np.intp), 0, height - 1), np.clip(np.rint(wx).astype(np.intp), 0, width - 1)]
    valid = (ids >= 0) & (landed >= 0)
    out = np.zeros((height, width), np.float32)
    if not valid.any():
        return out
    here = ids[valid]
    valid_rest = ok_rest[here]
    m = j_def[landed[valid]] @ grad[valid]
    g_rest = np.einsum("kij,kil->kjl", j_rest[here], j_rest[here])
    c = np.einsum("kij,kil->kjl", m, m)
    det_g = g_rest[:, 0, 0] * g_rest[:, 1, 1] - g_rest[:, 0, 1] ** 2
    good = valid_rest & (det_g > 1e-20)
    l11 = np.sqrt(np.where(good, g_rest[:, 0, 0], 1.0))
    l21 = np.where(good, g_rest[:, 0, 1], 0.0) / l11
    l22 = np.sqrt(np.maximum(np.where(good, g_rest[:, 1, 1], 1.0) - l21**2, 1e-30))
    inv = np.zeros_like(g_rest)
    inv[:, 0, 0] = 1 / l11
    inv[:, 1, 0] = -l21 / (l11 * l22)
    inv[:, 1, 1] = 1 / l22
    a = inv @ c @ np.transpose(inv, (0, 2, 1))
    half_trace = 0.5 * (a[:, 0, 0] + a[:, 1, 1])
    det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
    root = np.sqrt(np.maximum(half_trace**2 - det, 0.0))
    big, small = half_trace + root, np.maximum(half_trace - root, 1e-30)
    error = 0.5 * np.maximum(np.abs(np.log(np.maximum(big, 1e-30))), np.abs(np.log(small)))
    out[valid] = np.where(good, error, 0.0).astype(np.float32)
    return out


# --- rasterise_corner_values -------------------------------------------------------------------------

def test_corner_values_match_the_numpy_reference():
    pos, cv, sizes, uvs = jittered_sheet()
    values = np.random.default_rng(0).uniform(0, 1, len(pos)).astype(np.float32)[cv]
    got = tegument.rasterise_corner_values(uvs, sizes, values, 1001, (N, N))
    assert got.dtype == np.float32 and got.shape == (N, N)
    want = ref_rasterise(uvs, sizes, values, 1001, N, N)
    # The chart's border lies between texel centres and the values are continuous across inner
    # edges, so which triangle owns an edge texel does not matter: only float rounding differs.
    np.testing.assert_allclose(got, want, atol=2e-6)
    assert (got[want == 0] == 0).all() and (got > 0).sum() > 0.5 * N * N
    assert got.min() >= 0 and got.max() <= 1  # within the corner values' range, as a rigidity must be


def test_corner_values_of_ngons_in_another_tile_and_other_dtypes():
    # One pentagon and one triangle in tile 1012 (u tile 1, v tile 1), given as float64 and int64.
    uvs = np.array([[1.1, 1.1], [1.8, 1.15], [1.9, 1.6], [1.5, 1.9], [1.12, 1.7],
                    [1.02, 1.02], [1.15, 1.02], [1.02, 1.15]], np.float64)
    sizes = np.array([5, 3], np.int64)
    values = np.linspace(0.0, 1.0, 8)
    got = tegument.rasterise_corner_values(uvs, sizes, values, 1012, (32, 16))
    want = ref_rasterise(uvs, sizes, values, 1012, 16, 32)
    assert got.shape == (32, 16) and (got > 0).sum() > 100
    # The two polygons do not touch; rounding aside they agree everywhere.
    np.testing.assert_allclose(got, want, atol=2e-6)
    assert (tegument.rasterise_corner_values(uvs, sizes, values, 1001, (32, 16)) == 0).all()


def test_corner_value_errors_name_the_argument():
    pos, cv, sizes, uvs = jittered_sheet(n=2)
    values = np.zeros(len(cv), np.float32)
    with pytest.raises(tegument.TegumentError, match="corner_values"):
        tegument.rasterise_corner_values(uvs, sizes, values[:-1], 1001, (N, N))
    with pytest.raises(tegument.TegumentError, match="width must be a power of two"):
        tegument.rasterise_corner_values(uvs, sizes, values, 1001, (N, 60))
    with pytest.raises(tegument.TegumentError, match="udim must be a UDIM tile number"):
        tegument.rasterise_corner_values(uvs, sizes, values, 1000, (N, N))
    with pytest.raises(tegument.TegumentError, match="polygon sizes add up to"):
        tegument.rasterise_corner_values(uvs, sizes[:-1], values, 1001, (N, N))
    values[3] = np.nan
    with pytest.raises(tegument.TegumentError, match="corner_values: the value of corner 3 is not finite"):
        tegument.rasterise_corner_values(uvs, sizes, values, 1001, (N, N))


# --- resample_image ----------------------------------------------------------------------------------

@pytest.mark.parametrize("source", [(37, 53), (1, 7), (64, 64), (128, 256), (1, 1), (200, 3)])
def test_resample_matches_the_numpy_reference(source):
    pixels = np.random.default_rng(sum(source)).uniform(0, 1, source)
    got = tegument.resample_image(pixels, (N, 32))
    want = ref_resample(pixels.astype(np.float32), 32, N)
    assert got.dtype == np.float32 and got.shape == (N, 32)
    np.testing.assert_allclose(got, want, atol=1e-6)


def test_resample_takes_any_float_dtype_and_layout():
    pixels = np.random.default_rng(1).uniform(0, 1, (40, 30)).astype(np.float16)
    want = ref_resample(pixels.astype(np.float32), 16, 16)
    np.testing.assert_allclose(tegument.resample_image(pixels, (16, 16)), want, atol=1e-6)
    np.testing.assert_allclose(tegument.resample_image(np.asfortranarray(pixels), (16, 16)), want, atol=1e-6)
    with pytest.raises(tegument.TegumentError, match="pixels"):
        tegument.resample_image(np.zeros((4, 4, 3)), (16, 16))


# --- stretch_map -------------------------------------------------------------------------------------

def smooth_displacement(amplitude, seed=0):
    """A smooth displacement field in texels, (N, N, 2)."""
    rng = np.random.default_rng(seed)
    jj, ii = np.mgrid[0:N, 0:N] / N
    phase = rng.uniform(0, 2 * np.pi, 4)
    dx = amplitude * np.sin(2 * np.pi * jj + phase[0]) * np.cos(3 * np.pi * ii + phase[1])
    dy = amplitude * np.cos(2 * np.pi * ii + phase[2]) * np.sin(np.pi * jj + phase[3])
    return np.stack([dx, dy], -1).astype(np.float32)


def test_stretch_map_matches_the_numpy_reference():
    rest, cv, sizes, uvs = jittered_sheet()
    deformed = rest * np.array([1.6, 0.8, 1.0], np.float32)
    d = smooth_displacement(2.5)
    got = tegument.stretch_map(rest, deformed, cv, sizes, uvs, d)
    want = ref_stretch_map(rest, deformed, cv, sizes, uvs, 1001, d)
    assert got.dtype == np.float32 and got.shape == (N, N) and np.isfinite(got).all()
    # The stretch is piecewise constant per triangle: where a texel centre lies within a hair
    # (1/4096 texel) of an inner edge the core's watertight rasteriser and the old inclusive
    # test may give it to different neighbours. Everywhere else they agree to rounding.
    close = np.abs(got - want) <= 1e-5 * np.maximum(1.0, np.abs(want))
    assert close.mean() > 0.995, np.argwhere(~close)
    assert ((got == 0) == (want == 0)).mean() > 0.995
    assert got.max() > 0.1


def test_stretch_map_of_another_tile_and_a_folded_warp():
    rest, cv, sizes, uvs = jittered_sheet()
    shifted = uvs + np.array([0.0, 1.0], np.float32)
    d = np.zeros((N, N, 2), np.float32)
    # No deformation, no warp: no stretch anywhere, in tile 1011; nothing of the UVs in 1001.
    assert np.abs(tegument.stretch_map(rest, rest, cv, sizes, shifted, d, udim=1011)).max() < 1e-5
    assert (tegument.stretch_map(rest, rest, cv, sizes, shifted, d, udim=1001) == 0).all()
    # A warp that collapses the grid to one column: capped, never infinite.
    jj, ii = np.mgrid[0:N, 0:N]
    d[..., 0] = N / 2 - ii
    got = tegument.stretch_map(rest, rest, cv, sizes, uvs, d)
    assert np.isfinite(got).all() and got.max() == pytest.approx(0.5 * np.log(1e30), rel=1e-6)


def test_stretch_map_errors_name_the_argument():
    rest, cv, sizes, uvs = jittered_sheet(n=2)
    d = np.zeros((N, N, 2), np.float32)
    with pytest.raises(tegument.TegumentError, match="deformed_positions"):
        tegument.stretch_map(rest, rest[:-1], cv, sizes, uvs, d)
    with pytest.raises(tegument.TegumentError, match="displacement"):
        tegument.stretch_map(rest, rest, cv, sizes, uvs, d[..., :1])
    d[3, 4, 1] = np.inf
    with pytest.raises(tegument.TegumentError, match=r"displacement: texel \(row 3, column 4\) is not finite"):
        tegument.stretch_map(rest, rest, cv, sizes, uvs, d)
