"""PyramidDeformer.step(self_collision=...) and audit(self_intersections=True) through numpy.

The verdict on self-intersections is this file's own, from ``testkit/penetration.py``'s exact
segment–triangle test (no tegument code): every edge of the fan-triangulated mesh against every
triangle that shares no vertex with it.
"""

from __future__ import annotations

import numpy as np
import pytest

import penetration
import tegument


def tube(around: int = 24, along: int = 48, radius: float = 0.2, length: float = 2.0):
    """An open cylinder along +z: positions, corner_verts, polygon_sizes."""
    angle = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
    z = np.linspace(0.0, length, along + 1)
    positions = np.stack([np.tile(radius * np.cos(angle), along + 1), np.tile(radius * np.sin(angle), along + 1),
                          np.repeat(z, around)], axis=1).astype(np.float32)
    i, j = (a.ravel() for a in np.meshgrid(np.arange(around), np.arange(along)))
    at = lambda i, j: j * around + i % around  # noqa: E731
    quads = np.stack([at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)], axis=1)
    return positions, quads.ravel().astype(np.int32), np.full(len(quads), 4, np.int32)


def bend(positions: np.ndarray, degrees: float, pivot_z: float = 1.0, low: float = 0.85, high: float = 1.15) -> np.ndarray:
    """A joint's bend about the x axis through (0, 0, pivot_z), blended in between heights low and
    high, as a two-bone rig's linear blend does (the inner side folds through itself)."""
    t = np.clip((positions[:, 2] - low) / (high - low), 0.0, 1.0)
    w = (t * t * (3 - 2 * t))[:, None]
    a = np.radians(degrees)
    turn = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    pivot = np.array([0.0, 0.0, pivot_z])
    turned = (positions - pivot) @ turn.T + pivot
    return (positions * (1 - w) + turned * w).astype(np.float32)


def crossing_pairs(positions, corner_verts, polygon_sizes) -> int:
    """Edges crossing a triangle that shares no vertex with them (the independent check)."""
    triangles = penetration.fan_triangles(corner_verts, polygon_sizes)
    edges = penetration.triangle_edges(triangles)
    x = np.asarray(positions, dtype=np.float64)
    e_min = np.minimum(x[edges[:, 0]], x[edges[:, 1]])
    e_max = np.maximum(x[edges[:, 0]], x[edges[:, 1]])
    t_min, t_max = x[triangles].min(axis=1), x[triangles].max(axis=1)
    count = 0
    for i, j in penetration.overlapping_pairs(e_min, e_max, t_min, t_max):
        e, t = edges[i], triangles[j]
        apart = ~((e[:, :1] == t).any(axis=1) | (e[:, 1:] == t).any(axis=1))
        e, t = e[apart], t[apart]
        count += int(penetration.segments_cross_triangles(x[e[:, 0]], x[e[:, 1]], x[t[:, 0]], x[t[:, 1]], x[t[:, 2]]).sum())
    return count


def bake(self_collision, frames: int = 12):
    positions, corners, sizes = tube()
    deformer = tegument.PyramidDeformer(positions, corners, sizes)
    results, reports = [], []
    for frame in range(frames + 1):
        results.append(deformer.step(bend(positions, 150.0 * frame / frames), closeness=0.05, self_collision=self_collision))
        reports.append(deformer.last_step)
    return (positions, corners, sizes), results, reports


def test_a_bent_tube_folds_without_passing_through_itself():
    (_, corners, sizes), without, _ = bake(None)
    assert max(crossing_pairs(x, corners, sizes) for x in without) > 0, "without self-collision the fold must cross"
    (_, corners, sizes), with_self, reports = bake(tegument.SelfCollision(thickness=0.004))
    assert all(np.isfinite(x).all() for x in with_self)
    assert [crossing_pairs(x, corners, sizes) for x in with_self] == [0] * len(with_self)
    assert sum(r.self_contacts for r in reports) > 0
    assert all(r.self_intersections == 0 and r.self_tangled == 0 and len(r.self_pinched) == 0 for r in reports)
    assert reports[-1].self_pinched.dtype == np.int32


def test_the_audit_counts_self_intersections_with_its_own_geometry():
    (_, corners, sizes), without, _ = bake(None)
    folded = without[-1]
    ours = crossing_pairs(folded, corners, sizes)
    found = tegument.audit(folded, corners, sizes, [], self_intersections=True)
    assert (found.self_intersections > 0) == (ours > 0) and ours > 0
    pairs = found.self_intersection_indices
    assert pairs.shape == (found.self_intersections, 2) and pairs.dtype == np.int32
    assert (pairs[:, 0] < pairs[:, 1]).all()
    # Left out, nothing is counted (and nothing is spent on it).
    plain = tegument.audit(folded, corners, sizes, [])
    assert plain.self_intersections == 0 and plain.self_intersection_indices.shape == (0, 2)
    flat = tegument.audit(*tube(), [], self_intersections=True)
    assert flat.self_intersections == 0


def test_weights_limit_self_collision_to_a_region():
    positions, corners, sizes = tube()
    far = np.where(positions[:, 2] < 0.3, 1.0, 0.0).astype(np.float32)  # away from the joint
    deformer = tegument.PyramidDeformer(positions, corners, sizes)
    settings = tegument.SelfCollision(thickness=0.004, weights=far)
    for frame in range(13):
        out = deformer.step(bend(positions, 150.0 * frame / 12), closeness=0.05, self_collision=settings)
    assert crossing_pairs(out, corners, sizes) > 0, "the joint is outside the region: it folds through"
    assert deformer.last_step.self_contacts == 0
    np.testing.assert_array_equal(settings.weights, far)


def test_settings_defaults_and_repr():
    s = tegument.SelfCollision()
    d = tegument.DEFAULTS
    assert (s.thickness, s.friction, s.kinetic_friction, s.rings) == pytest.approx(
        (d.self_thickness, d.self_friction, d.self_kinetic_friction, d.self_rings))
    assert tegument.SelfCollision(friction=0.5).kinetic_friction == pytest.approx(0.5)
    assert tegument.SelfCollision(friction=0.5, kinetic_friction=0.1).kinetic_friction == pytest.approx(0.1)
    assert "thickness=" in repr(s) and s.weights is None


@pytest.mark.parametrize("kwargs, words", [
    ({"thickness": -1.0}, "thickness"),
    ({"thickness": float("nan")}, "thickness"),
    ({"friction": -0.1}, "friction"),
    ({"rings": -1}, "rings"),
    ({"rings": 9}, "rings"),
    ({"weights": np.array([1.0, np.nan], np.float32)}, "vertex 1"),
    ({"weights": np.zeros((2, 2), np.float32)}, "weights"),
])
def test_bad_settings_are_refused_naming_what(kwargs, words):
    with pytest.raises(tegument.TegumentError, match=words):
        tegument.SelfCollision(**kwargs)


def test_weights_of_another_mesh_are_refused_and_nothing_changes():
    positions, corners, sizes = tube(8, 4)
    deformer = tegument.PyramidDeformer(positions, corners, sizes)
    first = deformer.step(positions)
    with pytest.raises(tegument.TegumentError, match="weights have 3 values"):
        deformer.step(positions + 0.1, self_collision=tegument.SelfCollision(weights=np.ones(3, np.float32)))
    with pytest.raises(TypeError):
        deformer.step(positions, self_collision="on")
    # The failed steps left the history alone: the next step starts from the first's output.
    again = deformer.step(positions)
    np.testing.assert_allclose(again, first, atol=1e-6)
