"""Shared fixtures of the wheel's tests: small meshes in Blender's layout."""

from __future__ import annotations

import os
import pathlib
import sys
import threading
import time

import numpy as np
import pytest

# testkit/penetration.py, the independent penetration checker (no tegument import).
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[3] / "testkit"))

SHARED_DATA = pathlib.Path(__file__).resolve().parents[4] / "shared" / "data"  # ../shared/data beside the checkout


def pytest_configure(config):
    # The deprecated spellings are tested on purpose, each under
    # pytest.warns (test_api_results.py, test_api_warp.py); everywhere else a
    # test uses the API a user should write, so one that drifts back to a
    # deprecated spelling fails instead of adding to a wall of warnings.
    config.addinivalue_line("filterwarnings", "error:.*is deprecated and goes away:DeprecationWarning")


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


def ticks_of_another_thread_during(call) -> int:
    """How many times another Python thread ran while ``call`` ran.

    Python is told not to switch threads on its own for the duration (a switch interval of
    an hour), and the other thread hands the GIL back after every tick: so it can tick only
    while ``call`` lets go of the GIL. A call that holds the GIL throughout sees exactly 0,
    on any machine under any load; one that releases it sees at least 1 once the operating
    system runs that thread, which a call of a tenth of a second or more leaves time for.
    Counts, not rates: nothing here depends on how fast the machine is.
    """
    ticks = 0
    started, done = threading.Event(), threading.Event()

    def count():
        nonlocal ticks
        started.set()
        while not done.is_set():
            ticks += 1
            time.sleep(0)  # releases the GIL: the caller's thread can always take it back

    interval = sys.getswitchinterval()
    sys.setswitchinterval(3600.0)
    counter = threading.Thread(target=count)
    try:
        counter.start()
        started.wait()
        first = ticks  # this thread holds the GIL from here to the call
        call()
        return ticks - first
    finally:
        done.set()
        counter.join()
        sys.setswitchinterval(interval)
