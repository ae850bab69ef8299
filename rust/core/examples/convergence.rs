//! Convergence error of the pyramid solve against its own converged solution,
//! plain and Anderson-accelerated (issue 28):
//! `cargo run --release -p tegument-core --example convergence [path/to/base.obj]`.

use std::time::Instant;

use glam::{Mat3, Vec3};
use tegument_core::mesh::shapes::{cylinder, PolyMesh};
use tegument_core::pyramid::{Closeness, DeformerOptions, PyramidDeformer};

fn bend(mesh: &PolyMesh, axis_z: f32, low: f32, high: f32, angle: f32, twist: f32) -> Vec<Vec3> {
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

fn rms(a: &[Vec3], b: &[Vec3]) -> f64 {
    (a.iter().zip(b).map(|(p, q)| (*p - *q).as_dvec3().length_squared()).sum::<f64>() / a.len() as f64).sqrt()
}

fn load_obj_body(path: &str) -> PolyMesh {
    let text = std::fs::read_to_string(path).expect("read obj");
    let mut all = Vec::new();
    let mut faces: Vec<Vec<usize>> = Vec::new();
    let mut group = String::new();
    for line in text.lines() {
        let mut parts = line.split_whitespace();
        match parts.next() {
            Some("v") => {
                let c: Vec<f32> = parts.take(3).map(|v| v.parse().unwrap()).collect();
                all.push(Vec3::new(c[0], -c[2], c[1]) * 0.1);
            }
            Some("g") => group = parts.next().unwrap_or("").to_string(),
            Some("f") if group == "body" => {
                faces.push(parts.map(|r| r.split('/').next().unwrap().parse::<usize>().unwrap() - 1).collect())
            }
            _ => {}
        }
    }
    let mut used: Vec<usize> = faces.iter().flatten().copied().collect();
    used.sort_unstable();
    used.dedup();
    let mut index = vec![usize::MAX; all.len()];
    for (i, &v) in used.iter().enumerate() {
        index[v] = i;
    }
    let mut mesh = PolyMesh::default();
    mesh.positions = used.iter().map(|&v| all[v]).collect();
    for f in &faces {
        let corners: Vec<usize> = f.iter().map(|&v| index[v]).collect();
        mesh.push_polygon(&corners);
    }
    mesh
}

fn report(name: &str, mesh: &PolyMesh, input: &[Vec3], closeness: f32) {
    let mut deformer = PyramidDeformer::bind(mesh.input(), DeformerOptions::default()).unwrap();
    let reference = deformer.solve(input, 5000, Closeness::Uniform(closeness)).unwrap();
    let scale = rms(&reference, input);
    for window in [0usize, 3, 5, 8] {
        deformer.set_anderson_window(window);
        let mut row = format!("{name:>10} c={closeness:<5} window {window}:");
        for iterations in [5usize, 10, 20, 40, 80] {
            let started = Instant::now();
            let out = deformer.solve(input, iterations, Closeness::Uniform(closeness)).unwrap();
            let ms = started.elapsed().as_secs_f64() * 1e3;
            row += &format!(" {iterations}:{:.3}({ms:.0}ms)", rms(&out, &reference) / scale);
        }
        println!("{row}");
    }
}

fn main() {
    let tube = cylinder(256, 390, 0.5, 4.0); // ~100k vertices
    let tube_input = bend(&tube, 2.0, 1.6, 2.4, 1.6, 0.8);
    for closeness in [0.05, 0.01] {
        report("tube 100k", &tube, &tube_input, closeness);
    }
    if let Some(path) = std::env::args().nth(1) {
        let body = load_obj_body(&path);
        // Bend the upper body forward about a waist pivot, with a blend zone.
        let input = bend(&body, 0.1, 0.0, 0.25, 0.9, 0.3);
        for closeness in [0.05, 0.01] {
            report("body", &body, &input, closeness);
        }
    }
}
