"""Reports are typed classes; the dict spellings of 0.1.0 still work, with a DeprecationWarning."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import tegument
from conftest import cube_arrays, grid_arrays


def _triangles(corners):
    quads = corners.reshape(-1, 4)
    return np.ascontiguousarray(np.concatenate([quads[:, :3], quads[:, [0, 2, 3]]]), dtype=np.int32)


def _stepped():
    skin, corners, sizes = grid_arrays(6, 6)
    box, box_corners, _ = cube_arrays()
    collider = tegument.Collider(box * np.float32(0.3) - np.float32([0, 0, 0.5]), _triangles(box_corners), thickness=0.0, friction=0.0)
    deformer = tegument.PyramidDeformer(skin, corners, sizes)
    deformer.step(skin, [collider], iterations=2)
    collider.update(collider.positions + np.float32([0, 0, 0.6]))
    deformer.step(skin, [collider], iterations=2)
    return deformer, collider, skin, corners, sizes


def test_step_report_is_typed_and_frozen():
    deformer, *_ = _stepped()
    step = deformer.last_step
    assert isinstance(step, tegument.StepReport)
    assert isinstance(step.first_pass_contacts, int) and step.pinched.dtype == np.int32
    assert set(step.to_dict()) == {f.name for f in dataclasses.fields(step)}
    with pytest.raises(dataclasses.FrozenInstanceError):
        step.kinetic_energy = 1.0
    assert repr(step).startswith("tegument.StepReport(first_pass_contacts=")


def test_every_report_has_attributes_and_to_dict():
    deformer, collider, skin, corners, sizes = _stepped()
    update = collider.update(collider.positions)
    assert isinstance(update, tegument.ColliderUpdate) and isinstance(update.rebuilt, bool)
    found = tegument.audit(skin, corners, sizes, [collider])
    assert isinstance(found, tegument.AuditReport)
    assert found.vertices_inside == len(found.vertices_inside_indices)
    assert found.to_dict()["open_colliders"] == found.open_colliders
    report = tegument.Mesh(*cube_arrays()).report
    assert isinstance(report, tegument.MeshReport) and report.is_closed_manifold and report.vertex_count == 8


def test_dict_spellings_warn_and_give_the_same_values():
    deformer, collider, skin, corners, sizes = _stepped()
    step = deformer.last_step
    with pytest.warns(DeprecationWarning, match=r"StepReport\['worst_stretch'\] is deprecated .* use the attribute .worst_stretch"):
        assert step["worst_stretch"] == step.worst_stretch
    with pytest.warns(DeprecationWarning):
        assert step.get("max_recession") == step.max_recession
    with pytest.warns(DeprecationWarning):
        assert step.get("nope", 7) == 7
    with pytest.warns(DeprecationWarning):
        assert "pinched" in step
    with pytest.warns(DeprecationWarning):
        assert list(step.keys()) == list(step.to_dict())
    found = tegument.audit(skin, corners, sizes, [collider])
    with pytest.warns(DeprecationWarning):
        assert dict(found.items()).keys() == found.to_dict().keys()
    with pytest.warns(DeprecationWarning):
        assert {**found}.keys() == found.to_dict().keys()  # ** unpacking, as `{**report}` did
    with pytest.warns(DeprecationWarning), pytest.raises(KeyError):
        found["nope"]
    with pytest.warns(DeprecationWarning):
        assert collider.update(collider.positions)["rebuilt"] in (True, False)


def test_properties_hold_state_methods_compute():
    """The rule: stored state (no arguments, at most a copy) is a property; anything
    taking arguments or computing is a method. Mesh.edges, Mesh.boundary_vertices,
    Mesh.report and Collider.edges were methods: calling them still works, deprecated."""
    positions, corners, sizes = cube_arrays()
    mesh = tegument.Mesh(positions, corners, sizes)
    collider = tegument.Collider(positions, _triangles(corners), thickness=0.0, friction=0.0)
    for owner, name in ((mesh, "edges"), (mesh, "boundary_vertices"), (collider, "edges")):
        value = getattr(owner, name)
        assert isinstance(value, np.ndarray) and value.dtype == np.int32
        with pytest.warns(DeprecationWarning, match=rf"{type(owner).__name__}.{name}\(\) is deprecated"):
            called = value()
        assert type(called) is np.ndarray and np.array_equal(called, value)
    assert mesh.edges.shape == (12, 2) and collider.edges.shape == (18, 2)
    with pytest.warns(DeprecationWarning, match=r"Mesh.report\(\) is deprecated"):
        assert mesh.report() is mesh.report or mesh.report().to_dict() == mesh.report.to_dict()
    kinds = {
        tegument.Mesh: {"edges": property, "boundary_vertices": property, "report": property, "one_ring": "method", "problem_vertices": "method"},
        tegument.Collider: {"edges": property, "triangles": property, "positions": property, "update": "method"},
    }
    for cls, members in kinds.items():
        for name, kind in members.items():
            is_property = type(vars(cls)[name]).__name__ == "getset_descriptor"
            assert is_property == (kind is property), f"{cls.__name__}.{name}"


def test_defaults_come_from_the_core_and_are_the_keyword_defaults():
    d = tegument.DEFAULTS
    assert isinstance(d, tegument.Defaults)
    # closeness: the add-on's 0.05 became the core's default after 0.1.0 (it was 0.1).
    assert d.closeness == pytest.approx(0.05)
    assert (d.iterations, d.substeps, d.scale_safe, d.strain_mode) == (10, 1, True, "unified")
    dynamics = tegument.Dynamics()
    assert (dynamics.frame_time, dynamics.mass, dynamics.damping) == pytest.approx((d.frame_time, d.mass, d.damping))
    assert dynamics.gravity == pytest.approx(d.gravity)
    positions, corners, _ = cube_arrays()
    collider = tegument.Collider(positions, _triangles(corners))
    assert (collider.thickness, collider.friction, collider.kinetic_friction) == pytest.approx((d.thickness, d.friction, d.kinetic_friction))
    skin, corners, sizes = grid_arrays(4, 4)
    deformer = tegument.PyramidDeformer(skin, corners, sizes)
    bent = skin.copy()
    bent[:, 2] = 0.3 * bent[:, 0] ** 2
    np.testing.assert_array_equal(deformer.solve(bent), deformer.solve(bent, iterations=d.iterations, closeness=d.closeness))
