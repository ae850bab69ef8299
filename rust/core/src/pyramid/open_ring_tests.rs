//! Open one-rings (boundary vertices) are encoded like interior ones: a
//! garment's hem, a face's edge or the rim of a hole deforms with the surface
//! instead of following the input.

use glam::{Mat3, Quat, Vec3};

use super::project::target;
use super::*;
use crate::mesh::shapes::{cylinder, grid, PolyMesh};
use crate::mesh::Topology;

fn encoded(mesh: &PolyMesh, scale_safe: bool) -> Encoding {
    let topology = Topology::build(mesh.input()).unwrap();
    encode(&topology, &mesh.positions, scale_safe).unwrap()
}

fn boundary_vertices(mesh: &PolyMesh) -> Vec<usize> {
    let topology = Topology::build(mesh.input()).unwrap();
    (0..mesh.positions.len()).filter(|&v| topology.is_boundary(v)).collect()
}

/// The index of encoded vertex `v` in the encoding.
fn entry(encoding: &Encoding, v: usize) -> usize {
    encoding.vertices().binary_search(&(v as u32)).unwrap_or_else(|_| panic!("vertex {v} is not encoded"))
}

/// A disc of `rings` rings of quads around a hole of radius `inner`, slightly
/// domed so that its rings are not all in one plane.
fn disc_with_hole(around: usize, rings: usize, inner: f32, outer: f32) -> PolyMesh {
    let mut mesh = PolyMesh::default();
    for j in 0..=rings {
        let radius = inner + (outer - inner) * j as f32 / rings as f32;
        for i in 0..around {
            let angle = std::f32::consts::TAU * i as f32 / around as f32;
            mesh.positions.push(Vec3::new(radius * angle.cos(), radius * angle.sin(), 0.2 * (1.0 - radius * radius)));
        }
    }
    let at = |i: usize, j: usize| j * around + i % around;
    for j in 0..rings {
        for i in 0..around {
            mesh.push_polygon(&[at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    mesh
}

#[test]
fn every_boundary_vertex_of_open_tubes_and_holed_discs_is_encoded() {
    for (name, mesh) in [("open cylinder", cylinder(16, 8, 1.0, 3.0)), ("disc with a hole", disc_with_hole(24, 6, 0.3, 1.0))] {
        let boundary = boundary_vertices(&mesh);
        assert!(!boundary.is_empty(), "{name}: the shape has no boundary");
        for scale_safe in [false, true] {
            let encoding = encoded(&mesh, scale_safe);
            assert!(encoding.pinned().is_empty(), "{name}: pinned {:?}", encoding.pinned());
            for &v in &boundary {
                let e = entry(&encoding, v);
                let sum: f32 = encoding.weights(e).iter().sum();
                assert!((sum - 1.0).abs() < 1e-5, "{name}: weights of {v} sum to {sum}");
                // The rest position is reproduced (the bind's self-test, checked here directly).
                let t = target(&encoding, e, &mesh.positions).unwrap();
                assert!((t - mesh.positions[v]).length() < 1e-5, "{name}: {v} rebuilt at {t}, rest {}", mesh.positions[v]);
            }
        }
    }
}

#[test]
fn a_flat_grid_pins_only_its_four_two_neighbour_corners() {
    let mesh = grid(6, 5, 2.0);
    let encoding = encoded(&mesh, true);
    let corners = [0u32, 6, 5 * 7, 5 * 7 + 6];
    let mut pinned: Vec<u32> = encoding.pinned_vertices();
    pinned.sort_unstable();
    assert_eq!(pinned, corners);
    assert!(encoding.pinned().iter().all(|p| p.1 == PinReason::Boundary));
}

#[test]
fn boundary_targets_follow_rigid_motions_and_uniform_scales() {
    let mesh = disc_with_hole(20, 4, 0.4, 1.0);
    let boundary = boundary_vertices(&mesh);
    let rotation = Mat3::from_quat(Quat::from_axis_angle(Vec3::new(1.0, 2.0, -0.5).normalize(), 1.1));
    let shift = Vec3::new(3.0, -1.0, 0.5);
    for (scale_safe, scale) in [(false, 1.0f32), (true, 1.0), (true, 2.5)] {
        let encoding = encoded(&mesh, scale_safe);
        let moved: Vec<Vec3> = mesh.positions.iter().map(|&p| rotation * (scale * p) + shift).collect();
        for &v in &boundary {
            let t = target(&encoding, entry(&encoding, v), &moved).unwrap();
            assert!((t - moved[v]).length() < 1e-4 * scale, "scale-safe {scale_safe}, scale {scale}: vertex {v} off by {}", (t - moved[v]).length());
        }
    }
}

#[test]
fn a_bent_open_sleeve_keeps_its_hems_with_the_surface() {
    // The sleeve's input bends linearly along its length and squashes one hem
    // flat; Pyramid Deform must move the hem vertices (not leave them at the
    // input) and keep them smooth with their neighbours.
    let mesh = cylinder(24, 12, 0.5, 3.0);
    let mut deformer = PyramidDeformer::bind(mesh.input(), DeformerOptions::default()).unwrap();
    assert!(deformer.pinned_vertices().is_empty(), "{:?}", deformer.pinned());
    let input: Vec<Vec3> = mesh
        .positions
        .iter()
        .map(|p| {
            let t = p.z / 3.0;
            let bend = Quat::from_rotation_y(1.2 * t);
            let squash = if t < 0.05 { Vec3::new(1.0, 0.3, 1.0) } else { Vec3::ONE };
            bend * (*p * squash)
        })
        .collect();
    let out = deformer.solve(&input, 200, Closeness::Uniform(0.05)).unwrap();
    let hem: Vec<usize> = boundary_vertices(&mesh);
    let moved = hem.iter().map(|&v| (out[v] - input[v]).length()).fold(0.0f32, f32::max);
    assert!(moved > 0.01, "the hems followed the input exactly (moved at most {moved})");
    assert!(out.iter().all(|p| p.is_finite()));
    // The squashed hem is pulled back towards its round rest shape.
    let roundness = |positions: &[Vec3]| {
        let radii: Vec<f32> = (0..24).map(|i| Vec3::new(positions[i].x, positions[i].y, 0.0).length()).collect();
        radii.iter().cloned().fold(f32::MIN, f32::max) / radii.iter().cloned().fold(f32::MAX, f32::min)
    };
    assert!(roundness(&out) < 0.8 * roundness(&input), "hem roundness {} against the input's {}", roundness(&out), roundness(&input));
}
