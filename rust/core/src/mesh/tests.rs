use glam::Vec3;
use proptest::prelude::*;

use super::shapes::{cube, cylinder, grid, quad_sphere, PolyMesh};
use super::*;
use crate::Error;

fn build(mesh: &PolyMesh) -> Topology {
    Topology::build(mesh.input()).expect("valid mesh")
}

/// The ring of `v` turns counter-clockwise around the outward normal `n`.
fn ring_turns_with(topology: &Topology, positions: &[Vec3], v: usize, n: Vec3) -> bool {
    let ring = topology.one_ring(v);
    let centre = positions[v];
    ring.windows(2).all(|pair| {
        let a = positions[pair[0] as usize] - centre;
        let b = positions[pair[1] as usize] - centre;
        a.cross(b).dot(n) > 0.0
    })
}

#[test]
fn cube_is_a_closed_manifold() {
    let mesh = cube();
    let topology = build(&mesh);
    let report = topology.report();
    assert!(report.is_closed_manifold(), "{report:?}");
    assert_eq!(report.edge_count, 12);
    for v in 0..8 {
        assert_eq!(topology.one_ring(v).len(), 3);
        assert!(ring_turns_with(&topology, &mesh.positions, v, mesh.positions[v]));
    }
}

#[test]
fn grid_reports_its_boundary_and_orders_rings() {
    let mesh = grid(4, 3, 2.0);
    let topology = build(&mesh);
    let report = topology.report();
    assert!(report.is_clean());
    assert_eq!(report.boundary_vertices.len(), 2 * (4 + 3));
    assert_eq!(report.boundary_edges.len(), 2 * (4 + 3));
    assert_eq!(report.edge_count, 4 * 4 + 5 * 3);
    // Interior: closed ring of the four edge neighbours; corner: open ring of two.
    let interior = 6;
    assert!(!topology.is_boundary(interior));
    let ring = topology.one_ring(interior);
    let start = ring.iter().position(|&v| v == 7).expect("7 is a neighbour");
    let rotated: Vec<u32> = (0..4).map(|k| ring[(start + k) % 4]).collect();
    assert_eq!(rotated, vec![7, 11, 5, 1]);
    assert!(topology.is_boundary(0));
    assert_eq!(topology.one_ring(0), &[1, 5]);
    for v in 0..mesh.positions.len() {
        assert!(ring_turns_with(&topology, &mesh.positions, v, Vec3::Z), "vertex {v}");
    }
}

#[test]
fn three_polygons_on_one_edge_are_non_manifold() {
    let mut mesh = grid(1, 1, 1.0);
    // A third quad hanging below the edge 0-1.
    mesh.positions.push(Vec3::new(-0.5, -0.5, -1.0));
    mesh.positions.push(Vec3::new(0.5, -0.5, -1.0));
    mesh.corner_verts.extend([1, 0, 4, 5]);
    mesh.polygon_sizes.push(4);
    let report = build(&mesh).report().clone();
    assert!(report.non_manifold_edges.is_empty(), "two polygons so far: {report:?}");
    mesh.positions.push(Vec3::new(-0.5, -1.5, 0.0));
    mesh.positions.push(Vec3::new(0.5, -1.5, 0.0));
    mesh.corner_verts.extend([0, 1, 7, 6]);
    mesh.polygon_sizes.push(4);
    let report = build(&mesh).report().clone();
    assert_eq!(report.non_manifold_edges, vec![[0, 1]]);
    assert!(report.non_manifold_vertices.contains(&0) && report.non_manifold_vertices.contains(&1));
}

#[test]
fn bow_tie_vertex_is_non_manifold() {
    // Two triangles touching at vertex 0 only.
    let mesh = PolyMesh {
        positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, -Vec3::X, -Vec3::Y],
        corner_verts: vec![0, 1, 2, 0, 3, 4],
        polygon_sizes: vec![3, 3],
    };
    let report = build(&mesh).report().clone();
    assert_eq!(report.non_manifold_vertices, vec![0]);
    assert!(report.non_manifold_edges.is_empty());
}

#[test]
fn flipped_polygon_is_reported() {
    let mut mesh = grid(2, 1, 1.0);
    // Reverse the winding of the second quad.
    mesh.corner_verts[4..8].reverse();
    let report = build(&mesh).report().clone();
    assert_eq!(report.flipped_edges, vec![[1, 4]]);
    assert!(!report.is_clean());
}

#[test]
fn degenerate_and_isolated_are_reported() {
    let mut mesh = grid(1, 1, 1.0);
    mesh.positions.push(Vec3::splat(5.0)); // isolated: vertex 4
    // Zero-area triangle along an edge, and one with a repeated vertex.
    mesh.positions.push(Vec3::new(0.0, -0.5, 0.0)); // 5, on edge 0-1
    mesh.corner_verts.extend([1, 0, 5]);
    mesh.polygon_sizes.push(3);
    mesh.corner_verts.extend([2, 3, 3]);
    mesh.polygon_sizes.push(3);
    let topology = build(&mesh);
    let report = topology.report();
    assert_eq!(report.degenerate_polygons, vec![1, 2]);
    assert_eq!(report.isolated_vertices, vec![4]);
    assert!(topology.problem_vertices().contains(&4));
    assert!(topology.problem_vertices().contains(&5));
}

#[test]
fn bad_arrays_are_refused_with_their_place() {
    let mesh = cube();
    let check = |corner_verts: &[i32], sizes: &[i32], positions: &[Vec3]| -> String {
        let input = MeshInput { positions, corner_verts, polygon_sizes: sizes };
        match Topology::build(input) {
            Err(Error::InvalidInput(message)) => message,
            other => panic!("expected an error, got {other:?}"),
        }
    };
    let mut corners = mesh.corner_verts.clone();
    corners[17] = 8;
    assert_eq!(check(&corners, &mesh.polygon_sizes, &mesh.positions), "corner 17 refers to vertex 8, but the mesh has 8 vertices");
    corners[17] = -1;
    assert!(check(&corners, &mesh.polygon_sizes, &mesh.positions).starts_with("corner 17 refers to vertex -1"));
    let mut sizes = mesh.polygon_sizes.clone();
    sizes[2] = 2;
    assert_eq!(check(&mesh.corner_verts, &sizes, &mesh.positions), "polygon 2 has 2 corners; a polygon needs at least 3");
    sizes[2] = 3;
    assert!(check(&mesh.corner_verts, &sizes, &mesh.positions).contains("add up to 23 corners but 24"));
    let mut positions = mesh.positions.clone();
    positions[3].y = f32::NAN;
    assert!(check(&mesh.corner_verts, &mesh.polygon_sizes, &positions).contains("vertex 3 is not finite"));
}

#[test]
fn sphere_and_cylinder_have_expected_counts() {
    let sphere = quad_sphere(8, 1.0);
    assert_eq!(sphere.positions.len(), 6 * 64 + 2);
    let topology = build(&sphere);
    assert!(topology.report().is_closed_manifold(), "{:?}", topology.report());
    for v in 0..sphere.positions.len() {
        assert!(ring_turns_with(&topology, &sphere.positions, v, sphere.positions[v]), "vertex {v}");
    }
    let tube = cylinder(12, 5, 1.0, 3.0);
    let report = build(&tube).report().clone();
    assert!(report.is_clean());
    assert_eq!(report.boundary_vertices.len(), 24);
}

proptest! {
    /// On any grid, every edge appears once, every vertex's ring has as many
    /// entries as its degree (plus one when open), and rings turn with +Z.
    #[test]
    fn grid_rings_are_consistent(nx in 1usize..12, ny in 1usize..12) {
        let mesh = grid(nx, ny, 1.0);
        let topology = build(&mesh);
        let mut degree = vec![0usize; mesh.positions.len()];
        for [a, b] in topology.edges() {
            degree[*a as usize] += 1;
            degree[*b as usize] += 1;
        }
        for v in 0..mesh.positions.len() {
            prop_assert_eq!(topology.one_ring(v).len(), degree[v]);
            prop_assert!(ring_turns_with(&topology, &mesh.positions, v, Vec3::Z));
        }
        prop_assert_eq!(topology.edges().len(), nx * (ny + 1) + ny * (nx + 1));
    }

    /// Random index arrays never panic: they are refused exactly when they are not a mesh of
    /// these ten vertices, with a message, and what builds is the mesh that was given.
    #[test]
    fn random_arrays_never_panic(
        corners in proptest::collection::vec(-3i32..12, 0..40),
        sizes in proptest::collection::vec(-1i32..6, 0..12),
        consistent in proptest::bool::ANY,
    ) {
        // Half the cases are index arrays that fit together, so that the accepting side is
        // exercised too: sizes of at least 3, as many corners as they ask, every index in range.
        let (corners, sizes) = if consistent {
            let sizes: Vec<i32> = sizes.iter().map(|s| 3 + s.rem_euclid(3)).collect();
            let count = sizes.iter().sum::<i32>() as usize;
            let corners: Vec<i32> = (0..count).map(|i| corners.get(i).map_or(i as i32, |&c| c).rem_euclid(10)).collect();
            (corners, sizes)
        } else {
            (corners, sizes)
        };
        let positions: Vec<Vec3> = (0..10).map(|i| Vec3::new(i as f32, (i * i) as f32, 1.0)).collect();
        let is_a_mesh = sizes.iter().all(|&s| s >= 3)
            && sizes.iter().sum::<i32>() as usize == corners.len()
            && corners.iter().all(|&c| (0..10).contains(&c));
        match Topology::build(MeshInput { positions: &positions, corner_verts: &corners, polygon_sizes: &sizes }) {
            Ok(topology) => {
                prop_assert!(is_a_mesh, "accepted corners {:?} with sizes {:?}", corners, sizes);
                prop_assert_eq!(topology.vertex_count(), 10);
                prop_assert_eq!(topology.polygon_count(), sizes.len());
                let given: Vec<u32> = corners.iter().map(|&c| c as u32).collect();
                prop_assert_eq!(topology.corner_verts(), &given[..]);
                for &[a, b] in topology.edges() {
                    prop_assert!(a < 10 && b < 10 && a != b);
                    prop_assert!(topology.one_ring(a as usize).contains(&b));
                }
            }
            Err(error) => {
                prop_assert!(!is_a_mesh, "refused a valid mesh: {}", error);
                prop_assert!(!error.to_string().is_empty());
            }
        }
    }
}
