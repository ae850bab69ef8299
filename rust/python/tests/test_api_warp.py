"""UvWarp: the grid is (height, width) like every array; one result type per call."""

from __future__ import annotations

import numpy as np
import pytest

import tegument
from test_robustness import uv_quad


def two_tiles():
    positions, corners, sizes, uvs = uv_quad()
    uvs[len(uvs) // 2:] += np.array([1, 0], np.float32)
    return positions, corners, sizes, uvs


def test_grid_takes_the_shape_of_rigidity_height_first():
    positions, corners, sizes, uvs = uv_quad()
    warp = tegument.UvWarp(positions, corners, sizes, uvs, np.ones((16, 32), np.float32))
    assert (warp.height, warp.width) == (16, 32)
    assert warp.solve(positions * np.float32(1.1)).shape == (16, 32, 2)
    checked = tegument.UvWarp(positions, corners, sizes, uvs, np.ones((16, 32), np.float32), shape=(16, 32))
    assert (checked.height, checked.width) == (16, 32)
    with pytest.raises(tegument.TegumentError, match=r"rigidity: expected float32 \(32, 16\)"):
        tegument.UvWarp(positions, corners, sizes, uvs, np.ones((16, 32), np.float32), shape=(32, 16))


def test_old_width_first_form_warns_and_still_works():
    positions, corners, sizes, uvs = uv_quad()
    with pytest.warns(DeprecationWarning, match=r"UvWarp\(width, height, rest_positions, \.\.\.\) is deprecated"):
        old = tegument.UvWarp(32, 16, positions, corners, sizes, uvs, np.ones((16, 32), np.float32), warm_start=False)
    new = tegument.UvWarp(positions, corners, sizes, uvs, np.ones((16, 32), np.float32), warm_start=False)
    assert (old.width, old.height) == (32, 16)
    deformed = positions * np.float32(1.2)
    np.testing.assert_array_equal(old.solve(deformed), new.solve(deformed))


def test_positional_mask_and_argument_count():
    positions, corners, sizes, uvs = uv_quad()
    mask = np.ones((8, 8), np.float32)
    tegument.UvWarp(positions, corners, sizes, uvs, np.ones((8, 8), np.float32), mask)
    with pytest.raises(tegument.TegumentError, match="mask given twice"):
        tegument.UvWarp(positions, corners, sizes, uvs, np.ones((8, 8), np.float32), mask, mask=mask)
    with pytest.raises(tegument.TegumentError, match="UvWarp takes 5 or 6 positional arguments"):
        tegument.UvWarp(positions, corners, sizes, uvs)


def test_one_return_type_per_call_udim_names_the_tile():
    positions, corners, sizes, uvs = two_tiles()
    maps = {1001: np.ones((8, 8), np.float32), 1002: np.ones((8, 8), np.float32)}
    warp = tegument.UvWarp(positions, corners, sizes, uvs, maps)
    deformed = positions * np.float32(1.2)
    out = warp.solve(deformed, udim=1002)
    assert isinstance(out, np.ndarray) and out.shape == (8, 8, 2)
    np.testing.assert_array_equal(out, warp.redirection(1002))
    for method in (warp.redirection, warp.validity, warp.displacement):
        assert isinstance(method(udim=1001), np.ndarray)
    metrics = warp.metrics(deformed, udim=1001)
    assert isinstance(metrics, tegument.WarpMetrics) and metrics.udim == 1001
    with pytest.raises(tegument.TegumentError, match=r"udim: this warp has no UDIM tile 1005; its tiles are \[1001, 1002\]"):
        warp.redirection(1005)


def test_old_dict_per_tile_form_warns():
    positions, corners, sizes, uvs = two_tiles()
    maps = {1001: np.ones((8, 8), np.float32), 1002: np.ones((8, 8), np.float32)}
    warp = tegument.UvWarp(positions, corners, sizes, uvs, maps)
    deformed = positions * np.float32(1.2)
    with pytest.warns(DeprecationWarning, match=r"UvWarp.solve\(\) without udim= on a warp over several UDIM tiles"):
        out = warp.solve(deformed)
    assert set(out) == {1001, 1002}
    with pytest.warns(DeprecationWarning):
        metrics = warp.metrics(deformed)
    assert metrics[1002].udim == 1002


def test_single_tile_needs_no_udim_and_does_not_warn(recwarn):
    positions, corners, sizes, uvs = uv_quad()
    warp = tegument.UvWarp(positions, corners, sizes, uvs, np.ones((8, 8), np.float32))
    assert warp.solve(positions).shape == (8, 8, 2)
    assert isinstance(warp.metrics(positions), tegument.WarpMetrics)
    assert not [w for w in recwarn if issubclass(w.category, DeprecationWarning)]
