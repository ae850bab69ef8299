//! One plain iteration of a level with the fast kernels of
//! [`crate::warp::sweep`]: the projection's two phases, the regularisation
//! and, when asked, the scan for thin cells ([`ThinRows`]), fused band by
//! band so that the grid is streamed about once per iteration instead of
//! once per step (issue 28: the warm frame is memory-bound).
//!
//! The grid is cut into bands of [`BAND`] rows. Pass 1, one task per band:
//! phase A on its row pairs, phase B on the pairs inside it, then the
//! regularisation of the rows whose three-row neighbourhood is final, and
//! the scan of the cell rows between them, while the band is in cache.
//! Pass 2, one task per seam between two bands: phase B on the pair across
//! it, the regularisation of the four rows that pair changes or borders,
//! and the scan of the five cell rows that touch them.
//!
//! Every kernel reads the values it read when each step was its own pass
//! over the grid: phase B of rows `(j, j + 1)` needs phase A of those two
//! rows only, a row's regularisation needs its three rows after phase B,
//! and no task writes a row another task of the same pass reads. So the
//! result is the same bit for bit, whatever the band size and the number of
//! threads (`fused_iteration_equals_the_step_by_step_one` checks it).

use rayon::prelude::*;

use super::folds::ThinRows;
use super::{Level, PARALLEL_TEXELS};
use crate::warp::sweep::{self, Metric, Sweep};
use crate::warp::WarpSettings;

/// Rows per band: even (whole phase-A pairs) and at least 8, so that a
/// seam's task (two rows below the seam to three above) stays clear of the
/// next seam's. A seam re-reads six rows: 32 keeps that under a fifth of a pass.
const BAND: usize = 32;

/// `n` iterations of a level (projection, regularisation), without the
/// steps `drive` adds. `scan`: the last one also finds the iterate's
/// [`ThinRows`] for the fold-prevention constraint.
pub(super) fn iterate<M: Metric>(lv: &mut Level, metric: M, n: usize, s: &WarpSettings, avx2: bool, scan: bool) -> Option<ThinRows> {
    let mut thin = None;
    for k in 0..n {
        thin = once(lv, &metric, s, avx2, scan && k + 1 == n);
        std::mem::swap(&mut lv.dx, &mut lv.sx);
        std::mem::swap(&mut lv.dy, &mut lv.sy);
    }
    thin
}

/// One iteration, `dx, dy → sx, sy`.
fn once<M: Metric>(lv: &mut Level, metric: &M, s: &WarpSettings, avx2: bool, scan: bool) -> Option<ThinRows> {
    let (w, h) = (lv.w, lv.h);
    let parallel = w * h >= PARALLEL_TEXELS;
    let band = BAND.min(h);
    let bands = h.div_ceil(band);
    let sw = Sweep { w, active: &lv.active, metric, orientation: s.orientation, avx2 };
    let (rig, mask, smoothing) = (&lv.rig[..], &lv.mask[..], s.smoothing);
    // Rows `ys` (local to a window of `rows` rows starting at grid row
    // `first`) regularised from the window of `dx, dy` into the same rows of
    // `ox, oy`. The window's first and last rows count as the grid's for the
    // kernel's copied border rows: only the grid's own are ever asked for.
    let regularise = |first: usize, ys: std::ops::Range<usize>, dx: &[f32], dy: &[f32], ox: &mut [f32], oy: &mut [f32]| {
        let rows = dx.len() / w;
        let (rg, mk) = (&rig[first * w..(first + rows) * w], &mask[first * w..(first + rows) * w]);
        for y in ys {
            let r = y * w..(y + 1) * w;
            sweep::regularise_row(dx, dy, rg, mk, w, rows, y, smoothing, &mut ox[r.clone()], &mut oy[r], avx2);
        }
    };
    let found = |first: usize, ox: &[f32], oy: &[f32]| if scan { ThinRows::in_band(ox, oy, w, first) } else { Vec::new() };

    let pass1 = |(b, ((dx, dy), (ox, oy))): (usize, ((&mut [f32], &mut [f32]), (&mut [f32], &mut [f32])))| {
        let r0 = b * band;
        let rows = dx.len() / w;
        for (p, (cx, cy)) in dx.chunks_mut(2 * w).zip(dy.chunks_mut(2 * w)).enumerate() {
            let (j, pair) = (r0 + 2 * p, cx.len() / w);
            if sw.active.any(j, false) || (pair == 2 && sw.active.any(j + 1, false)) {
                sw.phase_a(j, pair, cx, cy);
            }
        }
        for (p, (cx, cy)) in dx[w..].chunks_mut(2 * w).zip(dy[w..].chunks_mut(2 * w)).enumerate() {
            let j = r0 + 1 + 2 * p;
            if cx.len() == 2 * w && sw.active.any(j, true) {
                sw.between(j, cx, cy);
            }
        }
        // Rows next to a seam wait for its phase B (pass 2).
        let lo = if b == 0 { 0 } else { 2 };
        let hi = if b + 1 == bands { rows } else { rows - 2 };
        regularise(r0, lo..hi, dx, dy, ox, oy);
        found(r0 + lo, &ox[lo * w..hi * w], &oy[lo * w..hi * w])
    };
    // Seam `b` lies between rows `j = (b + 1)·band − 1` and `j + 1`; its
    // window holds grid rows `j − 2 .. j + 4`.
    let pass2 = |(b, ((dx, dy), (ox, oy))): (usize, ((&mut [f32], &mut [f32]), (&mut [f32], &mut [f32])))| {
        let j = (b + 1) * band - 1;
        if sw.active.any(j, true) {
            sw.between(j, &mut dx[2 * w..4 * w], &mut dy[2 * w..4 * w]);
        }
        let (dx, dy, ox, oy) = (&dx[..6 * w], &dy[..6 * w], &mut ox[..6 * w], &mut oy[..6 * w]);
        regularise(j - 2, 1..5, dx, dy, ox, oy);
        found(j - 2, ox, oy)
    };

    let seam0 = (band - 3) * w;
    let mut thin: Vec<usize> = if parallel {
        let a = lv.dx.par_chunks_mut(band * w).zip(lv.dy.par_chunks_mut(band * w));
        let o = lv.sx.par_chunks_mut(band * w).zip(lv.sy.par_chunks_mut(band * w));
        let mut thin: Vec<usize> = a.zip(o).enumerate().flat_map_iter(pass1).collect();
        if bands > 1 {
            let a = lv.dx[seam0..].par_chunks_mut(band * w).zip(lv.dy[seam0..].par_chunks_mut(band * w));
            let o = lv.sx[seam0..].par_chunks_mut(band * w).zip(lv.sy[seam0..].par_chunks_mut(band * w));
            thin.par_extend(a.zip(o).take(bands - 1).enumerate().flat_map_iter(pass2));
        }
        thin
    } else {
        let a = lv.dx.chunks_mut(band * w).zip(lv.dy.chunks_mut(band * w));
        let o = lv.sx.chunks_mut(band * w).zip(lv.sy.chunks_mut(band * w));
        let mut thin: Vec<usize> = a.zip(o).enumerate().flat_map(pass1).collect();
        if bands > 1 {
            let a = lv.dx[seam0..].chunks_mut(band * w).zip(lv.dy[seam0..].chunks_mut(band * w));
            let o = lv.sx[seam0..].chunks_mut(band * w).zip(lv.sy[seam0..].chunks_mut(band * w));
            thin.extend(a.zip(o).take(bands - 1).enumerate().flat_map(pass2));
        }
        thin
    };
    if !scan {
        return None;
    }
    thin.sort_unstable();
    Some(ThinRows(thin))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::warp::sweep::ByTexel;

    /// The iteration as it was written before the bands: each step its own
    /// (parallel) pass over the grid (phase A, phase B, regularisation),
    /// then the scan for thin rows.
    fn step_by_step<M: Metric>(lv: &mut Level, metric: M, s: &WarpSettings, avx2: bool) -> Vec<usize> {
        let (w, h) = (lv.w, lv.h);
        let sw = Sweep { w, active: &lv.active, metric: &metric, orientation: s.orientation, avx2 };
        lv.dx.par_chunks_mut(2 * w).zip(lv.dy.par_chunks_mut(2 * w)).enumerate().for_each(|(p, (cx, cy))| {
            let (j, rows) = (2 * p, cx.len() / w);
            if sw.active.any(j, false) || (rows == 2 && sw.active.any(j + 1, false)) {
                sw.phase_a(j, rows, cx, cy);
            }
        });
        lv.dx[w..].par_chunks_mut(2 * w).zip(lv.dy[w..].par_chunks_mut(2 * w)).enumerate().for_each(|(p, (cx, cy))| {
            let j = 2 * p + 1;
            if cx.len() == 2 * w && sw.active.any(j, true) {
                sw.between(j, cx, cy);
            }
        });
        let (dx, dy, rig, mask) = (&lv.dx, &lv.dy, &lv.rig, &lv.mask);
        lv.sx.par_chunks_mut(w).zip(lv.sy.par_chunks_mut(w)).enumerate().for_each(|(y, (ox, oy))| sweep::regularise_row(dx, dy, rig, mask, w, h, y, s.smoothing, ox, oy, avx2));
        std::mem::swap(&mut lv.dx, &mut lv.sx);
        std::mem::swap(&mut lv.dy, &mut lv.sy);
        let (dx, dy) = (&lv.dx, &lv.dy);
        (0..h - 1).into_par_iter().filter(|&j| ThinRows::in_band(&dx[j * w..(j + 2) * w], &dy[j * w..(j + 2) * w], w, j).len() == 1).collect()
    }

    /// Random warps strong enough to leave thin cells, on grids of one band,
    /// several bands, and several bands above the parallel threshold, with
    /// fixed, partly movable and rigid texels: the banded iteration equals
    /// the step-by-step one bit for bit, and finds the same thin rows.
    #[test]
    fn fused_iteration_equals_the_step_by_step_one() {
        let mut next = 0x2545_f491u32;
        let mut rand = move || {
            next ^= next << 13;
            next ^= next >> 17;
            next ^= next << 5;
            (next % 10_000) as f32 / 10_000.0
        };
        // The row lists must be tested where they are neither empty nor full
        // (the two smaller grids; the largest is thin on every row).
        let mut some_thin_not_all = false;
        for (w, h) in [(24, 16), (40, 96), (136, 160)] {
            let n = w * h;
            let rig: Vec<u8> = (0..n).map(|_| if rand() < 0.5 { 0 } else { (rand() * 255.0) as u8 }).collect();
            let mask: Vec<u8> = (0..n).map(|_| [0, 128, 255, 255, 255][(rand() * 5.0) as usize]).collect();
            let mut lv = Level::new(w, h, rig, mask);
            lv.dx.iter_mut().chain(lv.dy.iter_mut()).for_each(|v| *v = 1.6 * rand() - 0.8);
            let go: Vec<[f32; 3]> = (0..n).map(|_| [1.0 + rand(), 0.2 * rand(), 1.0 + rand()]).collect();
            let gd: Vec<[f32; 3]> = (0..n).map(|_| [0.5 + 2.0 * rand(), 0.5 * rand() - 0.25, 0.5 + 2.0 * rand()]).collect();
            let s = WarpSettings::default();
            for avx2 in [false, sweep::has_avx2()] {
                let mut fused = lv.clone();
                let mut steps = lv.clone();
                let thin = iterate(&mut fused, ByTexel { go: &go, gd: &gd }, 1, &s, avx2, true).expect("scanned");
                let want = step_by_step(&mut steps, ByTexel { go: &go, gd: &gd }, &s, avx2);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&fused.dx), bits(&steps.dx), "{w}×{h}, avx2 {avx2}");
                assert_eq!(bits(&fused.dy), bits(&steps.dy), "{w}×{h}, avx2 {avx2}");
                assert_eq!(thin.0, want, "{w}×{h}, avx2 {avx2}");
                some_thin_not_all |= !want.is_empty() && want.len() < h - 1;
            }
        }
        assert!(some_thin_not_all, "no grid left some rows thin and others not");
    }

    /// Times the banded iteration against the step-by-step one on the warp
    /// benchmark's scene (`benches/warp.rs`: 1024², its strongest bend, the
    /// finest level after a cold solve), alternating them in one process so
    /// that the load of a shared machine falls on both alike:
    /// `cargo test --release -p tegument-core --lib fused_iteration_time -- --ignored --nocapture`
    /// (`TEGUMENT_WARP_N` for another size).
    #[test]
    #[ignore = "a measurement, not a check"]
    fn fused_iteration_time() {
        use crate::warp::fixtures::{bend, scales_map, uv_cylinder};
        use crate::warp::{TileMaps, UvWarp};
        let n: usize = std::env::var("TEGUMENT_WARP_N").ok().and_then(|v| v.parse().ok()).unwrap_or(1024);
        let m = uv_cylinder(256, 128, 1.0, std::f32::consts::TAU, 0.05);
        let rig = scales_map(n, n, 24);
        let mut warp = UvWarp::new(m.input(), &m.corner_uvs, n, n, &[TileMaps { udim: 1001, rigidity: &rig, mask: None }], WarpSettings::default()).unwrap();
        let def = bend(&m.positions, 2, 0, 0.0, 0.0, 0.5 * 0.64);
        warp.solve(&def).unwrap();
        let tile = &warp.tiles[0];
        let gd_tri = tile.layout.triangle_metrics(&warp.mesh, &def);
        let records: Vec<sweep::TriRecord> = tile.solver.rest_metrics().iter().zip(&gd_tri).map(|(&o, &d)| sweep::tri_record(o, d)).collect();
        let ids = &tile.layout.ids;
        let metric = sweep::ByTriangle { ids, records: &records };
        let (s, avx2) = (WarpSettings::default(), sweep::has_avx2());
        let (mut fused, mut steps) = (tile.solver.levels[0].clone(), tile.solver.levels[0].clone());
        let (mut tf, mut ts) = (Vec::new(), Vec::new());
        for _ in 0..40 {
            let t = std::time::Instant::now();
            let thin = iterate(&mut fused, &metric, 1, &s, avx2, true).expect("scanned");
            tf.push(t.elapsed().as_secs_f64() * 1e3);
            let t = std::time::Instant::now();
            let want = step_by_step(&mut steps, &metric, &s, avx2);
            ts.push(t.elapsed().as_secs_f64() * 1e3);
            assert_eq!(thin.0, want);
        }
        assert!(fused.dx.iter().zip(&steps.dx).all(|(a, b)| a.to_bits() == b.to_bits()));
        let stats = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            (v[0], v[v.len() / 2])
        };
        let (f, st) = (stats(tf), stats(ts));
        eprintln!("{n}², {} threads, one iteration of the finest level (ms, min / median of 40): banded {:.2} / {:.2}, step by step {:.2} / {:.2}", rayon::current_num_threads(), f.0, f.1, st.0, st.1);
    }
}
