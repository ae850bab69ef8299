"""Shared fixtures of the wheel's tests: small meshes in Blender's layout."""

from __future__ import annotations

import os
import pathlib
import sys

import numpy as np
import pytest

# testkit/penetration.py, the independent penetration checker (no tegument import).
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[3] / "testkit"))

SHARED_DATA = pathlib.Path(__file__).resolve().parents[4] / "shared" / "data"  # ../shared/data beside the checkout


def cube_arrays():
    """Blender's default cube: positions (8, 3) float32, corner_verts, polygon_sizes."""
    positions = np.array(
        [[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], dtype=np.float32
    )
    corner_verts = np.array(
        [0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5], dtype=np.int32
    )
    return positions, corner_verts, np.full(6, 4, dtype=np.int32)


def grid_arrays(nx: int = 4, ny: int = 3):
    """A flat grid of nx × ny quads facing +Z."""
    xs, ys = np.meshgrid(np.linspace(-1, 1, nx + 1), np.linspace(-1, 1, ny + 1))
    positions = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1).astype(np.float32)
    at = lambda i, j: j * (nx + 1) + i  # noqa: E731
    quads = [[at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)] for j in range(ny) for i in range(nx)]
    return positions, np.array(quads, dtype=np.int32).ravel(), np.full(nx * ny, 4, dtype=np.int32)


@pytest.fixture
def cube():
    return cube_arrays()


@pytest.fixture
def grid():
    return grid_arrays()


def shared_data(*parts: str) -> pathlib.Path:
    """A path under ``../shared/data``; skips where it is absent, fails under CI."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        message = f"{path} is absent: the shared test data sits beside the checkout in ../shared/data"
        if os.environ.get("CI") == "true":
            pytest.fail(message + " (required under CI)")
        pytest.skip(message)
    return path
