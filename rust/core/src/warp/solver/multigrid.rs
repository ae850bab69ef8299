//! Full-approximation-scheme (FAS) multigrid over the level hierarchy: the
//! solver of issue 28.
//!
//! The finest level's iteration `x ← G₀(x)` (projection, regularisation,
//! fold prevention) defines the warp: its fixed point is the converged warp.
//! Every coarser level `l` has an iteration `G_l` of its own (the same steps
//! on blurred rigidity, a reduced mask and averaged metrics) whose fixed
//! point alone is a different warp. That is why the old coarse-to-fine
//! cascade, which handed each level's own solution down, stopped somewhere
//! else than the finest level's fixed point, and why more iterations then
//! kept moving the result (issue 28: 1.2 × the warp's size away at 1024²).
//!
//! Here the coarse levels *correct* the finer one instead: in a cycle, level
//! `l + 1` solves `x = G_{l+1}(x) + f_{l+1}` from the restricted fine iterate
//! `R x`, with the forcing
//!
//! `f_{l+1} = S·R(G_l(x) + f_l − x) − (G_{l+1}(R x) − R x)`,
//!
//! and the change it makes is prolonged back and added. When the fine
//! residual `G_l(x) + f_l − x` is zero, `R x` is the coarse fixed point and
//! the correction is zero: a fixed point of the finest level is a fixed point
//! of every cycle, so more cycles converge to the finest level's own warp and
//! cannot drift away from it. `S = 4` is the ratio of one iteration's step on
//! levels of spacing 1 and 2 for a second-order operator (the Gaussian
//! regularisation, and the distance constraints' net force in rigid regions):
//! the restricted residual is expressed as the coarse level's step.
//!
//! A cycle (V-cycle) on level `l`: one smoothing iteration, then one more
//! whose change is the residual, the coarse correction computed from the
//! iterate before that last step (the step itself is discarded: applying the
//! correction on top of it diverged), then one smoothing iteration. The
//! coarsest level runs [`COARSEST_ITERATIONS`].
//!
//! Deterministic: every pass is elementwise or row-parallel with no shared
//! writes, so results do not depend on the thread count.

use rayon::prelude::*;

use super::folds::keep_areas;
use super::{Level, PARALLEL_TEXELS};

/// Smoothing iterations before the residual step and after the correction.
const PRE: usize = 1;
const POST: usize = 1;
/// Iterations on the coarsest level of a cycle (8² or 16²: negligible cost).
pub(super) const COARSEST_ITERATIONS: usize = 32;
/// Scale of the restricted residual (see the module documentation). Larger
/// factors overcorrect, and V-cycles compound the overcorrection of every
/// level: 5 diverged on a plain Laplace problem.
const RESIDUAL_SCALE: f32 = 4.0;
/// Passes of the fold-prevention constraint per iteration (as the old solver).
pub(super) const AREA_PASSES: usize = 4;

/// One plain iteration (projection and regularisation) of a level, with
/// that level's metric: what the solver's fast or reference kernels do.
pub(super) trait Smoother {
    fn step(&self, lv: &mut Level, l: usize);
}

/// `n` iterations of level `l`: the plain step, then the forcing (coarse
/// levels of a cycle) and the fold-prevention constraint.
pub(super) fn smooth(lv: &mut Level, l: usize, n: usize, forced: bool, g: &impl Smoother) {
    for _ in 0..n {
        g.step(lv, l);
        if forced {
            add_forcing(lv);
        }
        keep_areas(lv, AREA_PASSES, true, None);
    }
}

fn add_forcing(lv: &mut Level) {
    let add = |(d, f): (&mut f32, &f32)| *d += *f;
    if lv.w * lv.h >= PARALLEL_TEXELS {
        lv.dx.par_iter_mut().zip(&lv.fx).for_each(add);
        lv.dy.par_iter_mut().zip(&lv.fy).for_each(add);
    } else {
        lv.dx.iter_mut().zip(&lv.fx).for_each(add);
        lv.dy.iter_mut().zip(&lv.fy).for_each(add);
    }
}

/// One V-cycle with level `l` on top down to level `bottom`. `forced`: `l`
/// is itself the coarse level of a finer cycle and has a forcing term.
pub(super) fn cycle(levels: &mut [Level], l: usize, bottom: usize, forced: bool, g: &impl Smoother) {
    if l == bottom {
        smooth(&mut levels[l], l, COARSEST_ITERATIONS, forced, g);
        return;
    }
    {
        let lv = &mut levels[l];
        smooth(lv, l, PRE, forced, g);
        resize(&mut lv.ox, lv.dx.len());
        resize(&mut lv.oy, lv.dy.len());
        lv.ox.copy_from_slice(&lv.dx);
        lv.oy.copy_from_slice(&lv.dy);
        // The residual: one more step's change.
        smooth(lv, l, 1, forced, g);
    }
    {
        let (fine, coarse) = levels.split_at_mut(l + 1);
        let (f, c) = (&fine[l], &mut coarse[0]);
        restrict_fas(f, c);
        // τ: the coarse level's own (unforced) step from R x, subtracted.
        smooth(c, l + 1, 1, false, g);
        let tau = |(fv, (d, s)): (&mut f32, (&f32, &f32))| *fv -= *d - *s;
        if c.w * c.h >= PARALLEL_TEXELS {
            c.fx.par_iter_mut().zip(c.dx.par_iter().zip(&c.start_x)).for_each(tau);
            c.fy.par_iter_mut().zip(c.dy.par_iter().zip(&c.start_y)).for_each(tau);
        } else {
            c.fx.iter_mut().zip(c.dx.iter().zip(&c.start_x)).for_each(tau);
            c.fy.iter_mut().zip(c.dy.iter().zip(&c.start_y)).for_each(tau);
        }
        c.dx.copy_from_slice(&c.start_x);
        c.dy.copy_from_slice(&c.start_y);
    }
    cycle(levels, l + 1, bottom, true, g);
    let (fine, coarse) = levels.split_at_mut(l + 1);
    let (f, c) = (&mut fine[l], &coarse[0]);
    f.dx.copy_from_slice(&f.ox);
    f.dy.copy_from_slice(&f.oy);
    super::prolong(c, f);
    smooth(f, l, POST, forced, g);
}

pub(super) fn resize(v: &mut Vec<f32>, n: usize) {
    if v.len() != n {
        v.clear();
        v.resize(n, 0.0);
    }
}

/// Fine → coarse for a cycle: the coarse iterate and its start are the
/// restriction (2×2 mean, halved into coarse texels) of the fine iterate
/// before the residual step (`f.ox`, `f.oy`), also where the coarse mask
/// fixes the node (a fixed coarse node stays at the restricted fine warp, so
/// that the coarse grid does not fold against it); the forcing is
/// [`RESIDUAL_SCALE`] × the restricted residual (`f.d − f.o`), 0 at fixed nodes.
fn restrict_fas(f: &Level, c: &mut Level) {
    let (fw, cw, n) = (f.w, c.w, c.w * c.h);
    for v in [&mut c.fx, &mut c.fy, &mut c.start_x, &mut c.start_y] {
        resize(v, n);
    }
    let rows = c.dx.par_chunks_mut(cw).zip(c.dy.par_chunks_mut(cw)).zip(c.start_x.par_chunks_mut(cw).zip(c.start_y.par_chunks_mut(cw))).zip(c.fx.par_chunks_mut(cw).zip(c.fy.par_chunks_mut(cw)));
    rows.enumerate().for_each(|(y, (((cx, cy), (sx, sy)), (rx, ry)))| {
        let m = &c.mask[y * cw..(y + 1) * cw];
        let r0 = 2 * y * fw;
        let r1 = r0 + fw;
        for x in 0..cw {
            let q = [r0 + 2 * x, r0 + 2 * x + 1, r1 + 2 * x, r1 + 2 * x + 1];
            let mean = |v: &[f32]| 0.125 * (v[q[0]] + v[q[1]] + v[q[2]] + v[q[3]]);
            let (ox, oy) = (mean(&f.ox), mean(&f.oy));
            let (nx, ny) = (mean(&f.dx), mean(&f.dy));
            (cx[x], cy[x], sx[x], sy[x]) = (ox, oy, ox, oy);
            let keep = m[x] != 0;
            rx[x] = if keep { RESIDUAL_SCALE * (nx - ox) } else { 0.0 };
            ry[x] = if keep { RESIDUAL_SCALE * (ny - oy) } else { 0.0 };
        }
    });
}
