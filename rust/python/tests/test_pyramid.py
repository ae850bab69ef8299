"""tegument.PyramidDeformer through the numpy API: the "Must show (tests)" of
issue 3 (identity, rigid motion, candy wrapper, Jacobi fixed point, thread
count) and bad input."""

from __future__ import annotations

import pathlib
import subprocess
import sys

import numpy as np
import pytest

import tegument
from conftest import grid_arrays, ticks_of_another_thread_during

# ---------------------------------------------------------------- meshes


def cylinder_arrays(around: int = 16, along: int = 10, radius: float = 0.5, length: float = 4.0):
    """Open cylinder along +z, outward quads (same layout as the core's shapes::cylinder)."""
    angle = 2 * np.pi * np.arange(around) / around
    rings = [np.stack([radius * np.cos(angle), radius * np.sin(angle), np.full(around, length * j / along)], 1) for j in range(along + 1)]
    positions = np.concatenate(rings).astype(np.float32)
    at = lambda i, j: j * around + i % around  # noqa: E731
    quads = [[at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)] for j in range(along) for i in range(around)]
    return positions, np.array(quads, dtype=np.int32).ravel(), np.full(len(quads), 4, dtype=np.int32)


def quad_sphere_arrays(n: int = 6, radius: float = 1.0):
    """Closed quad sphere: a subdivided cube projected on the sphere, 6n²+2 vertices."""
    faces = [((1, 0, 0), (0, 1, 0), (0, 0, 1)), ((-1, 0, 0), (0, 0, 1), (0, 1, 0)),
             ((0, 1, 0), (0, 0, 1), (1, 0, 0)), ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
             ((0, 0, 1), (1, 0, 0), (0, 1, 0)), ((0, 0, -1), (0, 1, 0), (1, 0, 0))]
    index: dict[tuple[int, int, int], int] = {}
    positions, quads = [], []
    for normal, u, v in faces:
        normal, u, v = np.array(normal), np.array(u), np.array(v)
        ids = np.zeros((n + 1, n + 1), dtype=np.int64)
        for j in range(n + 1):
            for i in range(n + 1):
                key = tuple(int(c) for c in normal * n + u * (2 * i - n) + v * (2 * j - n))
                if key not in index:
                    index[key] = len(positions)
                    p = np.array(key, dtype=np.float64)
                    positions.append(p / np.linalg.norm(p) * radius)
                ids[j, i] = index[key]
        quads += [[ids[j, i], ids[j, i + 1], ids[j + 1, i + 1], ids[j + 1, i]] for j in range(n) for i in range(n)]
    return (np.array(positions, dtype=np.float32), np.array(quads, dtype=np.int32).ravel(),
            np.full(len(quads), 4, dtype=np.int32))


def diagonal(p: np.ndarray) -> float:
    return float(np.linalg.norm(p.max(0) - p.min(0)))


def max_distance(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a.astype(np.float64) - b, axis=1).max())


def rotation(axis, angle: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def candy_wrapper(rest: np.ndarray, length: float, twist: float, bend: float) -> np.ndarray:
    """Linear blend skinning of a cylinder to two bones; the upper one twisted
    about the axis and bent about x through the middle. LBS collapses the
    twisted region (candy wrapper) and pinches the inside of the bend."""
    middle = np.array([0, 0, length / 2])
    upper = rotation((1, 0, 0), bend) @ rotation((0, 0, 1), twist)
    t = np.clip((rest[:, 2] / length - 0.3) / 0.4, 0, 1)
    w = (t * t * (3 - 2 * t))[:, None]
    moved = (rest - middle) @ upper.T + middle
    return ((1 - w) * rest + w * moved).astype(np.float32)


MESHES = {"sphere": quad_sphere_arrays, "cylinder": cylinder_arrays, "grid": lambda: grid_arrays(6, 5)}

# ---------------------------------------------------------------- must show


@pytest.mark.parametrize("scale_safe", [False, True])
@pytest.mark.parametrize("name", sorted(MESHES))
def test_identity(name, scale_safe):
    rest, corners, sizes = MESHES[name]()
    deformer = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=scale_safe)
    out = deformer.solve(rest)
    assert out.dtype == np.float32 and out.shape == rest.shape and out.flags.c_contiguous
    assert max_distance(out, rest) <= 1e-5 * diagonal(rest)
    assert deformer.residual(rest) < 1e-5


@pytest.mark.parametrize("name", sorted(MESHES))
def test_rigid_motion(name):
    rest, corners, sizes = MESHES[name]()
    rng = np.random.default_rng(3)
    for _ in range(4):
        r = rotation(rng.normal(size=3), rng.uniform(-3, 3))
        t = rng.uniform(-20, 20, size=3)
        moved = (rest @ r.T + t).astype(np.float32)
        for scale_safe in (False, True):
            deformer = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=scale_safe)
            out = deformer.solve(moved, iterations=10, closeness=0.05)
            assert max_distance(out, moved) <= 1e-4 * diagonal(moved)
        # Scale-safe mode also reproduces a uniform scale.
        scaled = (rest @ r.T * rng.uniform(0.3, 4) + t).astype(np.float32)
        deformer = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=True)
        assert max_distance(deformer.solve(scaled, closeness=0.05), scaled) <= 1e-4 * diagonal(scaled)


def test_plain_mode_does_not_survive_scaling():
    rest, corners, sizes = quad_sphere_arrays()
    scaled = rest * np.float32(3)
    plain = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=False)
    assert plain.residual(scaled) > 1e-3
    assert max_distance(plain.solve(scaled, closeness=0.05), scaled) > 1e-4 * diagonal(scaled)


def candy_wrapper_case(scale_safe):
    """A tube twisted 150° and bent 60° by skinning, and a deformer bound to it."""
    length = 4.0
    rest, corners, sizes = cylinder_arrays(24, 16, 0.5, length)
    lbs = candy_wrapper(rest, length, np.radians(150), np.radians(60))
    return lbs, tegument.PyramidDeformer(rest, corners, sizes, scale_safe=scale_safe)


@pytest.mark.parametrize("scale_safe", [False, True])
def test_candy_wrapper_residual_falls_monotonically(scale_safe):
    lbs, deformer = candy_wrapper_case(scale_safe)
    assert not deformer.accelerated
    # solve(k iterations) from the same input is the k-th iterate.
    residuals = [deformer.residual(deformer.solve(lbs, iterations=k)) for k in range(11)]
    assert residuals[0] == pytest.approx(deformer.residual(lbs))
    assert residuals[0] > 0.02, "the LBS input must show artefacts"
    assert all(b < a for a, b in zip(residuals, residuals[1:])), residuals
    assert residuals[-1] < 0.8 * residuals[0]


@pytest.mark.parametrize("scale_safe", [False, True])
def test_accelerated_solve_converges_with_every_iteration(scale_safe):
    lbs, deformer = candy_wrapper_case(scale_safe)
    plain = [deformer.solve(lbs, iterations=k) for k in (6, 400)]
    deformer.accelerated = True
    assert deformer.accelerated
    # Each iteration is closer to the converged solve (issue 28's convergence
    # error), which is the plain solver's. This twist (150° over a third of a
    # 16-ring, 384-vertex tube) is extreme and the mesh small: 6 iterations get
    # within 6.7 % (scale safe) and 4.0 %, plain ones 61 % and 56 %; the core's
    # tests hold 5 % on bends of larger meshes.
    converged = deformer.solve(lbs, iterations=400)
    rms = lambda a, b: np.sqrt(((a - b) ** 2).sum(1).mean())  # noqa: E731
    assert rms(converged, plain[1]) < 2e-3 * rms(converged, lbs)
    errors = [rms(deformer.solve(lbs, iterations=k), converged) / rms(lbs, converged) for k in range(11)]
    assert all(b < a for a, b in zip(errors, errors[1:])), errors
    assert errors[6] <= 0.08, errors
    assert rms(plain[0], converged) / rms(lbs, converged) > 3 * errors[6]


def test_a_tolerance_stops_converged_solves_and_warm_solves_start_from_the_last_result():
    lbs, deformer = candy_wrapper_case(True)
    assert deformer.tolerance is None
    deformer.accelerated = True
    converged = deformer.solve(lbs, iterations=400)
    rms = lambda a, b: float(np.sqrt(((a - b) ** 2).sum(1).mean()))  # noqa: E731
    scale = rms(converged, lbs)
    deformer.tolerance = tegument.DEFAULTS.tolerance
    assert deformer.tolerance == pytest.approx(0.02)
    cold = deformer.solve(lbs, iterations=tegument.DEFAULTS.accelerated_iterations)
    cold_iterations = deformer.last_iterations
    assert cold_iterations <= tegument.DEFAULTS.accelerated_iterations
    assert rms(cold, converged) <= 0.05 * scale
    # The same frame again, warm: it starts where the last solve ended and stops early (on this
    # 408-vertex tube after a few steps: below 4,096 vertices the rule asks for a smaller step).
    warm = deformer.solve(lbs, iterations=50, warm=True)
    assert 2 <= deformer.last_iterations <= 4 < cold_iterations
    assert rms(warm, converged) <= 0.05 * scale
    # After a reset the warm solve has nothing to start from: it is a cold one.
    deformer.reset()
    again = deformer.solve(lbs, iterations=tegument.DEFAULTS.accelerated_iterations, warm=True)
    np.testing.assert_array_equal(again, cold)
    # Plain iterations run their count; a bad tolerance is refused and changes nothing.
    deformer.accelerated = False
    deformer.solve(lbs, iterations=7)
    assert deformer.last_iterations == 7
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(tegument.TegumentError, match="it must be a positive number"):
            deformer.tolerance = bad
    assert deformer.tolerance == pytest.approx(0.02)
    deformer.tolerance = None
    assert deformer.tolerance is None


def test_a_reset_with_the_last_result_and_its_input_resumes_warm_solves_where_they_were():
    """A bake that continues cached frames gives the deformer the last frame's result and input
    (``reset(history, input=)``): its next warm solve is then the one the uninterrupted bake ran."""
    lbs, deformer = candy_wrapper_case(True)
    deformer.accelerated = True
    deformer.tolerance = tegument.DEFAULTS.tolerance
    first_input = np.ascontiguousarray(lbs * 0.97, dtype=np.float32)  # the frame before: a little smaller
    first = deformer.solve(first_input, iterations=12, warm=True)
    uninterrupted = deformer.solve(lbs, iterations=12, warm=True)
    deformer.reset(first, input=first_input)
    resumed = deformer.solve(lbs, iterations=12, warm=True)
    np.testing.assert_array_equal(resumed, uninterrupted)
    deformer.reset()
    cold = deformer.solve(lbs, iterations=12, warm=True)
    assert not np.array_equal(cold, uninterrupted)  # the frame depends on where it starts
    with pytest.raises(tegument.TegumentError, match="input given without history"):
        deformer.reset(input=first_input)
    with pytest.raises(tegument.TegumentError, match=r"input: expected float32 \(408, 3\)"):
        deformer.reset(first, input=first_input[:3])


def jacobi_reference(rest, corners, sizes, pinned, source, closeness, sweeps, scale_safe):
    """StretchMesh-style Jacobi reconstruction, in numpy, encoded here from the
    rest mesh (not by the library): normal of the one-ring polygon, plane
    through the ring centroid, mean-value weights of the projected vertex,
    plain height or per-edge elevation tangents. Each sweep moves every vertex
    to (1 − c)·target + c·input, all from the previous sweep's positions."""
    mesh = tegument.Mesh(rest, corners, sizes)
    free = np.setdiff1d(np.arange(len(rest)), pinned)
    rings = np.array([mesh.one_ring(int(v)) for v in free])  # the cylinder's interior valence is 4
    rest64 = rest.astype(np.float64)

    def frame(x):
        ring = x[rings]  # (F, k, 3)
        normal = np.cross(ring, np.roll(ring, -1, axis=1)).sum(1)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        centroid = ring.mean(1)
        heights = np.einsum("fkc,fc->fk", ring - centroid[:, None], normal)
        projected = ring - heights[..., None] * normal[:, None]
        return normal, centroid, heights, projected

    normal, centroid, heights, projected = frame(rest64)
    height = np.einsum("fc,fc->f", rest64[free] - centroid, normal)
    d = projected - (rest64[free] - height[:, None] * normal)[:, None]
    r = np.linalg.norm(d, axis=2)
    nxt = np.roll(d, -1, axis=1)
    angles = np.arctan2(np.einsum("fkc,fc->fk", np.cross(d, nxt), normal), np.einsum("fkc,fkc->fk", d, nxt))
    assert np.all(angles > 0) and np.allclose(angles.sum(1), 2 * np.pi)
    half = np.tan(angles / 2)
    weights = (np.roll(half, 1, axis=1) + half) / r
    weights /= weights.sum(1, keepdims=True)
    tangents = (height[:, None] - heights) / r

    target_input = source.astype(np.float64)
    x = target_input.copy()
    for _ in range(sweeps):
        normal, centroid, heights, projected = frame(x)
        placed = np.einsum("fk,fkc->fc", weights, projected)
        if scale_safe:
            offset = (weights * (np.linalg.norm(placed[:, None] - projected, axis=2) * tangents + heights)).sum(1)
        else:
            offset = height
        new = x.copy()
        new[free] = (1 - closeness) * (placed + offset[:, None] * normal) + closeness * target_input[free]
        x = new
    return x


@pytest.mark.parametrize("scale_safe", [False, True])
def test_same_fixed_point_as_jacobi(scale_safe):
    length = 4.0
    rest, corners, sizes = cylinder_arrays(16, 10, 0.5, length)
    lbs = candy_wrapper(rest, length, np.radians(120), np.radians(45))
    deformer = tegument.PyramidDeformer(rest, corners, sizes, scale_safe=scale_safe)
    # The end rings (open one-rings, encoded by the library with a virtual
    # closing neighbour this reference does not model) are held to the input by
    # closeness 1, so the reference treats them as fixed.
    ends = np.r_[0:16, 160:176]
    closeness = np.full(len(rest), 0.1, np.float32)
    closeness[ends] = 1.0
    reference = jacobi_reference(rest, corners, sizes, ends, lbs, 0.1, 600, scale_safe)
    out = deformer.solve(lbs, iterations=600, closeness=closeness)
    tolerance = 1e-4 * diagonal(lbs)
    assert max_distance(out, reference) <= tolerance
    assert max_distance(out, lbs) > 100 * tolerance, "the fixed point must differ from the input"


SCRIPT = """
import sys, numpy as np, tegument
sys.path.insert(0, {tests!r})
from test_pyramid import quad_sphere_arrays
rest, corners, sizes = quad_sphere_arrays(30)
moved = (rest * np.array([1.3, 0.8, 1.0], np.float32) + (rest[:, :1] * rest[:, 1:2])).astype(np.float32)
closeness = (np.arange(len(rest)) % 7 / 10).astype(np.float32)
out = tegument.PyramidDeformer(rest, corners, sizes).solve(moved, 10, closeness)
np.save(sys.argv[1], out)
"""


def test_same_output_whatever_the_thread_count(tmp_path):
    outputs = []
    for threads in (1, 2, 3):
        path = tmp_path / f"out{threads}.npy"
        env = {"RAYON_NUM_THREADS": str(threads), "PATH": "/usr/bin:/bin"}
        script = SCRIPT.format(tests=str(pathlib.Path(__file__).parent))
        subprocess.run([sys.executable, "-c", script, str(path)], check=True, env=env)
        outputs.append(np.load(path))
    assert outputs[0].tobytes() == outputs[1].tobytes() == outputs[2].tobytes()


# ---------------------------------------------------------------- behaviour


def test_boundaries_are_encoded_and_pinned_vertices_follow_the_input():
    rest, corners, sizes = cylinder_arrays(16, 10)
    deformer = tegument.PyramidDeformer(rest, corners, sizes)
    assert deformer.vertex_count == len(rest)
    assert deformer.pinned_vertices.dtype == np.int32
    assert deformer.pinned_vertices.size == 0, "the open ends are encoded, not pinned"
    # A quad grid's corners have two neighbours and no ring to encode: they keep their offset from
    # those neighbours (a ring fit) and bend with the sheet instead of following the input.
    flat, grid_corners, grid_sizes = grid_arrays(6, 5)
    grid = tegument.PyramidDeformer(flat, grid_corners, grid_sizes)
    assert grid.pinned_vertices.size == 0
    bent = flat.copy()
    bent[:, 2] = 0.4 * np.sin(2.0 * bent[:, 0]) + 0.2 * bent[:, 1] ** 2
    out = grid.solve(bent, closeness=0.0)
    sheet_corners = [0, 6, 35, 41]
    assert max_distance(out[sheet_corners], bent[sheet_corners]) > 1e-3, "the corners must not follow the input"
    # Only a vertex with fewer than two neighbours (here a loose one) is pinned: it follows the input.
    loose = np.vstack([flat, [[5.0, 5.0, 0.0]]]).astype(np.float32)
    with_loose = tegument.PyramidDeformer(loose, grid_corners, grid_sizes)
    np.testing.assert_array_equal(with_loose.pinned_vertices, [len(flat)])
    assert list(with_loose.pinned_reasons) == ["isolated"]
    moved = np.vstack([bent, [[5.0, 5.0, 1.0]]]).astype(np.float32)
    out = with_loose.solve(moved, closeness=0.0)
    assert max_distance(out[-1:], moved[-1:]) < 1e-5
    closed = tegument.PyramidDeformer(*quad_sphere_arrays())
    assert closed.pinned_vertices.size == 0


def test_closeness_forms():
    rest, corners, sizes = cylinder_arrays(16, 10)
    lbs = candy_wrapper(rest, 4.0, np.radians(120), np.radians(45))
    deformer = tegument.PyramidDeformer(rest, corners, sizes)
    default = deformer.solve(lbs)
    iterations = tegument.DEFAULTS.iterations
    np.testing.assert_array_equal(default, deformer.solve(lbs, iterations, 0.05))
    np.testing.assert_array_equal(default, deformer.solve(lbs, iterations, np.full(len(rest), 0.05, np.float32)))
    np.testing.assert_allclose(deformer.solve(lbs, 10, 1.0), lbs, atol=1e-6)
    np.testing.assert_array_equal(deformer.solve(lbs, 0), lbs)
    # Painted: follow the input only on the lower half.
    painted = (rest[:, 2] < 2.0).astype(np.float32)
    out = deformer.solve(lbs, 10, painted)
    lower = rest[:, 2] < 2.0
    assert max_distance(out[lower], lbs[lower]) < 1e-6
    assert max_distance(out[~lower], lbs[~lower]) > 1e-3
    # The input arrays are never modified.
    assert np.array_equal(lbs, candy_wrapper(rest, 4.0, np.radians(120), np.radians(45)))


def test_solve_releases_the_gil():
    rest, corners, sizes = quad_sphere_arrays(60)  # 21 602 vertices
    deformer = tegument.PyramidDeformer(rest, corners, sizes)
    moved = (rest * np.array([1.2, 0.9, 1.0], np.float32)).astype(np.float32)
    # Counted as in test_mesh.py's GIL test: a solve that held the GIL would let the other
    # thread run not once.
    assert ticks_of_another_thread_during(lambda: deformer.solve(moved, iterations=400)) >= 1


# ---------------------------------------------------------------- bad input


@pytest.fixture(scope="module")
def bound():
    rest, corners, sizes = quad_sphere_arrays(3)
    return tegument.PyramidDeformer(rest, corners, sizes), rest


def test_bind_refuses_bad_arrays():
    rest, corners, sizes = cylinder_arrays(8, 3)
    cases = [
        ((rest.astype(np.complex64), corners, sizes), "rest_positions: expected float32"),
        ((rest[:, :2].copy(), corners, sizes), "rest_positions: expected float32 (N, 3)"),
        ((rest.astype(bool), corners, sizes), "got bool"),
        ((rest, corners.astype(np.float64), sizes), "corner_verts: expected int32"),
        ((rest, corners, sizes.astype(np.float32)), "polygon_sizes: expected int32"),
        ((rest, np.where(corners == 5, 99, corners).astype(np.int32), sizes), "vertex 99"),
        ((rest, corners, sizes[:-1].copy()), "corner"),
    ]
    for args, message in cases:
        with pytest.raises(tegument.TegumentError, match=message.replace("(", r"\(").replace(")", r"\)")):
            tegument.PyramidDeformer(*args)
    nan = rest.copy()
    nan[5, 1] = np.nan
    with pytest.raises(tegument.TegumentError, match="vertex 5"):
        tegument.PyramidDeformer(nan, corners, sizes)
    with pytest.raises(ValueError):  # TegumentError is a ValueError
        tegument.PyramidDeformer("positions", corners, sizes)


def test_solve_refuses_bad_input(bound):
    deformer, rest = bound
    n = len(rest)
    nan = rest.copy()
    nan[7] = np.inf
    cases = [
        (dict(positions=rest[:-1].copy()), rf"positions: expected float32 \({n}, 3\)"),
        (dict(positions=rest.astype(np.complex64)), "positions: expected float32"),
        (dict(positions=rest[::2]), "positions"),
        (dict(positions=nan), "vertex 7"),
        (dict(positions=rest, iterations=-1), "iterations is -1"),
        (dict(positions=rest, closeness=1.5), "between 0 and 1"),
        (dict(positions=rest, closeness=float("nan")), "between 0 and 1"),
        (dict(positions=rest, closeness=np.full(n - 1, 0.5, np.float32)), rf"closeness: expected float32 \({n},\)"),
        (dict(positions=rest, closeness=np.full(n, 0.5, np.complex64)), "closeness: expected float32"),
        (dict(positions=rest, closeness=np.r_[np.full(n - 1, 0.5), [-0.5]].astype(np.float32)), f"vertex {n - 1}"),
        (dict(positions=rest, closeness="strong"), "closeness: expected None, a float"),
        (dict(positions=rest, closeness=True), "got a bool"),
        (dict(positions=rest, iterations=10**6), "iterations"),
    ]
    for kwargs, message in cases:
        with pytest.raises(tegument.TegumentError, match=message):
            deformer.solve(**kwargs)
    with pytest.raises(tegument.TegumentError, match="vertex 7"):
        deformer.residual(nan)
    # Still usable after all of that.
    np.testing.assert_allclose(deformer.solve(rest), rest, atol=1e-5)


def test_pinned_reasons_name_the_kind_of_every_pinned_vertex():
    # Only vertices with fewer than two neighbours are pinned (they follow the input): here a loose
    # vertex and the lone corner of a polygon whose other corners repeat.
    positions, corners, sizes = grid_arrays(6, 5)
    positions = np.vstack([positions, [[9.0, 9.0, 0.0]]]).astype(np.float32)
    grid = tegument.PyramidDeformer(positions, corners, sizes)
    reasons = grid.pinned_reasons
    assert list(reasons) == ["isolated"]
    assert reasons["isolated"].dtype == np.int32
    np.testing.assert_array_equal(reasons["isolated"], grid.pinned_vertices)
    np.testing.assert_array_equal(grid.pinned_vertices, [len(positions) - 1])
    # Three faces on one edge: its two ends are non-manifold, but they have neighbours: not pinned.
    positions = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (1, 0, 1), (0, 0, 1), (0, -1, 0), (1, -1, 0)], np.float32)
    corners = np.array([0, 1, 2, 3, 1, 0, 5, 4, 0, 1, 7, 6], np.int32)
    fin = tegument.PyramidDeformer(positions, corners, np.array([4, 4, 4], np.int32))
    assert fin.pinned_reasons == {} and fin.pinned_vertices.size == 0
    closed = tegument.PyramidDeformer(*quad_sphere_arrays())
    assert closed.pinned_reasons == {}


# ---------------------------------------------------------------- split seams (issue 26)


def split_by_side(positions: np.ndarray, corners: np.ndarray, sizes: np.ndarray):
    """The mesh split along x = 0 as a glTF importer splits a UV seam: the faces on the +x side
    get their own copies of the vertices they share with the -x side. Returns the split arrays
    and, per split vertex, the original vertex."""
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    side = np.array([positions[corners[s:s + n]].mean(axis=0)[0] > 0 for s, n in zip(starts, sizes)])
    face_of_corner = np.repeat(np.arange(len(sizes)), sizes)
    negative = np.zeros(len(positions), bool)
    negative[corners[~side[face_of_corner]]] = True
    shared = np.flatnonzero(negative & np.isin(np.arange(len(positions)), corners[side[face_of_corner]]))
    copy_of = {v: len(positions) + k for k, v in enumerate(shared)}
    split_corners = corners.copy()
    for c in np.flatnonzero(side[face_of_corner]):
        split_corners[c] = copy_of.get(int(corners[c]), corners[c])
    original = np.concatenate((np.arange(len(positions)), shared))
    return positions[original].copy(), split_corners, sizes, original


def test_split_seams_are_welded_and_stay_closed():
    rest, corners, sizes = quad_sphere_arrays(8)
    split_rest, split_corners, split_sizes, original = split_by_side(rest, corners, sizes)
    assert len(split_rest) > len(rest) + 20
    whole = tegument.PyramidDeformer(rest, corners, sizes)
    split = tegument.PyramidDeformer(split_rest, split_corners, split_sizes)
    assert split.vertex_count == len(split_rest) and split.welded_vertex_count == len(rest)
    assert len(split.pinned_vertices) == 0, "the seam's vertices have whole rings once welded"

    bend = lambda p: p + np.stack([0 * p[:, 0], 0 * p[:, 0], 0.6 * p[:, 0] ** 2], 1).astype(np.float32)  # noqa: E731
    solved = split.solve(bend(split_rest))
    assert solved.shape == split_rest.shape and np.isfinite(solved).all()
    np.testing.assert_allclose(solved, whole.solve(bend(rest))[original], atol=1e-6)
    stepped = split.step(bend(split_rest), closeness=np.full(len(split_rest), 0.05, np.float32))
    for copy, first in enumerate(original):
        assert np.array_equal(stepped[copy], stepped[first]), f"seam vertex {copy} left vertex {first}"
    with pytest.raises(tegument.TegumentError, match=rf"closeness: expected float32 \({len(split_rest)},\)"):
        split.solve(split_rest, closeness=np.full(len(rest), 0.05, np.float32))


def test_the_users_arrays_are_only_read():
    rest, corners, sizes = quad_sphere_arrays(6)
    split_rest, split_corners, split_sizes, _ = split_by_side(rest, corners, sizes)
    copies = [a.copy() for a in (split_rest, split_corners, split_sizes)]
    deformer = tegument.PyramidDeformer(split_rest, split_corners, split_sizes)
    deformer.step(split_rest * np.float32(1.1))
    for before, after in zip(copies, (split_rest, split_corners, split_sizes)):
        assert before.tobytes() == after.tobytes()
