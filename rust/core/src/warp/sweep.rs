//! The hot loops of one solver iteration: the constraint projection sweeps
//! and the regularisation, written for throughput.
//!
//! The arithmetic is exactly that of the reference projection in
//! [`super::solver`] (same operations in the same order, so the results are
//! bitwise equal to it, which a test checks), but organised so that the
//! compiler can vectorise it:
//! - constraints of one set in one row are independent (that is what makes
//!   the set a set), so they are processed in runs of [`LANES`] lanes: node
//!   values and metrics are gathered into small arrays, the projection is
//!   evaluated branch-free over the lanes (skipped constraints get a zero
//!   correction, not a branch), and the corrections are scattered back;
//! - a run whose nodes are all fully elastic is skipped after a cheap test of
//!   its rigidities (most of an elastic region costs one byte load per node);
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

use super::solver::RELAXATION;

/// Constraints per run.
pub const LANES: usize = 16;

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
    pub rig: &'a [u8],
    pub mask: &'a [u8],
    pub metric: M,
    pub orientation: f32,
    /// Whether to use the AVX2 build of the kernels.
    pub avx2: bool,
}

/// One set's constraints in a slice of rows: constraint `k` joins local nodes
/// `a0 + k·stride` and `b0 + k·stride` (global: plus `g0`); its rest texel is
/// `rest0 + k·stride`.
#[derive(Clone, Copy)]
struct Run {
    dir: usize,
    a0: usize,
    b0: usize,
    stride: usize,
    count: usize,
    g0: usize,
    rest0: usize,
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
                self.run(Run { dir: HORIZONTAL, a0, b0: a0 + 1, stride: 2, count: (w - parity) / 2, g0, rest0: g0 + a0 + 1 }, dx, dy);
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
        self.run(Run { dir: VERTICAL, a0: 0, b0: w, stride: 1, count: w, g0, rest0: g0 + w }, dx, dy);
        self.run(Run { dir: DIAGONAL, a0: 0, b0: w + 1, stride: 1, count: w - 1, g0, rest0: g0 + w + 1 }, dx, dy);
        self.run(Run { dir: ANTIDIAGONAL, a0: 1, b0: w, stride: 1, count: w - 1, g0, rest0: g0 + w + 1 }, dx, dy);
    }

    #[inline]
    fn run(&self, run: Run, dx: &mut [f32], dy: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is only set when the CPU reports AVX2.
            unsafe { self.run_avx2(run, dx, dy) };
            return;
        }
        self.run_generic(run, dx, dy);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn run_avx2(&self, run: Run, dx: &mut [f32], dy: &mut [f32]) {
        self.run_body(run, dx, dy);
    }

    fn run_generic(&self, run: Run, dx: &mut [f32], dy: &mut [f32]) {
        self.run_body(run, dx, dy);
    }

    #[inline(always)]
    fn run_body(&self, run: Run, dx: &mut [f32], dy: &mut [f32]) {
        let Run { dir, a0, b0, stride, count, g0, rest0 } = run;
        let (ex, ey) = rest_segment(dir);
        let el = (ex * ex + ey * ey).sqrt();
        let (rig, mask) = (self.rig, self.mask);
        let mut k = 0;
        while k < count {
            let n = LANES.min(count - k);
            let mut any = 0u8;
            for l in 0..n {
                let a = g0 + a0 + (k + l) * stride;
                any |= rig[a] | rig[a - a0 + b0];
            }
            if any == 0 {
                k += n;
                continue;
            }
            let mut ra = [0.0f32; LANES];
            let mut rb = [0.0f32; LANES];
            let mut mka = [0.0f32; LANES];
            let mut mkb = [0.0f32; LANES];
            let mut pax = [0.0f32; LANES];
            let mut pay = [0.0f32; LANES];
            let mut pbx = [0.0f32; LANES];
            let mut pby = [0.0f32; LANES];
            let mut m = [[1.0f32; 4]; LANES];
            for l in 0..n {
                let c = (k + l) * stride;
                let (la, lb) = (a0 + c, b0 + c);
                ra[l] = rig[g0 + la] as f32;
                rb[l] = rig[g0 + lb] as f32;
                mka[l] = mask[g0 + la] as f32;
                mkb[l] = mask[g0 + lb] as f32;
                pax[l] = dx[la];
                pay[l] = dy[la];
                pbx[l] = dx[lb];
                pby[l] = dy[lb];
                m[l] = self.metric.fetch(rest0 + c, dir);
            }
            let mut ca = [[0.0f32; 2]; LANES];
            let mut cb = [[0.0f32; 2]; LANES];
            for l in 0..LANES {
                // The reference projection (solver::Ctx::project), branch-free.
                let k8 = ra[l].max(rb[l]);
                let ma = mka[l] * (1.0 - 0.9 / 255.0 * ra[l]);
                let mb = mkb[l] * (1.0 - 0.9 / 255.0 * rb[l]);
                let ms = ma + mb;
                let kk = k8 * (1.0 / 255.0);
                let vx = ex + pbx[l] - pax[l];
                let vy = ey + pby[l] - pay[l];
                let [g0, g1, g2, l02] = m[l];
                let ld2 = g0 * vx * vx + 2.0 * g1 * vx * vy + g2 * vy * vy;
                let active = k8 > 0.0 && ms > 0.0 && l02 > 0.0 && ld2 > l02 * 1e-6;
                let (l02s, ld2s) = if active { (l02, ld2) } else { (1.0, 1.0) };
                let ratio = (l02s / ld2s).sqrt().clamp(0.25, 4.0);
                let s = 1.0 + RELAXATION * kk * (ratio - 1.0);
                let (mut tx, mut ty) = (vx * s, vy * s);
                if self.orientation > 0.0 {
                    let o = self.orientation * kk;
                    let len = (tx * tx + ty * ty).sqrt();
                    let len_ok = len > 1e-12;
                    let lens = if len_ok { len } else { 1.0 };
                    let ux = tx / lens * (1.0 - o) + ex / el * o;
                    let uy = ty / lens * (1.0 - o) + ey / el * o;
                    let ul = (ux * ux + uy * uy).sqrt();
                    let ul_ok = ul > 1e-12;
                    let uls = if ul_ok { ul } else { 1.0 };
                    let turn = len_ok && ul_ok;
                    tx = if turn { ux / uls * len } else { tx };
                    ty = if turn { uy / uls * len } else { ty };
                }
                let (cx, cy) = if active { (tx - vx, ty - vy) } else { (0.0, 0.0) };
                let mss = if ms > 0.0 { ms } else { 1.0 };
                let (fa, fb) = (ma / mss, mb / mss);
                ca[l] = [cx * fa, cy * fa];
                cb[l] = [cx * fb, cy * fb];
            }
            for l in 0..n {
                let c = (k + l) * stride;
                let (la, lb) = (a0 + c, b0 + c);
                dx[la] = pax[l] - ca[l][0];
                dy[la] = pay[l] - ca[l][1];
                dx[lb] = pbx[l] + cb[l][0];
                dy[lb] = pby[l] + cb[l][1];
            }
            k += n;
        }
    }
}

/// Regularisation of one row `y` (seed eqs. 4–5 plus the 8-neighbourhood box
/// clamp) from `dx`, `dy` into `ox`, `oy`; the reference is
/// `solver::regularise_reference`.
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

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn regularise_row_avx2(dx: &[f32], dy: &[f32], rig: &[u8], mask: &[u8], w: usize, h: usize, y: usize, smoothing: f32, ox: &mut [f32], oy: &mut [f32]) {
    regularise_row_body(dx, dy, rig, mask, w, h, y, smoothing, ox, oy);
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn regularise_row_body(dx: &[f32], dy: &[f32], rig: &[u8], mask: &[u8], w: usize, h: usize, y: usize, smoothing: f32, ox: &mut [f32], oy: &mut [f32]) {
    let row = y * w;
    if y == 0 || y + 1 == h || mask[row..row + w].iter().all(|&m| m == 0) {
        ox.copy_from_slice(&dx[row..row + w]);
        oy.copy_from_slice(&dy[row..row + w]);
        return;
    }
    ox[0] = dx[row];
    oy[0] = dy[row];
    ox[w - 1] = dx[row + w - 1];
    oy[w - 1] = dy[row + w - 1];
    let n = w - 2;
    // Windows of the three rows shifted by −1, 0, +1 columns, all of length n.
    fn win(v: &[f32], r: usize, s: usize, n: usize) -> &[f32] {
        &v[r + s..r + s + n]
    }
    let (up, mid, dn) = (row - w, row, row + w);
    let (xul, xu, xur, xl, xc, xr, xdl, xd, xdr) = (win(dx, up, 0, n), win(dx, up, 1, n), win(dx, up, 2, n), win(dx, mid, 0, n), win(dx, mid, 1, n), win(dx, mid, 2, n), win(dx, dn, 0, n), win(dx, dn, 1, n), win(dx, dn, 2, n));
    let (yul, yu, yur, yl, yc, yr, ydl, yd, ydr) = (win(dy, up, 0, n), win(dy, up, 1, n), win(dy, up, 2, n), win(dy, mid, 0, n), win(dy, mid, 1, n), win(dy, mid, 2, n), win(dy, dn, 0, n), win(dy, dn, 1, n), win(dy, dn, 2, n));
    let rg = &rig[row + 1..row + 1 + n];
    let mk = &mask[row + 1..row + 1 + n];
    let (ox, oy) = (&mut ox[1..1 + n], &mut oy[1..1 + n]);
    for x in 0..n {
        let m = mk[x] as f32;
        let r = rg[x] as f32 * (1.0 / 255.0);
        let b = m * (1.0 / 255.0) * ((1.0 - r) + r * smoothing);
        let gx = (xul[x] + xur[x] + xdl[x] + xdr[x] + 2.0 * (xu[x] + xd[x] + xl[x] + xr[x]) + 4.0 * xc[x]) * (1.0 / 16.0);
        let gy = (yul[x] + yur[x] + ydl[x] + ydr[x] + 2.0 * (yu[x] + yd[x] + yl[x] + yr[x]) + 4.0 * yc[x]) * (1.0 / 16.0);
        let nx = (1.0 - b) * xc[x] + b * gx;
        let ny = (1.0 - b) * yc[x] + b * gy;
        let bx0 = (-1.0 + xul[x]).min(-1.0 + xl[x]).min(-1.0 + xdl[x]).min(xu[x]).min(xd[x]);
        let bx1 = (1.0 + xur[x]).max(1.0 + xr[x]).max(1.0 + xdr[x]).max(xu[x]).max(xd[x]);
        let by0 = (-1.0 + yul[x]).min(-1.0 + yu[x]).min(-1.0 + yur[x]).min(yl[x]).min(yr[x]);
        let by1 = (1.0 + ydl[x]).max(1.0 + yd[x]).max(1.0 + ydr[x]).max(yl[x]).max(yr[x]);
        let fixed = m == 0.0;
        ox[x] = if fixed { xc[x] } else { nx.max(bx0).min(bx1) };
        oy[x] = if fixed { yc[x] } else { ny.max(by0).min(by1) };
    }
}
