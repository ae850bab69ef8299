//! Mesh topology on arbitrary polygon soups: `MeshInput` validation,
//! `Topology::build`, every query on the result, and a pyramid bind plus one
//! solve when the topology is accepted. Must never panic; everything refused
//! must be an `Err`.
#![no_main]

use glam::Vec3;
use libfuzzer_sys::arbitrary::{Result, Unstructured};
use libfuzzer_sys::fuzz_target;
use tegument_core::mesh::{MeshInput, Topology};
use tegument_core::pyramid::{Closeness, DeformerOptions, PyramidDeformer};

/// Mostly small coordinates on a lattice (so that duplicate vertices,
/// collinear corners and zero-area faces are common), sometimes any f32.
fn coordinate(u: &mut Unstructured<'_>) -> Result<f32> {
    Ok(match u.int_in_range(0u8..=15)? {
        0 => f32::from_bits(u.arbitrary()?),
        1 => [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, f32::MIN_POSITIVE, 1e30, -1e-30][u.choose_index(7)?],
        _ => u.int_in_range(-4i8..=4)? as f32 * 0.5,
    })
}

/// Mostly a valid vertex index, sometimes anything.
fn index(u: &mut Unstructured<'_>, vertex_count: usize) -> Result<i32> {
    Ok(match u.int_in_range(0u8..=31)? {
        0 => u.arbitrary()?,
        1 => vertex_count as i32,
        2 => -1,
        _ => u.int_in_range(0..=vertex_count.max(1) as i32 - 1)?,
    })
}

fn run(u: &mut Unstructured<'_>) -> Result<()> {
    let vertex_count = u.int_in_range(0usize..=24)?;
    let mut positions = Vec::with_capacity(vertex_count);
    for _ in 0..vertex_count {
        positions.push(Vec3::new(coordinate(u)?, coordinate(u)?, coordinate(u)?));
    }
    let polygon_count = u.int_in_range(0usize..=24)?;
    let mut polygon_sizes = Vec::with_capacity(polygon_count);
    let mut corner_verts = Vec::new();
    for _ in 0..polygon_count {
        let size = match u.int_in_range(0u8..=31)? {
            0 => u.arbitrary::<i32>()?,
            1 => u.int_in_range(-2..=2)?,
            _ => u.int_in_range(3..=7)?,
        };
        polygon_sizes.push(size);
        for _ in 0..size.clamp(0, 8) {
            corner_verts.push(index(u, vertex_count)?);
        }
    }
    // Sometimes a corner array that disagrees with the sizes.
    if u.ratio(1u8, 16)? {
        corner_verts.truncate(u.int_in_range(0..=corner_verts.len())?);
    }
    let input = MeshInput { positions: &positions, corner_verts: &corner_verts, polygon_sizes: &polygon_sizes };
    let Ok(topology) = Topology::build(input) else { return Ok(()) };
    assert_eq!(topology.vertex_count(), vertex_count);
    for v in 0..vertex_count {
        for &n in topology.one_ring(v) {
            assert!((n as usize) < vertex_count, "one-ring of {v} holds vertex {n} of {vertex_count}");
        }
    }
    for e in topology.edges() {
        assert!(e[0] < e[1] && (e[1] as usize) < vertex_count, "edge {e:?}");
    }
    let _ = topology.report().is_clean();
    for v in topology.problem_vertices() {
        assert!((v as usize) < vertex_count);
    }
    if let Ok(mut deformer) = PyramidDeformer::bind(input, DeformerOptions { scale_safe: u.arbitrary()?, ..Default::default() }) {
        let _ = deformer.pinned_vertices();
        let moved: Vec<Vec3> = positions.iter().map(|p| *p * 1.5 + Vec3::X).collect();
        if let Ok(out) = deformer.solve(&moved, 2, Closeness::Uniform(0.1)) {
            assert_eq!(out.len(), vertex_count);
        }
        let _ = deformer.residual(&moved);
    }
    Ok(())
}

fuzz_target!(|data: &[u8]| {
    let _ = run(&mut Unstructured::new(data));
});
