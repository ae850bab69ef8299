//! UV warp benchmark: ms per frame (triangle metrics + hierarchical solve +
//! inversion) on a deforming mesh, warm-started, for 1024², 2048², 4096²
//! grids, with the median of each stage; peak memory per case (VmHWM of a
//! child process that runs only that case); the memory-bandwidth reference in
//! the same run, every stage also given as a multiple of it.
//!
//! `cargo bench -p tegument-core --bench warp` (set `TEGUMENT_WARP_SIZES=1024,2048`
//! to choose sizes, `TEGUMENT_WARP_THREADS=2` for the pool size,
//! `TEGUMENT_WARP_FRAMES` for the number of warm frames, default 10;
//! `TEGUMENT_WARP_VARIANT=multigrid` runs the multigrid solver (1 cycle a
//! frame) instead of the default cascade, `TEGUMENT_WARP_ITERATIONS` another
//! count than the variant's default; `TEGUMENT_WARP_DUMP=<dir>` writes the
//! last frame's displacement and redirection there, for comparing builds).

mod common;

use std::process::Command;
use std::time::Instant;

use tegument_core::warp::fixtures::{bend, scales_map, uv_cylinder};
use tegument_core::warp::{TileMaps, UvWarp, WarpSettings};

const FRAMES: usize = 10;

fn scene(n: usize) -> (tegument_core::warp::fixtures::UvPolyMesh, Vec<f32>) {
    // 256 × 128 quads (33k vertices), scales over 25% of the chart.
    (uv_cylinder(256, 128, 1.0, std::f32::consts::TAU, 0.05), scales_map(n, n, 24))
}

fn pose(m: &tegument_core::warp::fixtures::UvPolyMesh, frame: usize) -> Vec<glam::Vec3> {
    bend(&m.positions, 2, 0, 0.0, 0.0, 0.5 * (0.6 + 0.04 * frame as f32))
}

/// CPU time (user + system, all threads) of this process so far, in ms
/// (clock ticks of 10 ms: use over many frames).
fn cpu_ms() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = stat.rsplit_once(')').map(|(_, r)| r).unwrap_or("");
    let f: Vec<f64> = rest.split_whitespace().map(|x| x.parse().unwrap_or(0.0)).collect();
    if f.len() > 13 {
        (f[11] + f[12]) * 10.0
    } else {
        f64::NAN
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// Runs one case; returns named figures (ms unless named otherwise): medians
/// over the warm frames of the whole frame and of each stage.
fn run_case(n: usize) -> Vec<(&'static str, f64)> {
    let (m, rig) = scene(n);
    // `TEGUMENT_WARP_VARIANT=multigrid`: the multigrid solver (1 cycle a
    // frame by default) instead of the product's cascade, for comparisons
    // in one build.
    let multigrid = std::env::var("TEGUMENT_WARP_VARIANT").is_ok_and(|v| v == "multigrid");
    // `TEGUMENT_WARP_ITERATIONS`: another count than the variant's default.
    let count = std::env::var("TEGUMENT_WARP_ITERATIONS").ok().and_then(|v| v.parse().ok());
    let settings = WarpSettings { iterations: count.unwrap_or(if multigrid { 1 } else { WarpSettings::default().iterations }), ..Default::default() };
    let t = Instant::now();
    let mut warp = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &rig, mask: None }], settings).expect("warp");
    if multigrid {
        warp.set_variant(tegument_core::warp::solver::Variant::Multigrid);
    }
    let build = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    warp.solve(&pose(&m, 0)).expect("solve");
    let first = t.elapsed().as_secs_f64() * 1e3;
    let frames: usize = std::env::var("TEGUMENT_WARP_FRAMES").ok().and_then(|v| v.parse().ok()).unwrap_or(FRAMES);
    let (mut frame, mut surface, mut solve, mut inversion, mut prepare, mut fold) = (vec![], vec![], vec![], vec![], vec![], vec![]);
    let mut levels: Vec<Vec<f64>> = vec![vec![]; 3];
    let cpu_start = cpu_ms();
    for f in 1..=frames {
        let p = pose(&m, f);
        let t = Instant::now();
        warp.solve(&p).expect("solve");
        frame.push(t.elapsed().as_secs_f64() * 1e3);
        let tile = &warp.tiles[0];
        surface.push(tile.last_stage_ms[0]);
        solve.push(tile.last_stage_ms[1]);
        inversion.push(tile.last_stage_ms[2]);
        prepare.push(tile.solver.last_prepare_ms);
        let lm = &tile.solver.last_level_ms;
        fold.push(lm[lm.len() - 1]);
        for (l, v) in levels.iter_mut().enumerate() {
            v.push(lm.get(l).copied().unwrap_or(0.0));
        }
    }
    let cpu_frame = (cpu_ms() - cpu_start) / frames as f64;
    let tile = &warp.tiles[0];
    if let Ok(dir) = std::env::var("TEGUMENT_WARP_DUMP") {
        // The last frame's displacement and redirection, raw little-endian
        // f32, so that two builds' outputs can be compared byte for byte.
        let (dx, dy) = tile.displacement();
        let bytes: Vec<u8> = dx.iter().chain(dy).chain(&tile.redirection).flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(std::path::Path::new(&dir).join(format!("warp-{n}-{frames}.f32")), bytes).expect("dump");
    }
    eprintln!("  {n}²: last frame per level ms (finest first, then fold check): {:?}, iterations {:?}", tile.solver.last_level_ms.iter().map(|v| (v * 10.0).round() / 10.0).collect::<Vec<_>>(), tile.solver.last_iterations);
    let p = pose(&m, frames);
    let q = warp.metrics(&p).expect("metrics");
    eprintln!(
        "  {n}²: rigid stretch error identity mean {:.3} → warped {:.3}; folds {}; round trip max {:.3} texel",
        q[0].stretch_identity.mean, q[0].stretch_warped.mean, q[0].foldovers, q[0].round_trip_max
    );
    if std::env::var("TEGUMENT_WARP_CHECK").is_ok() {
        let (dx, dy) = tile.displacement();
        let mut other = vec![0.0f32; 2 * n * n];
        tegument_core::warp::invert::invert_scatter(dx, dy, n, n, tegument_core::warp::udim_offset(1001), &mut other);
        let worst = tile.redirection.iter().zip(&other).enumerate().map(|(i, (a, b))| ((a - b).abs() * n as f32, i)).fold((0.0f32, 0), |a, b| if b.0 > a.0 { b } else { a });
        eprintln!("  gather vs scatter inversion: worst {} texel at texel {}", worst.0, worst.1 / 2);
        let mut tmp = warp.clone();
        tmp.tiles[0].redirection = other;
        let q2 = tmp.metrics(&p).expect("metrics");
        eprintln!("  round trip with the scatter inversion: {:.3}; mean {:.4}; p95 err {:.3}; repair {:?}", q2[0].round_trip_max, q[0].round_trip_mean, q[0].stretch_warped.p95, tile.solver.last_repair);
        let mut cold = warp.clone();
        cold.settings.warm_start = false;
        cold.settings.iterations = 8;
        cold.solve(&p).expect("solve");
        let qc = cold.metrics(&p).expect("metrics");
        eprintln!("  cold solve, 8 iterations, same pose: error {:.3} (p95 {:.3}), round trip max {:.3} mean {:.4}, repair {:?}", qc[0].stretch_warped.mean, qc[0].stretch_warped.p95, qc[0].round_trip_max, qc[0].round_trip_mean, cold.tiles[0].solver.last_repair);
    }
    let fastest = frame.iter().copied().fold(f64::INFINITY, f64::min);
    vec![
        ("build", build),
        ("first", first),
        ("frame", median(frame)),
        ("frame_min", fastest),
        ("cpu_frame", cpu_frame),
        ("surface", median(surface)),
        ("solve", median(solve)),
        ("prepare", median(prepare)),
        ("level0", median(levels[0].clone())),
        ("level1", median(levels[1].clone())),
        ("level2", median(levels[2].clone())),
        ("fold", median(fold)),
        ("inversion", median(inversion)),
        ("err_identity", q[0].stretch_identity.mean),
        ("err_warped", q[0].stretch_warped.mean),
        ("folds", q[0].foldovers as f64),
        ("round_trip", q[0].round_trip_max),
    ]
}

fn vm_hwm_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("VmHWM:")).and_then(|l| l.split_whitespace().nth(1)?.parse().ok()))
        .unwrap_or(0)
}

fn main() {
    let threads: usize = std::env::var("TEGUMENT_WARP_THREADS").ok().and_then(|v| v.parse().ok()).unwrap_or(2);
    if let Ok(case) = std::env::var("TEGUMENT_WARP_CASE") {
        // Child: one case, then the figures and the peak resident memory on stdout.
        let n: usize = case.parse().expect("size");
        let r = common::with_threads(threads, || run_case(n));
        let fields: Vec<String> = r.iter().map(|(k, v)| format!("{k}={v}")).collect();
        println!("RESULT {} peak_kib={}", fields.join(" "), vm_hwm_kib());
        return;
    }
    let sizes: Vec<usize> = std::env::var("TEGUMENT_WARP_SIZES")
        .unwrap_or_else(|_| "1024,2048,4096".into())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    let mut report = common::Report::new("warp");
    let machine = common::machine();
    let exe = std::env::current_exe().expect("own path");
    for n in sizes {
        let out = Command::new(&exe).env("TEGUMENT_WARP_CASE", n.to_string()).env("TEGUMENT_WARP_THREADS", threads.to_string()).output().expect("run case");
        let text = String::from_utf8_lossy(&out.stdout);
        eprint!("{}", String::from_utf8_lossy(&out.stderr));
        let Some(line) = text.lines().find(|l| l.starts_with("RESULT ")) else {
            eprintln!("case {n} failed: {text}");
            continue;
        };
        let v: std::collections::HashMap<String, f64> = line
            .split_whitespace()
            .skip(1)
            .filter_map(|kv| kv.split_once('=').map(|(k, x)| (k.to_string(), x.parse().unwrap_or(f64::NAN))))
            .collect();
        let get = |k: &str| v.get(k).copied().unwrap_or(f64::NAN);
        let case = format!("{n}x{n} cylinder 33k verts, 25% rigid");
        let target = match n {
            1024 => "target <= 40 ms; GTX Titan 3.87 ms",
            2048 => "target <= 160 ms; GTX Titan ~14 ms",
            4096 => "GTX Titan 119 ms",
            _ => "",
        };
        // Bandwidth reference: one streaming pass over the finest level's
        // solver data, as one sweep moves it (dx, dy, rigidity, mask, triangle
        // ids read; dx, dy written), with the same thread count.
        let bw = common::bandwidth_reference_ms(n * n * 14, n * n * 8, threads);
        let passes = |ms: f64| format!("{:.1} bandwidth passes", ms / bw);
        report.add(&case, "frame (warm: surface+solve+invert)", get("frame"), "ms", threads, &format!("{target}; {}", passes(get("frame"))));
        report.add(&case, "  fastest frame", get("frame_min"), "ms", threads, "");
        report.add(&case, "  CPU time per frame (all threads)", get("cpu_frame"), "ms", threads, "user+system, mean over the warm frames; load-independent-ish");
        report.add(&case, "  surface metrics (per triangle)", get("surface"), "ms", threads, &passes(get("surface")));
        report.add(&case, "  solve", get("solve"), "ms", threads, &passes(get("solve")));
        report.add(&case, "    restriction + records", get("prepare"), "ms", threads, &passes(get("prepare")));
        report.add(&case, "    level 0 (finest) + prolong", get("level0"), "ms", threads, &passes(get("level0")));
        report.add(&case, "    level 1 + prolong", get("level1"), "ms", threads, &passes(get("level1")));
        report.add(&case, "    level 2 + prolong", get("level2"), "ms", threads, &passes(get("level2")));
        report.add(&case, "    fold check", get("fold"), "ms", threads, &passes(get("fold")));
        report.add(&case, "  inversion", get("inversion"), "ms", threads, &passes(get("inversion")));
        report.add(&case, "first frame (cold, from identity)", get("first"), "ms", threads, "");
        report.add(&case, "construction (layout + hierarchies)", get("build"), "ms", threads, "GTX Titan preprocess: 0.37/1.2/4.5 ms");
        report.add(&case, "peak memory (VmHWM, whole process)", get("peak_kib") / 1024.0, "MiB", threads, if n == 4096 { "target <= 2048 MiB" } else { "" });
        report.add(&case, "bandwidth reference (1 pass)", bw, "ms", threads, "read 14 B + write 8 B per texel");
        report.add(&case, "rigid stretch error, identity", get("err_identity"), "", threads, "mean over rigid texels, last frame");
        report.add(&case, "rigid stretch error, warped", get("err_warped"), "", threads, &format!("folds {}, round trip max {:.3} texel", get("folds"), get("round_trip")));
        let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
        report.add(&case, "load average (1 min) after", load.split_whitespace().next().and_then(|x| x.parse().ok()).unwrap_or(f64::NAN), "", threads, "");
    }
    report.add("machine", &machine, f64::NAN, "", threads, "");
    report.save();
}
