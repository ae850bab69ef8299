//! Convergence error of the pyramid solve against its own converged solution,
//! plain and Anderson-accelerated (issue 28):
//! `cargo run --release -p tegument-core --example convergence [path/to/base.obj]`.

use std::time::Instant;

use glam::Vec3;
use tegument_core::mesh::fixtures::{makehuman_body, smooth_bend as bend};
use tegument_core::mesh::shapes::{cylinder, PolyMesh};
use tegument_core::pyramid::{Closeness, DeformerOptions, PyramidDeformer};

fn rms(a: &[Vec3], b: &[Vec3]) -> f64 {
    (a.iter().zip(b).map(|(p, q)| (*p - *q).as_dvec3().length_squared()).sum::<f64>() / a.len() as f64).sqrt()
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
        let body = makehuman_body(std::path::Path::new(&path)).expect("a readable MakeHuman base.obj");
        // Bend the upper body forward about a waist pivot, with a blend zone.
        let input = bend(&body, 0.1, 0.0, 0.25, 0.9, 0.3);
        for closeness in [0.05, 0.01] {
            report("body", &body, &input, closeness);
        }
    }
}
