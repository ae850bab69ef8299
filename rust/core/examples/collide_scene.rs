//! The collision scene of `bench/blender_bench.py` (a 316² grid skin, 100k
//! vertices, and a 128 × 80 UV sphere, 20k triangles, rising into it for 5
//! frames and then sliding) stepped by `Sequence::step` in the core,
//! without Blender: time per frame, contacts, the audit of every frame and,
//! at the end, how far the resting skin stays from the sphere. For profiling
//! the collision passes (`perf record` on it) and for checking a change's
//! effect on the bake's result.
//!
//! `cargo run --release -p tegument-core --example collide_scene`
//! (`GRID=` skin subdivisions, `FRAMES=` frames; defaults 316 and 8)
use glam::Vec3;
use tegument_core::collide::{audit, AuditParams, Collider, ColliderSettings};
use tegument_core::mesh::shapes::{grid, uv_sphere_triangles};
use tegument_core::pyramid::{Closeness, DeformerOptions};
use tegument_core::sequence::{Sequence, StepOptions};

/// The sphere's centre at `frame` (1-based), as in `bench/blender_bench.py`.
fn centre(frame: usize) -> Vec3 {
    let k = (frame - 1) as f32;
    Vec3::new(-0.3 + 0.04 * (k - 5.0).max(0.0), 0.05, -0.32 + 0.03 * k.min(5.0))
}

fn main() {
    let n: usize = std::env::var("GRID").ok().and_then(|s| s.parse().ok()).unwrap_or(316);
    let frames: usize = std::env::var("FRAMES").ok().and_then(|s| s.parse().ok()).unwrap_or(8);
    let skin = grid(n, n, 2.0);
    let (sphere, tris) = uv_sphere_triangles(128, 80, 0.3);
    let at = |f: usize| sphere.iter().map(|&p| p + centre(f)).collect::<Vec<_>>();
    let settings = ColliderSettings { thickness: 0.005, static_friction: 0.3, kinetic_friction: 0.2 };
    let mut collider = Collider::new(&at(1), &tris, settings).unwrap();
    let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
    let mut times = Vec::new();
    for f in 1..=frames {
        let t = std::time::Instant::now();
        collider.update(&at(f)).unwrap();
        // The add-on's defaults: 10 iterations, closeness 0.05.
        let (x, report) = deformer.step(&skin.positions, &mut [&mut collider], &StepOptions::new(10, Closeness::Uniform(0.05))).unwrap();
        let ms = t.elapsed().as_secs_f64() * 1e3;
        times.push(ms);
        let found = audit(tegument_core::mesh::MeshInput { positions: &x, ..skin.input() }, &[&collider], &AuditParams::default()).unwrap();
        println!(
            "frame {f}: {ms:.1} ms, {} vertices moved by pass 1, {} in-loop contacts, {} pinched; audit: {} inside, {} edges crossing, {} collider edges crossing",
            report.first_pass.moved.len(),
            report.in_loop_contacts,
            report.pinched.len(),
            found.vertices_inside.len(),
            found.edges_crossing.len(),
            found.collider_edges_crossing.len()
        );
        if f == frames {
            let c = centre(f);
            let gaps: Vec<f32> = x.iter().map(|p| (*p - c).length() - 0.3).filter(|g| *g < 0.02).collect();
            let mean = gaps.iter().sum::<f32>() / gaps.len() as f32;
            let min = gaps.iter().copied().fold(f32::INFINITY, f32::min);
            println!("skin within 2 cm of the sphere: {} vertices, mean gap {mean:.5}, least {min:.5} (thickness 0.005)", gaps.len());
        }
    }
    times.sort_by(f64::total_cmp);
    println!("median frame {:.1} ms (the Blender bench's statistic)", times[times.len() / 2]);
}
