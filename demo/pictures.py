"""Pixel work of the demo's pictures, in numpy only (no bpy), so it is testable on its own.

Pixels are float RGBA arrays ``(height, width, 4)`` with row 0 at the bottom, as Blender's
``Image.pixels`` holds them.
"""

from __future__ import annotations

import numpy as np

# A perceptual dark-to-bright ramp (sampled from matplotlib's "inferno"), so a heat map reads the
# same in grey: 0 is near black, the top of the scale pale yellow.
_INFERNO = np.array([
    (0.001, 0.000, 0.014), (0.129, 0.047, 0.291), (0.342, 0.062, 0.429), (0.541, 0.135, 0.415),
    (0.736, 0.216, 0.330), (0.894, 0.353, 0.194), (0.978, 0.558, 0.035), (0.975, 0.798, 0.206),
    (0.988, 0.998, 0.645),
], np.float32)


def join_side_by_side(pictures: list[np.ndarray], gap: int = 4, gap_value: float = 1.0) -> np.ndarray:
    """Pictures of one height left to right, separated by `gap` columns of `gap_value` (opaque)."""
    if not pictures:
        raise ValueError("no pictures to join")
    height = pictures[0].shape[0]
    for k, picture in enumerate(pictures):
        if picture.ndim != 3 or picture.shape[0] != height or picture.shape[2] != 4:
            raise ValueError(f"picture {k} is {picture.shape}; every picture must be RGBA of height {height}")
    separator = np.full((height, gap, 4), gap_value, np.float32)
    separator[..., 3] = 1.0
    parts = []
    for k, picture in enumerate(pictures):
        if k:
            parts.append(separator)
        parts.append(picture.astype(np.float32))
    return np.concatenate(parts, axis=1)


def heat_colours(values: np.ndarray, top: float, valid: np.ndarray | None = None,
                 background=(0.12, 0.12, 0.12)) -> np.ndarray:
    """RGBA pixels of a scalar map: 0 → black … `top` and above → pale yellow (linear in value).

    Texels where `valid` is False (outside the UV charts) get the `background` colour.
    The colours are display (sRGB) values: save the result without a view transform.
    """
    if top <= 0:
        raise ValueError(f"the top of the scale must be positive, got {top}")
    t = np.clip(np.nan_to_num(values, nan=0.0) / top, 0.0, 1.0) * (len(_INFERNO) - 1)
    low = np.minimum(np.floor(t).astype(int), len(_INFERNO) - 2)
    f = (t - low)[..., None]
    rgb = _INFERNO[low] * (1 - f) + _INFERNO[low + 1] * f
    if valid is not None:
        rgb[~valid] = background
    out = np.ones(values.shape + (4,), np.float32)
    out[..., :3] = rgb
    return out


def crop_to(values: np.ndarray, mask: np.ndarray, margin: int = 4) -> tuple[slice, slice]:
    """Rows and columns of the bounding box of `mask` grown by `margin` (the whole array if empty)."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if not len(rows):
        return slice(0, values.shape[0]), slice(0, values.shape[1])
    return (slice(max(rows[0] - margin, 0), min(rows[-1] + margin + 1, values.shape[0])),
            slice(max(cols[0] - margin, 0), min(cols[-1] + margin + 1, values.shape[1])))


def crop_around(pixels: np.ndarray, centre: tuple[float, float], width: int, height: int) -> np.ndarray:
    """A `width` × `height` window of `pixels` centred on ``centre = (x, y)`` (pixels, row 0 at the
    bottom), shifted as needed to stay inside the picture."""
    rows, cols = pixels.shape[:2]
    if width > cols or height > rows:
        raise ValueError(f"a {width} × {height} window does not fit a {cols} × {rows} picture")
    left = int(round(min(max(centre[0] - width / 2, 0), cols - width)))
    bottom = int(round(min(max(centre[1] - height / 2, 0), rows - height)))
    return pixels[bottom:bottom + height, left:left + width]


def downscale(pixels: np.ndarray, factor: int) -> np.ndarray:
    """Mean over `factor` × `factor` blocks (rows and columns beyond a whole block are dropped)."""
    if factor < 1:
        raise ValueError(f"the factor must be at least 1, got {factor}")
    rows, cols = (pixels.shape[0] // factor) * factor, (pixels.shape[1] // factor) * factor
    trimmed = pixels[:rows, :cols]
    return trimmed.reshape(rows // factor, factor, cols // factor, factor, *pixels.shape[2:]).mean(axis=(1, 3))
