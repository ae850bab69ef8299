"""Arrays of any integer / float dtype and any layout are converted; bad kinds are refused."""

from __future__ import annotations

import numpy as np
import pytest

import tegument
from conftest import cube_arrays, grid_arrays

INT_TYPES = [np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint32, np.uint64]
FLOAT_TYPES = [np.float16, np.float32, np.float64, np.longdouble]


@pytest.mark.parametrize("dtype", INT_TYPES)
def test_index_arrays_of_any_integer_dtype_give_the_same_mesh(dtype):
    positions, corners, sizes = cube_arrays()
    expected = tegument.Mesh(positions, corners, sizes)
    mesh = tegument.Mesh(positions, corners.astype(dtype), sizes.astype(dtype))
    assert np.array_equal(mesh.edges, expected.edges)
    assert mesh.report.to_dict() == expected.report.to_dict()


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.longdouble])
def test_positions_of_any_float_dtype_solve_alike(dtype):
    positions, corners, sizes = grid_arrays(6, 6)
    deformer = tegument.PyramidDeformer(positions.astype(dtype), corners.astype(np.int64), sizes.astype(np.int64))
    bent = positions.copy()
    bent[:, 2] = 0.2 * bent[:, 0] ** 2
    reference = tegument.PyramidDeformer(positions, corners, sizes).solve(bent, iterations=3)
    out = deformer.solve(bent.astype(dtype), iterations=3)
    assert out.dtype == np.float32 and out.shape == bent.shape
    np.testing.assert_allclose(out, reference, atol=1e-6)


def test_float16_positions_are_converted():
    positions, corners, sizes = cube_arrays()
    mesh = tegument.Mesh(positions.astype(np.float16), corners, sizes)
    assert mesh.vertex_count == 8


def test_non_contiguous_arrays_are_copied_not_refused():
    positions, corners, sizes = cube_arrays()
    fortran = np.asfortranarray(positions)
    strided = np.repeat(corners, 2)[::2]
    assert not fortran.flags.c_contiguous and not strided.flags.c_contiguous
    mesh = tegument.Mesh(fortran, strided, sizes)
    assert np.array_equal(mesh.edges, tegument.Mesh(positions, corners, sizes).edges)
    points = np.asfortranarray(np.arange(12, dtype=np.float64).reshape(4, 3))
    moved = tegument.transform_points(points, np.eye(4, dtype=np.float32))
    np.testing.assert_array_equal(moved, points.astype(np.float32))


def test_triangles_of_any_integer_dtype():
    positions, corners, _ = cube_arrays()
    quads = corners.reshape(-1, 4)
    triangles = np.concatenate([quads[:, :3], quads[:, [0, 2, 3]]])
    for dtype in (np.int64, np.uint16):
        collider = tegument.Collider(positions.astype(np.float64), triangles.astype(dtype), thickness=0.0, friction=0.0)
        assert collider.triangle_count == 12 and collider.triangles.dtype == np.int32


def test_index_beyond_int32_names_the_argument_and_element():
    positions, corners, sizes = cube_arrays()
    big = corners.astype(np.int64)
    big[5] = 2**31
    with pytest.raises(tegument.TegumentError, match=r"corner_verts: element 5 is 2147483648; indices must be between 0 and 2147483647 \(int32\)"):
        tegument.Mesh(positions, big, sizes)
    huge = corners.astype(np.uint64)
    huge[0] = np.iinfo(np.uint64).max
    with pytest.raises(tegument.TegumentError, match=r"corner_verts: element 0 is 18446744073709551615"):
        tegument.Mesh(positions, huge, sizes)


def test_negative_converted_index_is_refused():
    positions, corners, sizes = cube_arrays()
    bad = corners.astype(np.int64)
    bad[3] = -1
    with pytest.raises(tegument.TegumentError, match=r"corner_verts: element 3 is -1"):
        tegument.Mesh(positions, bad, sizes)
    quads = corners.reshape(-1, 4)
    triangles = np.concatenate([quads[:, :3], quads[:, [0, 2, 3]]]).astype(np.int64)
    triangles[2, 1] = -7
    with pytest.raises(tegument.TegumentError, match=r"triangles: element \(2, 1\) is -7"):
        tegument.Collider(positions, triangles, thickness=0.0, friction=0.0)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p, c, s: (p.astype(np.complex64), c, s), r"positions: expected float32 \(N, 3\) \(other float types are converted\); got complex64 \(8, 3\)"),
        (lambda p, c, s: (p, c.astype(bool), s), r"corner_verts: expected int32 \(N,\) \(other integer types are converted\); got bool"),
        (lambda p, c, s: (p, c.astype(object), s), r"corner_verts: expected int32 \(N,\)"),
        (lambda p, c, s: (p, c, s.astype(np.float32)), r"polygon_sizes: expected int32 \(N,\)"),
        (lambda p, c, s: (p.astype(np.int32), c, s), r"positions: expected float32 \(N, 3\)"),
        (lambda p, c, s: (p, c.tolist(), s), r"corner_verts: expected int32 \(N,\) .*got a list"),
    ],
)
def test_wrong_kinds_are_still_refused(make, message):
    with pytest.raises(tegument.TegumentError, match=message):
        tegument.Mesh(*make(*cube_arrays()))


def test_float64_overflow_to_float32_is_reported_as_not_finite():
    positions, corners, sizes = cube_arrays()
    far = positions.astype(np.float64)
    far[2, 0] = 1e300
    with pytest.raises(tegument.TegumentError, match="finite"):
        tegument.Mesh(far, corners, sizes)


# `out=`: a bake hands the same arrays back every frame instead of getting new ones.

def _bent_grid():
    positions, corners, sizes = grid_arrays(6, 6)
    bent = positions.copy()
    bent[:, 2] = 0.2 * bent[:, 0] ** 2
    return tegument.PyramidDeformer(positions, corners, sizes), bent


def test_solve_and_step_write_into_out_and_return_it():
    deformer, bent = _bent_grid()
    expected = deformer.solve(bent, iterations=3)
    out = np.full_like(bent, np.nan)
    returned = deformer.solve(bent, iterations=3, out=out)
    assert returned is out
    np.testing.assert_array_equal(out, expected)
    # The input array itself as out: read first, then overwritten with the result.
    same = bent.copy()
    assert deformer.solve(same, iterations=3, out=same) is same
    np.testing.assert_array_equal(same, expected)
    # Frame after frame into one array, each frame's own result (nothing kept from the last).
    for scale in (1.0, 0.5, 0.0):
        frame = bent.copy()
        frame[:, 2] *= scale
        np.testing.assert_array_equal(deformer.solve(frame, iterations=3, out=out), deformer.solve(frame, iterations=3))
    stepped = deformer.step(bent, iterations=3)
    deformer.reset()
    out = np.zeros_like(bent)
    assert deformer.step(bent, iterations=3, out=out) is out
    np.testing.assert_array_equal(out, stepped)


def test_transform_points_writes_into_out():
    points = np.arange(12, dtype=np.float32).reshape(4, 3)
    matrix = np.diag([2.0, 2.0, 2.0, 1.0])
    out = np.empty_like(points)
    assert tegument.transform_points(points, matrix, out=out) is out
    np.testing.assert_array_equal(out, 2 * points)


@pytest.mark.parametrize("bad, what", [
    (np.zeros((49, 3), np.float64), "float64 (49, 3)"),
    (np.zeros((48, 3), np.float32), "float32 (48, 3)"),
    (np.zeros((3, 49), np.float32).T, "not C-contiguous"),
    ([[0.0, 0.0, 0.0]] * 49, "a list"),
])
def test_a_wrong_out_is_refused_naming_what_it_is(bad, what):
    deformer, bent = _bent_grid()
    with pytest.raises(tegument.TegumentError, match=r"out: expected a writable C-contiguous float32 array of shape \(49, 3\); got .*") as caught:
        deformer.solve(bent, iterations=1, out=bad)
    assert what in str(caught.value)


def test_a_read_only_out_is_refused_and_left_alone():
    deformer, bent = _bent_grid()
    out = np.zeros_like(bent)
    out.flags.writeable = False
    with pytest.raises(tegument.TegumentError, match="out: expected a writable"):
        deformer.solve(bent, iterations=1, out=out)
    assert not out.any()
