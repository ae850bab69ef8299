//! How far apart are UV warp results that differ only in iteration count
//! (issue 28)? On the benchmark cylinder of `benches/warp.rs` (256 × 128
//! quads, square scales over 25 % of the chart), default settings but for
//! the iteration count:
//!
//! - cold solves (from the identity) at the strongest bend, 4..128
//!   iterations: time, rigid stretch, fold-overs, and the convergence-style
//!   difference RMS|r_a − r_b| / RMS|r_b − identity| of the redirection
//!   against 128, 4 and 64 iterations; with `CONVERGE=1` also against the
//!   128-iteration solve continued 4,000 finest-level iterations;
//! - warm bakes of the benchmark's frames 0..=10 at 4, 8, 16 and 64
//!   iterations: the last frame's rigid stretch, and each frame's
//!   difference against the 64-iteration bake.
//!
//! `N=1024 [CONVERGE=1] cargo run --release -p tegument-core --example warp_iterations`
//! (N defaults to 1024; output on stderr).
use std::time::Instant;
use tegument_core::warp::fixtures::{bend, scales_map, uv_cylinder};
use tegument_core::warp::{TileMaps, UvWarp, WarpSettings};

fn diff(a: &[f32], b: &[f32], inf: &[f32], valid: &[u8], n: usize) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (t, _) in valid.iter().enumerate().filter(|(_, &v)| v != 0) {
        let id = [((t % n) as f64 + 0.5) / n as f64, ((t / n) as f64 + 0.5) / n as f64];
        for c in 0..2 {
            num += (a[2 * t + c] as f64 - b[2 * t + c] as f64).powi(2);
            den += (inf[2 * t + c] as f64 - id[c]).powi(2);
        }
    }
    (num / den).sqrt()
}

fn main() {
    let n: usize = std::env::var("N").ok().and_then(|v| v.parse().ok()).unwrap_or(1024);
    let m = uv_cylinder(256, 128, 1.0, std::f32::consts::TAU, 0.05);
    let pose = |f: usize| bend(&m.positions, 2, 0, 0.0, 0.0, 0.5 * (0.6 + 0.04 * f as f32));
    let rig = scales_map(n, n, 24);
    let mk = |warm: bool| UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &rig, mask: None }], WarpSettings { warm_start: warm, ..Default::default() }).unwrap();
    let strongest = pose(10);
    // Cold.
    let ks = [4usize, 6, 8, 12, 16, 24, 32, 48, 64, 128];
    let mut w = mk(false);
    let valid = w.tiles[0].validity().to_vec();
    let mut rs = Vec::new();
    for &k in &ks {
        w.settings.iterations = k as u32;
        let t = Instant::now();
        w.solve(&strongest).unwrap();
        let q = &w.metrics(&strongest).unwrap()[0];
        eprintln!("cold k={k}: {:.0} ms stretch {:.4} folds {} repair {:?}", t.elapsed().as_secs_f64() * 1e3, q.stretch_warped.mean, q.foldovers, w.tiles[0].solver.last_repair);
        rs.push(w.tiles[0].redirection.clone());
    }
    let last = rs.last().unwrap().clone();
    for (i, &k) in ks.iter().enumerate() {
        eprintln!("cold k={k}: diff to k=128 {:.4}, to k=4 {:.4}, to k=64 {:.4}", diff(&rs[i], &last, &last, &valid, n), diff(&rs[i], &rs[0], &last, &valid, n), diff(&rs[i], &rs[8], &last, &valid, n));
    }
    if std::env::var("CONVERGE").is_ok() {
        let t = Instant::now();
        let (done, ch) = w.converge(&strongest, 1e-7 * n as f32, 4000).unwrap();
        let inf = w.tiles[0].redirection.clone();
        let q = &w.metrics(&strongest).unwrap()[0];
        eprintln!("x_inf: +{done} ({:.0} s) change {ch:.2e} stretch {:.4}", t.elapsed().as_secs_f64(), q.stretch_warped.mean);
        for (i, &k) in ks.iter().enumerate() {
            eprintln!("cold k={k}: convergence error {:.4}", diff(&rs[i], &inf, &inf, &valid, n));
        }
    }
    // Warm bakes of frames 0..=10.
    let bk = [4usize, 8, 16, 64];
    let mut bakes: Vec<Vec<Vec<f32>>> = Vec::new();
    for &k in &bk {
        let mut w = mk(true);
        w.settings.iterations = k as u32;
        let mut frames = Vec::new();
        for f in 0..=10 {
            w.solve(&pose(f)).unwrap();
            frames.push(w.tiles[0].redirection.clone());
        }
        let q = &w.metrics(&strongest).unwrap()[0];
        eprintln!("bake k={k}: last stretch {:.4} folds {}", q.stretch_warped.mean, q.foldovers);
        bakes.push(frames);
    }
    for (i, &k) in bk.iter().enumerate() {
        let d: Vec<String> = (0..=10).map(|f| format!("{:.3}", diff(&bakes[i][f], &bakes[3][f], &bakes[3][f], &valid, n))).collect();
        eprintln!("bake k={k} vs k=64 per frame: {}", d.join(" "));
    }
}
