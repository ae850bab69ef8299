"""The penetration checker's own tests: it must see what is there and nothing else.

Run by ``make test-wheel`` (no product needed: these test the referee, not the player).
"""

from __future__ import annotations

import numpy as np
import pytest

import penetration as pen


def box(low=(-1.0, -1.0, -1.0), high=(1.0, 1.0, 1.0)):
    """A closed box as 6 outward quads (Blender's corner layout)."""
    (x0, y0, z0), (x1, y1, z1) = low, high
    positions = np.array([[x, y, z] for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)], dtype=np.float64)
    corners = np.array([0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5])
    return positions, pen.fan_triangles(corners, np.full(6, 4))


def l_shape():
    """A non-convex closed prism: an L in the xy plane (the corner square (1..2, 1..2) missing), z in 0..1."""
    outline = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], dtype=np.float64)
    n = len(outline)
    positions = np.concatenate([np.c_[outline, np.zeros(n)], np.c_[outline, np.ones(n)]])
    corners = list(range(n - 1, -1, -1)) + list(range(n, 2 * n))  # bottom facing -z, top facing +z
    sizes = [n, n]
    for i in range(n):
        j = (i + 1) % n
        corners += [i, j, n + j, n + i]
        sizes.append(4)
    # The n-gons are not convex: fan the bottom and top by hand from the reflex corner (3).
    bottom = [[3, 2, 1], [3, 1, 0], [3, 0, 5], [3, 5, 4]]
    top = [[n + 3, n + 4, n + 5], [n + 3, n + 5, n], [n + 3, n, n + 1], [n + 3, n + 1, n + 2]]
    sides = pen.fan_triangles(np.array(corners[2 * n :]), np.array(sizes[2:]))
    return positions, np.concatenate([np.array(bottom), np.array(top), sides])


def uv_sphere(radius=1.0, segments=32, rings=16, centre=(0.0, 0.0, 0.0)):
    """Vertices and triangles laid out like Blender's UV sphere."""
    rows = [[0.0, 0.0, radius]]
    for k in range(1, rings):
        phi = np.pi * k / rings
        for j in range(segments):
            theta = 2 * np.pi * j / segments
            rows.append([radius * np.sin(phi) * np.cos(theta), radius * np.sin(phi) * np.sin(theta), radius * np.cos(phi)])
    rows.append([0.0, 0.0, -radius])
    at = lambda k, j: 1 + (k - 1) * segments + j % segments  # noqa: E731
    bottom = len(rows) - 1
    tris = [[0, at(1, j), at(1, j + 1)] for j in range(segments)]
    for k in range(1, rings - 1):
        for j in range(segments):
            tris += [[at(k, j), at(k + 1, j), at(k + 1, j + 1)], [at(k, j), at(k + 1, j + 1), at(k, j + 1)]]
    tris += [[bottom, at(rings - 1, j + 1), at(rings - 1, j)] for j in range(segments)]
    return np.array(rows) + centre, np.array(tris)


def grid(n=10, size=2.0, z=0.0):
    xs, ys = np.meshgrid(np.linspace(-size / 2, size / 2, n + 1), np.linspace(-size / 2, size / 2, n + 1))
    positions = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], axis=1)
    at = lambda i, j: j * (n + 1) + i  # noqa: E731
    corners = np.array([[at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)] for j in range(n) for i in range(n)]).ravel()
    return positions, corners, np.full(n * n, 4)


# --- Topology ------------------------------------------------------------------------------------


def test_fan_triangles_and_edges_include_the_diagonals():
    triangles = pen.fan_triangles([0, 1, 2, 3, 4, 5, 6], [4, 3])
    assert triangles.tolist() == [[0, 1, 2], [0, 2, 3], [4, 5, 6]]
    assert pen.triangle_edges(triangles).tolist() == [[0, 1], [0, 2], [0, 3], [1, 2], [2, 3], [4, 5], [4, 6], [5, 6]]
    with pytest.raises(ValueError):
        pen.fan_triangles([0, 1, 2], [4])


def test_closed_and_open_surfaces_are_told_apart():
    assert pen.is_closed(box()[1]) and pen.is_closed(l_shape()[1]) and pen.is_closed(uv_sphere()[1])
    positions, corners, sizes = grid(3)
    assert not pen.is_closed(pen.fan_triangles(corners, sizes))
    assert not pen.is_closed(box()[1][:-1])


# --- Inside / outside ----------------------------------------------------------------------------


def test_points_inside_and_outside_a_box_including_near_its_surface():
    positions, triangles = box()
    points = np.array([
        [0, 0, 0], [0.999, 0.5, -0.5], [0.5, 0.999, 0.999],  # inside, two near a face or an edge
        [1.001, 0, 0], [0, 0, -1.001], [1.0001, 1.0001, 1.0001], [5, 5, 5],  # outside, three near it
        [1.0, 0.2, 0.3],  # on a face: contact, not inside
    ])
    assert pen.points_inside(points, positions, triangles).tolist() == [0, 1, 2]
    w = pen.winding_numbers(points, positions, triangles)
    np.testing.assert_allclose(w[:3], 1.0, atol=1e-9)
    np.testing.assert_allclose(w[3:7], 0.0, atol=1e-9)
    # On the surface the winding number is undefined (0 or 1 by a signed zero): the distance
    # to the surface, not the winding number, keeps such a point out.
    assert pen.points_inside(points[7:], positions, triangles, tolerance=0.0).tolist() == []


def test_the_tolerance_is_a_depth_under_the_surface():
    positions, triangles = box()
    points = np.array([[0.99999, 0, 0], [0.9999, 0, 0], [0, 0, 0]])
    assert pen.points_inside(points, positions, triangles, tolerance=1e-5).tolist() == [1, 2]
    assert pen.points_inside(points, positions, triangles, tolerance=0.0).tolist() == [0, 1, 2]


def test_points_in_the_notch_of_a_non_convex_shape_are_outside():
    positions, triangles = l_shape()
    points = np.array([
        [0.5, 0.5, 0.5], [1.5, 0.5, 0.5], [0.5, 1.5, 0.5], [0.99, 0.99, 0.01],  # in the L
        [1.5, 1.5, 0.5], [1.01, 1.01, 0.5], [1.9, 1.9, 0.99],  # in the notch (inside the bounding box)
        [0.5, 0.5, 1.2], [-0.01, 1.0, 0.5],  # outside beside it
    ])
    assert pen.points_inside(points, positions, triangles).tolist() == [0, 1, 2, 3]


def test_a_sphere_inside_outside_and_its_analytic_inradius():
    positions, triangles = uv_sphere(0.3, centre=(1.0, 2.0, 3.0))
    inradius = pen.uv_sphere_inradius(0.3, 32, 16)
    # The mesh's nearest face plane, measured on the mesh, equals the formula's.
    a, b, c = (positions[triangles[:, k]] - (1, 2, 3) for k in range(3))
    n = np.cross(b - a, c - a)
    measured = (np.abs(np.einsum("ij,ij->i", a, n)) / np.linalg.norm(n, axis=1)).min()
    assert inradius == pytest.approx(measured, rel=1e-12) and 0.29 < inradius < 0.3
    rng = np.random.default_rng(1)
    directions = rng.normal(size=(500, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    inner = (1, 2, 3) + directions * (inradius - 1e-3)
    outer = (1, 2, 3) + directions * (0.3 + 1e-3)
    points = np.concatenate([inner, outer])
    assert pen.points_inside(points, positions, triangles).tolist() == list(range(500))
    assert pen.points_inside_sphere(points, (1, 2, 3), inradius).tolist() == list(range(500))


# --- Crossings -----------------------------------------------------------------------------------


TRIANGLE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


@pytest.mark.parametrize(
    "p, q, crosses",
    [
        ([0.2, 0.2, -1], [0.2, 0.2, 1], True),  # straight through
        ([0.2, 0.2, 1], [0.3, 0.1, -1], True),  # through, slanted, the other way
        ([0.2, 0.2, 0.1], [0.2, 0.2, 1], False),  # above it
        ([0.6, 0.6, -1], [0.6, 0.6, 1], False),  # through the plane beside it
        ([0.5, 0.5, -1], [0.5, 0.5, 1], True),  # through its long edge: a crossing
        ([0.0, 0.0, -1], [0.0, 0.0, 1], True),  # through a corner
        ([0.5, 0.5 + 1e-12, -1], [0.5, 0.5 + 1e-12, 1], False),  # grazing just outside the edge
        ([0.5, -1e-12, -1], [0.5, -1e-12, 1], False),  # grazing just outside another edge
        ([0.2, 0.2, 0.0], [0.2, 0.2, 1], False),  # ends on it: touching
        ([-1, 0.2, 0.0], [2, 0.2, 0.0], False),  # lies in its plane
    ],
)
def test_segment_crosses_triangle(p, q, crosses):
    got = pen.segments_cross_triangles([p], [q], *TRIANGLE[:, None, :])
    assert got.tolist() == [crosses]
    # Orientation of either does not matter.
    assert pen.segments_cross_triangles([q], [p], TRIANGLE[0], TRIANGLE[2], TRIANGLE[1]).tolist() == [crosses]


def test_a_segment_through_the_shared_edge_of_two_triangles_crosses_the_surface():
    positions, corners, sizes = grid(2)
    triangles = pen.fan_triangles(corners, sizes)
    # Through the diagonal of the first quad, between its two triangles.
    a, c = positions[corners[0]], positions[corners[2]]
    mid = (a + c) / 2
    edges = np.array([[0, 1]])
    points = np.array([mid - (0, 0, 1), mid + (0, 0, 1)])
    assert pen.edges_crossing(points, edges, positions, triangles).tolist() == [0]


def test_edges_crossing_finds_exactly_the_crossing_edges_among_many():
    rng = np.random.default_rng(7)
    positions, triangles = uv_sphere(0.5)
    starts = rng.uniform(-1, 1, size=(400, 3))
    ends = starts + rng.normal(scale=0.3, size=(400, 3))
    points = np.concatenate([starts, ends])
    edges = np.stack([np.arange(400), np.arange(400) + 400], axis=1)
    got = pen.edges_crossing(points, edges, positions, triangles)
    # Brute force over every pair, no broad phase.
    p, q = points[edges[:, 0]], points[edges[:, 1]]
    i, j = np.meshgrid(np.arange(400), np.arange(len(triangles)), indexing="ij")
    i, j = i.ravel(), j.ravel()
    t = triangles[j]
    hit = pen.segments_cross_triangles(p[i], q[i], positions[t[:, 0]], positions[t[:, 1]], positions[t[:, 2]])
    want = np.unique(i[hit])
    assert len(want) > 20 and got.tolist() == want.tolist()
    # A segment crossing a closed surface has one end inside and one outside, or crosses twice.
    inside = np.zeros(800, bool)
    inside[pen.points_inside(points, positions, triangles, tolerance=0)] = True
    one_in = inside[edges[:, 0]] != inside[edges[:, 1]]
    assert set(np.nonzero(one_in)[0]) <= set(got.tolist())


def test_overlapping_pairs_matches_brute_force():
    rng = np.random.default_rng(3)
    a_min = rng.uniform(0, 10, (300, 3))
    a_max = a_min + rng.uniform(0, 1, (300, 3))
    b_min = rng.uniform(0, 10, (200, 3))
    b_max = b_min + rng.uniform(0, 3, (200, 3))
    got = set()
    for i, j in pen.overlapping_pairs(a_min, a_max, b_min, b_max):
        got |= set(zip(i.tolist(), j.tolist()))
    overlap = ((a_min[:, None] <= b_max[None]) & (b_min[None] <= a_max[:, None])).all(axis=2)
    assert got == set(zip(*map(lambda x: x.tolist(), np.nonzero(overlap))))


# --- A skin against colliders --------------------------------------------------------------------


def test_a_skin_resting_at_thickness_on_a_sphere_is_clean_and_one_pushed_through_is_not():
    positions, corners, sizes = grid(20, 2.0)
    triangles = pen.fan_triangles(corners, sizes)
    # The flat skin 0.01 above the sphere's pole (thickness distance) and just touching it.
    for top in (-0.01, -1e-6):
        sphere, tris = uv_sphere(0.3, centre=(0.0, 0.0, top - 0.3))
        clean = pen.find_penetrations(positions, triangles, [(sphere, tris)])
        assert clean.total == 0 and clean.open_colliders == [], (top, clean.counts())
    # The sphere pushed 0.1 through the skin: vertices inside, edges through it both ways.
    sphere, tris = uv_sphere(0.3, centre=(0.0, 0.0, -0.2))
    counts = pen.find_penetrations(positions, triangles, [(sphere, tris)]).counts()
    assert counts["vertices_inside"] > 0 and counts["skin_edges_crossing"] > 0, counts
    assert counts["collider_edges_crossing"] > 0, counts
    # A sphere small enough to pass between the skin's vertices: only its own edges show it.
    small, small_tris = uv_sphere(0.02, segments=8, rings=4, centre=(0.05, 0.05, 0.0))
    between = pen.find_penetrations(positions, triangles, [(small, small_tris)])
    assert between.counts()["vertices_inside"] == 0 and between.counts()["collider_edges_crossing"] > 0


def test_an_open_collider_is_checked_for_crossings_only():
    positions, corners, sizes = grid(4, 2.0)
    triangles = pen.fan_triangles(corners, sizes)
    board, board_corners, board_sizes = grid(3, 1.0, z=0.0)
    board = board @ np.array([[1, 0, 0], [0, 0, 1], [0, 1, 0]])  # stood up on its edge, through the skin
    found = pen.find_penetrations(positions, triangles, [(board, pen.fan_triangles(board_corners, board_sizes))])
    assert found.open_colliders == [0] and found.counts()["vertices_inside"] == 0
    assert found.counts()["skin_edges_crossing"] + found.counts()["collider_edges_crossing"] > 0


def test_a_penetration_planted_in_a_cache_is_found_at_its_frame(tmp_path):
    sphere, tris = uv_sphere(0.3)
    positions, corners, sizes = grid(20, 2.0, z=0.0)
    # Object space: the skin object sits 0.5 above the world origin, the sphere at the origin.
    to_world = np.eye(4)
    to_world[2, 3] = 0.5
    frames = np.repeat(positions[None], 4, axis=0)
    planted = np.argmin(np.linalg.norm(positions[:, :2], axis=1))
    frames[2, planted] = (0.0, 0.0, -0.6)  # 0.1 below the world origin: deep in the sphere
    pen.write_pc2(tmp_path / "skin.pc2", frames)
    reports = pen.check_cache(tmp_path / "skin.pc2", corners, sizes, lambda k: [(sphere, tris)], to_world)
    assert [r.total for r in reports[:2] + reports[3:]] == [0, 0, 0]
    assert reports[2].vertices_inside.tolist() == [planted]
    assert reports[2].counts()["skin_edges_crossing"] > 0
    # Without the object's matrix the skin lies through the sphere at every frame.
    assert all(r.total > 0 for r in pen.check_cache(tmp_path / "skin.pc2", corners, sizes, lambda k: [(sphere, tris)]))


def test_a_cache_that_is_not_pc2_is_refused(tmp_path):
    (tmp_path / "bad.pc2").write_bytes(b"POINTCACHE3\0" + bytes(20))
    with pytest.raises(ValueError, match="not a PC2"):
        pen.read_pc2(tmp_path / "bad.pc2")
    pen.write_pc2(tmp_path / "short.pc2", np.zeros((2, 3, 3)))
    (tmp_path / "short.pc2").write_bytes((tmp_path / "short.pc2").read_bytes()[:-4])
    with pytest.raises(ValueError, match="length"):
        pen.read_pc2(tmp_path / "short.pc2")


def test_a_dense_skin_against_a_few_thousand_triangles_finds_exactly_the_cap_inside():
    # A 64 × 32 sphere (~4,000 triangles) whose top pokes 0.05 through a 40 × 40 grid: the
    # vertices inside are the grid's points inside the cap, every skin edge from one of them to
    # a point outside crosses the sphere, and the sphere's edges that cross the grid ring the
    # cap. (How long the checker takes is the benchmarks' business, not a test's.)
    centre, radius = np.array([0.0, 0.0, -0.55]), 0.6
    sphere, tris = uv_sphere(radius, segments=64, rings=32, centre=tuple(centre))
    positions, corners, sizes = grid(40, 2.0)  # 1,681 vertices, spacing 0.05
    triangles = pen.fan_triangles(corners, sizes)
    found = pen.find_penetrations(positions, triangles, [(sphere, tris)])
    distance = np.linalg.norm(positions - centre, axis=1)
    # The polygonal sphere lies between its inscribed radius and the true one: points clear of
    # that band must be classified as the true sphere says; none of the grid's points is in it.
    inscribed = radius * np.cos(np.pi / 32)
    assert not ((distance > inscribed - 1e-9) & (distance < radius + 1e-9)).any()
    inside = np.flatnonzero(distance < inscribed)
    assert len(inside) > 50
    np.testing.assert_array_equal(np.sort(found.vertices_inside), inside)
    edges = pen.triangle_edges(triangles)
    cut = np.isin(edges, inside).sum(axis=1) == 1
    assert {tuple(e) for e in np.sort(found.skin_edges_crossing, axis=1)} == {tuple(e) for e in np.sort(edges[cut], axis=1)}
    assert len(found.collider_edges_crossing[0]) > 0 and found.open_colliders == []
