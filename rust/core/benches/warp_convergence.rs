//! UV warp convergence (issue 28), the cascade solver of `main` before the
//! multigrid ("old": `Variant::Cascade`, the product's default) against the
//! multigrid solver ("new", selectable, 1 cycle a frame) in one run, on the benchmark cylinder of
//! `benches/warp.rs` (256 × 128 quads, square scales over 25 % of the chart)
//! at its strongest bend (curvature 0.5: the +X side squashed to half),
//! default settings but for the iteration count (old: iterations per level;
//! new: multigrid cycles):
//!
//! 1. warm frame times, old and new frames taken in turn (the machine is
//!    shared: only a comparison in one run means anything), 1024² and 2048²;
//! 2. cold solves (from the identity) by iteration count, both against the
//!    same converged warp `x_∞`: the finest level's fixed point, reached by
//!    multigrid cycles until a cycle moves no node by more than 1e-7 of the
//!    grid size, then checked with the finest level's own iteration (the
//!    largest change in the last of 200 plain iterations is recorded): time,
//!    rigid stretch error, fold-overs and the convergence error
//!    RMS|r_k − r_∞| / RMS|r_∞ − identity| over the redirection texture's
//!    texels inside the chart;
//! 3. fold-overs of the default solver's (the cascade's) cold solves at every iteration count
//!    1..64 at 2048² and 4096², on this cylinder and on the tests' squares
//!    scene, before the end-of-solve repair (which then has nothing to do)
//!    and after;
//! 4. bakes that differ only in iteration count: frames 0..10 of the warm
//!    benchmark (frame 0 cold) at 1, 2, 4 and 8 cycles against 64, the
//!    largest convergence-style difference per frame (issue 28 asks at most
//!    5 %), new solver.
//!
//! Rows go to `bench/results/warp_convergence.json`, the curves to
//! `bench/results/warp_convergence_curves.json` (drawn by
//! `bench/plot_warp_convergence.py`). Environment: `TEGUMENT_WARP_THREADS`
//! (2), `TEGUMENT_WARP_FRAME_SIZES` (1024,2048), `TEGUMENT_WARP_CONV_SIZES`
//! (256,1024,2048), `TEGUMENT_WARP_FOLD_SIZES` (2048,4096), `TEGUMENT_WARP_FOLD_MAX`
//! (64), `TEGUMENT_WARP_BAKE_SIZES` (256,1024), `TEGUMENT_WARP_CONVERGE_CAP` (most cycles for `x_∞`, 400).

mod common;

use std::time::Instant;

use tegument_core::warp::fixtures::{bend, rectangles, scales_map, uv_cylinder, UvPolyMesh};
use tegument_core::warp::solver::Variant;
use tegument_core::warp::{TileMaps, UvWarp, WarpSettings};

const ITERATIONS: [usize; 12] = [1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64];

fn env_list(name: &str, default: &str) -> Vec<usize> {
    std::env::var(name).unwrap_or_else(|_| default.into()).split(',').filter_map(|s| s.trim().parse().ok()).collect()
}

fn env_num(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn mesh() -> UvPolyMesh {
    uv_cylinder(256, 128, 1.0, std::f32::consts::TAU, 0.05)
}

/// The warm benchmark's pose of frame `f` (`benches/warp.rs`); frame 10 is the strongest bend.
fn pose(m: &UvPolyMesh, frame: usize) -> Vec<glam::Vec3> {
    bend(&m.positions, 2, 0, 0.0, 0.0, 0.5 * (0.6 + 0.04 * frame as f32))
}

/// The old solver's default iteration count (per level, the product's
/// default); the new one's cycles a frame.
const OLD_DEFAULT: u32 = 4;
const NEW_DEFAULT: u32 = 1;

fn warp(m: &UvPolyMesh, n: usize, old: bool, warm: bool) -> UvWarp {
    let rig = scales_map(n, n, 24);
    let iterations = if old { OLD_DEFAULT } else { NEW_DEFAULT };
    let settings = WarpSettings { warm_start: warm, iterations, ..Default::default() };
    let mut w = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &rig, mask: None }], settings).expect("warp");
    w.set_variant(if old { Variant::Cascade } else { Variant::Multigrid });
    w
}

fn name(old: bool) -> &'static str {
    if old {
        "old"
    } else {
        "new"
    }
}

/// `x_∞` of the strongest bend at grid `n`: the multigrid solve continued
/// until converged (module documentation), its redirection, rigid stretch,
/// and what the convergence reached.
fn converged(m: &UvPolyMesh, n: usize, pose: &[glam::Vec3], cap: usize) -> (Vec<f32>, f64, tegument_core::warp::Convergence, f64) {
    let mut w = warp(m, n, false, false);
    let t = Instant::now();
    w.solve(pose).expect("solve");
    let c = w.converge(pose, 1e-7 * n as f32, cap, 200).expect("converge");
    let q = &w.metrics(pose).expect("metrics")[0];
    (w.tiles[0].redirection.clone(), q.stretch_warped.mean, c, t.elapsed().as_secs_f64())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// RMS|r − inf| / RMS|inf − identity| over texels inside the chart.
fn convergence_error(r: &[f32], inf: &[f32], valid: &[u8], n: usize) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (t, _) in valid.iter().enumerate().filter(|(_, &v)| v != 0) {
        let id = [((t % n) as f64 + 0.5) / n as f64, ((t / n) as f64 + 0.5) / n as f64];
        for c in 0..2 {
            let (a, b) = (r[2 * t + c] as f64, inf[2 * t + c] as f64);
            num += (a - b).powi(2);
            den += (b - id[c]).powi(2);
        }
    }
    (num / den.max(1e-300)).sqrt()
}

fn json_list(v: &[f64]) -> String {
    format!("[{}]", v.iter().map(|x| format!("{x}")).collect::<Vec<_>>().join(", "))
}

fn main() {
    let threads = env_num("TEGUMENT_WARP_THREADS", 2);
    let cap = env_num("TEGUMENT_WARP_CONVERGE_CAP", 400);
    let mut report = common::Report::new("warp_convergence");
    let mut curves: Vec<String> = Vec::new();
    let m = mesh();
    let strongest = pose(&m, 10);
    common::with_threads(threads, || {
        // 1. Warm frame times, old and new in turn.
        for n in env_list("TEGUMENT_WARP_FRAME_SIZES", "1024,2048") {
            let case = format!("{n}x{n} cylinder, warm frames");
            let mut warps = [warp(&m, n, true, true), warp(&m, n, false, true)];
            let mut first = [0.0; 2];
            for (k, w) in warps.iter_mut().enumerate() {
                let t = Instant::now();
                w.solve(&pose(&m, 0)).expect("solve");
                first[k] = t.elapsed().as_secs_f64() * 1e3;
            }
            let mut times = [Vec::new(), Vec::new()];
            for f in 1..=10 {
                let p = pose(&m, f);
                for (k, w) in warps.iter_mut().enumerate() {
                    let t = Instant::now();
                    w.solve(&p).expect("solve");
                    times[k].push(t.elapsed().as_secs_f64() * 1e3);
                }
            }
            for (k, w) in warps.iter().enumerate() {
                let q = &w.metrics(&strongest).expect("metrics")[0];
                let legacy = k == 0;
                let count = w.settings.iterations;
                let target = if n == 1024 { "target <= 40 ms" } else { "target <= 160 ms" };
                report.add(&case, &format!("frame (warm), {} solver", name(legacy)), median(times[k].clone()), "ms", threads, &format!("{target}; median of 10, frames of both solvers in turn"));
                report.add(&case, &format!("first frame (cold, {count} iterations), {} solver", name(legacy)), first[k], "ms", threads, "");
                report.add(&case, &format!("rigid stretch after 10 warm frames, {} solver", name(legacy)), q.stretch_warped.mean, "", threads, &format!("folds {}", q.foldovers));
            }
        }
        // 2. Cold solves by iteration count against the finest level's fixed point.
        for n in env_list("TEGUMENT_WARP_CONV_SIZES", "256,1024,2048") {
            let case = format!("{n}x{n} cylinder, cold, strongest bend");
            let (inf, conv, reached, secs) = converged(&m, n, &strongest, cap);
            eprintln!("  {n}² x_∞: {} cycles ({secs:.0} s), last cycle's change {:.2e}, plain iteration's {:.2e} texel, rigid stretch {conv:.4}", reached.cycles, reached.cycle_change, reached.iteration_change);
            report.add(&case, "rigid stretch, converged", conv, "", threads, &format!("x_inf: {} multigrid cycles, last cycle moved {:.1e} texel, the 200th plain finest iteration {:.1e} (tolerance {:.1e})", reached.cycles, reached.cycle_change, reached.iteration_change, 1e-7 * n as f64));
            for old in [true, false] {
                let mut w = warp(&m, n, old, false);
                let default = w.settings.iterations as usize;
                let valid = w.tiles[0].validity().to_vec();
                let mut runs = Vec::new();
                for &k in &ITERATIONS {
                    w.settings.iterations = k as u32;
                    let t = Instant::now();
                    w.solve(&strongest).expect("solve");
                    let ms = t.elapsed().as_secs_f64() * 1e3;
                    let q = &w.metrics(&strongest).expect("metrics")[0];
                    let (passes, scale) = w.tiles[0].solver.last_repair;
                    let e = convergence_error(&w.tiles[0].redirection, &inf, &valid, n);
                    eprintln!("  {n}² {} k={k}: {ms:.0} ms, rigid stretch {:.4}, convergence error {e:.3}, folds {} (repair {passes} passes, scale {scale})", name(old), q.stretch_warped.mean, q.foldovers);
                    runs.push((k, ms, q.stretch_warped.mean, passes > 0 || scale < 1.0, e));
                }
                let who = name(old);
                for r in &runs {
                    if [1, 2, 4, 8, 16, 64].contains(&r.0) {
                        let tag = if r.0 == default { " (default)" } else { "" };
                        report.add(&case, &format!("{} iterations{tag}, {who} solver: rigid stretch", r.0), r.2, "", threads, &format!("{:.0} ms; convergence error {:.3}; {:+.1} % of converged; repair needed: {}", r.1, r.4, 100.0 * (r.2 / conv - 1.0), r.3));
                    }
                }
                curves.push(format!(
                    "  {{\"grid\": {n}, \"solver\": \"{who}\", \"default\": {default}, \"iterations\": {}, \"ms\": {}, \"rigid_stretch\": {}, \"convergence_error\": {}, \"repaired\": {}, \"converged_rigid_stretch\": {conv}, \"converge_cycles\": {}, \"converge_last_change\": {}}}",
                    json_list(&runs.iter().map(|r| r.0 as f64).collect::<Vec<_>>()),
                    json_list(&runs.iter().map(|r| r.1).collect::<Vec<_>>()),
                    json_list(&runs.iter().map(|r| r.2).collect::<Vec<_>>()),
                    json_list(&runs.iter().map(|r| r.4).collect::<Vec<_>>()),
                    json_list(&runs.iter().map(|r| r.3 as u8 as f64).collect::<Vec<_>>()),
                    reached.cycles,
                    reached.iteration_change,
                ));
            }
        }
        // 3. Fold-overs of the default solver's cold solves, every count 1..=64,
        //    on the benchmark cylinder and on the tests' squares scene
        //    (`warp::tests::squares_cylinder`: 64 × 32 quads, two rigid squares
        //    on the squashed and the stretched side, full bend).
        let max = env_num("TEGUMENT_WARP_FOLD_MAX", 64);
        let squares = uv_cylinder(64, 32, 1.0, std::f32::consts::TAU, 0.1);
        let squares_bent = bend(&squares.positions, 2, 0, 0.0, 0.0, 0.5);
        for n in env_list("TEGUMENT_WARP_FOLD_SIZES", "2048,4096") {
            let s = 0.06;
            let squares_rig = rectangles(n, n, &[(0.7 - s, 0.5 - s, 0.7 + s, 0.5 + s), (0.3 - s, 0.5 - s, 0.3 + s, 0.5 + s)]);
            let scenes: [(&str, &UvPolyMesh, &[glam::Vec3], Vec<f32>); 2] = [("cylinder", &m, &strongest, scales_map(n, n, 24)), ("squares", &squares, &squares_bent, squares_rig)];
            for (scene, mesh, def, rig) in scenes {
                let case = format!("{n}x{n} {scene}, cold, strongest bend");
                let settings = WarpSettings { warm_start: false, ..Default::default() };
                let mut w = UvWarp::new(mesh.input(), &mesh.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &rig, mask: None }], settings).expect("warp");
                let (mut raw, mut after, mut worst) = (0usize, 0usize, 0.0f64);
                let t = Instant::now();
                for k in 1..=max {
                    w.settings.iterations = k as u32;
                    w.solve(def).expect("solve");
                    let q = &w.metrics(def).expect("metrics")[0];
                    let (passes, scale) = w.tiles[0].solver.last_repair;
                    raw += (passes > 0 || scale < 1.0) as usize;
                    after += q.foldovers;
                    worst = worst.max(q.stretch_warped.mean);
                    eprintln!("  {n}² {scene} default k={k}: rigid stretch {:.4}, folds {}, repair ({passes}, {scale}), {:.0} s so far", q.stretch_warped.mean, q.foldovers, t.elapsed().as_secs_f64());
                }
                let note = format!("iteration counts 1..{max}, default solver (cascade); {:.0} s", t.elapsed().as_secs_f64());
                report.add(&case, "cold solves that needed the fold repair", raw as f64, "", threads, &note);
                report.add(&case, "fold-overs, summed over the cold solves", after as f64, "", threads, &note);
                report.add(&case, "worst rigid stretch over the cold solves", worst, "", threads, &note);
            }
        }
        // 4. Bakes that differ only in iteration count (issue 28: at most 5 %
        //    apart beyond the default): frames 0..=10 (0 cold, the others
        //    warm), against 64 cycles, new solver.
        for n in env_list("TEGUMENT_WARP_BAKE_SIZES", "256,1024") {
            let case = format!("{n}x{n} cylinder, bake of frames 0-10 (warm)");
            let bake = |k: usize| {
                let mut w = warp(&m, n, false, true);
                w.settings.iterations = k as u32;
                let t = Instant::now();
                let frames: Vec<Vec<f32>> = (0..=10)
                    .map(|f| {
                        w.solve(&pose(&m, f)).expect("solve");
                        w.tiles[0].redirection.clone()
                    })
                    .collect();
                let ms = t.elapsed().as_secs_f64() * 1e3 / 11.0;
                let q = &w.metrics(&strongest).expect("metrics")[0];
                (frames, w.tiles[0].validity().to_vec(), ms, q.stretch_warped.mean, q.foldovers)
            };
            let (reference, valid, ms64, stretch64, folds64) = bake(64);
            let default = NEW_DEFAULT as usize;
            for k in [default, 2 * default, 4 * default, 8 * default] {
                let (frames, _, ms, stretch, folds) = bake(k);
                let d: Vec<f64> = frames.iter().zip(&reference).map(|(a, b)| convergence_error(a, b, &valid, n)).collect();
                eprintln!("  {n}² bake {k} vs 64 cycles, per frame: {d:.3?}");
                let (first, last) = (d[0], d[d.len() - 1]);
                let worst = d.iter().cloned().fold(0.0, f64::max);
                report.add(&case, &format!("{k} iterations against 64: largest difference per frame"), worst, "", threads, &format!("target <= 0.05; frame 0 (cold) {first:.3}, frame 10 {last:.3}; {ms:.0} ms per frame; last frame rigid stretch {stretch:.4}, folds {folds}"));
            }
            report.add(&case, "64 iterations: last frame rigid stretch", stretch64, "", threads, &format!("{ms64:.0} ms per frame; folds {folds64}"));
        }
    });
    report.add("machine", &common::machine(), f64::NAN, "", threads, "");
    report.save();
    let path = common::results_dir().join("warp_convergence_curves.json");
    std::fs::write(&path, format!("[\n{}\n]\n", curves.join(",\n"))).expect("write curves");
    println!("curves: {}", path.display());
}
