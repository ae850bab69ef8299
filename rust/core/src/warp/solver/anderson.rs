//! Anderson acceleration (nonlinear GMRES) of the multigrid's finest cycles
//! (issue 28).
//!
//! One FAS cycle is a fixed-point map `x ↦ G(x)` of the finest warp. On
//! high-contrast rigidity it leaves a few slow modes, about one per rigid
//! feature, that shrink by only 0.6–0.86 a cycle (docs/performance.md).
//! Anderson's method keeps the last few residuals `f_i = G(x_i) − x_i` and
//! steps to the combination of the last images whose residuals cancel best:
//!
//! `x_{k+1} = G(x_k) − ΔG γ`, `γ = argmin ‖f_k − ΔF γ‖`,
//!
//! with `ΔF`, `ΔG` the differences of consecutive residuals and images. It
//! costs `2 · depth` vectors of the finest level, not a matrix.
//!
//! Safeguards: a residual that grew drops the history (the plain image is
//! taken), and an accelerated iterate that still folds after the
//! fold-prevention constraint is replaced by the plain image, so the iterate
//! is never folded and never worse than the plain cycle by more than the step
//! that detected it.
//!
//! Sums run over fixed chunks in a fixed order: the result does not depend
//! on the number of threads.

use rayon::prelude::*;

use super::folds::keep_areas;
use super::{Level, AREA_PASSES};

/// Values per chunk of a parallel sum: fixed, so the order of the sum is too.
const CHUNK: usize = 8192;

/// Tikhonov term of the small least-squares problem, relative to its trace:
/// keeps it solvable when residual differences are (nearly) parallel.
const REGULARISATION: f64 = 1e-9;

/// The history of the finest level's cycles.
#[derive(Debug, Clone)]
pub struct Anderson {
    depth: usize,
    /// Ring buffers of `Δf` and `Δg` (both channels: `dx` then `dy`); `len`
    /// entries used, the newest at `newest`.
    delta_f: Vec<Vec<f32>>,
    delta_g: Vec<Vec<f32>>,
    len: usize,
    newest: usize,
    /// `ΔFᵀΔF`, one row updated per step.
    gram: Vec<f64>,
    last_f: Vec<f32>,
    last_g: Vec<f32>,
    last_norm2: f64,
    started: bool,
    /// The iterate before the cycle, and the cycle's image.
    x: Vec<f32>,
    g: Vec<f32>,
    /// Steps taken accelerated, and steps that fell back to the plain image
    /// (residual grew, singular system, or a fold).
    pub accepted: usize,
    pub rejected: usize,
}

impl Anderson {
    pub fn new(depth: usize) -> Self {
        Anderson { depth, delta_f: Vec::new(), delta_g: Vec::new(), len: 0, newest: 0, gram: vec![0.0; depth * depth], last_f: Vec::new(), last_g: Vec::new(), last_norm2: f64::INFINITY, started: false, x: Vec::new(), g: Vec::new(), accepted: 0, rejected: 0 }
    }

    /// Forgets the history (a cold solve, or a step that made things worse).
    pub fn restart(&mut self) {
        self.len = 0;
        self.started = false;
        self.last_norm2 = f64::INFINITY;
    }

    /// Remembers the iterate `x` before the cycle.
    pub fn before(&mut self, lv: &Level) {
        gather(&mut self.x, lv);
    }

    /// `lv` holds the cycle's image `G(x)`: overwrites it with the
    /// accelerated iterate (or leaves the image, see the safeguards).
    pub fn after(&mut self, lv: &mut Level) {
        let n = self.x.len();
        gather(&mut self.g, lv);
        if self.delta_f.len() != self.depth || self.delta_f.first().is_some_and(|v| v.len() != n) {
            self.delta_f = vec![vec![0.0; n]; self.depth];
            self.delta_g = vec![vec![0.0; n]; self.depth];
            self.last_f = vec![0.0; n];
            self.last_g = vec![0.0; n];
            self.restart();
        }
        let (x, g) = (&self.x, &self.g);
        let norm2 = chunked_sum(n, |r| r.map(|i| ((g[i] - x[i]) as f64).powi(2)).sum());
        if self.started && (norm2.is_nan() || norm2 >= self.last_norm2) {
            // The residual grew: the combination overshot (or the frame
            // changed the map too much). Start again from this plain image.
            (self.len, self.started) = (0, false);
            self.rejected += 1;
        }
        self.last_norm2 = norm2;
        if !self.started {
            for (i, (lf, lg)) in self.last_f.iter_mut().zip(self.last_g.iter_mut()).enumerate() {
                (*lf, *lg) = (g[i] - x[i], g[i]);
            }
            self.started = true;
            return;
        }
        let slot = if self.len < self.depth { self.len } else { (self.newest + 1) % self.depth };
        {
            let (df, dg) = (&mut self.delta_f[slot], &mut self.delta_g[slot]);
            let parts = df.par_chunks_mut(CHUNK).zip(dg.par_chunks_mut(CHUNK)).zip(self.last_f.par_chunks_mut(CHUNK).zip(self.last_g.par_chunks_mut(CHUNK)));
            parts.enumerate().for_each(|(c, ((df, dg), (lf, lg)))| {
                let base = c * CHUNK;
                for k in 0..df.len() {
                    let (xi, gi) = (x[base + k], g[base + k]);
                    let fi = gi - xi;
                    (df[k], dg[k], lf[k], lg[k]) = (fi - lf[k], gi - lg[k], fi, gi);
                }
            });
        }
        self.newest = slot;
        self.len = (self.len + 1).min(self.depth);
        let d = self.depth;
        for j in 0..self.len {
            let v = dot(&self.delta_f[slot], &self.delta_f[j]);
            (self.gram[slot * d + j], self.gram[j * d + slot]) = (v, v);
        }
        // γ = (ΔFᵀΔF + λI)⁻¹ ΔFᵀ f_k.
        let m = self.len;
        let trace: f64 = (0..m).map(|a| self.gram[a * d + a]).sum();
        let mut matrix = faer::Mat::<f64>::from_fn(m, m, |a, b| self.gram[a * d + b] + if a == b { REGULARISATION * trace.max(f64::MIN_POSITIVE) } else { 0.0 });
        let mut gamma = faer::Mat::<f64>::from_fn(m, 1, |a, _| dot(&self.delta_f[a], &self.last_f));
        use faer::linalg::solvers::Solve;
        let lu = std::mem::replace(&mut matrix, faer::Mat::zeros(0, 0)).partial_piv_lu();
        lu.solve_in_place(gamma.as_mut());
        let gamma: Vec<f32> = (0..m).map(|a| gamma[(a, 0)] as f32).collect();
        if gamma.iter().any(|v| !v.is_finite()) {
            self.restart();
            self.rejected += 1;
            return;
        }
        let delta_g = &self.delta_g[..m];
        let mut next = std::mem::take(&mut self.x);
        next.par_chunks_mut(CHUNK).enumerate().for_each(|(c, out)| {
            let base = c * CHUNK;
            for (k, o) in out.iter_mut().enumerate() {
                let mut v = g[base + k];
                for (a, dg) in delta_g.iter().enumerate() {
                    v -= gamma[a] * dg[base + k];
                }
                *o = v;
            }
        });
        // A step that overflows is refused like one that folds (a fold count
        // cannot see a NaN: its comparisons are false).
        let finite = next.par_iter().all(|v| v.is_finite());
        scatter(&next, lv);
        self.x = next;
        // `keep_areas` tells whether a cell is still folded (no count needed).
        if !finite || keep_areas(lv, AREA_PASSES, true, None) {
            scatter(&self.g, lv);
            self.restart();
            self.rejected += 1;
        } else {
            self.accepted += 1;
        }
    }
}

/// Both channels of a level into one vector (`dx` then `dy`).
fn gather(out: &mut Vec<f32>, lv: &Level) {
    out.clear();
    out.extend_from_slice(&lv.dx);
    out.extend_from_slice(&lv.dy);
}

fn scatter(v: &[f32], lv: &mut Level) {
    let n = lv.dx.len();
    lv.dx.copy_from_slice(&v[..n]);
    lv.dy.copy_from_slice(&v[n..]);
}

fn chunked_sum(n: usize, part: impl Fn(std::ops::Range<usize>) -> f64 + Sync) -> f64 {
    let parts: Vec<f64> = (0..n.div_ceil(CHUNK)).into_par_iter().map(|c| part(c * CHUNK..((c + 1) * CHUNK).min(n))).collect();
    parts.iter().sum()
}

fn dot(a: &[f32], b: &[f32]) -> f64 {
    chunked_sum(a.len(), |r| r.map(|i| a[i] as f64 * b[i] as f64).sum())
}
