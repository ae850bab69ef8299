//! Quality measures of a warp (for tests, bake reports and pictures).
//!
//! Per texel `t`, the feature-space deformation gradient is
//! `F = J_def(W(t)) · ∇W(t) · J_rest(t)⁻¹`. Its singular values are the square
//! roots of the generalised eigenvalues of `A = ∇Wᵀ G_def(W(t)) ∇W` with
//! respect to `G_rest(t)` (first fundamental forms), so no tangent frames are
//! needed. The rigid-region stretch error is `max(|log σ1|, |log σ2|)` over
//! texels with rigidity ≥ 0.5 that lie inside a chart (all 8 neighbours in the
//! same chart, so that `∇W` by central differences is meaningful).

use rayon::prelude::*;

use super::solver::count_folds;

/// Mean, 95th percentile and maximum.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Stats {
    pub mean: f64,
    pub p95: f64,
    pub max: f64,
}

impl Stats {
    pub fn of(mut values: Vec<f64>) -> Stats {
        if values.is_empty() {
            return Stats::default();
        }
        values.sort_by(|a, b| a.total_cmp(b));
        let n = values.len();
        Stats { mean: values.iter().sum::<f64>() / n as f64, p95: values[((n - 1) as f64 * 0.95) as usize], max: values[n - 1] }
    }
}

/// The figures of one tile.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WarpMetrics {
    pub udim: u32,
    /// Texels the stretch statistics are taken over.
    pub rigid_texels: usize,
    /// Stretch error of rigid texels without warp (the baseline).
    pub stretch_identity: Stats,
    /// Stretch error of rigid texels with the current warp.
    pub stretch_warped: Stats,
    /// Triangles of the warped grid with `det ∇W ≤ 0`.
    pub foldovers: usize,
    /// Largest displacement (texels) of a texel the mask fixes.
    pub max_masked_displacement: f64,
    /// Largest displacement (texels) of any texel.
    pub max_displacement: f64,
    /// `|redirection(W(t)) − t|` in texels over texels inside charts.
    pub round_trip_max: f64,
    pub round_trip_mean: f64,
}

/// Everything [`measure`] reads.
pub struct MeasureInput<'a> {
    pub udim: u32,
    pub w: usize,
    pub h: usize,
    pub ids: &'a [u32],
    pub interior: &'a [u8],
    pub rigidity: &'a [u8],
    pub mask: &'a [u8],
    pub go_tri: &'a [[f32; 3]],
    pub gd_tri: &'a [[f32; 3]],
    pub dx: &'a [f32],
    pub dy: &'a [f32],
    /// Redirection, interleaved absolute UVs.
    pub redirection: &'a [f32],
    pub offset: [f32; 2],
}

/// `max(|ln λ1|, |ln λ2|) / 2` for the generalised eigenvalues of `a` w.r.t. `g`.
pub fn stretch_error(a: [f64; 3], g: [f64; 3]) -> Option<f64> {
    let d1 = g[0] * g[2] - g[1] * g[1];
    if !(d1 > 0.0) {
        return None;
    }
    let t = a[0] * g[2] + a[2] * g[0] - 2.0 * a[1] * g[1];
    let d2 = a[0] * a[2] - a[1] * a[1];
    let disc = (t * t - 4.0 * d1 * d2).max(0.0).sqrt();
    let l1 = (t + disc) / (2.0 * d1);
    let l2 = (t - disc) / (2.0 * d1);
    if !(l2 > 0.0) {
        return Some(f64::INFINITY);
    }
    Some(l1.ln().abs().max(l2.ln().abs()) * 0.5)
}

pub fn measure(m: &MeasureInput<'_>) -> WarpMetrics {
    let (w, h) = (m.w, m.h);
    let lookup = |x: f64, y: f64| {
        let ix = (x.max(0.0) as usize).min(w - 1);
        let iy = (y.max(0.0) as usize).min(h - 1);
        m.gd_tri[m.ids[iy * w + ix] as usize].map(|v| v as f64)
    };
    let per_row: Vec<(Vec<f64>, Vec<f64>, f64, f64, f64, f64, usize)> = (1..h - 1)
        .into_par_iter()
        .map(|j| {
            let (mut base, mut warped) = (Vec::new(), Vec::new());
            let (mut masked_max, mut disp_max, mut rt_max, mut rt_sum, mut rt_n) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0usize);
            for i in 1..w - 1 {
                let p = j * w + i;
                let (dx, dy) = (m.dx[p] as f64, m.dy[p] as f64);
                let disp = (dx * dx + dy * dy).sqrt();
                disp_max = disp_max.max(disp);
                if m.mask[p] == 0 {
                    masked_max = masked_max.max(disp);
                }
                if m.interior[p] == 0 {
                    continue;
                }
                let (x, y) = (i as f64 + 0.5 + dx, j as f64 + 0.5 + dy);
                // Round trip: sample the redirection bilinearly at W(t).
                let (sx, sy) = (x - 0.5, y - 0.5);
                let x0 = (sx.floor().max(0.0) as usize).min(w - 2);
                let y0 = (sy.floor().max(0.0) as usize).min(h - 2);
                let (fx, fy) = ((sx - x0 as f64).clamp(0.0, 1.0), (sy - y0 as f64).clamp(0.0, 1.0));
                let r = |xx: usize, yy: usize, c: usize| m.redirection[2 * (yy * w + xx) + c] as f64;
                let mut back = [0.0; 2];
                for (c, b) in back.iter_mut().enumerate() {
                    *b = (r(x0, y0, c) * (1.0 - fx) + r(x0 + 1, y0, c) * fx) * (1.0 - fy) + (r(x0, y0 + 1, c) * (1.0 - fx) + r(x0 + 1, y0 + 1, c) * fx) * fy;
                }
                let bx = (back[0] - m.offset[0] as f64) * w as f64;
                let by = (back[1] - m.offset[1] as f64) * h as f64;
                let e = ((bx - (i as f64 + 0.5)).powi(2) + (by - (j as f64 + 0.5)).powi(2)).sqrt();
                rt_max = rt_max.max(e);
                rt_sum += e;
                rt_n += 1;
                if m.rigidity[p] < 128 {
                    continue;
                }
                let g0 = m.go_tri[m.ids[p] as usize].map(|v| v as f64);
                let gi = lookup(i as f64 + 0.5, j as f64 + 0.5);
                if let Some(e) = stretch_error(gi, g0) {
                    base.push(e);
                }
                // ∇W (texel units), columns c0 = ∂W/∂x, c1 = ∂W/∂y, by
                // differences that stay inside the feature: central where both
                // neighbours are rigid, one-sided towards the rigid one at the
                // feature's edge (W is piecewise linear: a one-sided difference
                // is the exact gradient of the grid cells on that side).
                let rigid = |q: usize| m.rigidity[q] >= 128;
                let diff = |a: usize, b: usize| -> (usize, usize, f64) {
                    match (rigid(a), rigid(b)) {
                        (true, false) => (a, p, 1.0),
                        (false, true) => (p, b, 1.0),
                        _ => (a, b, 0.5),
                    }
                };
                let (hi, lo, f) = diff(p + 1, p - 1);
                let c0 = [1.0 + f * (m.dx[hi] - m.dx[lo]) as f64, f * (m.dy[hi] - m.dy[lo]) as f64];
                let (hi, lo, f) = diff(p + w, p - w);
                let c1 = [f * (m.dx[hi] - m.dx[lo]) as f64, 1.0 + f * (m.dy[hi] - m.dy[lo]) as f64];
                let g = lookup(x, y);
                let q = |u: [f64; 2], v: [f64; 2]| g[0] * u[0] * v[0] + g[1] * (u[0] * v[1] + u[1] * v[0]) + g[2] * u[1] * v[1];
                if let Some(e) = stretch_error([q(c0, c0), q(c0, c1), q(c1, c1)], g0) {
                    warped.push(e);
                }
            }
            (base, warped, masked_max, disp_max, rt_max, rt_sum, rt_n)
        })
        .collect();
    let mut base = Vec::new();
    let mut warped = Vec::new();
    let mut out = WarpMetrics { udim: m.udim, ..Default::default() };
    let mut rt_sum = 0.0;
    let mut rt_n = 0;
    for (b, wv, mm, dm, rm, rs, rn) in per_row {
        base.extend(b);
        warped.extend(wv);
        out.max_masked_displacement = out.max_masked_displacement.max(mm);
        out.max_displacement = out.max_displacement.max(dm);
        out.round_trip_max = out.round_trip_max.max(rm);
        rt_sum += rs;
        rt_n += rn;
    }
    // Border rows and columns (always fixed by construction) still count.
    for (p, (&dx, &dy)) in m.dx.iter().zip(m.dy).enumerate() {
        let (i, j) = (p % w, p / w);
        if i == 0 || j == 0 || i + 1 == w || j + 1 == h {
            let d = ((dx as f64).powi(2) + (dy as f64).powi(2)).sqrt();
            out.max_displacement = out.max_displacement.max(d);
            if m.mask[p] == 0 {
                out.max_masked_displacement = out.max_masked_displacement.max(d);
            }
        }
    }
    out.round_trip_mean = if rt_n > 0 { rt_sum / rt_n as f64 } else { 0.0 };
    out.rigid_texels = warped.len();
    out.stretch_identity = Stats::of(base);
    out.stretch_warped = Stats::of(warped);
    out.foldovers = count_folds(m.dx, m.dy, w, h, 0.0);
    out
}
