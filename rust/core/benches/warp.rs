//! UV warp benchmark: ms per frame (triangle metrics + hierarchical solve +
//! inversion) on a deforming mesh, warm-started, for 1024², 2048², 4096²
//! grids; peak memory per case (VmHWM of a child process that runs only that
//! case); the memory-bandwidth reference in the same run.
//!
//! `cargo bench -p tegument-core --bench warp` (set `TEGUMENT_WARP_SIZES=1024,2048`
//! to choose sizes, `TEGUMENT_WARP_THREADS=2` for the pool size).

mod common;

use std::process::Command;
use std::time::Instant;

use tegument_core::warp::fixtures::{bend, scales_map, uv_cylinder};
use tegument_core::warp::{invert, udim_offset, TileMaps, UvWarp, WarpSettings};

const FRAMES: usize = 6;

fn scene(n: usize) -> (tegument_core::warp::fixtures::UvPolyMesh, Vec<f32>) {
    // 256 × 128 quads (33k vertices), scales over 25% of the chart.
    (uv_cylinder(256, 128, 1.0, std::f32::consts::TAU, 0.05), scales_map(n, n, 24))
}

fn pose(m: &tegument_core::warp::fixtures::UvPolyMesh, frame: usize) -> Vec<glam::Vec3> {
    bend(&m.positions, 2, 0, 0.0, 0.0, 0.5 * (0.6 + 0.04 * frame as f32))
}

/// Runs one case; returns (construction ms, median frame ms, median metrics ms, median inversion ms, first-frame cold ms).
fn run_case(n: usize) -> (f64, f64, f64, f64, f64) {
    let (m, rig) = scene(n);
    let settings = WarpSettings { iterations: 4, ..Default::default() };
    let t = Instant::now();
    let mut warp = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &rig, mask: None }], settings).expect("warp");
    let build = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    warp.solve(&pose(&m, 0)).expect("solve");
    let first = t.elapsed().as_secs_f64() * 1e3;
    let mut frame_ms = Vec::new();
    for f in 1..=FRAMES {
        let p = pose(&m, f);
        let t = Instant::now();
        warp.solve(&p).expect("solve");
        frame_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let tile = &warp.tiles[0];
    eprintln!("  {n}²: per level ms (finest first, then fold check): {:?}, iterations {:?}", tile.solver.last_level_ms.iter().map(|v| (v * 10.0).round() / 10.0).collect::<Vec<_>>(), tile.solver.last_iterations);
    let p = pose(&m, FRAMES);
    let metrics_ms = common::median_ms(3, || {
        std::hint::black_box(tile.layout.triangle_metrics(&warp.mesh, &p));
    });
    let (dx, dy) = tile.displacement();
    let mut out = vec![0.0f32; 2 * n * n];
    let invert_ms = common::median_ms(3, || invert::invert(dx, dy, n, n, udim_offset(1001), &mut out));
    let q = warp.metrics(&p).expect("metrics");
    eprintln!(
        "  {n}²: rigid stretch error identity mean {:.3} → warped {:.3}; folds {}; round trip max {:.3} texel",
        q[0].stretch_identity.mean, q[0].stretch_warped.mean, q[0].foldovers, q[0].round_trip_max
    );
    frame_ms.sort_by(|a, b| a.total_cmp(b));
    (build, frame_ms[frame_ms.len() / 2], metrics_ms, invert_ms, first)
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
        println!("RESULT {} {} {} {} {} {}", r.0, r.1, r.2, r.3, r.4, vm_hwm_kib());
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
        let v: Vec<f64> = line.split_whitespace().skip(1).map(|x| x.parse().unwrap_or(f64::NAN)).collect();
        let case = format!("{n}x{n} cylinder 33k verts, 25% rigid");
        let target = match n {
            1024 => "target <= 40 ms; GTX Titan 3.87 ms",
            2048 => "target <= 160 ms; GTX Titan ~14 ms",
            4096 => "GTX Titan 119 ms",
            _ => "",
        };
        report.add(&case, "frame (warm, metrics+solve+invert)", v[1], "ms", threads, target);
        report.add(&case, "  of which triangle metrics", v[2], "ms", threads, "");
        report.add(&case, "  of which inversion", v[3], "ms", threads, "");
        report.add(&case, "first frame (cold, from identity)", v[4], "ms", threads, "");
        report.add(&case, "construction (layout + hierarchies)", v[0], "ms", threads, "GTX Titan preprocess: 0.37/1.2/4.5 ms");
        report.add(&case, "peak memory (VmHWM, whole process)", v[5] / 1024.0, "MiB", threads, if n == 4096 { "target <= 2048 MiB" } else { "" });
        // Bandwidth reference: one streaming pass over the finest level's
        // solver data (dx, dy, rigidity, mask, triangle ids read; dx, dy written).
        let bw = common::bandwidth_reference_ms(n * n * 14, n * n * 8, threads);
        report.add(&case, "bandwidth reference (1 pass)", bw, "ms", threads, "read 14 B + write 8 B per texel");
        report.add(&case, "frame / bandwidth pass", v[1] / bw, "passes", threads, "");
    }
    report.add("machine", &machine, f64::NAN, "", threads, "");
    report.save();
}
