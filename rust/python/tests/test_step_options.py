"""PyramidDeformer.step's dynamics, compliant colliders and strain limits through numpy."""

from __future__ import annotations

import numpy as np
import pytest

import penetration
import tegument

from conftest import grid_arrays
from test_collide import uv_sphere


def _skin(n: int):
    positions, corner_verts, polygon_sizes = grid_arrays(n, n)
    return positions, corner_verts, polygon_sizes, tegument.PyramidDeformer(positions, corner_verts, polygon_sizes)


def _audit(positions, corner_verts, polygon_sizes, colliders):
    """The product's own audit: its output, checked against the independent checker below."""
    found = tegument.audit(positions, corner_verts, polygon_sizes, colliders)
    return found.vertices_inside, found.edges_crossing, found.collider_edges_crossing


def _penetrations(positions, corner_verts, polygon_sizes, colliders, spheres=()):
    """The verdict: testkit/penetration.py (no code shared with tegument) on ``colliders``
    ``[(positions, triangles)]``, plus vertices within the inradius of ``spheres``
    ``[(centre, radius)]`` (test_collide.uv_sphere's 24 segments, 12 rings)."""
    triangles = penetration.fan_triangles(corner_verts, polygon_sizes)
    counts = penetration.find_penetrations(positions, triangles, colliders).counts()
    counts["inside_sphere"] = sum(
        len(penetration.points_inside_sphere(positions, centre, penetration.uv_sphere_inradius(radius, 24, 12)))
        for centre, radius in spheres
    )
    return counts


def test_dynamics_overshoot_then_settle_and_energy_is_reported():
    positions, _, _, deformer = _skin(10)
    dynamics = tegument.Dynamics(frame_time=1 / 24, mass=1.0, damping=1.0)
    xs, energies = [], []
    for frame in range(120):
        shift = 0.5 * min(frame, 6) / 6
        out = deformer.step(positions + np.float32([shift, 0, 0]), closeness=0.1, dynamics=dynamics)
        xs.append(float(out[:, 0].mean() - positions[:, 0].mean()))
        energies.append(deformer.last_step.kinetic_energy)
    assert max(xs) > 0.52, f"no overshoot: peak {max(xs)}"
    assert abs(xs[-1] - 0.5) < 0.005, f"not settled: {xs[-1]}"
    assert max(energies) > 0 and energies[-1] < 1e-3 * max(energies)
    assert deformer.velocity.shape == positions.shape and deformer.velocity.dtype == np.float32


def test_closeness_one_follows_the_input_with_dynamics_and_substeps():
    positions, _, _, deformer = _skin(6)
    for frame in range(5):
        target = positions + np.float32([0.1 * frame, 0.0, 0.0]) + np.float32([0, 0, 0.1]) * np.sin(positions[:, :1] * frame)
        out = deformer.step(target.astype(np.float32), closeness=1.0, substeps=3, dynamics=tegument.Dynamics())
        np.testing.assert_allclose(out, target, atol=1e-5)


def test_dynamics_and_step_settings_are_checked():
    with pytest.raises(tegument.TegumentError, match="mass"):
        tegument.Dynamics(mass=0.0)
    with pytest.raises(tegument.TegumentError, match="frame time"):
        tegument.Dynamics(frame_time=-1.0)
    positions, _, _, deformer = _skin(4)
    with pytest.raises(tegument.TegumentError, match="substeps"):
        deformer.step(positions, substeps=0)
    with pytest.raises(tegument.TegumentError, match="substeps"):
        deformer.step(positions, substeps=65)
    with pytest.raises(tegument.TegumentError, match="strain_mode"):
        deformer.step(positions, max_stretch=0.1, strain_mode="later")
    with pytest.raises(tegument.TegumentError, match="max_stretch"):
        deformer.step(positions, max_stretch="a lot")
    with pytest.raises(tegument.TegumentError, match="max_stretch"):
        deformer.step(positions, max_stretch=np.zeros(3, np.float32))
    assert "mass=2" in repr(tegument.Dynamics(mass=2.0))


def _drag(strain_mode: str | None):
    """A sphere pressed into the skin with friction, then dragged sideways."""
    positions, corner_verts, polygon_sizes = grid_arrays(40, 40)
    deformer = tegument.PyramidDeformer(positions, corner_verts, polygon_sizes)
    sphere, tris = uv_sphere(0.3, center=(-0.3, 0.0, -0.32))
    collider = tegument.Collider(sphere, tris, thickness=0.01, friction=2.0)
    path = [np.float32([0, 0, 0.03 * k]) for k in range(6)] + [np.float32([0.05 * k, 0, 0.15]) for k in range(1, 9)]
    audits, found, out = [], [], positions
    for offset in path:
        collider.update(sphere + offset)
        kwargs = {} if strain_mode is None else {"max_stretch": 0.1, "strain_mode": strain_mode}
        out = deformer.step(positions, [collider], closeness=0.5, **kwargs)
        audits.append(_audit(out, corner_verts, polygon_sizes, [collider]))
        found.append(_penetrations(out, corner_verts, polygon_sizes, [(collider.positions, tris)], [((-0.3, 0.0, -0.32) + offset, 0.3)]))
    starts = corner_verts.reshape(-1, 4)
    edges = np.concatenate([starts[:, [0, 1]], starts[:, [1, 2]], starts[:, [2, 3]], starts[:, [3, 0]]])
    rest = np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=1)
    now = np.linalg.norm(out[edges[:, 0]] - out[edges[:, 1]], axis=1)
    return audits, found, float((now / rest).max()), deformer.last_step


def test_strain_limits_unified_hold_with_no_penetration_and_post_leaves_some():
    _, _, free_stretch, _ = _drag(None)
    assert free_stretch > 1.15, f"the scenario should stretch edges: {free_stretch}"
    audits, found, stretch, report = _drag("unified")
    assert all(not any(counts.values()) for counts in found), found
    assert all(a == (0, 0, 0) for a in audits), audits
    assert stretch <= 1.1 * 1.01
    assert report.worst_stretch == pytest.approx(stretch, abs=1e-4)
    post_audits, post_found, post_stretch, _ = _drag("post")
    assert post_stretch <= 1.1 * 1.01
    assert any(any(counts.values()) for counts in post_found), "post-collision limiting left no penetration"
    assert any(a != (0, 0, 0) for a in post_audits), "the audit missed the penetrations the checker found"


def test_a_compliant_collider_recedes_instead_of_pinching_the_skin():
    positions, corner_verts, polygon_sizes = grid_arrays(30, 30)
    positions *= np.float32(0.8)
    torso_mesh, tris = uv_sphere(0.3, center=(0.0, 0.0, -0.32))
    arm_mesh, _ = uv_sphere(0.3)

    def run(stiffness):
        deformer = tegument.PyramidDeformer(positions, corner_verts, polygon_sizes)
        torso = tegument.Collider(torso_mesh, tris, thickness=0.01)
        arm = tegument.Collider(arm_mesh + np.float32([0, 0, 0.5]), tris, thickness=0.01)
        arm.set_compliance(stiffness)
        pinched, out = 0, positions
        for k in range(9):
            arm.update(arm_mesh + np.float32([0, 0, 0.5 - 0.05 * k]))
            out = deformer.step(positions, [torso, arm], closeness=0.2)
            pinched = max(pinched, len(deformer.last_step.pinched))
        return out, arm, pinched, deformer.last_step

    _, kinematic_arm, pinched, _ = run(None)
    assert not kinematic_arm.is_compliant
    assert pinched > 0
    out, arm, pinched, report = run(100.0)
    assert arm.is_compliant and pinched == 0
    # Neither the torso the skin is pressed on nor the receded arm is penetrated.
    found = _penetrations(out, corner_verts, polygon_sizes, [(torso_mesh, tris), (arm.positions, tris)], [((0.0, 0.0, -0.32), 0.3)])
    assert not any(found.values()), found
    torso = tegument.Collider(torso_mesh, tris, thickness=0.01)
    assert _audit(out, corner_verts, polygon_sizes, [torso, arm]) == (0, 0, 0)
    recession = np.linalg.norm(arm.positions - arm.goal_positions, axis=1).max()
    assert recession > 0.1 and report.max_recession == pytest.approx(recession, rel=1e-4)
    np.testing.assert_array_equal(arm.goal_positions, arm_mesh + np.float32([0, 0, 0.1]))


def test_bad_compliance_is_refused_and_none_turns_it_off():
    sphere, tris = uv_sphere(0.3)
    collider = tegument.Collider(sphere, tris, thickness=0.0, friction=0.0)
    stiffness = np.full(len(sphere), 10.0, np.float32)
    stiffness[5] = -1.0
    with pytest.raises(tegument.TegumentError, match="vertex 5"):
        collider.set_compliance(stiffness)
    with pytest.raises(tegument.TegumentError, match="stiffness"):
        collider.set_compliance(np.ones(3, np.float32))
    with pytest.raises(tegument.TegumentError, match="stiffness"):
        collider.set_compliance("soft")
    collider.set_compliance(np.zeros(len(sphere), np.float32))
    assert not collider.is_compliant
    collider.set_compliance(5.0)
    assert collider.is_compliant
    collider.set_compliance(None)
    assert not collider.is_compliant


def test_place_moves_a_compliant_collider_without_touching_its_goals():
    sphere, tris = uv_sphere(0.3)
    collider = tegument.Collider(sphere, tris, thickness=0.0, friction=0.0)
    collider.set_compliance(10.0)
    collider.update(sphere + np.float32([0, 0, 1]))
    collider.place(sphere + np.float32([0, 0, 0.5]))
    np.testing.assert_array_equal(collider.positions, sphere + np.float32([0, 0, 0.5]))
    np.testing.assert_array_equal(collider.previous_positions, collider.positions)
    np.testing.assert_array_equal(collider.goal_positions, sphere + np.float32([0, 0, 1]))
    with pytest.raises(tegument.TegumentError, match="positions"):
        collider.place(sphere[:3])
