//! Hierarchical position-based warp solver (seed 001 §4).
//!
//! The warp `W` is stored as a displacement per grid node, in the node's own
//! level's texel units, as a structure of arrays (`dx`, `dy`, f32). Node
//! `(i, j)` sits at texel centre `(i + 0.5, j + 0.5)`; the warped node is at
//! `(i + 0.5 + dx, j + 0.5 + dy)`.
//!
//! One iteration on a level:
//! 1. **Constraint projection.** Distance constraints on the 8-connected grid
//!    make the deformed surface length of every grid segment, measured through
//!    the first fundamental form of the deformed surface at the warped
//!    segment's midpoint, equal its rest length (seed eq. 1). A constraint is
//!    weighted by the larger rigidity of its ends, skipped when both ends are
//!    fully elastic or both are fixed by the mask, and split between its ends
//!    in proportion to their mask values (a fixed end never moves). After the
//!    projection the segment is rotated towards its rest direction by the
//!    orientation fraction (times the rigidity).
//!    The 8 disjoint constraint sets are grouped into two phases so that each
//!    phase is a parallel sweep over row pairs that never share a node: phase
//!    A owns rows (2k, 2k+1) and runs, in this order, the even and odd
//!    horizontal sets of both rows, the vertical set and both diagonal sets
//!    between them; phase B owns rows (2k+1, 2k+2) and runs the remaining
//!    vertical and diagonal sets. Each node is written by one task only, so the
//!    result does not depend on the number of threads.
//! 2. **Regularisation** (seed eqs. 4–5): `p' = (1−b)p + b·K_G(p)` with
//!    `b = M((1−R) + R·s)`, `K_G` the 3×3 Gaussian, followed by clamping each
//!    node to the bounding box of its 8 neighbours, written to a second buffer
//!    (Jacobi, deterministic).
//!
//! The default solver ([`Variant::Cascade`]) goes coarse to fine once; a level's change is
//! prolonged bilinearly to the next finer level (times that level's mask). Warm starts restrict the
//! previous frame's fine warp to every level first. Fold-overs left on the
//! finest level are repaired at the end (local relaxation, then a global
//! scale towards the identity, which is always fold-free).
//! [`Variant::Multigrid`] runs full-approximation-scheme multigrid cycles
//! over the levels instead (`multigrid.rs`), converging to the finest
//! level's fixed point; selectable, not yet the default (see [`Variant`]).

//!
//! Files: this one drives the hierarchy (levels, restriction, prolongation);
//! `iteration.rs` runs one iteration of a level with the fast sweeps of
//! [`super::sweep`], fused band by band; `multigrid.rs` the cycles;
//! `anderson.rs` the multigrid's optional Anderson acceleration of its
//! finest cycles (issue 28); `reference.rs` is the reference
//! path, one constraint at a time, which the sweeps must match bit for bit
//! and which serves `sample_warped`; `folds.rs` counts and repairs
//! fold-overs.

mod anderson;
mod folds;
mod iteration;
mod multigrid;
mod reference;

use rayon::prelude::*;

use folds::{keep_areas, repair_folds, ThinRows};
use iteration::iterate;
pub use folds::{cell_dets, count_folds};
use reference::{iterate_reference, Direct, Indexed};
use super::maps;
use super::sweep::{self, ByTexel, ByTriangle, TriRecord};
use super::WarpSettings;

/// Smallest side of the coarsest level.
const COARSEST: usize = 8;
/// Smallest side of the levels a warm solve iterates.
const WARM_COARSEST: usize = 256;
/// Most iterations on any level.
const MAX_LEVEL_ITERATIONS: usize = 96;

/// One level of the hierarchy.
#[derive(Debug, Clone)]
pub struct Level {
    pub w: usize,
    pub h: usize,
    pub rig: Vec<u8>,
    pub mask: Vec<u8>,
    /// The constraints the sweeps visit.
    active: sweep::ActiveSpans,
    /// Coarse levels only: per-texel metrics of the rest and deformed surface.
    go: Vec<[f32; 3]>,
    gd: Vec<[f32; 3]>,
    pub dx: Vec<f32>,
    pub dy: Vec<f32>,
    sx: Vec<f32>,
    sy: Vec<f32>,
    start_x: Vec<f32>,
    start_y: Vec<f32>,
    /// Levels below the coarsest: the next coarser level's change of `dx`
    /// and `dy`, interpolated along x to this level's width (see
    /// [`prolong`]); kept between frames so that no frame pays for fresh pages.
    prolong_dx: Vec<f32>,
    prolong_dy: Vec<f32>,
    /// Multigrid: the forcing of a coarse level in a cycle, and the iterate
    /// before the residual step (see [`multigrid`]); empty until used.
    fx: Vec<f32>,
    fy: Vec<f32>,
    ox: Vec<f32>,
    oy: Vec<f32>,
}

impl Level {
    fn new(w: usize, h: usize, rig: Vec<u8>, mask: Vec<u8>) -> Self {
        let n = w * h;
        let active = sweep::ActiveSpans::new(w, h, &rig, &mask);
        Level {
            w,
            h,
            active,
            rig,
            mask,
            go: Vec::new(),
            gd: Vec::new(),
            dx: vec![0.0; n],
            dy: vec![0.0; n],
            sx: vec![0.0; n],
            sy: vec![0.0; n],
            start_x: Vec::new(),
            start_y: Vec::new(),
            prolong_dx: Vec::new(),
            prolong_dy: Vec::new(),
            fx: Vec::new(),
            fy: Vec::new(),
            ox: Vec::new(),
            oy: Vec::new(),
        }
    }
}


/// Levels with fewer texels than this run on the calling thread: their whole
/// iteration takes less than a fork–join of the pool under load.
const PARALLEL_TEXELS: usize = 128 * 128;

/// What [`drive`] adds to the plain iterations.
#[derive(Debug, Clone, Copy)]
struct Steps {
    /// The fold-prevention constraint at the end of every iteration.
    areas: bool,
    /// Chebyshev acceleration.
    chebyshev: bool,
    /// The fold prevention settles cells at its limit (the multigrid's
    /// iteration, see [`keep_areas`]) rather than only unfolding them.
    settle: bool,
}

/// `n` iterations of a level: `one` runs one plain iteration (the fast or
/// the reference kernels; asked to, it may return the iterate's
/// [`ThinRows`]), then, per `steps`, the Chebyshev extrapolation
/// (Wang 2015) `x_{k+1} = ω_{k+1}(F(x_k) − x_{k−1}) + x_{k−1}` and the
/// fold-prevention constraint ([`keep_areas`]), so that the iterate every
/// iteration leaves, extrapolated or not, has no folded cell. Returns
/// whether the last iterate has a folded cell, when the constraint ran
/// (`None`: count them).
fn drive(lv: &mut Level, n: usize, steps: Steps, mut one: impl FnMut(&mut Level, bool) -> Option<ThinRows>) -> Option<bool> {
    let chebyshev = steps.chebyshev && n > CHEBYSHEV_WARMUP;
    let mut folded = None;
    if !chebyshev {
        for _ in 0..n {
            let thin = one(lv, steps.areas);
            if steps.areas {
                folded = Some(keep_areas(lv, AREA_PASSES, steps.settle, thin.as_ref()));
            }
        }
        return folded;
    }
    // `p` = x_k, `q` = x_{k−1}.
    let (mut px, mut py) = (lv.dx.clone(), lv.dy.clone());
    let (mut qx, mut qy) = (px.clone(), py.clone());
    let (mut rx, mut ry) = (px.clone(), py.clone());
    let parallel = lv.w * lv.h >= PARALLEL_TEXELS;
    let mut omega = 1.0f32;
    let mut since = 0;
    for _ in 0..n {
        std::mem::swap(&mut qx, &mut px);
        std::mem::swap(&mut qy, &mut py);
        px.copy_from_slice(&lv.dx);
        py.copy_from_slice(&lv.dy);
        // The rows describe the plain iterate, which the extrapolation
        // replaces: they are only asked for when it is kept.
        let thin = one(lv, steps.areas && since < CHEBYSHEV_WARMUP);
        if since >= CHEBYSHEV_WARMUP {
            let rho2 = CHEBYSHEV_RHO * CHEBYSHEV_RHO;
            omega = if since == CHEBYSHEV_WARMUP { 2.0 / (2.0 - rho2) } else { 4.0 / (4.0 - rho2 * omega) };
            let o = omega;
            // Fixed nodes have x = q = their value: they stay.
            let extrapolate = |o: f32, x: &mut [f32], q: &[f32]| {
                let step = |(x, &q): (&mut f32, &f32)| *x = o * (*x - q) + q;
                if parallel {
                    x.par_iter_mut().zip(q).for_each(step);
                } else {
                    x.iter_mut().zip(q).for_each(step);
                }
            };
            // The plain iterate is kept: an extrapolated one that still
            // folds after the area constraint is replaced by it (4096² cold
            // solves folded from 3 iterations: the first long steps folded
            // more than the constraint's few passes untangle).
            rx.copy_from_slice(&lv.dx);
            ry.copy_from_slice(&lv.dy);
            extrapolate(o, &mut lv.dx, &qx);
            extrapolate(o, &mut lv.dy, &qy);
            if keep_areas(lv, AREA_PASSES, steps.settle, None) {
                lv.dx.copy_from_slice(&rx);
                lv.dy.copy_from_slice(&ry);
            } else {
                folded = Some(false);
                since += 1;
                continue;
            }
        }
        since += 1;
        if steps.areas {
            folded = Some(keep_areas(lv, AREA_PASSES, steps.settle, thin.as_ref()));
        }
    }
    folded
}

/// Passes of the fold-prevention constraint per iteration.
const AREA_PASSES: usize = 4;
/// Spectral radius the Chebyshev acceleration of cold solves assumes, and
/// the plain iterations before it starts. Measured on the benchmark cylinder
/// (issue 28): 0.9 and 0.97 gain less at 4 iterations; the fold-prevention
/// constraint keeps the extrapolation's overshoot from folding.
const CHEBYSHEV_RHO: f32 = 0.99;
const CHEBYSHEV_WARMUP: usize = 2;
/// Smallest level side the acceleration runs on. Smaller levels get enough
/// plain iterations from the cold schedule; and on Spot's 256² grid (13
/// charts, unevenly stretched small triangles) the extrapolation left cells
/// squashed so thin that the redirection's round trip missed by up to 1.2
/// texels (0.47 at ρ = 0.95, 0.29 at 0.9), where plain iterations give 0.25.
const CHEBYSHEV_SIDE: usize = 512;

/// The whole hierarchy of one tile.
#[derive(Debug, Clone)]
pub struct Solver {
    pub levels: Vec<Level>,
    /// Per local triangle rest metric (finest level, looked up through ids).
    go_tri: Vec<[f32; 3]>,
    /// Chart of every local triangle (and `u32::MAX` for "no triangle").
    tri_chart: Vec<u32>,
    /// Iterations run per level in the last solve, finest first.
    pub last_iterations: Vec<usize>,
    /// Fold repair passes and global scale applied in the last solve.
    pub last_repair: (usize, f32),
    /// Wall time per level in the last solve (ms), finest first; the last
    /// entry is the fold check/repair.
    pub last_level_ms: Vec<f64>,
    /// Wall time of the per-frame preparation (restriction to the coarse
    /// levels, metric records) in the last solve (ms).
    pub last_prepare_ms: f64,
    /// The finest level's per-triangle records of the last solve (kept for
    /// their allocation).
    records: Vec<TriRecord>,
    /// Run the reference kernels (tests compare them with the fast ones).
    pub(crate) reference: bool,
    /// Which solver runs (see [`Variant`]; set with [`Solver::set_variant`]).
    variant: Variant,
    /// The multigrid's finest cycles accelerated by Anderson's method
    /// ([`anderson`]); `None`: plain cycles.
    anderson: Option<anderson::Anderson>,
    /// Keep the Anderson history from one warm frame to the next (the cycle
    /// map changes little between frames) rather than only within a frame.
    anderson_across_frames: bool,
}

/// The solvers: the product's, and the earlier ones kept so that one
/// benchmark run compares them (issue 28).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Variant {
    /// Full-approximation-scheme multigrid cycles ([`multigrid`]): converges
    /// to the finest level's fixed point. `iterations` = cycles per frame.
    /// Not the default yet (issue 28): a cycle removes only 15–40 % of the
    /// error on rigid features, so one cycle a frame lags and alternates
    /// from frame to frame, and the cycles a frame that converge cost 3–4 ×
    /// the frame budget (docs/performance.md).
    Multigrid,
    /// The coarse-to-fine cascade of the first half of issue 28 (fold
    /// prevention in every iteration, Chebyshev acceleration of cold solves
    /// on levels of 512² and larger; `iterations` per level): the product's.
    #[default]
    Cascade,
    /// The cascade as it was before issue 28 (no fold prevention, no acceleration).
    Legacy,
}

/// Whether two variants build the same coarse masks.
fn coarse_kind(variant: Variant) -> bool {
    variant == Variant::Multigrid
}

/// The mask of the next coarser level. The cascades erode it (seed eq. 8:
/// a coarse constraint must not pull across a fixed border); the multigrid
/// fixes a coarse node only where one of its four finer nodes is fixed:
/// erosion took about 2^l texels along the chart borders away from level
/// `l`'s corrections, and the first cycle then left 0.77 of the error
/// instead of 0.38 on the benchmark cylinder at 256².
fn coarse_mask(fine: &[u8], w: usize, h: usize, variant: Variant) -> Vec<u8> {
    match variant {
        Variant::Multigrid => maps::reduce_min(fine, w, h),
        Variant::Cascade | Variant::Legacy => maps::reduce_min(&maps::erode3(fine, w, h), w, h),
    }
}

impl Solver {
    /// Builds the level hierarchy from the finest rigidity (`[0, 1]`) and mask
    /// (already combined with the automatic mask).
    pub fn new(w: usize, h: usize, rigidity: &[f32], mask: Vec<u8>, ids: &[u32], go_tri: Vec<[f32; 3]>, tri_chart: Vec<u32>) -> Self {
        let mut levels = vec![Level::new(w, h, maps::quantise(rigidity), mask)];
        let mut r = rigidity.to_vec();
        let (mut lw, mut lh) = (w, h);
        while lw / 2 >= COARSEST && lh / 2 >= COARSEST {
            r = maps::reduce_mean(&maps::gaussian3(&r, lw, lh), lw, lh);
            let prev = levels.last().expect("at least the finest level");
            let m = coarse_mask(&prev.mask, lw, lh, Variant::default());
            let go = if levels.len() == 1 { maps::reduce_metric(&go_tri, Some(ids), lw, lh) } else { maps::reduce_metric(&prev.go, None, lw, lh) };
            lw /= 2;
            lh /= 2;
            let mut level = Level::new(lw, lh, maps::quantise(&r), m);
            level.go = go;
            level.start_x = vec![0.0; lw * lh];
            level.start_y = vec![0.0; lw * lh];
            levels.push(level);
        }
        Solver { levels, go_tri, tri_chart, last_iterations: Vec::new(), last_repair: (0, 1.0), last_level_ms: Vec::new(), last_prepare_ms: 0.0, records: Vec::new(), reference: false, variant: Variant::default(), anderson: None, anderson_across_frames: false }
    }

    /// Chooses the solver (benchmarks and tests compare them); rebuilds the
    /// coarse levels' masks, which differ between the multigrid and the cascades.
    #[doc(hidden)]
    pub fn set_variant(&mut self, variant: Variant) {
        if coarse_kind(variant) != coarse_kind(self.variant) {
            for l in 1..self.levels.len() {
                let (fine, coarse) = self.levels.split_at_mut(l);
                let (f, c) = (&fine[l - 1], &mut coarse[0]);
                c.mask = coarse_mask(&f.mask, f.w, f.h, variant);
                c.active = sweep::ActiveSpans::new(c.w, c.h, &c.rig, &c.mask);
            }
        }
        self.variant = variant;
        self.reset();
    }

    /// Multigrid only: Anderson acceleration of the finest cycles with a
    /// history of `depth` cycles (0: off); `across_frames` keeps the history
    /// between warm frames.
    #[doc(hidden)]
    pub fn set_anderson(&mut self, depth: usize, across_frames: bool) {
        self.anderson = (depth > 0).then(|| anderson::Anderson::new(depth));
        self.anderson_across_frames = across_frames;
    }

    /// Anderson steps taken accelerated and rejected (plain image kept) so far.
    #[doc(hidden)]
    pub fn anderson_counts(&self) -> Option<(usize, usize)> {
        self.anderson.as_ref().map(|a| (a.accepted, a.rejected))
    }

    pub fn variant(&self) -> Variant {
        self.variant
    }

    /// Back to the identity warp.
    pub fn reset(&mut self) {
        for lv in &mut self.levels {
            lv.dx.fill(0.0);
            lv.dy.fill(0.0);
        }
    }

    pub fn rest_metrics(&self) -> &[[f32; 3]] {
        &self.go_tri
    }

    /// Solves for the deformed surface given by per-triangle metrics `gd_tri`.
    /// Without `warm`, starts from the identity.
    pub fn solve(&mut self, ids: &[u32], gd_tri: &[[f32; 3]], warm: bool, s: &WarpSettings) {
        if !warm {
            self.reset();
        }
        if self.variant == Variant::Multigrid {
            self.solve_multigrid(ids, gd_tri, warm, s);
            return;
        }
        let legacy = self.variant == Variant::Legacy;
        let prepare = std::time::Instant::now();
        // A warm solve corrects last frame's warp for a small change of the
        // surface: the levels down to [`WARM_COARSEST`] carry that change (the
        // coarser ones would only restrict and prolong an almost unchanged
        // warp). The change has to cross features whose size in texels grows
        // with the grid, so the cut is a resolution, not a level count (three
        // levels only at 4096² let folds build up over the frames). At 1024²
        // (levels 1024, 512, 256) this gives a lower rigid stretch error than
        // running every level (0.101 against 0.115 after ten frames).
        // Grids whose finest level is below twice that size have no level to
        // spare (a 128² warm solve would run on 128² alone and barely move):
        // they run every level, which costs little at that size.
        let finest = self.levels[0].w.min(self.levels[0].h);
        let used = if warm && finest >= 2 * WARM_COARSEST {
            self.levels.iter().take_while(|lv| lv.w.min(lv.h) >= WARM_COARSEST).count().max(1)
        } else {
            self.levels.len()
        };
        // Deformed metrics and starting states of the coarse levels.
        for l in 1..used {
            let (fine, coarse) = self.levels.split_at_mut(l);
            let f = &fine[l - 1];
            let c = &mut coarse[0];
            if l == 1 {
                maps::reduce_metric_into(gd_tri, Some(ids), f.w, f.h, &mut c.gd);
            } else {
                maps::reduce_metric_into(&f.gd, None, f.w, f.h, &mut c.gd);
            }
            restrict(f, c);
        }
        // One record per triangle (deformed metric, rest lengths) for the finest level's sweeps.
        let mut records = std::mem::take(&mut self.records);
        self.go_tri.par_iter().zip(gd_tri).map(|(&o, &d)| sweep::tri_record(o, d)).collect_into_vec(&mut records);
        let avx2 = sweep::has_avx2();
        self.last_iterations = vec![0; self.levels.len()];
        self.last_level_ms = vec![0.0; self.levels.len() + 1];
        self.last_prepare_ms = prepare.elapsed().as_secs_f64() * 1e3;
        let mut finest_folded = None;
        for l in (0..used).rev() {
            let started = std::time::Instant::now();
            // Cold solves start from the identity and need the coarse levels
            // to carry the bulk of the warp: `iterations · 2^l` there. Warm
            // solves only correct last frame's warp: `iterations` on each
            // level down to [`WARM_COARSEST`] (on grids so small that these
            // include the three coarsest, those keep the cold schedule).
            let coarse = l + 3 >= self.levels.len();
            let n = if warm && !coarse {
                s.iterations as usize
            } else {
                (s.iterations as usize).saturating_mul(1 << l.min(16)).min(MAX_LEVEL_ITERATIONS.max(s.iterations as usize))
            };
            self.last_iterations[l] = n;
            let (fine, rest) = self.levels.split_at_mut(l);
            let lv = &mut rest[0];
            let reference = s.sample_warped || self.reference;
            // Old solver: neither. Warm solves: no acceleration (they start
            // next to their solution, and their frame time is the budget).
            // Levels below [`CHEBYSHEV_SIDE`]: no acceleration either.
            let steps = Steps { areas: !legacy, chebyshev: !legacy && !warm && lv.w.min(lv.h) >= CHEBYSHEV_SIDE, settle: false };
            if l == 0 {
                finest_folded = if reference {
                    drive(lv, n, steps, |lv, _| {
                        iterate_reference(lv, Indexed(ids, &self.tri_chart), &self.go_tri, gd_tri, 1, s);
                        None
                    })
                } else {
                    drive(lv, n, steps, |lv, scan| iterate(lv, ByTriangle { ids, records: &records }, 1, s, avx2, scan))
                };
            } else {
                let (go, gd) = (std::mem::take(&mut lv.go), std::mem::take(&mut lv.gd));
                if reference {
                    drive(lv, n, steps, |lv, _| {
                        iterate_reference(lv, Direct, &go, &gd, 1, s);
                        None
                    });
                } else {
                    drive(lv, n, steps, |lv, scan| iterate(lv, ByTexel { go: &go, gd: &gd }, 1, s, avx2, scan));
                }
                lv.go = go;
                lv.gd = gd;
                prolong(lv, &mut fine[l - 1]);
            }
            self.last_level_ms[l] = started.elapsed().as_secs_f64() * 1e3;
        }
        self.records = records;
        let started = std::time::Instant::now();
        // The new solver keeps every cell above [`folds::MIN_AREA`] in its
        // iterations; the repair is for cells that still fold (none in the
        // benchmark's cold solves), not for thin ones, which it would
        // flatten: relaxing them towards their neighbours folds others.
        // The finest level's last fold-prevention step already knows whether
        // a cell is folded; only the old solver, which has none, counts.
        let lv = &mut self.levels[0];
        let folded = finest_folded.unwrap_or_else(|| count_folds(&lv.dx, &lv.dy, lv.w, lv.h, 0.0) > 0);
        self.last_repair = if !legacy && !folded { (0, 1.0) } else { repair_folds(lv) };
        self.last_level_ms[self.levels.len()] = started.elapsed().as_secs_f64() * 1e3;
    }
}

/// The plain iteration of each level, for [`multigrid`].
struct LevelSteps<'a> {
    ids: &'a [u32],
    records: &'a [TriRecord],
    go_tri: &'a [[f32; 3]],
    gd_tri: &'a [[f32; 3]],
    tri_chart: &'a [u32],
    s: &'a WarpSettings,
    avx2: bool,
    reference: bool,
    /// Iterations and wall time (ms) per level, for the report.
    counts: Vec<std::cell::Cell<usize>>,
    ms: Vec<std::cell::Cell<f64>>,
}

impl multigrid::Smoother for LevelSteps<'_> {
    fn step(&self, lv: &mut Level, l: usize) {
        let started = std::time::Instant::now();
        self.step_untimed(lv, l);
        self.counts[l].set(self.counts[l].get() + 1);
        self.ms[l].set(self.ms[l].get() + started.elapsed().as_secs_f64() * 1e3);
    }
}

impl LevelSteps<'_> {
    fn step_untimed(&self, lv: &mut Level, l: usize) {
        let s = self.s;
        if l == 0 {
            if self.reference {
                iterate_reference(lv, Indexed(self.ids, self.tri_chart), self.go_tri, self.gd_tri, 1, s);
            } else {
                iterate(lv, ByTriangle { ids: self.ids, records: self.records }, 1, s, self.avx2, false);
            }
        } else {
            let (go, gd) = (std::mem::take(&mut lv.go), std::mem::take(&mut lv.gd));
            if self.reference {
                iterate_reference(lv, Direct, &go, &gd, 1, s);
            } else {
                iterate(lv, ByTexel { go: &go, gd: &gd }, 1, s, self.avx2, false);
            }
            lv.go = go;
            lv.gd = gd;
        }
    }
}

impl Solver {
    /// The [`Variant::Multigrid`] solve. Warm: `iterations` cycles from the
    /// previous frame's warp. Cold (from the identity): full multigrid, each
    /// level from the coarsest up starting from the next coarser level's
    /// solution and running `iterations + 1` cycles (a solve from scratch has
    /// the whole warp to find, a warm frame only its change).
    fn solve_multigrid(&mut self, ids: &[u32], gd_tri: &[[f32; 3]], warm: bool, s: &WarpSettings) {
        let prepare = std::time::Instant::now();
        for l in 1..self.levels.len() {
            let (fine, coarse) = self.levels.split_at_mut(l);
            let (f, c) = (&fine[l - 1], &mut coarse[0]);
            if l == 1 {
                maps::reduce_metric_into(gd_tri, Some(ids), f.w, f.h, &mut c.gd);
            } else {
                maps::reduce_metric_into(&f.gd, None, f.w, f.h, &mut c.gd);
            }
        }
        let mut records = std::mem::take(&mut self.records);
        self.go_tri.par_iter().zip(gd_tri).map(|(&o, &d)| sweep::tri_record(o, d)).collect_into_vec(&mut records);
        let levels = self.levels.len();
        self.last_prepare_ms = prepare.elapsed().as_secs_f64() * 1e3;
        let steps = LevelSteps {
            ids,
            records: &records,
            go_tri: &self.go_tri,
            gd_tri,
            tri_chart: &self.tri_chart,
            s,
            avx2: sweep::has_avx2(),
            reference: s.sample_warped || self.reference,
            counts: vec![std::cell::Cell::new(0); levels],
            ms: vec![std::cell::Cell::new(0.0); levels],
        };
        let bottom = levels - 1;
        let cycles = s.iterations as usize;
        let anderson = &mut self.anderson;
        if let Some(a) = anderson.as_mut() {
            if !warm || !self.anderson_across_frames {
                a.restart();
            }
        }
        let mut finest_cycle = |levels: &mut [Level]| {
            if let Some(a) = anderson.as_mut() {
                a.before(&levels[0]);
            }
            multigrid::cycle(levels, 0, bottom, false, &steps);
            if let Some(a) = anderson.as_mut() {
                a.after(&mut levels[0]);
            }
        };
        if warm {
            for _ in 0..cycles {
                finest_cycle(&mut self.levels);
            }
        } else {
            for l in (0..=bottom).rev() {
                if l == bottom {
                    multigrid::smooth(&mut self.levels[l], l, multigrid::COARSEST_ITERATIONS, false, &steps);
                } else {
                    let (fine, coarse) = self.levels.split_at_mut(l + 1);
                    prolong(&coarse[0], &mut fine[l]);
                    for _ in 0..cycles + 1 {
                        if l == 0 {
                            finest_cycle(&mut self.levels);
                        } else {
                            multigrid::cycle(&mut self.levels, l, bottom, false, &steps);
                        }
                    }
                }
                if l > 0 {
                    // The identity is where this level started: the next finer
                    // level receives its whole warp.
                    let lv = &mut self.levels[l];
                    multigrid::resize(&mut lv.start_x, lv.w * lv.h);
                    multigrid::resize(&mut lv.start_y, lv.w * lv.h);
                    lv.start_x.fill(0.0);
                    lv.start_y.fill(0.0);
                }
            }
        }
        self.last_iterations = steps.counts.iter().map(|c| c.get()).collect();
        self.last_level_ms = steps.ms.iter().map(|c| c.get()).collect();
        self.records = records;
        let started = std::time::Instant::now();
        let lv = &mut self.levels[0];
        self.last_repair = if count_folds(&lv.dx, &lv.dy, lv.w, lv.h, 0.0) == 0 { (0, 1.0) } else { repair_folds(lv) };
        self.last_level_ms.push(started.elapsed().as_secs_f64() * 1e3);
    }

    /// `n` plain iterations of the finest level (fold prevention included,
    /// no acceleration); returns the largest change of a node in the last.
    #[doc(hidden)]
    pub fn iterate_finest_plain(&mut self, ids: &[u32], gd_tri: &[[f32; 3]], n: usize, s: &WarpSettings) -> f32 {
        let records: Vec<TriRecord> = self.go_tri.par_iter().zip(gd_tri).map(|(&o, &d)| sweep::tri_record(o, d)).collect();
        let avx2 = sweep::has_avx2();
        let lv = &mut self.levels[0];
        if n == 0 {
            return 0.0;
        }
        let steps = Steps { areas: true, chebyshev: false, settle: true };
        drive(lv, n - 1, steps, |lv, scan| iterate(lv, ByTriangle { ids, records: &records }, 1, s, avx2, scan));
        let (bx, by) = (lv.dx.clone(), lv.dy.clone());
        drive(lv, 1, steps, |lv, scan| iterate(lv, ByTriangle { ids, records: &records }, 1, s, avx2, scan));
        lv.dx.par_iter().zip(&bx).chain(lv.dy.par_iter().zip(&by)).map(|(a, b)| (a - b).abs()).reduce(|| 0.0, f32::max)
    }

    /// The end-of-solve fold repair on its own (see [`Solver::iterate_finest_plain`]).
    #[doc(hidden)]
    pub fn repair(&mut self) -> (usize, f32) {
        repair_folds(&mut self.levels[0])
    }
}

/// Fine → coarse: 2×2 mean of displacements, halved (coarse texels are twice
/// as big), 0 where the coarse mask fixes the node; written to the coarse
/// level and to its starting state. Both channels in one pass.
fn restrict(f: &Level, c: &mut Level) {
    let (fw, cw) = (f.w, c.w);
    let rows = c.dx.par_chunks_mut(cw).zip(c.dy.par_chunks_mut(cw)).zip(c.start_x.par_chunks_mut(cw).zip(c.start_y.par_chunks_mut(cw)));
    rows.enumerate().for_each(|(y, ((cx, cy), (sx, sy)))| {
        let m = &c.mask[y * cw..(y + 1) * cw];
        let (fx0, fx1) = (&f.dx[2 * y * fw..(2 * y + 1) * fw], &f.dx[(2 * y + 1) * fw..(2 * y + 2) * fw]);
        let (fy0, fy1) = (&f.dy[2 * y * fw..(2 * y + 1) * fw], &f.dy[(2 * y + 1) * fw..(2 * y + 2) * fw]);
        for x in 0..cw {
            let keep = m[x] != 0;
            let vx = 0.125 * (fx0[2 * x] + fx0[2 * x + 1] + fx1[2 * x] + fx1[2 * x + 1]);
            let vy = 0.125 * (fy0[2 * x] + fy0[2 * x + 1] + fy1[2 * x] + fy1[2 * x + 1]);
            (cx[x], cy[x]) = (if keep { vx } else { 0.0 }, if keep { vy } else { 0.0 });
            (sx[x], sy[x]) = (cx[x], cy[x]);
        }
    });
}

/// Adds the change of the coarse level since its start, bilinearly
/// interpolated and doubled, to the finer level (times the finer mask).
///
/// Two passes, both over contiguous rows: each coarse row's change is first
/// interpolated along x to the fine width (half as many values as fine
/// texels, each used by four fine rows), then each fine row blends its two
/// coarse rows along y. The arithmetic is the bilinear formula's, in its order.
fn prolong(c: &Level, f: &mut Level) {
    let (cw, ch, fw) = (c.w, c.h, f.w);
    let parallel = fw * f.h >= PARALLEL_TEXELS;
    // The coarse change, doubled (fine texels are half as big), along x.
    let (mut hx, mut hy) = (std::mem::take(&mut f.prolong_dx), std::mem::take(&mut f.prolong_dy));
    hx.resize(ch * fw, 0.0);
    hy.resize(ch * fw, 0.0);
    // Fine column x samples coarse column u = (x + 0.5)/2 − 0.5 (clamped at
    // 0): column 2k + 1 blends coarse k and k + 1 by ¼, column 2k + 2 by ¾,
    // column 0 takes coarse 0, and the last column (2·cw − 1) coarse cw − 1
    // twice. These weights are exact, so this is `a·(1 − t) + b·t` as written.
    debug_assert!(fw == 2 * cw && cw >= 2, "prolong: fine width {fw} is not twice the coarse width {cw}");
    let along_x = |(y, (ox, oy)): (usize, (&mut [f32], &mut [f32]))| {
        let r = y * cw..(y + 1) * cw;
        for (o, (c, s)) in [(ox, (&c.dx[r.clone()], &c.start_x[r.clone()])), (oy, (&c.dy[r.clone()], &c.start_y[r.clone()]))] {
            let d = |k: usize| 2.0 * (c[k] - s[k]);
            o[0] = d(0) * 1.0 + d(1) * 0.0;
            for k in 0..cw - 1 {
                let (a, b) = (d(k), d(k + 1));
                o[2 * k + 1] = a * 0.75 + b * 0.25;
                o[2 * k + 2] = a * 0.25 + b * 0.75;
            }
            let a = d(cw - 1);
            o[fw - 1] = a * 0.75 + a * 0.25;
        }
    };
    if parallel {
        hx.par_chunks_mut(fw).zip(hy.par_chunks_mut(fw)).enumerate().for_each(along_x);
    } else {
        hx.chunks_mut(fw).zip(hy.chunks_mut(fw)).enumerate().for_each(along_x);
    }
    let mask = &f.mask;
    let along_y = |(y, (rx, ry)): (usize, (&mut [f32], &mut [f32]))| {
        let fm = &mask[y * fw..(y + 1) * fw];
        let v = ((y as f32 + 0.5) * 0.5 - 0.5).max(0.0);
        let y0 = (v as usize).min(ch - 1);
        let y1 = (y0 + 1).min(ch - 1);
        let ty = v - y0 as f32;
        // The coarse rows below and above, interpolated along x: x and y channel.
        let (below_x, above_x) = (&hx[y0 * fw..(y0 + 1) * fw], &hx[y1 * fw..(y1 + 1) * fw]);
        let (below_y, above_y) = (&hy[y0 * fw..(y0 + 1) * fw], &hy[y1 * fw..(y1 + 1) * fw]);
        let (rx, ry) = (&mut rx[..fw], &mut ry[..fw]);
        for ((((((ox, oy), &m), &a), &b), &c), &d) in rx.iter_mut().zip(ry.iter_mut()).zip(fm).zip(below_x).zip(above_x).zip(below_y).zip(above_y) {
            let mf = m as f32 * (1.0 / 255.0);
            let ix = a * (1.0 - ty) + b * ty;
            let iy = c * (1.0 - ty) + d * ty;
            // Fixed texels keep their value exactly (not `+ 0·ix`, which
            // would turn −0 into +0).
            *ox = if m == 0 { *ox } else { *ox + ix * mf };
            *oy = if m == 0 { *oy } else { *oy + iy * mf };
        }
    };
    if parallel {
        f.dx.par_chunks_mut(fw).zip(f.dy.par_chunks_mut(fw)).enumerate().for_each(along_y);
    } else {
        f.dx.chunks_mut(fw).zip(f.dy.chunks_mut(fw)).enumerate().for_each(along_y);
    }
    (f.prolong_dx, f.prolong_dy) = (hx, hy);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Restriction and prolongation, rewritten as row passes, still compute
    /// the formulas as first written, bit for bit (a coarse level of 8 × 8
    /// under a 16 × 16 one, random displacements, a partial mask).
    #[test]
    fn row_pass_restriction_and_prolongation_equal_the_formulas() {
        let (fw, cw) = (16usize, 8usize);
        let mut next = 0x9e37_79b9u32;
        let mut rand = move || {
            next ^= next << 13;
            next ^= next >> 17;
            next ^= next << 5;
            (next % 2001) as f32 / 1000.0 - 1.0
        };
        let fmask: Vec<u8> = (0..fw * fw).map(|i| [0, 128, 255, 255][i % 4]).collect();
        let cmask: Vec<u8> = (0..cw * cw).map(|i| if i % 5 == 0 { 0 } else { 255 }).collect();
        let mut f = Level::new(fw, fw, vec![0; fw * fw], fmask.clone());
        let mut c = Level::new(cw, cw, vec![0; cw * cw], cmask.clone());
        (c.start_x, c.start_y) = (vec![0.0; cw * cw], vec![0.0; cw * cw]);
        f.dx.iter_mut().chain(f.dy.iter_mut()).for_each(|v| *v = rand());
        restrict(&f, &mut c);
        for y in 0..cw {
            for x in 0..cw {
                let i = 2 * y * fw + 2 * x;
                for (fv, cv, sv) in [(&f.dx, &c.dx, &c.start_x), (&f.dy, &c.dy, &c.start_y)] {
                    let v = 0.125 * (fv[i] + fv[i + 1] + fv[i + fw] + fv[i + fw + 1]);
                    let want = if cmask[y * cw + x] == 0 { 0.0 } else { v };
                    assert_eq!((cv[y * cw + x].to_bits(), sv[y * cw + x].to_bits()), (want.to_bits(), want.to_bits()));
                }
            }
        }
        c.dx.iter_mut().chain(c.dy.iter_mut()).for_each(|v| *v += rand());
        let (before_x, before_y) = (f.dx.clone(), f.dy.clone());
        prolong(&c, &mut f);
        for y in 0..fw {
            for x in 0..fw {
                let (u, v) = (((x as f32 + 0.5) * 0.5 - 0.5).max(0.0), ((y as f32 + 0.5) * 0.5 - 0.5).max(0.0));
                let (x0, y0) = ((u as usize).min(cw - 1), (v as usize).min(cw - 1));
                let (x1, y1, tx, ty) = ((x0 + 1).min(cw - 1), (y0 + 1).min(cw - 1), u - x0 as f32, v - y0 as f32);
                for (cv, sv, before, after) in [(&c.dx, &c.start_x, &before_x, &f.dx), (&c.dy, &c.start_y, &before_y, &f.dy)] {
                    let d = |xx: usize, yy: usize| 2.0 * (cv[yy * cw + xx] - sv[yy * cw + xx]);
                    let i = (d(x0, y0) * (1.0 - tx) + d(x1, y0) * tx) * (1.0 - ty) + (d(x0, y1) * (1.0 - tx) + d(x1, y1) * tx) * ty;
                    let m = fmask[y * fw + x];
                    let want = if m == 0 { before[y * fw + x] } else { before[y * fw + x] + i * (m as f32 * (1.0 / 255.0)) };
                    assert_eq!(after[y * fw + x].to_bits(), want.to_bits(), "texel ({x}, {y})");
                }
            }
        }
    }

    /// A fully rigid, fully movable grid (but its fixed edge ring) over a
    /// surface uniformly stretched 1.5× along v: the interior spacing along v
    /// must become 1/1.5 everywhere, with no odd-even pattern.
    #[test]
    fn uniform_stretch_gives_uniform_spacing() {
        let n = 32;
        let mut mask = vec![255u8; n * n];
        for j in 0..n {
            for i in 0..n {
                if i < 1 || j < 1 || i >= n - 1 || j >= n - 1 {
                    mask[j * n + i] = 0;
                }
            }
        }
        // Rigid in the middle only, so that elastic margins can absorb.
        let mut rig = vec![0.0f32; n * n];
        for j in 10..22 {
            for i in 10..22 {
                rig[j * n + i] = 1.0;
            }
        }
        let ids = vec![0u32; n * n];
        let go = vec![[1.0, 0.0, 1.0], [0.0; 3]];
        let gd = vec![[1.0, 0.0, 2.25], [0.0; 3]];
        let mut s = Solver::new(n, n, &rig, mask, &ids, go, vec![0, u32::MAX]);
        let set = WarpSettings { iterations: 200, orientation: 0.0, smoothing: 0.0, ..Default::default() };
        s.solve(&ids, &gd, false, &set);
        let lv = &s.levels[0];
        let steps: Vec<f32> = (10..21).map(|j| 1.0 + lv.dy[(j + 1) * n + 16] - lv.dy[j * n + 16]).collect();
        eprintln!("{steps:?}");
        for st in &steps {
            assert!((st - 1.0 / 1.5).abs() < 0.05, "{steps:?}");
        }
        let spread = steps.iter().fold(0.0f32, |a, &b| a.max(b)) - steps.iter().fold(9.0f32, |a, &b| a.min(b));
        assert!(spread < 0.06, "odd-even pattern: {steps:?}");
    }
}
