//! Convergence of the Pyramid Deform solve (issue 28): convergence error
//! against wall time, plain local/global iterations ("plain") against the
//! accelerated solver ("accelerated": the multilevel correction of
//! `solve::coarse`), and the add-on's Converge (the accelerated
//! solver stopped by its tolerance within its iteration limit), cold (a first frame, starting from the input) and
//! warm (the next frame of a bake, starting from the previous frame's result
//! moved with the input), on the 100k benchmark tube at closeness 0.05 and
//! 0.01 and on the MakeHuman body (`../shared/data/makehuman/base.obj`;
//! skipped with a message when absent, unless `CI=true`).
//!
//! Convergence error = RMS |x_k − x_∞| / RMS |x_∞ − x_input|, x_∞ the same
//! solve continued until the RMS change per iteration is below 1e-7 of the
//! mesh size (bounding-box diagonal).
//!
//! `cargo bench -p tegument-core --bench convergence`; rows go to
//! `bench/results/convergence.json`, `bench/plot_convergence.py` draws them.
//! `TEGUMENT_BENCH_QUICK=1` runs a 6k tube instead of the 100k one.

mod common;

use std::time::Instant;

use common::{machine, median_ms, with_threads, Report};
use glam::Vec3;
use tegument_core::mesh::fixtures::{makehuman_body, makehuman_obj, smooth_bend as bend};
use tegument_core::mesh::shapes::{cylinder, PolyMesh};
use tegument_core::pyramid::{Closeness, DeformerOptions, PyramidDeformer, ACCELERATED_ITERATIONS, CONVERGE_TOLERANCE};

const KS: &[usize] = &[1, 2, 3, 4, 5, 6, 8, 10, 15, 20, 40];
const TOLERANCE: f64 = 1e-7;
const MAX_ITERATIONS: usize = 30_000;

fn rms(a: &[Vec3], b: &[Vec3]) -> f64 {
    (a.iter().zip(b).map(|(p, q)| (*p - *q).as_dvec3().length_squared()).sum::<f64>() / a.len() as f64).sqrt()
}

fn size(positions: &[Vec3]) -> f64 {
    let (lo, hi) = positions.iter().fold((Vec3::MAX, Vec3::MIN), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
    (hi - lo).length() as f64
}

#[derive(Clone, Copy)]
enum Solver {
    Plain,
    Accelerated,
}

impl Solver {
    fn name(self) -> &'static str {
        match self {
            Solver::Plain => "plain",
            Solver::Accelerated => "accelerated",
        }
    }

    fn deformer(self, mesh: &PolyMesh) -> PyramidDeformer {
        let mut deformer = PyramidDeformer::bind(mesh.input(), DeformerOptions::default()).expect("bind");
        deformer.set_accelerated(matches!(self, Solver::Accelerated));
        deformer.prepare().expect("prepare");
        deformer
    }
}

/// The solve from `start` continued until it stops moving; returns it and the iterations it took.
fn converged(deformer: &mut PyramidDeformer, input: &[Vec3], start: &[Vec3], closeness: f32, size: f64) -> (Vec<Vec3>, usize) {
    let mut x = start.to_vec();
    let mut total = 0;
    let chunk = 200;
    loop {
        deformer.solve_into(input, &mut x, chunk, Closeness::Uniform(closeness), None).unwrap();
        total += chunk;
        let mut y = x.clone();
        deformer.solve_into(input, &mut y, 1, Closeness::Uniform(closeness), None).unwrap();
        if rms(&y, &x) < TOLERANCE * size || total >= MAX_ITERATIONS {
            return (y, total + 1);
        }
        x = y;
    }
}

#[allow(clippy::too_many_arguments)]
fn case(report: &mut Report, name: &str, mesh: &PolyMesh, frame1: &[Vec3], frame2: &[Vec3], closeness: f32) {
    let size = size(&mesh.positions);
    for solver in [Solver::Plain, Solver::Accelerated] {
        let mut deformer = solver.deformer(mesh);
        let tag = solver.name();
        // Cold: frame 1 from its input.
        let (reference, took) = converged(&mut deformer, frame1, frame1, closeness, size);
        let scale = rms(&reference, frame1);
        report.add(&format!("{name} cold"), &format!("{tag}: x_inf iterations"), took as f64, "", 2, "");
        // Warm: frame 2 from frame 1's result at the same iteration count, moved with the input.
        let (reference2, took2) = converged(&mut deformer, frame2, frame2, closeness, size);
        let scale2 = rms(&reference2, frame2);
        report.add(&format!("{name} warm"), &format!("{tag}: x_inf iterations"), took2 as f64, "", 2, "");
        for &k in KS {
            let mut out = frame1.to_vec();
            let ms = with_threads(2, || {
                median_ms(3, || {
                    out.copy_from_slice(frame1);
                    deformer.solve_into(frame1, &mut out, k, Closeness::Uniform(closeness), None).unwrap();
                })
            });
            report.add(&format!("{name} cold"), &format!("{tag}: curve k={k}"), rms(&out, &reference) / scale, "", 2, &format!("{ms:.3} ms"));
            let start: Vec<Vec3> = out.iter().zip(frame2).zip(frame1).map(|((x, b), a)| *x + (*b - *a)).collect();
            let mut warm = start.clone();
            let ms = with_threads(2, || {
                median_ms(3, || {
                    warm.copy_from_slice(&start);
                    deformer.solve_into(frame2, &mut warm, k, Closeness::Uniform(closeness), None).unwrap();
                })
            });
            report.add(&format!("{name} warm"), &format!("{tag}: curve k={k}"), rms(&warm, &reference2) / scale2, "", 2, &format!("{ms:.3} ms"));
        }
        // The add-on's Converge: the tolerance stops the solve
        // within the iteration limit; the warm frame starts from the cold
        // frame's default result moved with the input, as a bake does.
        if let Solver::Accelerated = solver {
            deformer.set_tolerance(Some(CONVERGE_TOLERANCE)).unwrap();
            let mut out = frame1.to_vec();
            let ms = with_threads(2, || {
                median_ms(3, || {
                    out.copy_from_slice(frame1);
                    deformer.solve_into(frame1, &mut out, ACCELERATED_ITERATIONS, Closeness::Uniform(closeness), None).unwrap();
                })
            });
            let took = deformer.last_iterations();
            report.add(&format!("{name} cold"), "Converge: convergence error", rms(&out, &reference) / scale, "", 2, &format!("{ms:.3} ms, {took} iterations"));
            let start: Vec<Vec3> = out.iter().zip(frame2).zip(frame1).map(|((x, b), a)| *x + (*b - *a)).collect();
            let mut warm = start.clone();
            let ms = with_threads(2, || {
                median_ms(3, || {
                    warm.copy_from_slice(&start);
                    deformer.solve_into(frame2, &mut warm, ACCELERATED_ITERATIONS, Closeness::Uniform(closeness), None).unwrap();
                })
            });
            let took = deformer.last_iterations();
            report.add(&format!("{name} warm"), "Converge: convergence error", rms(&warm, &reference2) / scale2, "", 2, &format!("{ms:.3} ms, {took} iterations"));
            deformer.set_tolerance(None).unwrap();
        }
        // Same fixed point: the two solvers' x_inf, relative to the displacement.
        if let Solver::Accelerated = solver {
            let mut plain = Solver::Plain.deformer(mesh);
            let (plain_reference, _) = converged(&mut plain, frame1, frame1, closeness, size);
            report.add(&format!("{name} cold"), "x_inf accelerated vs plain", rms(&reference, &plain_reference) / scale, "", 2, "RMS difference / RMS displacement");
        }
    }
}

fn main() {
    let started = Instant::now();
    let mut report = Report::new("convergence");
    report.add("machine", &machine(), 0.0, "", 0, "");
    let quick = std::env::var("TEGUMENT_BENCH_QUICK").is_ok();
    let (tube, label) = if quick { (cylinder(64, 100, 0.5, 4.0), "tube 6k") } else { (cylinder(256, 390, 0.5, 4.0), "tube 100k") };
    let frame1 = bend(&tube, 2.0, 1.6, 2.4, 1.6, 0.8);
    let frame2 = bend(&tube, 2.0, 1.6, 2.4, 1.65, 0.82);
    for closeness in [0.05, 0.01] {
        case(&mut report, &format!("{label} ({} v) c={closeness}", tube.positions.len()), &tube, &frame1, &frame2, closeness);
    }
    let path = makehuman_obj();
    match makehuman_body(&path) {
        Some(body) => {
            // The upper body bent forward about the waist, then a little further.
            let frame1 = bend(&body, 0.1, 0.0, 0.25, 0.9, 0.3);
            let frame2 = bend(&body, 0.1, 0.0, 0.25, 0.93, 0.31);
            case(&mut report, &format!("MakeHuman body ({} v) c=0.05", body.positions.len()), &body, &frame1, &frame2, 0.05);
        }
        None if std::env::var("CI").is_ok_and(|v| v == "true") => panic!("{} is missing (CI=true)", path.display()),
        None => println!("skipped the MakeHuman body: {} is absent", path.display()),
    }
    report.save();
    println!("convergence benchmark: {:.0} s", started.elapsed().as_secs_f64());
}
