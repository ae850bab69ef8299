"""tegument.Collider and tegument.audit: numpy checking, frame updates, the audit."""

from __future__ import annotations

import numpy as np
import pytest

import tegument

from conftest import grid_arrays


def uv_sphere(radius: float = 1.0, rings: int = 12, segments: int = 24, center=(0.0, 0.0, 0.0)):
    """A closed, outward-wound triangulated UV sphere: positions (N, 3), triangles (T, 3)."""
    pts = [[0.0, 0.0, radius]]
    for i in range(1, rings):
        theta = np.pi * i / rings
        for j in range(segments):
            phi = 2 * np.pi * j / segments
            pts.append([radius * np.sin(theta) * np.cos(phi), radius * np.sin(theta) * np.sin(phi), radius * np.cos(theta)])
    pts.append([0.0, 0.0, -radius])
    top, bottom = 0, len(pts) - 1
    ring = lambda i, j: 1 + (i - 1) * segments + j % segments  # noqa: E731
    tris = []
    for j in range(segments):
        tris.append([top, ring(1, j), ring(1, j + 1)])
        tris.append([bottom, ring(rings - 1, j + 1), ring(rings - 1, j)])
    for i in range(1, rings - 1):
        for j in range(segments):
            a, b, c, d = ring(i, j), ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)
            tris.append([a, d, c])
            tris.append([a, c, b])
    positions = np.array(pts, dtype=np.float32) + np.array(center, dtype=np.float32)
    return positions, np.array(tris, dtype=np.int32)


def test_collider_properties_and_update_keeps_last_frame():
    positions, triangles = uv_sphere()
    collider = tegument.Collider(positions, triangles, thickness=0.01, friction=0.5)
    assert collider.vertex_count == len(positions)
    assert collider.triangle_count == len(triangles)
    assert collider.is_closed
    assert collider.thickness == pytest.approx(0.01)
    assert collider.friction == pytest.approx(0.5)
    assert collider.kinetic_friction == pytest.approx(0.5)
    moved = positions + np.float32(0.25)
    report = collider.update(moved)
    assert set(report.to_dict()) == {"cost_ratio", "rebuilt"}
    np.testing.assert_array_equal(collider.previous_positions, positions)
    np.testing.assert_array_equal(collider.positions, moved)
    np.testing.assert_array_equal(collider.triangles, triangles)
    assert collider.edges.shape == (len(triangles) * 3 // 2, 2)
    assert "Collider(" in repr(collider)
    collider.hold()
    np.testing.assert_array_equal(collider.previous_positions, moved)


def test_bvh_is_rebuilt_when_refitting_degrades_it():
    positions, triangles = uv_sphere()
    collider = tegument.Collider(positions, triangles, thickness=0.0, friction=0.0)
    rng = np.random.default_rng(1)
    scrambled = rng.permutation(positions).astype(np.float32) * np.float32(5.0)
    report = collider.update(np.ascontiguousarray(scrambled))
    assert report.rebuilt and report.cost_ratio > 1.0
    assert collider.bvh_rebuilds == 1


def test_topology_change_on_update_names_both_counts():
    positions, triangles = uv_sphere()
    collider = tegument.Collider(positions, triangles, thickness=0.0, friction=0.0)
    n = len(positions)
    with pytest.raises(tegument.TegumentError, match=f"collider had {n} vertices, update gave {n - 2}"):
        collider.update(positions[:-2].copy())


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p, t: (p.astype(np.complex64), t), "positions: expected float32"),
        (lambda p, t: (p, t.astype(bool)), "triangles: expected int32 (T, 3)"),
        (lambda p, t: (p, t.astype(np.float32)), "triangles: expected int32 (T, 3)"),
        (lambda p, t: (p, t[:, :2].copy()), "triangles: expected int32 (T, 3)"),
        (lambda p, t: (p, np.where(t == 5, 10_000, t).astype(np.int32)), "refers to vertex 10000"),
        (lambda p, t: (p, np.where(t == 5, -1, t).astype(np.int32)), "negative vertex index"),
    ],
)
def test_bad_collider_input_is_refused_with_a_message(make, message):
    positions, triangles = uv_sphere()
    p, t = make(positions, triangles)
    with pytest.raises(tegument.TegumentError) as info:
        tegument.Collider(p, t, thickness=0.0, friction=0.0)
    assert message in str(info.value)


def test_bad_settings_and_nan_positions_are_refused():
    positions, triangles = uv_sphere()
    with pytest.raises(tegument.TegumentError, match="thickness"):
        tegument.Collider(positions, triangles, thickness=-1.0)
    with pytest.raises(tegument.TegumentError, match="friction"):
        tegument.Collider(positions, triangles, friction=float("nan"))
    bad = positions.copy()
    bad[7, 1] = np.nan
    collider = tegument.Collider(positions, triangles, thickness=0.0, friction=0.0)
    with pytest.raises(tegument.TegumentError, match="vertex 7"):
        collider.update(bad)
    # The failed update left the collider untouched.
    np.testing.assert_array_equal(collider.positions, positions)


def test_audit_counts_vertices_inside_and_edges_crossing_both_ways():
    sphere_p, sphere_t = uv_sphere(radius=1.0)
    sphere = tegument.Collider(sphere_p, sphere_t, thickness=0.0, friction=0.0)
    positions, corner_verts, polygon_sizes = grid_arrays(10, 10)
    positions = positions * np.float32(2.0)
    positions[:, 2] = 0.05
    result = tegument.audit(positions, corner_verts, polygon_sizes, [sphere])
    radius = np.linalg.norm(positions, axis=1)
    deep = int(np.sum(radius < 0.95))
    assert deep <= result.vertices_inside <= int(np.sum(radius < 1.0))
    assert result.edges_crossing > 0
    assert result.collider_edges_crossing > 0
    assert result.vertices_inside_indices.dtype == np.int32
    assert len(result.vertices_inside_indices) == result.vertices_inside
    assert result.edges_crossing_indices.shape == (result.edges_crossing, 2)
    assert result.collider_edges_crossing_indices.shape == (result.collider_edges_crossing, 2)
    assert result.open_colliders == []
    # Every crossing edge has one end inside and one outside the sphere.
    for a, b in result.edges_crossing_indices:
        assert (radius[a] < 1.0) != (radius[b] < 1.0)
    # Lifted clear of the sphere: nothing.
    lifted = positions.copy()
    lifted[:, 2] = 3.0
    clear = tegument.audit(lifted, corner_verts, polygon_sizes, (sphere,))
    assert (clear.vertices_inside, clear.edges_crossing, clear.collider_edges_crossing) == (0, 0, 0)


def test_audit_sees_colliders_after_update_and_skips_open_ones_for_inside():
    sphere_p, sphere_t = uv_sphere(radius=0.5)
    sphere = tegument.Collider(sphere_p, sphere_t, thickness=0.0, friction=0.0)
    open_cap = tegument.Collider(sphere_p, sphere_t[:-10].copy(), thickness=0.0, friction=0.0)
    positions, corner_verts, polygon_sizes = grid_arrays(6, 6)
    positions[:, 2] = 3.0
    assert tegument.audit(positions, corner_verts, polygon_sizes, [sphere]).vertices_inside == 0
    sphere.update(sphere_p + np.array([0, 0, 3.0], dtype=np.float32))
    assert tegument.audit(positions, corner_verts, polygon_sizes, [sphere]).vertices_inside > 0
    result = tegument.audit(positions, corner_verts, polygon_sizes, [open_cap])
    assert result.open_colliders == [0] and result.vertices_inside == 0


def test_audit_refuses_bad_arguments():
    positions, corner_verts, polygon_sizes = grid_arrays(2, 2)
    sphere = tegument.Collider(*uv_sphere(), thickness=0.0, friction=0.0)
    with pytest.raises(tegument.TegumentError, match=r"colliders\[1\]: expected a tegument.Collider"):
        tegument.audit(positions, corner_verts, polygon_sizes, [sphere, "sphere"])
    with pytest.raises(tegument.TegumentError, match="colliders: expected a sequence"):
        tegument.audit(positions, corner_verts, polygon_sizes, 3)
    with pytest.raises(tegument.TegumentError, match="corner_verts: expected int32"):
        tegument.audit(positions, corner_verts.astype(np.float32), polygon_sizes, [sphere])
    with pytest.raises(tegument.TegumentError, match="refers to vertex 99"):
        tegument.audit(positions, np.where(corner_verts == 0, 99, corner_verts).astype(np.int32), polygon_sizes, [sphere])
    with pytest.raises(tegument.TegumentError, match="depth tolerance"):
        tegument.audit(positions, corner_verts, polygon_sizes, [sphere], depth_tolerance=-1.0)


def test_no_colliders_means_a_clean_audit():
    positions, corner_verts, polygon_sizes = grid_arrays(3, 3)
    result = tegument.audit(positions, corner_verts, polygon_sizes, [])
    assert (result.vertices_inside, result.edges_crossing, result.collider_edges_crossing) == (0, 0, 0)


def _skin(n: int = 24):
    positions, corner_verts, polygon_sizes = grid_arrays(n, n)
    return positions, corner_verts, polygon_sizes, tegument.PyramidDeformer(positions, corner_verts, polygon_sizes)


def test_step_keeps_skin_outside_a_sphere_pushed_through_it_and_remembers():
    positions, corner_verts, polygon_sizes, deformer = _skin()
    sphere, tris = uv_sphere(0.4, center=(0.0, 0.0, -0.6))
    collider = tegument.Collider(sphere, tris, thickness=0.01)
    assert deformer.last_step is None
    raised = []
    for dz in np.linspace(0.0, 0.9, 7):  # ends with the centre 0.3 above the skin
        collider.update(sphere + np.float32([0.0, 0.0, dz]))
        out = deformer.step(positions, [collider], iterations=10, closeness=0.05)
        assert out.dtype == np.float32 and out.shape == positions.shape and np.isfinite(out).all()
        found = tegument.audit(out, corner_verts, polygon_sizes, [collider])
        assert (found.vertices_inside, found.edges_crossing, found.collider_edges_crossing) == (0, 0, 0)
        assert len(deformer.last_step.pinched) == 0
        raised.append(out[:, 2].max())
    # The skin rides over the sphere's top (0.3 + 0.4 + thickness).
    assert raised[-1] > 0.7
    assert deformer.last_step.first_pass_contacts > 0
    # Without colliders a step is the plain solve from the input; reset forgets the history.
    deformer.reset()
    assert deformer.last_step is None
    np.testing.assert_array_equal(deformer.step(positions), deformer.solve(positions))
    # A history given to reset is where the next step's first pass starts:
    # from the skin lifted over the sphere, the sphere (still) keeps it there.
    collider.update(collider.positions)
    deformer.reset(out)
    again = deformer.step(positions, [collider], iterations=10, closeness=0.05)
    assert again[:, 2].max() > 0.7
    with pytest.raises(tegument.TegumentError, match="history"):
        deformer.reset(out[:-1])


def test_step_refuses_bad_colliders_and_positions():
    positions, _, _, deformer = _skin(4)
    with pytest.raises(tegument.TegumentError, match=r"colliders\[0\]: expected a tegument.Collider"):
        deformer.step(positions, [object()])
    with pytest.raises(tegument.TegumentError, match="positions"):
        deformer.step(positions[:-1], [])
    bad = positions.copy()
    bad[3, 1] = np.nan
    with pytest.raises(tegument.TegumentError, match="not finite"):
        deformer.step(bad)


def test_step_refuses_the_same_collider_twice_instead_of_waiting_on_itself():
    # step() locks each collider for writing (compliant colliders are solved
    # by it): one object listed twice must be an error, not a deadlock.
    positions, _, _, deformer = _skin(4)
    sphere, tris = uv_sphere(0.2, center=(0.0, 0.0, -0.5))
    collider = tegument.Collider(sphere, tris, thickness=0.0, friction=0.0)
    with pytest.raises(tegument.TegumentError, match="item 1 is the same Collider"):
        deformer.step(positions, [collider, collider])
    out = deformer.step(positions, [collider])
    assert np.isfinite(out).all()


def test_collider_settings_left_out_come_from_the_core_defaults():
    positions, triangles = uv_sphere()
    bare = tegument.Collider(positions, triangles)
    defaults = tegument.DEFAULTS
    assert (bare.thickness, bare.friction, bare.kinetic_friction) == pytest.approx(
        (defaults.thickness, defaults.friction, defaults.kinetic_friction))
    assert defaults.thickness > 0 and defaults.friction > defaults.kinetic_friction > 0
    # A friction given alone is both coefficients, as before.
    rough = tegument.Collider(positions, triangles, friction=0.9)
    assert (rough.friction, rough.kinetic_friction) == pytest.approx((0.9, 0.9))
    split = tegument.Collider(positions, triangles, friction=0.9, kinetic_friction=0.4)
    assert split.kinetic_friction == pytest.approx(0.4)
