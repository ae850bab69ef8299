//! Test and benchmark inputs beyond the procedural shapes: the MakeHuman
//! body from the shared data (`../shared/data/makehuman`, beside the
//! checkout) and the smooth bend the convergence cases apply.

use std::path::{Path, PathBuf};

use glam::{Mat3, Vec3};

use super::shapes::PolyMesh;

/// `<project root>/../shared/data/makehuman/base.obj`, or under `$TEGUMENT_DATA_DIR`.
pub fn makehuman_obj() -> PathBuf {
    let root = match std::env::var_os("TEGUMENT_DATA_DIR") {
        Some(dir) => PathBuf::from(dir),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    };
    root.join("makehuman/base.obj")
}

/// The `body` group of MakeHuman's `base.obj` (the skin, 13,380 vertices),
/// z up, in metres (MakeHuman writes decimetres, y up); `None` if the file
/// cannot be read.
pub fn makehuman_body(path: &Path) -> Option<PolyMesh> {
    let text = std::fs::read_to_string(path).ok()?;
    let (mut all, mut faces, mut group) = (Vec::new(), Vec::<Vec<usize>>::new(), String::new());
    for line in text.lines() {
        let mut parts = line.split_whitespace();
        match parts.next() {
            Some("v") => {
                let c: Vec<f32> = parts.take(3).filter_map(|v| v.parse().ok()).collect();
                if c.len() != 3 {
                    return None;
                }
                all.push(Vec3::new(c[0], -c[2], c[1]) * 0.1);
            }
            Some("g") => group = parts.next().unwrap_or("").to_string(),
            Some("f") if group == "body" => {
                let face: Option<Vec<usize>> =
                    parts.map(|r| r.split('/').next()?.parse::<usize>().ok()?.checked_sub(1)).collect();
                faces.push(face?);
            }
            _ => {}
        }
    }
    let mut used: Vec<usize> = faces.iter().flatten().copied().collect();
    used.sort_unstable();
    used.dedup();
    if used.last().is_some_and(|&v| v >= all.len()) {
        return None; // a face names a vertex the file does not have
    }
    let mut index = vec![usize::MAX; all.len()];
    for (i, &v) in used.iter().enumerate() {
        index[v] = i;
    }
    let mut mesh = PolyMesh { positions: used.iter().map(|&v| all[v]).collect(), ..Default::default() };
    for face in &faces {
        mesh.push_polygon(&face.iter().map(|&v| index[v]).collect::<Vec<_>>());
    }
    Some(mesh)
}

/// The mesh bent about the x axis through `(0, 0, axis_z)` by `angle`
/// (radians) and twisted about z by `twist`, blended in smoothly between
/// heights `low` and `high`: a joint's bend without a skeleton.
pub fn smooth_bend(mesh: &PolyMesh, axis_z: f32, low: f32, high: f32, angle: f32, twist: f32) -> Vec<Vec3> {
    let pivot = Vec3::new(0.0, 0.0, axis_z);
    let turn = Mat3::from_rotation_x(angle) * Mat3::from_rotation_z(twist);
    mesh.positions
        .iter()
        .map(|&p| {
            let t = ((p.z - low) / (high - low)).clamp(0.0, 1.0);
            let w = t * t * (3.0 - 2.0 * t);
            p * (1.0 - w) + (turn * (p - pivot) + pivot) * w
        })
        .collect()
}

/// A quad `0 1 2 3` creased along its diagonal 1–3 (corners 0 and 2 lifted
/// by `lift`), and a thin upright quad (the needle) under its middle, raised
/// by `raise`: at 0 the needle's top pierces only the split along 1–3
/// (`0 1 3`, `1 2 3`), not the fan split (`0 1 2`, `0 2 3`), whose crease
/// runs above it.
pub fn creased_quad_and_a_needle(lift: f32, raise: f32) -> PolyMesh {
    let mut mesh = PolyMesh::default();
    mesh.positions.extend([Vec3::new(0.0, 0.0, lift), Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 1.0, lift), Vec3::new(0.0, 1.0, 0.0)]);
    mesh.push_polygon(&[0, 1, 2, 3]);
    // Over the needle the fan split lies at 0.95–1 × lift, the other at 0–0.05 × lift.
    let z = 0.5 * lift + raise;
    mesh.positions.extend([Vec3::new(0.45, 0.5, z - 1.0), Vec3::new(0.55, 0.5, z - 1.0), Vec3::new(0.55, 0.5, z), Vec3::new(0.45, 0.5, z)]);
    mesh.push_polygon(&[4, 5, 6, 7]);
    mesh
}
