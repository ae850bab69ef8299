//! Flesh benchmark (issue 6): the added per-frame cost of dynamics, strain
//! limits and a compliant collider on the scene of the collision benchmark —
//! a ~100k-vertex skin (a 316² grid) and a ~20k-triangle quad sphere that
//! rises into it and slides sideways — through the whole
//! `Sequence::step` (pyramid solve, both collision passes, and the
//! feature under test), 10 plain iterations (or Converge, below), 2 threads.
//!
//! Every frame is audited (`collide::audit`, which shares no geometry with
//! the passes) outside the timing; the rows say the worst stretch and the
//! penetrations over all frames.
//!
//! `cargo bench -p tegument-core --bench flesh`; to measure some
//! configurations only, `TEGUMENT_BENCH_FLESH=compliant,unified` (words of
//! their names; collisions only, the baseline, always runs) with
//! `TEGUMENT_BENCH_DIR=/tmp/somewhere` so the partial run does not replace
//! `bench/results/flesh.json`.
//!
//! `TEGUMENT_BENCH_FLESH_SOLVER=converge` solves as the add-on does by
//! default (Converge: the accelerated solve to its tolerance, at most
//! `ACCELERATED_ITERATIONS`) instead of 10 plain iterations (`plain`, the
//! default): the strain rounds and compliant recessions run in the
//! iterations that close a solve, so the two measure different steps.
//! `make bench` runs both; the Converge run writes
//! `bench/results/flesh_converge.json` and leaves out the contact-region
//! scaling rows, which the plain run measures.
//!
//! Under `valgrind --tool=callgrind` every step of the rows is dumped on its
//! own (`common::callgrind`), labelled `<row> frame <k>`: the instructions of
//! one step, all threads, without the bind, the audits or the other rows.
//! `TEGUMENT_BENCH_THREADS=1` runs the rows on one thread instead of two:
//! rayon's work then never moves to another thread, so a profile's inclusive
//! costs tell the step's phases apart (with two, work a phase hands to the
//! other thread is counted under rayon's job, not under the phase).
//! `TEGUMENT_BENCH_INSTRUMENT_FROM=<k>` with `valgrind --tool=callgrind
//! --instr-atstart=no` instruments only the steps of frames `k` and on:
//! the frames before run uninstrumented, several times faster, to the same
//! state, so the timed frames' counts are the same as in a whole run.

mod common;

use common::{callgrind, machine, with_threads, Report};
use std::ffi::CString;
use glam::Vec3;
use tegument_core::mesh::fan_triangles;
use tegument_core::collide::{audit, AuditParams, Collider, ColliderSettings};
use tegument_core::mesh::MeshInput;
use tegument_core::mesh::shapes::{grid, quad_sphere, PolyMesh};
use tegument_core::pyramid::{Closeness, ACCELERATED_ITERATIONS};
use tegument_core::sequence::{Dynamics, Sequence, StepOptions, StrainMode, StrainOptions};
use tegument_core::strain::MaxStretch;

const FRAMES: usize = 8;
/// Frames timed at the end of the animation (the sliding phase, in contact).
const TIMED: usize = 3;
const RADIUS: f32 = 0.3;

/// Sphere centre at frame `k`, as in the collision benchmark.
fn centre(k: usize) -> Vec3 {
    let k = k as f32;
    Vec3::new(-0.3 + 0.04 * (k - 6.0).max(0.0), 0.05, -RADIUS - 0.02 + 0.03 * k.min(6.0))
}

/// The largest length / rest length over the polygons' edges of `skin` at `x`.
fn longest_edge(skin: &PolyMesh, x: &[Vec3]) -> f32 {
    let mut worst = 0.0f32;
    let mut start = 0;
    for &size in &skin.polygon_sizes {
        let corners = &skin.corner_verts[start..start + size as usize];
        for (k, &a) in corners.iter().enumerate() {
            let b = corners[(k + 1) % corners.len()];
            let (a, b) = (a as usize, b as usize);
            worst = worst.max((x[a] - x[b]).length() / (skin.positions[a] - skin.positions[b]).length());
        }
        start += size as usize;
    }
    worst
}

/// CPU time of this process so far (all threads, user and system), in ms,
/// from `/proc/self/stat` (clock ticks of 10 ms); `None` where there is no
/// such file. On a shared host the wall time of a frame also counts the time
/// other processes had the cores; the CPU time counts only this one's work.
fn process_cpu_ms() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The fields after the command name (which is in parentheses and may hold spaces).
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks = |k: usize| fields.get(k)?.parse::<f64>().ok();
    // utime and stime are fields 14 and 15 of the line, 12 and 13 after the name.
    Some((ticks(11)? + ticks(12)?) * 10.0)
}

/// With `TEGUMENT_BENCH_DUMP=<dir>`, writes the skin's and the collider's
/// positions after frame `k` of row `name` there (little-endian f32 triples),
/// so that two builds' results can be compared vertex by vertex.
fn dump_positions(name: &str, k: usize, skin: &[Vec3], collider: &[Vec3]) {
    let Ok(dir) = std::env::var("TEGUMENT_BENCH_DUMP") else { return };
    let slug: String = name.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '-' }).collect();
    for (what, points) in [("skin", skin), ("collider", collider)] {
        let bytes: Vec<u8> = points.iter().flat_map(|p| p.to_array()).flat_map(f32::to_le_bytes).collect();
        std::fs::write(format!("{dir}/{slug}-frame{k}-{what}.bin"), bytes).expect("dump positions");
    }
}

/// Whether the rows solve as the add-on does by default (Converge), or with
/// 10 plain iterations (the default here; `TEGUMENT_BENCH_FLESH_SOLVER=plain|converge`).
fn converges() -> bool {
    match std::env::var("TEGUMENT_BENCH_FLESH_SOLVER").as_deref() {
        Ok("converge") => true,
        Ok("plain") | Err(_) => false,
        Ok(other) => panic!("TEGUMENT_BENCH_FLESH_SOLVER is {other:?}: plain or converge"),
    }
}

/// A sequence bound to `skin` that solves as [`converges`] says.
fn bind(skin: &PolyMesh) -> Sequence {
    common::bind_sequence(skin.input(), converges())
}

/// The first frame whose step callgrind instruments, from
/// `TEGUMENT_BENCH_INSTRUMENT_FROM`; `None` (unset): instrumentation is left
/// as valgrind started it.
fn instrumented_from() -> Option<usize> {
    std::env::var("TEGUMENT_BENCH_INSTRUMENT_FROM").ok().map(|k| k.parse().expect("TEGUMENT_BENCH_INSTRUMENT_FROM is a frame number"))
}

/// Threads the rows run on: 2, or `TEGUMENT_BENCH_THREADS`.
fn threads() -> usize {
    std::env::var("TEGUMENT_BENCH_THREADS").ok().and_then(|t| t.parse().ok()).filter(|&t| t > 0).unwrap_or(2)
}

struct Config {
    name: &'static str,
    options: StepOptions<'static>,
    compliant: bool,
}

fn main() {
    let mut report = Report::new(if converges() { "flesh_converge" } else { "flesh" });
    report.add("machine", &machine(), 0.0, "", 0, "");
    let skin = grid(316, 316, 2.0);
    let sphere = quad_sphere(41, RADIUS);
    let tris = fan_triangles(&sphere.corner_verts, &sphere.input().validate().unwrap());
    let case = format!("skin {} v vs collider {} tri, step", skin.positions.len(), tris.len());
    println!("{case}");
    let settings = ColliderSettings { thickness: 0.005, static_friction: 0.4, kinetic_friction: 0.3 };
    let iterations = if converges() { ACCELERATED_ITERATIONS } else { 10 };
    println!("solver: {}, at most {iterations} iterations", if converges() { "converge" } else { "plain" });
    let base = StepOptions::new(iterations, Closeness::Uniform(0.1));
    let configs = [
        Config { name: "collisions only", options: base, compliant: false },
        Config { name: "+ dynamics", options: StepOptions { dynamics: Some(Dynamics::default()), ..base }, compliant: false },
        Config {
            name: "+ strain limits (unified)",
            options: StepOptions { strain: Some(StrainOptions { max_stretch: MaxStretch::Uniform(0.1), mode: StrainMode::Unified }), ..base },
            compliant: false,
        },
        Config {
            name: "+ strain limits (post)",
            options: StepOptions { strain: Some(StrainOptions { max_stretch: MaxStretch::Uniform(0.1), mode: StrainMode::Post }), ..base },
            compliant: false,
        },
        Config { name: "+ compliant collider", options: base, compliant: true },
        Config {
            name: "+ all three",
            options: StepOptions {
                dynamics: Some(Dynamics::default()),
                strain: Some(StrainOptions { max_stretch: MaxStretch::Uniform(0.1), mode: StrainMode::Unified }),
                ..base
            },
            compliant: true,
        },
    ];
    let selected = |name: &str| {
        std::env::var("TEGUMENT_BENCH_FLESH").map_or(true, |list| list.split(',').any(|word| name.contains(word.trim())))
    };
    let mut baseline = None;
    for config in configs.iter().filter(|c| c.name == "collisions only" || selected(c.name)) {
        let mut deformer = bind(&skin);
        let at = |k: usize| sphere.positions.iter().map(|&p| p + centre(k)).collect::<Vec<_>>();
        let mut collider = Collider::new(&at(0), &tris, settings).unwrap();
        if config.compliant {
            collider.set_compliance(Some(&vec![200.0; sphere.positions.len()])).unwrap();
        }
        let mut times = Vec::new();
        let mut cpu_times = Vec::new();
        let mut last = None;
        // Over all frames: the worst stretch (measured here from the
        // polygons, not by the strain limits' own code) and what the audit
        // (its own geometry, not the passes') finds.
        let (mut worst, mut penetrations) = (0.0f32, 0usize);
        with_threads(threads(), || {
            for k in 1..=FRAMES {
                collider.update(&at(k)).unwrap();
                let started = std::time::Instant::now();
                let cpu_started = process_cpu_ms();
                let instrumented = instrumented_from().is_some_and(|from| k >= from);
                if instrumented {
                    callgrind::start_instrumentation();
                }
                callgrind::zero_stats();
                let (x, step) = deformer.step(&skin.positions, &mut [&mut collider], &config.options).unwrap();
                callgrind::dump_stats_at(&CString::new(format!("{} frame {k}", config.name)).unwrap());
                if instrumented {
                    callgrind::stop_instrumentation();
                }
                let ms = started.elapsed().as_secs_f64() * 1e3;
                let cpu_ms = cpu_started.zip(process_cpu_ms()).map(|(a, b)| b - a);
                let found = audit(MeshInput { positions: &x, ..skin.input() }, &[&collider], &AuditParams::default()).unwrap();
                dump_positions(config.name, k, &x, collider.current());
                println!(
                    "{:<28} frame {k}: {ms:.0} ms ({} ms CPU), {} pinched, worst stretch {:.4}, recession {:.4}, in-loop: {} clearances, {} vertices tested, {} skin refits; audit {} inside {} crossing {} collider edges crossing",
                    config.name,
                    cpu_ms.map_or("?".to_string(), |c| format!("{c:.0}")),
                    step.pinched.len(),
                    step.worst_stretch,
                    step.max_recession,
                    step.clearance_measurements,
                    step.in_loop_tested,
                    step.in_loop_skin_refits,
                    found.vertices_inside.len(),
                    found.edges_crossing.len(),
                    found.collider_edges_crossing.len()
                );
                let w = step.contact_work;
                println!(
                    "{:<28} frame {k} phases (ms; {} solver iterations): compliant targets {:.0}, first recession {:.0}, first pass {:.0}, in-loop passes {:.0}, strain {:.0} ({} rounds, {} multilevel cycles), recession headings {:.0}, recession contacts {:.0}",
                    config.name,
                    deformer.deformer().last_iterations(),
                    w.compliant_targets_ms,
                    w.first_recession_ms,
                    w.first_pass_ms,
                    w.in_loop_pass_ms,
                    w.strain_ms,
                    w.strain_rounds,
                    w.strain_cycles,
                    w.recession_heading_ms,
                    w.recession_contacts_ms
                );
                worst = worst.max(longest_edge(&skin, &x));
                penetrations += found.vertices_inside.len() + found.edges_crossing.len() + found.collider_edges_crossing.len();
                if k > FRAMES - TIMED {
                    times.push(ms);
                    cpu_times.extend(cpu_ms);
                }
                last = Some(step);
            }
        });
        times.sort_by(f64::total_cmp);
        let median = times[times.len() / 2];
        let step = last.unwrap();
        let note = format!(
            "median of the last {TIMED} frames; worst stretch {:.3}, {} compliant skin vertices, recession {:.4}",
            step.worst_stretch, step.compliant_skin_vertices, step.max_recession
        );
        report.add(&case, config.name, median, "ms", 2, &note);
        if cpu_times.len() == times.len() {
            cpu_times.sort_by(f64::total_cmp);
            let cpu = cpu_times[cpu_times.len() / 2];
            report.add(&case, &format!("{}: CPU time", config.name), cpu, "ms", 2, "median of the last frames' process CPU time (both threads), less sensitive to the host's load");
        }
        report.add(&case, &format!("{}: worst stretch (all frames)", config.name), worst as f64, "× rest", 2, "");
        report.add(&case, &format!("{}: penetrations (all frames, audit)", config.name), penetrations as f64, "", 2, "vertices inside, skin and collider edges crossing");
        match baseline {
            None => baseline = Some(median),
            Some(base) => report.add(&case, &format!("added by {}", config.name.trim_start_matches("+ ")), median - base, "ms", 2, ""),
        }
    }
    if selected("scaling") && !converges() {
        contact_region_scaling(&mut report, &sphere, &tris, settings, base);
    }
    report.save();
}

/// The same compliant collider against skins of 25k, 100k and 400k vertices
/// at the benchmark's spacing: the contact region stays the same, so the
/// cost the collider adds to a step should not grow with the skin.
/// (`TEGUMENT_BENCH_FLESH=scaling` runs only this and the baseline above.)
/// The sphere's path is moved 41 cells towards the middle, where the
/// smallest skin covers all of it; the grids' vertices coincide there.
fn contact_region_scaling(report: &mut Report, sphere: &PolyMesh, tris: &[[u32; 3]], settings: ColliderSettings, options: StepOptions<'static>) {
    let shift = Vec3::X * (41.0 * 2.0 / 316.0);
    for (cells, size) in [(158, 1.0), (316, 2.0), (632, 4.0)] {
        let skin = grid(cells, cells, size);
        let case = format!("compliant collider added to a step, skin {} v (spacing {:.4})", skin.positions.len(), size / cells as f32);
        let mut medians = [0.0f64; 2];
        let mut cpu_medians = [None; 2];
        for (slot, compliant) in [(0, false), (1, true)] {
            let mut deformer = bind(&skin);
            let at = |k: usize| sphere.positions.iter().map(|&p| p + centre(k) + shift).collect::<Vec<_>>();
            let mut collider = Collider::new(&at(0), tris, settings).unwrap();
            if compliant {
                collider.set_compliance(Some(&vec![200.0; sphere.positions.len()])).unwrap();
            }
            let mut times = Vec::new();
            let mut cpu_times = Vec::new();
            let mut penetrations = 0;
            with_threads(threads(), || {
                for k in 1..=FRAMES {
                    collider.update(&at(k)).unwrap();
                    let started = std::time::Instant::now();
                    let cpu_started = process_cpu_ms();
                    let (x, step) = deformer.step(&skin.positions, &mut [&mut collider], &options).unwrap();
                    let ms = started.elapsed().as_secs_f64() * 1e3;
                    let cpu_ms = cpu_started.zip(process_cpu_ms()).map(|(a, b)| b - a);
                    let found = audit(MeshInput { positions: &x, ..skin.input() }, &[&collider], &AuditParams::default()).unwrap();
                    penetrations += found.vertices_inside.len() + found.edges_crossing.len() + found.collider_edges_crossing.len() + step.pinched.len();
                    println!(
                        "{case}, {}: frame {k}: {ms:.0} ms ({} ms CPU), recession {:.4}, in-loop: {} vertices tested, {} skin refits",
                        if compliant { "compliant" } else { "kinematic" },
                        cpu_ms.map_or("?".to_string(), |c| format!("{c:.0}")),
                        step.max_recession,
                        step.in_loop_tested,
                        step.in_loop_skin_refits
                    );
                    if k > FRAMES - TIMED {
                        times.push(ms);
                        cpu_times.extend(cpu_ms);
                    }
                }
            });
            times.sort_by(f64::total_cmp);
            medians[slot] = times[times.len() / 2];
            if cpu_times.len() == times.len() {
                cpu_times.sort_by(f64::total_cmp);
                cpu_medians[slot] = Some(cpu_times[cpu_times.len() / 2]);
            }
            assert_eq!(penetrations, 0, "{case}: penetrations or pinched vertices");
        }
        report.add(&case, "collisions only", medians[0], "ms", 2, "median of the last frames");
        report.add(&case, "+ compliant collider", medians[1], "ms", 2, "0 penetrations by the audit in every frame");
        report.add(&case, "added by the compliant collider", medians[1] - medians[0], "ms", 2, "");
        if let [Some(kinematic), Some(compliant)] = cpu_medians {
            let note = "median of the last frames' process CPU time (both threads)";
            report.add(&case, "added by the compliant collider: CPU time", compliant - kinematic, "ms", 2, note);
            report.add(&case, "compliant collider / collisions only: CPU time", compliant / kinematic.max(1.0), "×", 2, note);
        }
    }
}
