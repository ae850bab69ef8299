"""tegument.Mesh: topology through the numpy API, and every bad input refused."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import tegument
from conftest import cube_arrays, ticks_of_another_thread_during


def test_error_is_a_value_error():
    assert issubclass(tegument.TegumentError, ValueError)


def test_cube_is_closed(cube):
    mesh = tegument.Mesh(*cube)
    report = mesh.report
    assert report.is_closed_manifold
    assert mesh.vertex_count == 8 and mesh.polygon_count == 6
    edges = mesh.edges
    assert edges.dtype == np.int32 and edges.shape == (12, 2)
    assert (edges[:, 0] < edges[:, 1]).all()
    assert len(mesh.boundary_vertices) == 0
    for key in ("non_manifold_edges", "boundary_vertices", "degenerate_polygons", "isolated_vertices"):
        assert getattr(report, key) == 0


def test_grid_boundary_and_ordered_rings(grid):
    positions = grid[0]
    mesh = tegument.Mesh(*grid)
    assert mesh.report.boundary_vertices == 14
    assert sorted(mesh.boundary_vertices) == sorted({*range(5), *range(15, 20), 5, 10, 9, 14})
    for v in range(mesh.vertex_count):
        ring = mesh.one_ring(v)
        d = positions[ring] - positions[v]
        turns = np.cross(d[:-1], d[1:])[:, 2]
        assert (turns > 0).all(), f"ring of {v} is not counter-clockwise: {ring}"
    assert len(mesh.one_ring(6)) == 4 and len(mesh.one_ring(0)) == 2


def test_defects_are_counted(grid):
    positions, corners, sizes = grid
    positions = np.vstack([positions, [[9, 9, 9]], [[0, -1, -1]], [[0.5, -1, -1]]]).astype(np.float32)
    # a third quad on the boundary edge 0-1 makes it non-manifold; vertex 20 is loose
    corners = np.concatenate([corners, [1, 0, 21, 22], [0, 1, 0]]).astype(np.int32)
    sizes = np.concatenate([sizes, [4, 3]]).astype(np.int32)
    report = tegument.Mesh(positions, corners, sizes).report
    assert report.isolated_vertices == 1
    assert report.degenerate_polygons == 1
    assert not report.is_clean
    mesh = tegument.Mesh(positions, corners, sizes)
    assert 20 in mesh.problem_vertices()


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda p, c, s: (p.astype(np.complex64), c, s), r"positions: expected float32 \(N, 3\) \(other float types are converted\); got complex64 \(8, 3\)"),
        (lambda p, c, s: (np.zeros((8, 4), np.float32), c, s), r"got float32 \(8, 4\)"),
        (lambda p, c, s: (p.astype(bool), c, s), r"got bool \(8, 3\)"),
        (lambda p, c, s: (p.tolist(), c, s), r"positions: expected float32 \(N, 3\) \(other float types are converted\); got a list"),
        (lambda p, c, s: (p, c.astype(np.float32), s), r"corner_verts: expected int32 \(N,\)"),
        (lambda p, c, s: (p, np.where(np.arange(24) == 17, 99, c).astype(np.int32), s), r"corner 17 refers to vertex 99, but the mesh has 8 vertices"),
        (lambda p, c, s: (p, np.where(np.arange(24) == 3, -5, c).astype(np.int32), s), r"corner 3 refers to vertex -5"),
        (lambda p, c, s: (np.where(np.arange(8)[:, None] == 3, np.nan, p).astype(np.float32), c, s), r"vertex 3 is not finite"),
        (lambda p, c, s: (np.where(np.arange(8)[:, None] == 5, np.inf, p).astype(np.float32), c, s), r"vertex 5 is not finite"),
        (lambda p, c, s: (p, c, np.array([4, 4, 2, 4, 4, 6], np.int32)), r"polygon 2 has 2 corners"),
        (lambda p, c, s: (p, c, np.array([4, 4, 4, 4, 4], np.int32)), r"add up to 20 corners but 24"),
        (lambda p, c, s: (p, c, np.array([4, 4, 4, 4, 4, 8], np.int32)), r"add up to more corners than the 24 given"),
    ],
)
def test_bad_input_is_refused_with_a_clear_message(cube, mutate, message):
    with pytest.raises(tegument.TegumentError, match=message):
        tegument.Mesh(*mutate(*cube))


def test_one_ring_out_of_range(cube):
    mesh = tegument.Mesh(*cube)
    with pytest.raises(tegument.TegumentError, match="vertex 8 is out of range: the mesh has 8 vertices"):
        mesh.one_ring(8)
    with pytest.raises(tegument.TegumentError, match="vertex -1 is out of range"):
        mesh.one_ring(-1)


def test_many_threads_at_once():
    results = []

    def work():
        for _ in range(20):
            results.append(tegument.Mesh(*cube_arrays()).report.edge_count)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results == [12] * 80


def test_large_mesh_releases_the_gil():
    # A 600×600 grid: another Python thread must run while Rust builds it. The control, a
    # call CPython makes without releasing the GIL (sorting a list), shows that the count
    # separates the two: it lets the other thread run not once.
    n = 600
    xs, ys = np.meshgrid(np.arange(n + 1, dtype=np.float32), np.arange(n + 1, dtype=np.float32))
    positions = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size, np.float32)], axis=1)
    i, j = np.meshgrid(np.arange(n), np.arange(n))
    base = (j * (n + 1) + i).ravel()
    corners = np.stack([base, base + 1, base + n + 2, base + n + 1], axis=1).astype(np.int32).ravel()
    sizes = np.full(n * n, 4, np.int32)
    meshes = []
    during = ticks_of_another_thread_during(lambda: meshes.append(tegument.Mesh(positions, corners, sizes)))
    assert meshes[0].report.boundary_vertices == 4 * n
    numbers = np.random.default_rng(0).permutation(1_000_000).tolist()
    held = ticks_of_another_thread_during(lambda: sorted(numbers))
    assert held == 0, f"control: the other thread ran {held} times during a call that holds the GIL"
    assert during >= 1, "the other thread never ran while the mesh was built: the call held the GIL"


def test_transform_points_applies_the_affine_part_of_an_object_matrix():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(20_000, 3)).astype(np.float32)
    angle = 0.7
    matrix = np.array(
        [
            [np.cos(angle), -np.sin(angle) * 2.0, 0.0, 1.0e4],
            [np.sin(angle), np.cos(angle) * 2.0, 0.0, -2.0],
            [0.0, 0.0, 0.5, 3.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )
    moved = tegument.transform_points(points, matrix)
    assert moved.dtype == np.float32 and moved.shape == points.shape
    exact = points.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]
    # Rounded once from the double-precision product: within half an ulp of the exact value.
    assert (np.abs(moved - exact) <= np.spacing(np.abs(exact).astype(np.float32)) / 2).all()
    back = tegument.transform_points(moved, np.linalg.inv(matrix))
    assert np.abs(back - points).max() < 5e-3
    # The last row is not used; a non-finite point stays non-finite.
    projective = matrix.copy()
    projective[3] = [1.0, 2.0, 3.0, 4.0]
    assert np.array_equal(tegument.transform_points(points, projective), moved)
    nan = points[:3].copy()
    nan[1, 2] = np.nan
    out = tegument.transform_points(nan, matrix)
    assert np.isfinite(out[0]).all() and np.isnan(out[1]).any()
    assert tegument.transform_points(np.zeros((0, 3), np.float32), matrix).shape == (0, 3)


@pytest.mark.parametrize(
    "points, matrix, message",
    [
        (np.zeros((4, 3), np.complex64), np.eye(4), r"points: expected float32 \(N, 3\)"),
        (np.zeros((4, 2), np.float32), np.eye(4), r"points: expected float32 \(N, 3\)"),
        (np.zeros((4, 3), np.float32), np.eye(3), r"matrix: expected float64 \(4, 4\)"),
        (np.zeros((4, 3), np.float32), np.eye(4, dtype=np.int64), r"matrix: expected float64 \(4, 4\)"),
        (np.zeros((4, 3), np.float32), np.where(np.eye(4) == 1, np.inf, 0.0), r"matrix: element \(0, 0\) is inf"),
    ],
)
def test_transform_points_refuses_bad_arrays(points, matrix, message):
    with pytest.raises(tegument.TegumentError, match=message):
        tegument.transform_points(points, matrix)
