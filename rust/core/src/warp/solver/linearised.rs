//! The multigrid's linear coarse-grid correction (issue 28): the finest
//! level's iteration `x ← G(x)` linearised once per bake and coarsened by
//! Galerkin products with operator-dependent interpolation ([`galerkin`]),
//! so that the coarse levels see the rigid features exactly as the finest
//! level does (the rediscretised coarse levels of [`super::multigrid`] see
//! a blurred rigidity and keep 0.6–0.86 of the error a cycle).
//!
//! **The operator.** `A = I − J`, `J` the Jacobian of one finest
//! iteration (projection, regularisation, fold prevention: the real
//! kernels), *probed*: the iteration is local, so the columns of `J` for
//! nodes [`STRIDE`] apart in both directions do not overlap within
//! [`RADIUS`] and one iteration with all of them displaced by [`PROBE`]
//! texel measures them together (finite differences; 25 colours × 2
//! channels = 50 iterations). Couplings beyond `RADIUS` are cut off. The
//! fixed point `x = G(x)` has residual `r = G(x) − x ≈ A (x_∞ − x)`, so the
//! correction is `x += A⁻¹ r`, `A⁻¹` approximated by one V-cycle of the
//! Galerkin hierarchy. A zero residual gives a zero correction: the fixed
//! point stays the finest level's, whatever the linearisation's accuracy.
//!
//! A cycle: one iteration; one more, whose change is the residual (the
//! step itself discarded, as the FAS cycle does); the correction added to
//! the iterate before it; the fold prevention; one iteration.

use super::galerkin::{Csr, GridOperator, Hierarchy};
use super::multigrid::{smooth, Smoother, AREA_PASSES};
use super::folds::keep_areas;
use super::Level;

/// Reach of the probed stencil (texels) and the colouring's period.
const RADIUS: isize = 2;
const STRIDE: usize = 2 * RADIUS as usize + 1;
/// Displacement of the probes (texels): small against a texel, large
/// against f32 rounding of displacements of a few texels.
const PROBE: f32 = 1e-2;
/// Couplings under this are dropped (noise of the finite differences).
const NEGLIGIBLE: f64 = 1e-4;
/// How much larger the residual after a correction may be than before it
/// (RMS). Not 1: a good correction adds detail the next iteration smooths,
/// so the one-step residual after it is larger while the error is smaller
/// (the squares scene: 1–5 × on cycles that halved the error).
const GROWTH: f64 = 10.0;
/// Unknowns of the level solved directly.
const DIRECT: usize = 1200;

/// The probed operator and its hierarchy.
#[derive(Debug, Clone)]
pub(super) struct Correction {
    hierarchy: Hierarchy,
    /// Wall time of the probe and of the hierarchy's construction (ms).
    pub probe_ms: f64,
    pub build_ms: f64,
}

impl Correction {
    /// Probes the finest level's iteration at its current warp (restored
    /// afterwards) and builds the hierarchy.
    pub fn new(lv: &mut Level, g: &impl Smoother) -> Self {
        let started = std::time::Instant::now();
        let a = probe(lv, g);
        let probe_ms = started.elapsed().as_secs_f64() * 1e3;
        let started = std::time::Instant::now();
        let hierarchy = Hierarchy::new(a, DIRECT);
        Correction { hierarchy, probe_ms, build_ms: started.elapsed().as_secs_f64() * 1e3 }
    }

    /// Nonzeros of every level's operator, finest first.
    pub fn nonzeros(&self) -> Vec<usize> {
        self.hierarchy.nonzeros()
    }

    /// One cycle on the finest level (see the module documentation).
    /// Returns whether the correction was kept: it is not when the residual
    /// after it (the change of the last iteration) is more than [`GROWTH`]
    /// times, in RMS, the one before it: the linearisation does not hold
    /// (the benchmark cylinder's strongest bend, cells at the
    /// fold-prevention limit: 360–660 ×); the level is then back at the
    /// iterate before the residual step, for the caller's FAS cycle.
    pub fn cycle(&self, lv: &mut Level, g: &impl Smoother) -> bool {
        smooth(lv, 0, 1, false, g);
        let (x0, y0) = (lv.dx.clone(), lv.dy.clone());
        smooth(lv, 0, 1, false, g);
        let n = lv.w * lv.h;
        let mut r = vec![0.0f64; 2 * n];
        for t in 0..n {
            r[2 * t] = (lv.dx[t] - x0[t]) as f64;
            r[2 * t + 1] = (lv.dy[t] - y0[t]) as f64;
        }
        let mut e = vec![0.0f64; 2 * n];
        self.hierarchy.cycle(&mut e, &r);
        for t in 0..n {
            let movable = lv.mask[t] != 0;
            lv.dx[t] = if movable { x0[t] + e[2 * t] as f32 } else { x0[t] };
            lv.dy[t] = if movable { y0[t] + e[2 * t + 1] as f32 } else { y0[t] };
        }
        keep_areas(lv, AREA_PASSES, true);
        let (x1, y1) = (lv.dx.clone(), lv.dy.clone());
        smooth(lv, 0, 1, false, g);
        let after: f64 = (0..n).map(|t| ((lv.dx[t] - x1[t]) as f64).powi(2) + ((lv.dy[t] - y1[t]) as f64).powi(2)).sum();
        let before: f64 = r.iter().map(|v| v * v).sum();
        if after <= GROWTH * GROWTH * before {
            return true;
        }
        lv.dx.copy_from_slice(&x0);
        lv.dy.copy_from_slice(&y0);
        false
    }
}

/// `A = I − J` of the finest level's iteration at its current warp.
fn probe(lv: &mut Level, g: &impl Smoother) -> GridOperator {
    let (w, h) = (lv.w, lv.h);
    let n = w * h;
    let (x0, y0) = (lv.dx.clone(), lv.dy.clone());
    smooth(lv, 0, 1, false, g);
    let (gx, gy) = (lv.dx.clone(), lv.dy.clone());
    let mut rows: Vec<Vec<(u32, f64)>> = (0..2 * n).map(|u| vec![(u as u32, 1.0)]).collect();
    for cj in 0..STRIDE {
        for ci in 0..STRIDE {
            for c in 0..2 {
                let probed = |i: usize, j: usize| i % STRIDE == ci && j % STRIDE == cj;
                lv.dx.copy_from_slice(&x0);
                lv.dy.copy_from_slice(&y0);
                let moved = if c == 0 { &mut lv.dx } else { &mut lv.dy };
                for j in 0..h {
                    for i in 0..w {
                        if probed(i, j) && lv.mask[j * w + i] != 0 {
                            moved[j * w + i] += PROBE;
                        }
                    }
                }
                smooth(lv, 0, 1, false, g);
                for qj in 0..h {
                    for qi in 0..w {
                        let q = qj * w + qi;
                        if lv.mask[q] == 0 {
                            continue;
                        }
                        // The probed node within RADIUS of q.
                        let off = |v: usize, colour: usize| ((colour + STRIDE - v % STRIDE) % STRIDE) as isize;
                        let (mut di, mut dj) = (off(qi, ci), off(qj, cj));
                        if di > RADIUS {
                            di -= STRIDE as isize;
                        }
                        if dj > RADIUS {
                            dj -= STRIDE as isize;
                        }
                        let (pi, pj) = (qi as isize + di, qj as isize + dj);
                        if pi < 0 || pj < 0 || pi >= w as isize || pj >= h as isize || lv.mask[pj as usize * w + pi as usize] == 0 {
                            continue;
                        }
                        let p = pj as usize * w + pi as usize;
                        for (cq, (now, base)) in [(&lv.dx, &gx), (&lv.dy, &gy)].into_iter().enumerate() {
                            let jac = ((now[q] - base[q]) / PROBE) as f64;
                            if jac.abs() > NEGLIGIBLE {
                                rows[2 * q + cq].push(((2 * p + c) as u32, -jac));
                            }
                        }
                    }
                }
            }
        }
    }
    lv.dx.copy_from_slice(&x0);
    lv.dy.copy_from_slice(&y0);
    GridOperator { w, h, comps: 2, a: Csr::from_rows(2 * n, rows) }
}
