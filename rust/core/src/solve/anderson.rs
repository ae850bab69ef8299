//! Anderson acceleration of the local/global iteration (Peng et al. 2018,
//! "Anderson Acceleration for Geometry Optimization and Physics Simulation").
//!
//! One local/global iteration is a fixed-point map `x ↦ G(x)`. Its slow modes
//! (the smooth, low-frequency shape changes that closeness barely anchors)
//! shrink by a factor close to 1 per iteration, which is why a low closeness
//! needs hundreds of plain iterations. Anderson's method keeps the last few
//! residuals `f_i = G(x_i) − x_i` and steps to the combination of the last
//! images `G(x_i)` whose residuals cancel best:
//!
//! `x_{k+1} = G(x_k) − ΔG γ`, with `γ = argmin ‖f_k − ΔF γ‖`,
//!
//! `ΔF`, `ΔG` the differences of consecutive residuals and images. When a
//! residual grows instead of shrinking, the history is dropped and the plain
//! step taken (the safeguard): the iteration is then never worse than the
//! plain one by more than the step that detected it.
//!
//! All sums run in fixed chunks in a fixed order, so results do not depend on
//! the number of threads.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Vertices per chunk of a parallel sum: fixed, so the sum's order is too.
const CHUNK: usize = 4096;

/// Tikhonov term of the small least-squares problem, relative to its trace:
/// keeps it solvable when two residual differences are (nearly) parallel.
const REGULARISATION: f64 = 1e-10;

/// The history of one solve.
pub(super) struct Anderson {
    window: usize,
    /// Ring buffers of `Δf` and `Δg`; `len` entries used, newest at `newest`.
    delta_f: Vec<Vec<Vec3>>,
    delta_g: Vec<Vec<Vec3>>,
    len: usize,
    newest: usize,
    /// `ΔFᵀΔF`, kept up to date one row at a time.
    gram: Vec<f64>,
    last_f: Vec<Vec3>,
    last_g: Vec<Vec3>,
    last_norm2: f64,
    started: bool,
}

impl Anderson {
    pub(super) fn new(window: usize, vertex_count: usize) -> Self {
        Anderson {
            window,
            delta_f: (0..window).map(|_| vec![Vec3::ZERO; vertex_count]).collect(),
            delta_g: (0..window).map(|_| vec![Vec3::ZERO; vertex_count]).collect(),
            len: 0,
            newest: 0,
            gram: vec![0.0; window * window],
            last_f: vec![Vec3::ZERO; vertex_count],
            last_g: vec![Vec3::ZERO; vertex_count],
            last_norm2: f64::INFINITY,
            started: false,
        }
    }

    /// Forgets the history (a new solve, or a step that made things worse).
    pub(super) fn restart(&mut self) {
        self.len = 0;
        self.started = false;
        self.last_norm2 = f64::INFINITY;
    }

    /// Given the iterate `x` and its image `g = G(x)`, overwrites `g` with
    /// the accelerated next iterate.
    pub(super) fn accelerate(&mut self, x: &[Vec3], g: &mut [Vec3]) {
        // f = g − x, its squared norm; and the newest differences.
        let norm2 = chunked_sum(x.len(), |range| {
            let mut s = 0.0;
            for i in range {
                s += (g[i] - x[i]).as_dvec3().length_squared();
            }
            s
        });
        if self.started && !(norm2 < self.last_norm2) {
            // The residual grew: the combination overshot. Start again from
            // this plain image.
            self.restart();
        }
        if self.started {
            let slot = if self.len < self.window { self.len } else { (self.newest + 1) % self.window };
            {
                let (df, dg) = (&mut self.delta_f[slot], &mut self.delta_g[slot]);
                let (last_f, last_g) = (&mut self.last_f, &mut self.last_g);
                df.par_chunks_mut(CHUNK)
                    .zip(dg.par_chunks_mut(CHUNK))
                    .zip(last_f.par_chunks_mut(CHUNK).zip(last_g.par_chunks_mut(CHUNK)))
                    .enumerate()
                    .for_each(|(c, ((df, dg), (lf, lg)))| {
                        let base = c * CHUNK;
                        for k in 0..df.len() {
                            let (xi, gi) = (x[base + k], g[base + k]);
                            let fi = gi - xi;
                            df[k] = fi - lf[k];
                            dg[k] = gi - lg[k];
                            lf[k] = fi;
                            lg[k] = gi;
                        }
                    });
            }
            self.newest = slot;
            self.len = (self.len + 1).min(self.window);
            // The new row and column of the Gram matrix.
            for j in 0..self.window {
                if j >= self.len && j != slot {
                    continue;
                }
                let value = dot(&self.delta_f[slot], &self.delta_f[j]);
                self.gram[slot * self.window + j] = value;
                self.gram[j * self.window + slot] = value;
            }
            // γ = (ΔFᵀΔF + λI)⁻¹ ΔFᵀ f.
            let used: Vec<usize> = (0..self.len).collect();
            let m = used.len();
            let mut matrix = vec![0.0; m * m];
            let mut rhs = vec![0.0; m];
            let mut trace = 0.0;
            for (a, &i) in used.iter().enumerate() {
                for (b, &j) in used.iter().enumerate() {
                    matrix[a * m + b] = self.gram[i * self.window + j];
                }
                trace += matrix[a * m + a];
                rhs[a] = dot(&self.delta_f[i], &self.last_f);
            }
            for a in 0..m {
                matrix[a * m + a] += REGULARISATION * trace.max(f64::MIN_POSITIVE);
            }
            if let Some(gamma) = solve_symmetric(&mut matrix, &mut rhs, m) {
                let (delta_g, gamma) = (&self.delta_g, gamma);
                g.par_chunks_mut(CHUNK).enumerate().for_each(|(c, chunk)| {
                    let base = c * CHUNK;
                    for (k, gi) in chunk.iter_mut().enumerate() {
                        let mut correction = DVec3::ZERO;
                        for (a, &i) in used.iter().enumerate() {
                            correction += gamma[a] * delta_g[i][base + k].as_dvec3();
                        }
                        *gi -= correction.as_vec3();
                    }
                });
            } else {
                self.restart();
            }
        } else {
            self.last_f.par_chunks_mut(CHUNK).zip(self.last_g.par_chunks_mut(CHUNK)).enumerate().for_each(
                |(c, (lf, lg))| {
                    let base = c * CHUNK;
                    for k in 0..lf.len() {
                        lf[k] = g[base + k] - x[base + k];
                        lg[k] = g[base + k];
                    }
                },
            );
            self.started = true;
        }
        self.last_norm2 = norm2;
    }
}

fn chunked_sum(n: usize, part: impl Fn(std::ops::Range<usize>) -> f64 + Sync) -> f64 {
    let parts: Vec<f64> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| part(c * CHUNK..((c + 1) * CHUNK).min(n)))
        .collect();
    parts.iter().sum()
}

fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    chunked_sum(a.len(), |range| {
        let mut s = 0.0;
        for i in range {
            s += a[i].as_dvec3().dot(b[i].as_dvec3());
        }
        s
    })
}

/// Solves the small symmetric positive definite system by Cholesky; `None`
/// when it is not positive definite (numerically).
fn solve_symmetric(matrix: &mut [f64], rhs: &mut [f64], m: usize) -> Option<Vec<f64>> {
    for j in 0..m {
        let mut d = matrix[j * m + j];
        for k in 0..j {
            d -= matrix[j * m + k] * matrix[j * m + k];
        }
        if !(d > 0.0) {
            return None;
        }
        let d = d.sqrt();
        matrix[j * m + j] = d;
        for i in j + 1..m {
            let mut s = matrix[i * m + j];
            for k in 0..j {
                s -= matrix[i * m + k] * matrix[j * m + k];
            }
            matrix[i * m + j] = s / d;
        }
    }
    for i in 0..m {
        let mut s = rhs[i];
        for k in 0..i {
            s -= matrix[i * m + k] * rhs[k];
        }
        rhs[i] = s / matrix[i * m + i];
    }
    for i in (0..m).rev() {
        let mut s = rhs[i];
        for k in i + 1..m {
            s -= matrix[k * m + i] * rhs[k];
        }
        rhs[i] = s / matrix[i * m + i];
    }
    rhs.iter().all(|v| v.is_finite()).then(|| rhs.to_vec())
}
