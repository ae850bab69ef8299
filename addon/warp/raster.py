# SPDX-License-Identifier: GPL-3.0-or-later
"""UV-space grids from Blender data: images resampled, per-vertex values rasterised.

Grids follow the wheel's convention: float32 ``(height, width)``, row 0 = the
lowest v, texel ``(j, i)`` of UDIM tile ``t`` centred at
``(tile_u + (i + 0.5) / width, tile_v + (j + 0.5) / height)``.
Everything is vectorised numpy: this runs once per bake, not per frame.
"""

from __future__ import annotations

import numpy as np


def udim_of(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """UDIM number of each UV (1001 + u tile + 10 · v tile)."""
    return (1001 + np.floor(u) + 10 * np.floor(v)).astype(np.int64)


def tile_origin(udim: int) -> tuple[int, int]:
    index = udim - 1001
    return index % 10, index // 10


def udim_tiles(corner_uvs: np.ndarray, polygon_sizes: np.ndarray) -> list[int]:
    """Tiles the polygons touch, judged by each polygon's UV centre (as the wheel assigns them)."""
    if len(polygon_sizes) == 0:
        return []
    starts = np.concatenate(([0], np.cumsum(polygon_sizes)[:-1])).astype(np.intp)
    centre = np.add.reduceat(corner_uvs.astype(np.float64), starts, axis=0) / polygon_sizes[:, None]
    return sorted(int(t) for t in np.unique(udim_of(centre[:, 0], centre[:, 1])))


def resample(pixels: np.ndarray, width: int, height: int) -> np.ndarray:
    """Bilinear resample of an image ``(h, w)`` (row 0 = bottom) to ``(height, width)`` texel centres."""
    h, w = pixels.shape
    if (h, w) == (height, width):
        return np.ascontiguousarray(pixels, dtype=np.float32)
    # Texel centres of the target in the source's pixel coordinates (pixel centres at k + 0.5).
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
    # Fancy indexing can hand back a Fortran-ordered array; the wheel takes C order.
    return np.ascontiguousarray(top * (1 - fy)[:, None] + bottom * fy[:, None], dtype=np.float32)


def triangulate(polygon_sizes: np.ndarray) -> np.ndarray:
    """Corner indices ``(T, 3)`` of a fan triangulation of every polygon."""
    sizes = polygon_sizes.astype(np.intp)
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.intp)
    fans = sizes - 2
    owner = np.repeat(np.arange(len(sizes)), fans)
    # k-th triangle of its polygon: corners (start, start + k + 1, start + k + 2).
    k = np.arange(fans.sum()) - np.repeat(np.cumsum(fans) - fans, fans)
    first = starts[owner]
    return np.stack([first, first + k + 1, first + k + 2], axis=1)


def rasterise(corner_uvs: np.ndarray, polygon_sizes: np.ndarray, corner_values: np.ndarray,
              udim: int, width: int, height: int) -> np.ndarray:
    """Linear interpolation of per-corner values over the UV triangles of one tile.

    Texels whose centre lies in no triangle are 0.
    """
    tris = triangulate(polygon_sizes)
    return rasterise_triangles(corner_uvs[tris], corner_values[tris], udim, width, height)


def triangle_ids(corner_uvs: np.ndarray, polygon_sizes: np.ndarray, udim: int, width: int, height: int) -> np.ndarray:
    """Index (into :func:`triangulate`'s triangles) of the triangle under each texel centre, −1 for none."""
    tris = triangulate(polygon_sizes)
    ids = np.repeat(np.arange(1, len(tris) + 1, dtype=np.float64)[:, None], 3, axis=1)
    # Ids + 1 so that 0 means "no triangle"; float64 holds every id exactly.
    grid = rasterise_triangles(corner_uvs[tris], ids, udim, width, height, dtype=np.float64)
    return np.rint(grid).astype(np.int64) - 1


def rasterise_triangles(uv: np.ndarray, values: np.ndarray, udim: int, width: int, height: int, *,
                        dtype=np.float32, chunk_texels: int = 1 << 22) -> np.ndarray:
    """Rasterises triangles ``uv (T, 3, 2)`` carrying ``values (T, 3)`` at texel centres.

    Triangles are processed in chunks of similar bounding-box size, each chunk
    as one array operation over every candidate texel of its triangles.
    """
    out = np.zeros((height, width), dtype)
    if len(uv) == 0:
        return out
    tu, tv = tile_origin(udim)
    p = uv.astype(np.float64)
    p[..., 0] = (p[..., 0] - tu) * width - 0.5  # texel-centre coordinates: centre (i, j) at (i, j)
    p[..., 1] = (p[..., 1] - tv) * height - 0.5
    values = values.astype(np.float64)
    lo = np.ceil(p.min(axis=1)).astype(np.int64)
    hi = np.floor(p.max(axis=1)).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi[:, 0] = np.minimum(hi[:, 0], width - 1)
    hi[:, 1] = np.minimum(hi[:, 1], height - 1)
    size = hi - lo + 1
    keep = (size > 0).all(axis=1)
    p, values, lo, size = p[keep], values[keep], lo[keep], size[keep]
    order = np.argsort(size[:, 0] * size[:, 1], kind="stable")
    p, values, lo, size = p[order], values[order], lo[order], size[order]
    area = size[:, 0] * size[:, 1]
    start = 0
    while start < len(p):
        end = min(len(p), start + max(1, chunk_texels // int(area[start])))
        while True:
            bx, by = size[start:end].max(axis=0)
            if (end - start) * bx * by <= chunk_texels or end - start == 1:
                break
            end = start + (end - start) // 2
        _fill(out, p[start:end], values[start:end], lo[start:end], size[start:end], int(bx), int(by))
        start = end
    return out


def _fill(out, p, values, lo, size, bx, by) -> None:
    ox, oy = np.meshgrid(np.arange(bx), np.arange(by))
    ox, oy = ox.ravel(), oy.ravel()
    x = lo[:, 0:1] + ox[None, :]  # (T, K)
    y = lo[:, 1:2] + oy[None, :]
    valid = (ox[None, :] < size[:, 0:1]) & (oy[None, :] < size[:, 1:2])
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = np.abs(det) > 1e-12
    det = np.where(ok, det, 1.0)[:, None]
    dx = x - a[:, 0:1]
    dy = y - a[:, 1:2]
    w1 = (dx * (c[:, 1:2] - a[:, 1:2]) - dy * (c[:, 0:1] - a[:, 0:1])) / det
    w2 = (dy * (b[:, 0:1] - a[:, 0:1]) - dx * (b[:, 1:2] - a[:, 1:2])) / det
    w0 = 1 - w1 - w2
    eps = -1e-9
    inside = valid & ok[:, None] & (w0 >= eps) & (w1 >= eps) & (w2 >= eps)
    value = w0 * values[:, 0:1] + w1 * values[:, 1:2] + w2 * values[:, 2:3]
    out[y[inside], x[inside]] = value[inside]
