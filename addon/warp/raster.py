# SPDX-License-Identifier: GPL-3.0-or-later
"""UDIM bookkeeping of the UV layout: which tiles a bake covers and where they sit.

No numerics here: the grids themselves (per-vertex values rasterised, images
resampled, the stretch heat map) come from the wheel
(``tegument.rasterise_corner_values``, ``tegument.resample_image``,
``tegument.stretch_map``). These few lines stay in the add-on because they
decide what the add-on asks for (one rigidity map per tile, the tile a UDIM
number names in the inner node tree) before any wheel object exists.
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
    """Tiles the polygons touch, judged by each polygon's UV centre."""
    if len(polygon_sizes) == 0:
        return []
    starts = np.concatenate(([0], np.cumsum(polygon_sizes)[:-1])).astype(np.intp)
    centre = np.add.reduceat(corner_uvs.astype(np.float64), starts, axis=0) / polygon_sizes[:, None]
    return sorted(int(t) for t in np.unique(udim_of(centre[:, 0], centre[:, 1])))
