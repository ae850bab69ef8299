//! The hot loops of one solver iteration: the constraint projection sweeps
//! and the regularisation, written for throughput.
//!
//! The arithmetic is exactly that of the reference projection in
//! [`super::solver`] (same operations in the same order, so the results are
//! bitwise equal to it, which a test checks), but organised so that the
//! compiler can vectorise it:
//! - constraints of one set in one row are independent (that is what makes
//!   the set a set), so they are processed in runs of [`LANES`] lanes: node
//!   values and metrics are gathered into small arrays (what rigidity and mask
//!   contribute is precomputed per constraint and loaded as vectors), the projection is
//!   evaluated branch-free over the lanes (skipped constraints get a zero
//!   correction, not a branch), and the corrections are scattered back;
//! - only constraints that can be active are visited: rigidity and mask are
//!   fixed per bind, so [`ActiveSpans`] lists, per row and set, the spans of
//!   constraints with a rigid end and a movable end, and lanes are packed
//!   across spans (an elastic region costs nothing);
//! - the rest texel whose metric a constraint uses is an integer offset from
//!   its first node (the reference finds it from float midpoints; the two agree
//!   for the unwarped midpoint, the only one this path serves);
//! - on the finest level the metrics come from one 32-byte record per
//!   triangle (deformed `G` and the rest squared length in each of the four
//!   directions), built once per frame, instead of two 12-byte tables;
//! - the regularisation selects instead of branching on the mask.
//!
//! Where the CPU has AVX2, the same code is compiled a second time with it
//! enabled (eight lanes per instruction instead of four); no FMA, so both
//! versions round identically.

use super::RELAXATION;

/// Whether the CPU has AVX2 (the kernels here and in [`super::invert`] have an AVX2 build).
pub(crate) fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Constraints per packed run (gathered across spans).
pub const LANES: usize = 16;
/// Constraints per contiguous run: a span's constraints in blocks of this
/// many are loaded and stored as vectors; only its remainder is packed.
pub const CONTIG: usize = 8;

/// The four constraint directions: rest segment `(ex, ey)` from node a to node b.
pub const HORIZONTAL: usize = 0;
pub const VERTICAL: usize = 1;
pub const DIAGONAL: usize = 2;
pub const ANTIDIAGONAL: usize = 3;

#[inline(always)]
const fn rest_segment(dir: usize) -> (f32, f32) {
    match dir {
        HORIZONTAL => (1.0, 0.0),
        VERTICAL => (0.0, 1.0),
        DIAGONAL => (1.0, 1.0),
        _ => (-1.0, 1.0),
    }
}

/// `eᵀ G e` for a rest segment, written exactly as the reference's
/// `o[0]·ex·ex + 2·o[1]·ex·ey + o[2]·ey·ey` evaluates for these unit entries.
#[inline(always)]
pub fn rest_length2(o: [f32; 3], dir: usize) -> f32 {
    let (ex, ey) = rest_segment(dir);
    o[0] * ex * ex + 2.0 * o[1] * ex * ey + o[2] * ey * ey
}

/// Per-triangle record of the finest level: deformed `G` and the rest squared
/// lengths of the four directions.
pub type TriRecord = [f32; 8];

pub fn tri_record(go: [f32; 3], gd: [f32; 3]) -> TriRecord {
    [gd[0], gd[1], gd[2], rest_length2(go, 0), rest_length2(go, 1), rest_length2(go, 2), rest_length2(go, 3), 0.0]
}

/// Where a level finds, for the rest texel of a constraint, the deformed
/// metric and the rest squared length along the constraint's direction.
pub trait Metric: Sync {
    fn fetch(&self, texel: usize, dir: usize) -> [f32; 4];
}

impl<T: Metric> Metric for &T {
    #[inline(always)]
    fn fetch(&self, texel: usize, dir: usize) -> [f32; 4] {
        (**self).fetch(texel, dir)
    }
}

/// Finest level: per-texel triangle index into per-triangle records.
pub struct ByTriangle<'a> {
    pub ids: &'a [u32],
    pub records: &'a [TriRecord],
}

impl Metric for ByTriangle<'_> {
    #[inline(always)]
    fn fetch(&self, texel: usize, dir: usize) -> [f32; 4] {
        let r = &self.records[self.ids[texel] as usize];
        [r[0], r[1], r[2], r[3 + dir]]
    }
}

/// Coarse levels: per-texel averaged metrics.
pub struct ByTexel<'a> {
    pub go: &'a [[f32; 3]],
    pub gd: &'a [[f32; 3]],
}

impl Metric for ByTexel<'_> {
    #[inline(always)]
    fn fetch(&self, texel: usize, dir: usize) -> [f32; 4] {
        let g = self.gd[texel];
        [g[0], g[1], g[2], rest_length2(self.go[texel], dir)]
    }
}

/// What one sweep reads besides the displacements.
pub struct Sweep<'a, M: Metric> {
    pub w: usize,
    pub active: &'a ActiveSpans,
    pub metric: M,
    pub orientation: f32,
    /// Whether to use the AVX2 build of the kernels.
    pub avx2: bool,
}

/// One set's constraints in a slice of rows (the set's direction is the
/// kernels' `DIR` parameter, so that its rest segment is a constant): constraint `k` joins local nodes
/// `a0 + k·stride` and `b0 + k·stride`; its rest texel is
/// `rest0 + k·stride`. Only the constraints in `spans` can be active; their
/// coefficients follow one another in `coef` from index `coef0`.
#[derive(Clone, Copy)]
struct Run<'s> {
    a0: usize,
    b0: usize,
    stride: usize,
    rest0: usize,
    spans: &'s [Span],
    coef0: usize,
}

/// A half-open range of constraint indices of one set in one row (pair).
pub type Span = (u32, u32);

/// End of the whole [`CONTIG`] blocks of span `s..e`.
#[inline(always)]
fn blocks_end(s: u32, e: u32) -> usize {
    s as usize + (e - s) as usize / CONTIG * CONTIG
}

/// The sets of a row `j`: the even and odd horizontal sets of row `j`, and the
/// vertical, diagonal and antidiagonal sets between rows `j` and `j + 1`.
pub const SETS: usize = 5;

/// Per level and per bind: which constraints can ever be projected. A
/// constraint is skipped when both ends are fully elastic or both are fixed by
/// the mask, and rigidity and mask only change when the warp is rebuilt, so
/// the sweeps visit only these spans (in the benchmark scene, a third of the
/// constraints).
#[derive(Debug, Clone, Default)]
pub struct ActiveSpans {
    spans: Vec<Span>,
    /// `first[j·SETS + set]` .. `first[j·SETS + set + 1]` index `spans`.
    first: Vec<u32>,
    /// Per constraint of the spans, in span order: what the projection needs
    /// from rigidity and mask, computed here once instead of per lane and
    /// iteration (four byte gathers and two divisions). `coef_first[j·SETS +
    /// set]` is the first entry of row `j`'s set.
    coef: Coefficients,
    coef_first: Vec<u32>,
}

/// Structure of arrays, so that a run of lanes loads each as one vector.
#[derive(Debug, Clone, Default)]
struct Coefficients {
    /// Share of the correction taken by node a, b: `ma / (ma + mb)`, `mb / (ma + mb)`.
    fa: Vec<f32>,
    fb: Vec<f32>,
    /// Weight of the constraint, `max(rig) / 255`; 0 when it is inactive
    /// (both ends elastic or both fixed: whole-row spans include such).
    kk: Vec<f32>,
}

impl Coefficients {
    /// Exactly the reference's arithmetic (`solver::reference::Ctx::project`), so that the
    /// sweeps stay bitwise equal to it.
    fn push(&mut self, ra: u8, rb: u8, mka: u8, mkb: u8) {
        let ma = mka as f32 * (1.0 - 0.9 / 255.0 * ra as f32);
        let mb = mkb as f32 * (1.0 - 0.9 / 255.0 * rb as f32);
        let ms = ma + mb;
        let k8 = ra.max(rb);
        let live = k8 > 0 && ms > 0.0;
        let mss = if ms > 0.0 { ms } else { 1.0 };
        self.fa.push(ma / mss);
        self.fb.push(mb / mss);
        self.kk.push(if live { k8 as f32 * (1.0 / 255.0) } else { 0.0 });
    }
}

impl ActiveSpans {
    pub fn new(w: usize, h: usize, rig: &[u8], mask: &[u8]) -> Self {
        let live = |a: usize, b: usize| (rig[a] > 0 || rig[b] > 0) && (mask[a] > 0 || mask[b] > 0);
        let mut spans = Vec::new();
        let mut first = Vec::with_capacity(h * SETS + 1);
        let mut coef = Coefficients::default();
        let mut coef_first = Vec::with_capacity(h * SETS + 1);
        for j in 0..h {
            let g0 = j * w;
            for set in 0..SETS {
                first.push(spans.len() as u32);
                coef_first.push(coef.kk.len() as u32);
                let (count, a, b, stride): (usize, usize, usize, usize) = match set {
                    0 | 1 => ((w - set) / 2, g0 + set, g0 + set + 1, 2),
                    _ if j + 1 == h => (0, 0, 0, 1),
                    2 => (w, g0, g0 + w, 1),
                    3 => (w - 1, g0, g0 + w + 1, 1),
                    _ => (w - 1, g0 + 1, g0 + w, 1),
                };
                let start = spans.len();
                let mut k = 0;
                while k < count {
                    if !live(a + k * stride, b + k * stride) {
                        k += 1;
                        continue;
                    }
                    let s = k;
                    while k < count && live(a + k * stride, b + k * stride) {
                        k += 1;
                    }
                    spans.push((s as u32, k as u32));
                }
                // Lanes are packed across spans, so a span costs a few
                // instructions and a skipped constraint saves a whole lane:
                // sweep the whole row only when its gaps are on average
                // shorter than one constraint (scattered rigidity). (A rule of
                // one span per 16 constraints swept whole rows of the coarse
                // levels here, 24 scales per row.)
                let live_count: usize = spans[start..].iter().map(|&(s, e)| (e - s) as usize).sum();
                if count - live_count < spans.len() - start {
                    spans.truncate(start);
                    spans.push((0, count as u32));
                }
                // In the sweep's order: every span's whole blocks, then the remainders.
                let mut push = |k: usize| coef.push(rig[a + k * stride], rig[b + k * stride], mask[a + k * stride], mask[b + k * stride]);
                for &(s, e) in &spans[start..] {
                    (s as usize..blocks_end(s, e)).for_each(&mut push);
                }
                for &(s, e) in &spans[start..] {
                    (blocks_end(s, e)..e as usize).for_each(&mut push);
                }
            }
        }
        first.push(spans.len() as u32);
        coef_first.push(coef.kk.len() as u32);
        spans.shrink_to_fit();
        ActiveSpans { spans, first, coef, coef_first }
    }

    /// Row `j`'s spans of `set` and the index of their first coefficient.
    #[inline]
    fn of(&self, j: usize, set: usize) -> (&[Span], usize) {
        let i = j * SETS + set;
        (&self.spans[self.first[i] as usize..self.first[i + 1] as usize], self.coef_first[i] as usize)
    }

    /// Whether row `j`'s sets (`between`: only the three between rows `j` and `j + 1`) have any work.
    #[inline]
    pub fn any(&self, j: usize, between: bool) -> bool {
        let i = j * SETS + if between { 2 } else { 0 };
        self.first[i] != self.first[j * SETS + SETS]
    }
}

impl<M: Metric> Sweep<'_, M> {
    /// Phase A on rows `j` and (if `rows == 2`) `j + 1`, held in `dx`, `dy`:
    /// the even then odd horizontal sets of each row, then the sets between them.
    pub fn phase_a(&self, j: usize, rows: usize, dx: &mut [f32], dy: &mut [f32]) {
        let w = self.w;
        let g0 = j * w;
        for r in 0..rows {
            for parity in 0..2 {
                let a0 = r * w + parity;
                let (spans, coef0) = self.active.of(j + r, parity);
                self.run::<HORIZONTAL>(Run { a0, b0: a0 + 1, stride: 2, rest0: g0 + a0 + 1, spans, coef0 }, dx, dy);
            }
        }
        if rows == 2 {
            self.between(j, dx, dy);
        }
    }

    /// The vertical and both diagonal sets between rows `j` and `j + 1`.
    pub fn between(&self, j: usize, dx: &mut [f32], dy: &mut [f32]) {
        let w = self.w;
        let g0 = j * w;
        let a = self.active;
        let ((v, cv), (d, cd), (e, ce)) = (a.of(j, 2), a.of(j, 3), a.of(j, 4));
        self.run::<VERTICAL>(Run { a0: 0, b0: w, stride: 1, rest0: g0 + w, spans: v, coef0: cv }, dx, dy);
        self.run::<DIAGONAL>(Run { a0: 0, b0: w + 1, stride: 1, rest0: g0 + w + 1, spans: d, coef0: cd }, dx, dy);
        self.run::<ANTIDIAGONAL>(Run { a0: 1, b0: w, stride: 1, rest0: g0 + w + 1, spans: e, coef0: ce }, dx, dy);
    }

    #[inline]
    fn run<const DIR: usize>(&self, run: Run<'_>, dx: &mut [f32], dy: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is only set when the CPU reports AVX2.
            unsafe { self.run_avx2::<DIR>(run, dx, dy) };
            return;
        }
        self.run_generic::<DIR>(run, dx, dy);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn run_avx2<const DIR: usize>(&self, run: Run<'_>, dx: &mut [f32], dy: &mut [f32]) {
        self.run_body::<DIR>(run, dx, dy);
    }

    fn run_generic<const DIR: usize>(&self, run: Run<'_>, dx: &mut [f32], dy: &mut [f32]) {
        self.run_body::<DIR>(run, dx, dy);
    }

    #[inline(always)]
    fn run_body<const DIR: usize>(&self, run: Run<'_>, dx: &mut [f32], dy: &mut [f32]) {
        // Constraints of one set are independent, so they may be taken in any
        // order: first the whole blocks of every span, then the remainders
        // packed across spans (the order of the coefficients, see `ActiveSpans::new`).
        let mut ci = run.coef0;
        for &(s, e) in run.spans {
            let mut k = s as usize;
            while k < blocks_end(s, e) {
                self.block::<DIR>(&run, k, ci, dx, dy);
                ci += CONTIG;
                k += CONTIG;
            }
        }
        let mut idx = [0usize; LANES];
        let mut n = 0;
        for &(s, e) in run.spans {
            for k in blocks_end(s, e)..e as usize {
                idx[n] = k * run.stride;
                n += 1;
                if n == LANES {
                    self.batch::<DIR>(&run, &idx, n, ci, dx, dy);
                    ci += n;
                    n = 0;
                }
            }
        }
        if n > 0 {
            self.batch::<DIR>(&run, &idx, n, ci, dx, dy);
        }
    }

    /// Projects the [`CONTIG`] constraints `k0..k0 + CONTIG` of one span, whose
    /// coefficients start at `ci`: node values are loaded and stored as
    /// vectors (horizontal sets: a and b interleave, `b = a + 1`; the other
    /// sets: a and b lie in different rows), only the metric is gathered.
    #[inline(always)]
    fn block<const DIR: usize>(&self, run: &Run<'_>, k0: usize, ci: usize, dx: &mut [f32], dy: &mut [f32]) {
        const C: usize = CONTIG;
        let Run { a0, b0, stride, rest0, .. } = *run;
        let dir = DIR;
        let (ex, ey) = rest_segment(dir);
        let el = (ex * ex + ey * ey).sqrt();
        let coef = &self.active.coef;
        let vec = |v: &[f32], at: usize| -> [f32; C] { v[at..at + C].try_into().expect("block") };
        let (fa, fb, kk) = (vec(&coef.fa, ci), vec(&coef.fb, ci), vec(&coef.kk, ci));
        let (la0, lb0) = (a0 + k0 * stride, b0 + k0 * stride);
        let (mut pax, mut pay, mut pbx, mut pby) = ([0.0f32; C], [0.0f32; C], [0.0f32; C], [0.0f32; C]);
        if stride == 2 {
            let (sx, sy): (&[f32; 2 * C], &[f32; 2 * C]) = (dx[la0..la0 + 2 * C].try_into().expect("block"), dy[la0..la0 + 2 * C].try_into().expect("block"));
            for l in 0..C {
                (pax[l], pbx[l], pay[l], pby[l]) = (sx[2 * l], sx[2 * l + 1], sy[2 * l], sy[2 * l + 1]);
            }
        } else {
            (pax, pay, pbx, pby) = (vec(dx, la0), vec(dy, la0), vec(dx, lb0), vec(dy, lb0));
        }
        let (mut mg0, mut mg1, mut mg2, mut ml0) = ([0.0f32; C], [0.0f32; C], [0.0f32; C], [0.0f32; C]);
        for l in 0..C {
            [mg0[l], mg1[l], mg2[l], ml0[l]] = self.metric.fetch(rest0 + (k0 + l) * stride, dir);
        }
        let (mut cax, mut cay, mut cbx, mut cby) = ([0.0f32; C], [0.0f32; C], [0.0f32; C], [0.0f32; C]);
        let lanes = Lanes { fa: &fa, fb: &fb, kk: &kk, pax: &pax, pay: &pay, pbx: &pbx, pby: &pby, g0: &mg0, g1: &mg1, g2: &mg2, l02: &ml0 };
        if self.orientation > 0.0 {
            project_lanes::<true, C>(&lanes, ex, ey, el, self.orientation, [&mut cax, &mut cay, &mut cbx, &mut cby]);
        } else {
            project_lanes::<false, C>(&lanes, ex, ey, el, 0.0, [&mut cax, &mut cay, &mut cbx, &mut cby]);
        }
        if stride == 2 {
            let (sx, sy): (&mut [f32; 2 * C], &mut [f32; 2 * C]) = ((&mut dx[la0..la0 + 2 * C]).try_into().expect("block"), (&mut dy[la0..la0 + 2 * C]).try_into().expect("block"));
            for l in 0..C {
                sx[2 * l] = pax[l] - cax[l];
                sx[2 * l + 1] = pbx[l] + cbx[l];
                sy[2 * l] = pay[l] - cay[l];
                sy[2 * l + 1] = pby[l] + cby[l];
            }
        } else {
            for (o, (p, c)) in dx[la0..la0 + C].iter_mut().zip(pax.iter().zip(&cax)) {
                *o = p - c;
            }
            for (o, (p, c)) in dy[la0..la0 + C].iter_mut().zip(pay.iter().zip(&cay)) {
                *o = p - c;
            }
            for (o, (p, c)) in dx[lb0..lb0 + C].iter_mut().zip(pbx.iter().zip(&cbx)) {
                *o = p + c;
            }
            for (o, (p, c)) in dy[lb0..lb0 + C].iter_mut().zip(pby.iter().zip(&cby)) {
                *o = p + c;
            }
        }
    }

    /// Projects the `n` constraints at offsets `idx` (constraint index · stride)
    /// whose coefficients start at `ci`.
    #[inline(always)]
    fn batch<const DIR: usize>(&self, run: &Run<'_>, idx: &[usize; LANES], n: usize, ci: usize, dx: &mut [f32], dy: &mut [f32]) {
        let Run { a0, b0, rest0, .. } = *run;
        let dir = DIR;
        let (ex, ey) = rest_segment(dir);
        let el = (ex * ex + ey * ey).sqrt();
        // Unused lanes keep zero coefficients: inactive, no correction.
        let mut fa = [0.0f32; LANES];
        let mut fb = [0.0f32; LANES];
        let mut kk = [0.0f32; LANES];
        let coef = &self.active.coef;
        fa[..n].copy_from_slice(&coef.fa[ci..ci + n]);
        fb[..n].copy_from_slice(&coef.fb[ci..ci + n]);
        kk[..n].copy_from_slice(&coef.kk[ci..ci + n]);
        let mut pax = [0.0f32; LANES];
        let mut pay = [0.0f32; LANES];
        let mut pbx = [0.0f32; LANES];
        let mut pby = [0.0f32; LANES];
        let mut mg0 = [1.0f32; LANES];
        let mut mg1 = [0.0f32; LANES];
        let mut mg2 = [1.0f32; LANES];
        let mut ml0 = [1.0f32; LANES];
        for l in 0..n {
            let c = idx[l];
            let (la, lb) = (a0 + c, b0 + c);
            pax[l] = dx[la];
            pay[l] = dy[la];
            pbx[l] = dx[lb];
            pby[l] = dy[lb];
            [mg0[l], mg1[l], mg2[l], ml0[l]] = self.metric.fetch(rest0 + c, dir);
        }
        let mut cax = [0.0f32; LANES];
        let mut cay = [0.0f32; LANES];
        let mut cbx = [0.0f32; LANES];
        let mut cby = [0.0f32; LANES];
        let lanes = Lanes { fa: &fa, fb: &fb, kk: &kk, pax: &pax, pay: &pay, pbx: &pbx, pby: &pby, g0: &mg0, g1: &mg1, g2: &mg2, l02: &ml0 };
        if self.orientation > 0.0 {
            project_lanes::<true, LANES>(&lanes, ex, ey, el, self.orientation, [&mut cax, &mut cay, &mut cbx, &mut cby]);
        } else {
            project_lanes::<false, LANES>(&lanes, ex, ey, el, 0.0, [&mut cax, &mut cay, &mut cbx, &mut cby]);
        }
        for l in 0..n {
            let c = idx[l];
            let (la, lb) = (a0 + c, b0 + c);
            dx[la] = pax[l] - cax[l];
            dy[la] = pay[l] - cay[l];
            dx[lb] = pbx[l] + cbx[l];
            dy[lb] = pby[l] + cby[l];
        }
    }
}

/// Inputs of [`project_lanes`], one entry per lane.
struct Lanes<'a, const N: usize> {
    fa: &'a [f32; N],
    fb: &'a [f32; N],
    kk: &'a [f32; N],
    pax: &'a [f32; N],
    pay: &'a [f32; N],
    pbx: &'a [f32; N],
    pby: &'a [f32; N],
    g0: &'a [f32; N],
    g1: &'a [f32; N],
    g2: &'a [f32; N],
    l02: &'a [f32; N],
}

/// The reference projection (`solver::reference::Ctx::project`), branch-free over
/// `N` independent constraints; writes the corrections of node a
/// (subtracted) and node b (added).
#[inline(always)]
fn project_lanes<const ORIENT: bool, const N: usize>(i: &Lanes<'_, N>, ex: f32, ey: f32, el: f32, orientation: f32, out: [&mut [f32; N]; 4]) {
    let [cax, cay, cbx, cby] = out;
    for l in 0..N {
        let kk = i.kk[l];
        let vx = ex + i.pbx[l] - i.pax[l];
        let vy = ey + i.pby[l] - i.pay[l];
        let ld2 = i.g0[l] * vx * vx + 2.0 * i.g1[l] * vx * vy + i.g2[l] * vy * vy;
        let l02 = i.l02[l];
        let active = (kk > 0.0) & (l02 > 0.0) & (ld2 > l02 * 1e-6);
        let l02s = if active { l02 } else { 1.0 };
        let ld2s = if active { ld2 } else { 1.0 };
        let ratio = (l02s / ld2s).sqrt().max(0.25).min(4.0);
        let s = 1.0 + RELAXATION * kk * (ratio - 1.0);
        let mut tx = vx * s;
        let mut ty = vy * s;
        if ORIENT {
            let o = orientation * kk;
            let t2 = tx * tx + ty * ty;
            let len = t2.sqrt();
            let (ux, uy) = (tx * (1.0 - o) + ex / el * (o * len), ty * (1.0 - o) + ey / el * (o * len));
            let u2 = ux * ux + uy * uy;
            let turn = (len > 1e-12) & (u2 > 1e-24 * t2);
            let f = (t2 / if turn { u2 } else { 1.0 }).sqrt();
            tx = if turn { ux * f } else { tx };
            ty = if turn { uy * f } else { ty };
        }
        let cx = if active { tx - vx } else { 0.0 };
        let cy = if active { ty - vy } else { 0.0 };
        cax[l] = cx * i.fa[l];
        cay[l] = cy * i.fa[l];
        cbx[l] = cx * i.fb[l];
        cby[l] = cy * i.fb[l];
    }
}

/// Regularisation of one row `y` (seed eqs. 4–5 plus the 8-neighbourhood box
/// clamp) from `dx`, `dy` into `ox`, `oy`; the reference is
/// `solver::reference::regularise_reference`.
#[allow(clippy::too_many_arguments)]
pub fn regularise_row(dx: &[f32], dy: &[f32], rig: &[u8], mask: &[u8], w: usize, h: usize, y: usize, smoothing: f32, ox: &mut [f32], oy: &mut [f32], avx2: bool) {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: `avx2` is only set when the CPU reports AVX2.
        unsafe { regularise_row_avx2(dx, dy, rig, mask, w, h, y, smoothing, ox, oy) };
        return;
    }
    let _ = avx2;
    regularise_row_body(dx, dy, rig, mask, w, h, y, smoothing, ox, oy);
}

/// [`regularise_row_body`] written with AVX2 intrinsics, eight texels per
/// step: the compiler's vectorisation of the portable body keeps its 3×3
/// neighbourhoods of both channels in memory (about 2.5 times slower). Same
/// operations in the same order, so the results are bitwise equal.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn regularise_row_avx2(dx: &[f32], dy: &[f32], rig: &[u8], mask: &[u8], w: usize, h: usize, y: usize, smoothing: f32, ox: &mut [f32], oy: &mut [f32]) {
    use std::arch::x86_64::*;
    let row = y * w;
    if copy_fixed(dx, dy, mask, w, h, y, ox, oy) {
        return;
    }
    let n = w - 2;
    let full = n / 8 * 8;
    // Every load below reads columns 0..w of rows y − 1, y, y + 1 and every
    // store writes columns 1..w − 1 of the output row.
    assert!((y + 2) * w <= dx.len() && (y + 2) * w <= dy.len() && row + w <= rig.len() && row + w <= mask.len() && ox.len() == w && oy.len() == w);
    let (up, dn) = (row - w, row + w);
    let (one, neg_one, two, four) = (_mm256_set1_ps(1.0), _mm256_set1_ps(-1.0), _mm256_set1_ps(2.0), _mm256_set1_ps(4.0));
    let (sixteenth, inv255, s) = (_mm256_set1_ps(1.0 / 16.0), _mm256_set1_ps(1.0 / 255.0), _mm256_set1_ps(smoothing));
    let mut x0 = 0;
    while x0 < full {
        // Lane l is the texel of column 1 + x0 + l; `at(v, r, k)` its
        // neighbour in column offset k − 1 of the row starting at r.
        // SAFETY: r + x0 + k + 8 ≤ r + n + 2 = r + w, within the rows asserted above.
        let at = |v: &[f32], r: usize, k: usize| unsafe { _mm256_loadu_ps(v.as_ptr().add(r + x0 + k)) };
        // SAFETY: columns 1 + x0 .. 1 + x0 + 8 of row `row`, within the asserted length.
        let bytes = |v: &[u8]| unsafe { _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(v.as_ptr().add(row + 1 + x0) as *const __m128i))) };
        let m = bytes(mask);
        let r = _mm256_mul_ps(bytes(rig), inv255);
        let b = _mm256_mul_ps(_mm256_mul_ps(m, inv255), _mm256_add_ps(_mm256_sub_ps(one, r), _mm256_mul_ps(r, s)));
        let fixed = _mm256_cmp_ps::<_CMP_EQ_OQ>(m, _mm256_setzero_ps());
        // `gx` of `regularise_one`, summed in its order.
        let smooth = |ul, uc, ur, l, c, r_, dl, dc, dr| {
            let corners = _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(ul, ur), dl), dr);
            let edges = _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(uc, dc), l), r_);
            _mm256_mul_ps(_mm256_add_ps(_mm256_add_ps(corners, _mm256_mul_ps(two, edges)), _mm256_mul_ps(four, c)), sixteenth)
        };
        let blend = |c, g, lo, hi| {
            let nv = _mm256_add_ps(_mm256_mul_ps(_mm256_sub_ps(one, b), c), _mm256_mul_ps(b, g));
            _mm256_blendv_ps(_mm256_min_ps(_mm256_max_ps(nv, lo), hi), c, fixed)
        };
        let (xul, xuc, xur, xl, xc, xr, xdl, xdc, xdr) = (at(dx, up, 0), at(dx, up, 1), at(dx, up, 2), at(dx, row, 0), at(dx, row, 1), at(dx, row, 2), at(dx, dn, 0), at(dx, dn, 1), at(dx, dn, 2));
        let gx = smooth(xul, xuc, xur, xl, xc, xr, xdl, xdc, xdr);
        let bx0 = _mm256_min_ps(_mm256_min_ps(_mm256_min_ps(_mm256_min_ps(_mm256_add_ps(neg_one, xul), _mm256_add_ps(neg_one, xl)), _mm256_add_ps(neg_one, xdl)), xuc), xdc);
        let bx1 = _mm256_max_ps(_mm256_max_ps(_mm256_max_ps(_mm256_max_ps(_mm256_add_ps(one, xur), _mm256_add_ps(one, xr)), _mm256_add_ps(one, xdr)), xuc), xdc);
        let vx = blend(xc, gx, bx0, bx1);
        let (yul, yuc, yur, yl, yc, yr, ydl, ydc, ydr) = (at(dy, up, 0), at(dy, up, 1), at(dy, up, 2), at(dy, row, 0), at(dy, row, 1), at(dy, row, 2), at(dy, dn, 0), at(dy, dn, 1), at(dy, dn, 2));
        let gy = smooth(yul, yuc, yur, yl, yc, yr, ydl, ydc, ydr);
        let by0 = _mm256_min_ps(_mm256_min_ps(_mm256_min_ps(_mm256_min_ps(_mm256_add_ps(neg_one, yul), _mm256_add_ps(neg_one, yuc)), _mm256_add_ps(neg_one, yur)), yl), yr);
        let by1 = _mm256_max_ps(_mm256_max_ps(_mm256_max_ps(_mm256_max_ps(_mm256_add_ps(one, ydl), _mm256_add_ps(one, ydc)), _mm256_add_ps(one, ydr)), yl), yr);
        let vy = blend(yc, gy, by0, by1);
        // SAFETY: output columns 1 + x0 .. 1 + x0 + 8 < w.
        unsafe {
            _mm256_storeu_ps(ox.as_mut_ptr().add(1 + x0), vx);
            _mm256_storeu_ps(oy.as_mut_ptr().add(1 + x0), vy);
        }
        x0 += 8;
    }
    for x in full..n {
        let t = |v: &[f32], r: usize| -> [[f32; 1]; 3] { [[v[r + x]], [v[r + x + 1]], [v[r + x + 2]]] };
        (ox[1 + x], oy[1 + x]) = regularise_one(&t(dx, up), &t(dx, row), &t(dx, dn), &t(dy, up), &t(dy, row), &t(dy, dn), 0, rig[row + 1 + x], mask[row + 1 + x], smoothing);
    }
}

/// The part of row `y`'s regularisation that copies: the whole row when it
/// is the first or last or fully masked (then returns true), else its first
/// and last texels.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn copy_fixed(dx: &[f32], dy: &[f32], mask: &[u8], w: usize, h: usize, y: usize, ox: &mut [f32], oy: &mut [f32]) -> bool {
    let row = y * w;
    if y == 0 || y + 1 == h || mask[row..row + w].iter().all(|&m| m == 0) {
        ox.copy_from_slice(&dx[row..row + w]);
        oy.copy_from_slice(&dy[row..row + w]);
        return true;
    }
    ox[0] = dx[row];
    oy[0] = dy[row];
    ox[w - 1] = dx[row + w - 1];
    oy[w - 1] = dy[row + w - 1];
    false
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn regularise_row_body(dx: &[f32], dy: &[f32], rig: &[u8], mask: &[u8], w: usize, h: usize, y: usize, smoothing: f32, ox: &mut [f32], oy: &mut [f32]) {
    let row = y * w;
    if copy_fixed(dx, dy, mask, w, h, y, ox, oy) {
        return;
    }
    let n = w - 2;
    let (up, mid, dn) = (row - w, row, row + w);
    let rg = &rig[row + 1..row + 1 + n];
    let mk = &mask[row + 1..row + 1 + n];
    let (ox, oy) = (&mut ox[1..1 + n], &mut oy[1..1 + n]);
    // Fixed-size blocks so that the compiler vectorises across texels.
    const B: usize = 16;
    let mut x0 = 0;
    while x0 < n {
        let m = B.min(n - x0);
        let mut bx = [0.0f32; B];
        let mut by = [0.0f32; B];
        if m == B {
            let a = |v: &[f32], r: usize, s: usize| -> [f32; B] { v[r + s + x0..r + s + x0 + B].try_into().expect("block") };
            let (xu, xm, xd) = ([a(dx, up, 0), a(dx, up, 1), a(dx, up, 2)], [a(dx, mid, 0), a(dx, mid, 1), a(dx, mid, 2)], [a(dx, dn, 0), a(dx, dn, 1), a(dx, dn, 2)]);
            let (yu, ym, yd) = ([a(dy, up, 0), a(dy, up, 1), a(dy, up, 2)], [a(dy, mid, 0), a(dy, mid, 1), a(dy, mid, 2)], [a(dy, dn, 0), a(dy, dn, 1), a(dy, dn, 2)]);
            let rb: [u8; B] = rg[x0..x0 + B].try_into().expect("block");
            let mb: [u8; B] = mk[x0..x0 + B].try_into().expect("block");
            for l in 0..B {
                (bx[l], by[l]) = regularise_one(&xu, &xm, &xd, &yu, &ym, &yd, l, rb[l], mb[l], smoothing);
            }
        } else {
            for l in 0..m {
                let x = x0 + l;
                let t = |v: &[f32], r: usize| -> [[f32; 1]; 3] { [[v[r + x]], [v[r + x + 1]], [v[r + x + 2]]] };
                (bx[l], by[l]) = regularise_one(&t(dx, up), &t(dx, mid), &t(dx, dn), &t(dy, up), &t(dy, mid), &t(dy, dn), 0, rg[x], mk[x], smoothing);
            }
        }
        ox[x0..x0 + m].copy_from_slice(&bx[..m]);
        oy[x0..x0 + m].copy_from_slice(&by[..m]);
        x0 += m;
    }
}

#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// One node of the regularisation: rows `u`, `m`, `d` (above, own, below), each
/// as columns left, centre, right; entry `l` of each.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn regularise_one<const B: usize>(xu: &[[f32; B]; 3], xm: &[[f32; B]; 3], xd: &[[f32; B]; 3], yu: &[[f32; B]; 3], ym: &[[f32; B]; 3], yd: &[[f32; B]; 3], l: usize, rig: u8, mask: u8, smoothing: f32) -> (f32, f32) {
    let m = mask as f32;
    let r = rig as f32 * (1.0 / 255.0);
    let b = m * (1.0 / 255.0) * ((1.0 - r) + r * smoothing);
    let (xul, xuc, xur, xl, xc, xr, xdl, xdc, xdr) = (xu[0][l], xu[1][l], xu[2][l], xm[0][l], xm[1][l], xm[2][l], xd[0][l], xd[1][l], xd[2][l]);
    let (yul, yuc, yur, yl, yc, yr, ydl, ydc, ydr) = (yu[0][l], yu[1][l], yu[2][l], ym[0][l], ym[1][l], ym[2][l], yd[0][l], yd[1][l], yd[2][l]);
    let gx = (xul + xur + xdl + xdr + 2.0 * (xuc + xdc + xl + xr) + 4.0 * xc) * (1.0 / 16.0);
    let gy = (yul + yur + ydl + ydr + 2.0 * (yuc + ydc + yl + yr) + 4.0 * yc) * (1.0 / 16.0);
    let nx = (1.0 - b) * xc + b * gx;
    let ny = (1.0 - b) * yc + b * gy;
    // Bounding box of the 8 neighbours, relative to this node's rest position.
    let bx0 = fmin(fmin(fmin(fmin(-1.0 + xul, -1.0 + xl), -1.0 + xdl), xuc), xdc);
    let bx1 = fmax(fmax(fmax(fmax(1.0 + xur, 1.0 + xr), 1.0 + xdr), xuc), xdc);
    let by0 = fmin(fmin(fmin(fmin(-1.0 + yul, -1.0 + yuc), -1.0 + yur), yl), yr);
    let by1 = fmax(fmax(fmax(fmax(1.0 + ydl, 1.0 + ydc), 1.0 + ydr), yl), yr);
    let fixed = mask == 0;
    (if fixed { xc } else { fmin(fmax(nx, bx0), bx1) }, if fixed { yc } else { fmin(fmax(ny, by0), by1) })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The AVX2 regularisation equals the portable one bit for bit, on rows
    /// whose width leaves a tail, with fixed, elastic, rigid and partly masked
    /// texels and displacements large enough to hit the box clamp.
    #[test]
    fn avx2_regularisation_equals_the_portable_one() {
        if !has_avx2() {
            eprintln!("skipped: this CPU has no AVX2, so only the portable regularisation runs");
            return;
        }
        let (w, h) = (45, 7);
        let wave = |k: usize, a: f32| 1.7 * (a * k as f32).sin() * ((k % 11) as f32 - 5.0) * 0.3;
        let dx: Vec<f32> = (0..w * h).map(|k| wave(k, 0.37)).collect();
        let dy: Vec<f32> = (0..w * h).map(|k| wave(k, 0.71)).collect();
        let rig: Vec<u8> = (0..w * h).map(|k| [0, 255, 128, 7][k % 4]).collect();
        let mask: Vec<u8> = (0..w * h).map(|k| [255, 0, 255, 90, 255][k % 5]).collect();
        for y in 0..h {
            let (mut ax, mut ay, mut px, mut py) = (vec![0.0f32; w], vec![0.0f32; w], vec![0.0f32; w], vec![0.0f32; w]);
            regularise_row(&dx, &dy, &rig, &mask, w, h, y, 0.1, &mut ax, &mut ay, true);
            regularise_row(&dx, &dy, &rig, &mask, w, h, y, 0.1, &mut px, &mut py, false);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&ax), bits(&px), "row {y}, x");
            assert_eq!(bits(&ay), bits(&py), "row {y}, y");
            if y > 0 && y + 1 < h {
                assert!(ax.iter().zip(&dx[y * w..]).any(|(a, d)| a != d), "row {y} must change");
            }
        }
    }
}
