# SPDX-License-Identifier: GPL-3.0-or-later
"""Per-texel stretch error of texture detail after the warp: the bake's optional heat map.

Texture detail at texel centre ``t`` is drawn at ``W(t) = t + d(t)``; it sits
on the rest surface at ``X_rest(t)`` and on the deformed surface at
``X_def(W(t))``. Its deformation gradient is
``F = J_def(W(t)) · ∇W(t) · J_rest(t)⁻¹`` (the J are the per-triangle
UV → 3D Jacobians), and the error is ``max(|log σ1|, |log σ2|)`` of F —
the measure the wheel's ``UvWarp.metrics`` aggregates, here as an image.
Vectorised numpy, once per bake.
"""

from __future__ import annotations

import numpy as np

from . import raster


def triangle_jacobians(positions: np.ndarray, corner_verts: np.ndarray, tris: np.ndarray,
                       uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(J (T, 3, 2), ok (T,))``: d position / d uv of every triangle; ok = non-degenerate in UV."""
    x = positions[corner_verts[tris]].astype(np.float64)  # (T, 3, 3)
    p = uv[tris].astype(np.float64)  # (T, 3, 2)
    edges = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]], axis=2)  # (T, 3, 2)
    t = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=2)  # (T, 2, 2)
    det = t[:, 0, 0] * t[:, 1, 1] - t[:, 0, 1] * t[:, 1, 0]
    ok = np.abs(det) > 1e-14
    safe = np.where(ok, det, 1.0)
    inverse = np.stack([np.stack([t[:, 1, 1], -t[:, 0, 1]], 1), np.stack([-t[:, 1, 0], t[:, 0, 0]], 1)], 1) / safe[:, None, None]
    return edges @ inverse, ok


def stretch_map(rest: np.ndarray, deformed: np.ndarray, corner_verts: np.ndarray, polygon_sizes: np.ndarray,
                corner_uvs: np.ndarray, udim: int, displacement: np.ndarray) -> np.ndarray:
    """``(height, width)`` float32 stretch error of one tile; 0 outside the UV charts."""
    height, width = displacement.shape[:2]
    tris = raster.triangulate(polygon_sizes)
    j_rest, ok_rest = triangle_jacobians(rest, corner_verts, tris, corner_uvs)
    j_def, _ = triangle_jacobians(deformed, corner_verts, tris, corner_uvs)
    ids = raster.triangle_ids(corner_uvs, polygon_sizes, udim, width, height)
    # Warped positions in texel units, and their gradient (central differences inside the grid).
    jj, ii = np.mgrid[0:height, 0:width].astype(np.float64)
    wx = ii + displacement[..., 0]
    wy = jj + displacement[..., 1]
    grad = np.empty((height, width, 2, 2))
    grad[..., 0, 0], grad[..., 0, 1] = np.gradient(wx, axis=1), np.gradient(wx, axis=0)
    grad[..., 1, 0], grad[..., 1, 1] = np.gradient(wy, axis=1), np.gradient(wy, axis=0)
    # The triangle the detail lands in on the deformed surface.
    landed = ids[np.clip(np.rint(wy).astype(np.intp), 0, height - 1), np.clip(np.rint(wx).astype(np.intp), 0, width - 1)]
    valid = (ids >= 0) & (landed >= 0)
    out = np.zeros((height, width), np.float32)
    if not valid.any():
        return out
    here = ids[valid]
    valid_rest = ok_rest[here]
    m = j_def[landed[valid]] @ grad[valid]  # (K, 3, 2): detail → deformed surface
    g_rest = np.einsum("kij,kil->kjl", j_rest[here], j_rest[here])  # rest metric of the detail
    c = np.einsum("kij,kil->kjl", m, m)
    # σ² are the eigenvalues of G_rest⁻¹ C (symmetric-definite pair): solve via Cholesky of G_rest.
    det_g = g_rest[:, 0, 0] * g_rest[:, 1, 1] - g_rest[:, 0, 1] ** 2
    good = valid_rest & (det_g > 1e-20)
    l11 = np.sqrt(np.where(good, g_rest[:, 0, 0], 1.0))
    l21 = np.where(good, g_rest[:, 0, 1], 0.0) / l11
    l22 = np.sqrt(np.maximum(np.where(good, g_rest[:, 1, 1], 1.0) - l21**2, 1e-30))
    inv = np.zeros_like(g_rest)
    inv[:, 0, 0] = 1 / l11
    inv[:, 1, 0] = -l21 / (l11 * l22)
    inv[:, 1, 1] = 1 / l22
    a = inv @ c @ np.transpose(inv, (0, 2, 1))  # L⁻¹ C L⁻ᵀ, same eigenvalues
    half_trace = 0.5 * (a[:, 0, 0] + a[:, 1, 1])
    det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
    root = np.sqrt(np.maximum(half_trace**2 - det, 0.0))
    big, small = half_trace + root, np.maximum(half_trace - root, 1e-30)
    error = 0.5 * np.maximum(np.abs(np.log(np.maximum(big, 1e-30))), np.abs(np.log(small)))
    values = np.where(good, error, 0.0).astype(np.float32)
    out[valid] = values
    return out
