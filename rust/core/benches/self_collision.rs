//! Self-collision benchmark (issue 30): the whole `Sequence::step` with and
//! without self-collision, frame by frame over a bend, the two sequences
//! stepped alternately in the same run (so that load on a shared host falls
//! on both), at the add-on's default solver (Converge: the accelerated solve
//! to its tolerance, at most 12 iterations; `TEGUMENT_SELF_BENCH_SOLVER=plain`
//! for 10 plain iterations, the rows of runs before 2026-12-01), 2 threads,
//! plus where the self-collision time
//! goes and the self-intersecting polygon pairs of the last frame by the
//! audit's own count.
//!
//! * the 100k-vertex tube (a 316 × 316 open cylinder) bent 150° at its
//!   middle over 12 frames by a smooth blend (what a two-bone rig's linear
//!   blend does: the inner side folds through itself);
//! * the MakeHuman body (../shared/data) bent forward 100° at the waist
//!   over 12 frames, the belly folding onto the thighs.
//!
//! `cargo bench -p tegument-core --bench self_collision`
//! (`TEGUMENT_BENCH_QUICK=1`: a 20k tube only).

mod common;

use std::time::Instant;

use common::self_work::{cpu_seconds, work_line};
use common::{machine, with_threads, Report};
use tegument_core::collide::{self_intersections, SelfSettings};
use tegument_core::mesh::fixtures::{makehuman_body, makehuman_obj, smooth_bend};
use tegument_core::mesh::shapes::{cylinder, PolyMesh};
use tegument_core::mesh::MeshInput;
use tegument_core::pyramid::{Closeness, ACCELERATED_ITERATIONS};
use tegument_core::sequence::{SelfOptions, Sequence, StepOptions};

const FRAMES: usize = 12;

/// Seconds of self-collision steps after which a case stops (`TEGUMENT_SELF_BENCH_BUDGET_S`,
/// default 120): while self-collision costs hundreds of times a plain step (issue 30), the
/// 100k tube's later frames take minutes each, and `make bench` must finish. The rows then say
/// how many frames were measured; the ratio is over those frames only.
fn budget_seconds() -> f64 {
    std::env::var("TEGUMENT_SELF_BENCH_BUDGET_S").ok().and_then(|v| v.parse().ok()).unwrap_or(120.0)
}

/// The last frame stepped (`TEGUMENT_SELF_BENCH_FRAMES`, default all 12): two binaries compared
/// side by side on a loaded host must do the same work, which a budget in wall-clock seconds
/// does not guarantee.
fn last_frame() -> usize {
    std::env::var("TEGUMENT_SELF_BENCH_FRAMES").ok().and_then(|v| v.parse().ok()).unwrap_or(FRAMES).min(FRAMES)
}

struct Bend {
    axis_z: f32,
    low: f32,
    high: f32,
    degrees: f32,
}

/// Whether the sequences solve as the add-on does by default (Converge), or
/// with 10 plain iterations (`TEGUMENT_SELF_BENCH_SOLVER=plain`). Self
/// Collision starts a step warm only under Converge (issue 30), so the two
/// measure different steps.
fn converges() -> bool {
    std::env::var("TEGUMENT_SELF_BENCH_SOLVER").map_or(true, |v| v != "plain")
}

fn bind(mesh: &PolyMesh) -> Sequence {
    common::bind_sequence(mesh.input(), converges())
}

fn case(report: &mut Report, label: &str, mesh: &PolyMesh, bend: &Bend, thickness: f32) {
    let iterations = if converges() { ACCELERATED_ITERATIONS } else { 10 };
    let plain = StepOptions::new(iterations, Closeness::Uniform(0.05));
    let settings = SelfSettings { thickness, ..SelfSettings::default() };
    let with = StepOptions { self_collision: Some(SelfOptions { settings, weights: None }), ..plain };
    let frames: Vec<Vec<glam::Vec3>> = (0..=FRAMES)
        .map(|k| smooth_bend(mesh, bend.axis_z, bend.low, bend.high, (bend.degrees * k as f32 / FRAMES as f32).to_radians(), 0.0))
        .collect();
    with_threads(2, || {
        let started = Instant::now();
        let mut a = bind(mesh);
        let mut b = bind(mesh);
        println!("bind x2 {:.0} ms", 1000.0 * started.elapsed().as_secs_f64());
        let (mut time_a, mut time_b) = (Vec::new(), Vec::new());
        let (mut last_a, mut last_b) = (Vec::new(), Vec::new());
        let mut contacts = 0;
        let mut held = 0;
        let mut reached = 0;
        let mut phases: std::collections::BTreeMap<&str, f64> = std::collections::BTreeMap::new();
        let budget = budget_seconds();
        for (k, input) in frames.iter().enumerate() {
            let t = Instant::now();
            let (xa, _) = a.step(input, &mut [], &plain).unwrap();
            let ta = t.elapsed().as_secs_f64();
            let (t, cpu) = (Instant::now(), cpu_seconds());
            let (xb, rb) = b.step(input, &mut [], &with).unwrap();
            let tb = t.elapsed().as_secs_f64();
            let cpu_b = cpu.zip(cpu_seconds()).map_or(f64::NAN, |(a, b)| 1000.0 * (b - a));
            // Frame 0 binds self-collision (the patch tree, the separations at rest): timed apart.
            if k == 0 {
                report.add(label, "self-collision first step (bind)", 1000.0 * tb, "ms", 2, "the patch tree and the separations at rest, once per bind");
            } else {
                time_a.push(ta);
                time_b.push(tb);
            }
            contacts += rb.self_contacts;
            held += rb.self_held;
            let w = rb.self_work;
            println!(
                "frame {k}: {:.1} / {:.1} ms ({cpu_b:.0} CPU ms), self contacts {}, held {}, intersections {}; {}",
                1000.0 * ta,
                1000.0 * tb,
                rb.self_contacts,
                rb.self_held,
                rb.self_intersections,
                work_line(&w)
            );
            if k > 0 {
                for (phase, ms) in [("begin", w.begin_ms), ("first pass", w.first_pass_ms), ("in-loop rounds", w.in_loop_rounds_ms), ("in-loop fail-safe", w.in_loop_fail_safe_ms), ("tangles", w.tangles_ms)] {
                    *phases.entry(phase).or_insert(0.0) += ms;
                }
            }
            (last_a, last_b) = (xa, xb);
            reached = k;
            if k == last_frame() && k < FRAMES {
                println!("stopped after frame {k} (TEGUMENT_SELF_BENCH_FRAMES)");
                break;
            }
            if time_b.iter().sum::<f64>() > budget && k < FRAMES {
                println!("stopped after frame {k}: the self-collision steps passed the {budget:.0} s budget");
                break;
            }
        }
        report.add(label, "frames measured", reached as f64, "", 2, &format!("of {FRAMES}; stops once the self-collision steps pass {budget:.0} s"));
        let median = |t: &mut Vec<f64>| {
            t.sort_by(f64::total_cmp);
            1000.0 * t[t.len() / 2]
        };
        let total = |t: &[f64]| t.iter().sum::<f64>();
        let ratio = total(&time_b) / total(&time_a);
        let (ma, mb) = (median(&mut time_a), median(&mut time_b));
        report.add(label, "step without self-collision", ma, "ms", 2, "median of the bend's frames");
        report.add(label, "step with self-collision", mb, "ms", 2, "median of the bend's frames");
        report.add(label, "with / without (all frames)", ratio, "x", 2, "sum of the measured frames' times; target <= 2");
        for (phase, ms) in &phases {
            report.add(label, &format!("self-collision time: {phase} (all frames)"), *ms, "ms", 2, "sum over the measured frames after the first");
        }
        report.add(label, "self contacts (all frames)", contacts as f64, "", 2, "");
        report.add(label, "self fail-safe vertices (all frames)", held as f64, "", 2, "");
        let audit = |x: &[glam::Vec3]| self_intersections(MeshInput { positions: x, ..mesh.input() }).unwrap().len() as f64;
        report.add(label, "self-intersecting pairs, rest", audit(&mesh.positions), "", 2, "the audit's count");
        report.add(label, "self-intersecting pairs, input", audit(&frames[reached]), "", 2, "last frame measured");
        report.add(label, "self-intersecting pairs, without", audit(&last_a), "", 2, "last frame measured");
        report.add(label, "self-intersecting pairs, with", audit(&last_b), "", 2, "last frame measured");
    });
}

fn main() {
    let mut report = Report::new("self_collision");
    report.add("machine", &machine(), 0.0, "", 0, "");
    let quick = std::env::var("TEGUMENT_BENCH_QUICK").is_ok();
    let (around, along) = if quick { (140, 140) } else { (316, 316) };
    let tube = cylinder(around, along, 0.25, 2.0);
    let label = format!("tube {}k bent 150°", tube.positions.len() / 1000);
    case(&mut report, &label, &tube, &Bend { axis_z: 1.0, low: 0.8, high: 1.2, degrees: 150.0 }, 0.002);
    if !quick {
        let path = makehuman_obj();
        match makehuman_body(&path) {
            Some(body) => {
                let label = format!("MakeHuman body ({} v) bent 100° at the waist", body.positions.len());
                case(&mut report, &label, &body, &Bend { axis_z: 0.1, low: 0.0, high: 0.25, degrees: 100.0 }, 0.002);
            }
            None if std::env::var("CI").is_ok_and(|v| v == "true") => panic!("{} is missing (CI=true)", path.display()),
            None => println!("skipped the MakeHuman body: {} is absent", path.display()),
        }
    }
    report.save();
}
