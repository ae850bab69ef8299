//! Inversion of the warp (seed 001 §5, eq. 9): the "UV redirection" texture
//! `W⁻¹`, piecewise linear over the warped grid's triangles (each cell split
//! along the diagonal from node `(i, j)` to `(i+1, j+1)`): for a surface point
//! whose UV is `t`, sample the texture at `redirection(t)`.
//!
//! [`invert`] gathers: every output texel finds the warped triangle holding
//! its centre by a short walk that starts at the cell its own node's
//! displacement points back to (warps are smooth, so the walk is one or two
//! steps), and interpolates the triangle's rest coordinates there. Nodes sit
//! at texel centres, so a texel whose node did not move is a vertex of the
//! warped grid and maps to itself exactly. Each texel is computed alone from
//! the displacements: no write conflicts, and the result does not depend on
//! the number of threads. This replaced the scatter rasterisation of every
//! warped triangle ([`invert_scatter`], kept as the reference the tests compare
//! with): 190 ms against 43 ms for the gather at 1024² on the shared 2-core
//! benchmark machine (docs/performance.md).

use glam::Vec2;
use rayon::prelude::*;

use super::raster::Prepared;

const BAND: usize = 64;

/// Walk steps before [`walk_from`] gives up its first walk and walks again
/// cell by cell from the same first cell (then the local search is the
/// safety net for pathological warps).
const MAX_WALK: usize = 48;
/// A centre this far outside a triangle (in barycentric units) still counts as
/// inside: it lies on the shared edge, where both sides interpolate the same.
const EDGE_TOLERANCE: f32 = 1e-5;

/// Writes the redirection (absolute UVs, interleaved `u, v`, row 0 = lowest
/// `v`) of a `w × h` tile whose lower-left corner is at `offset`.
///
/// Rows are taken in bands of [`GATHER_ROWS`], in order within a band, so
/// that a row's walks can start where the two rows below it found their rest
/// positions, extrapolated ([`first_cell_guess`]). The result is, texel for
/// texel and bit for bit, that of [`invert_per_texel`]; the texels of a row
/// are only organised differently (see [`invert_row`]).
pub fn invert(dx: &[f32], dy: &[f32], w: usize, h: usize, offset: Vec2, out: &mut [f32]) {
    let avx2 = super::sweep::has_avx2();
    out.par_chunks_mut(2 * w * GATHER_ROWS).enumerate().for_each(|(band, chunk)| {
        let mut scratch = RowScratch::default();
        for (k, row) in chunk.chunks_mut(2 * w).enumerate() {
            invert_row(dx, dy, w, h, band * GATHER_ROWS + k, offset, row, &mut scratch, avx2);
            scratch.next_row();
        }
    });
}

/// [`invert`] one texel at a time, each with the scalar [`walk_from`] from the
/// same first cell: the reference the lane-wise path is tested against.
pub fn invert_per_texel(dx: &[f32], dy: &[f32], w: usize, h: usize, offset: Vec2, out: &mut [f32]) {
    let (sw, sh) = (1.0 / w as f64, 1.0 / h as f64);
    out.par_chunks_mut(2 * w * GATHER_ROWS).enumerate().for_each(|(band, chunk)| {
        let mut scratch = RowScratch::default();
        for (k, row) in chunk.chunks_mut(2 * w).enumerate() {
            let y = band * GATHER_ROWS + k;
            scratch.u.resize(w, 0.0);
            scratch.v.resize(w, 0.0);
            for x in 0..w {
                let n = y * w + x;
                let (u, v) = if dx[n] == 0.0 && dy[n] == 0.0 {
                    (x as i32 as f32, y as i32 as f32)
                } else {
                    let below = (scratch.below == 2).then_some([&scratch.pu[..], &scratch.pv[..], &scratch.ppu[..], &scratch.ppv[..]]);
                    let start = first_cell_guess(below, x, y, dx[n], dy[n], (w - 2) as i32, (h - 2) as i32);
                    walk_from(dx, dy, w, h, x, y, start).0
                };
                (scratch.u[x], scratch.v[x]) = (u, v);
                row[2 * x] = offset.x + ((u as f64 + 0.5) * sw) as f32;
                row[2 * x + 1] = offset.y + ((v as f64 + 0.5) * sh) as f32;
            }
            scratch.next_row();
        }
    });
}

/// Rows per band of the inversion: the first two rows of a band start their
/// walks from the texel's own displacement, the others from the rows below.
const GATHER_ROWS: usize = 32;

/// The first cell a texel's walk tries: where the two rows below (in the same
/// band) found their rest positions, extrapolated linearly (on a smooth warp
/// that is off by the change of the warp's gradient, a small fraction of a
/// cell); without them, the rest position the texel's own node displacement
/// points back to (off by about the displacement times its gradient, several
/// cells where a large grid is strongly compressed).
#[inline(always)]
fn first_cell_guess(below: Option<[&[f32]; 4]>, x: usize, y: usize, ddx: f32, ddy: f32, hi_x: i32, hi_y: i32) -> (i32, i32) {
    match below {
        Some([pu, pv, ppu, ppv]) => (first_cell(2.0 * pu[x] - ppu[x], hi_x), first_cell(2.0 * pv[x] - ppv[x], hi_y)),
        None => (first_cell(x as i32 as f32 - ddx, hi_x), first_cell(y as i32 as f32 - ddy, hi_y)),
    }
}

/// Texels per group of the lane-wise walk.
const LANES: usize = 8;

/// Per-thread buffers of [`invert_row`].
#[derive(Default)]
struct RowScratch {
    /// Rest coordinates found for the texels of the row.
    u: Vec<f32>,
    v: Vec<f32>,
    /// Those of the row below and of the one below that, when `below` says they are there.
    pu: Vec<f32>,
    pv: Vec<f32>,
    ppu: Vec<f32>,
    ppv: Vec<f32>,
    below: usize,
    /// Texels whose first cell missed: (column, next cell column, next cell row, first cell column, first cell row).
    pending: Vec<(u32, i32, i32, i32, i32)>,
}

impl RowScratch {
    /// The row just done becomes the row below.
    fn next_row(&mut self) {
        std::mem::swap(&mut self.ppu, &mut self.pu);
        std::mem::swap(&mut self.ppv, &mut self.pv);
        std::mem::swap(&mut self.pu, &mut self.u);
        std::mem::swap(&mut self.pv, &mut self.v);
        self.below = (self.below + 1).min(2);
    }
}

/// One output row. The walk of [`walk_from`] is taken two steps at a time
/// over groups of [`LANES`] texels: every texel of a group tries its first
/// cell ([`first_cell_guess`]) branch-free (both triangles, the weights and the
/// next cell of the walk computed for every lane, so that the compiler
/// vectorises it); the texels that missed try their next cell in a second
/// round, packed into groups again; the few left walk one by one with
/// [`walk_from`] from the same first cell, which takes the same first two
/// steps. So every texel gets exactly [`walk_from`]'s result, without the
/// mispredicted branches of a scalar walk (which triangle, which step).
#[allow(clippy::too_many_arguments)]
fn invert_row(dx: &[f32], dy: &[f32], w: usize, h: usize, y: usize, offset: Vec2, row: &mut [f32], scratch: &mut RowScratch, avx2: bool) {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: `avx2` is only set when the CPU reports AVX2.
        unsafe { invert_row_avx2(dx, dy, w, h, y, offset, row, scratch) };
        return;
    }
    let _ = avx2;
    invert_row_body(dx, dy, w, h, y, offset, row, scratch);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn invert_row_avx2(dx: &[f32], dy: &[f32], w: usize, h: usize, y: usize, offset: Vec2, row: &mut [f32], scratch: &mut RowScratch) {
    invert_row_body(dx, dy, w, h, y, offset, row, scratch);
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn invert_row_body(dx: &[f32], dy: &[f32], w: usize, h: usize, y: usize, offset: Vec2, row: &mut [f32], scratch: &mut RowScratch) {
    let RowScratch { u, v, pu, pv, ppu, ppv, below, pending } = scratch;
    u.resize(w, 0.0);
    v.resize(w, 0.0);
    pending.clear();
    let below = (*below == 2).then_some([&pu[..], &pv[..], &ppu[..], &ppv[..]]);
    let yf = y as i32 as f32;
    let (hi_x, hi_y) = ((w - 2) as i32, (h - 2) as i32);
    // Texels left to walk one by one: (column, first cell).
    let mut fallback: Vec<(usize, (i32, i32))> = Vec::new();
    // Round 1: every texel tries its first cell.
    let groups = w / LANES;
    for g in 0..groups {
        let x0 = g * LANES;
        let n0 = y * w + x0;
        let (ddx, ddy): (&[f32; LANES], &[f32; LANES]) = (dx[n0..n0 + LANES].try_into().expect("group"), dy[n0..n0 + LANES].try_into().expect("group"));
        let mut xs = [0.0f32; LANES];
        let (mut ci, mut cj) = ([0i32; LANES], [0i32; LANES]);
        for l in 0..LANES {
            xs[l] = (x0 + l) as i32 as f32;
            (ci[l], cj[l]) = first_cell_guess(below, x0 + l, y, ddx[l], ddy[l], hi_x, hi_y);
        }
        let t = try_cells::<true>(dx, dy, w, &xs, yf, &ci, &cj, hi_x, hi_y);
        // Found and unmoved texels are written branch-free; the misses are
        // taken from a bit mask (a branch per lane would mispredict on the
        // texels that miss).
        let mut missed = 0u32;
        for l in 0..LANES {
            let x = x0 + l;
            let unmoved = (ddx[l] == 0.0) & (ddy[l] == 0.0);
            u[x] = if unmoved { xs[l] } else { t.u[l] };
            v[x] = if unmoved { yf } else { t.v[l] };
            missed |= ((!unmoved & !t.found[l]) as u32) << l;
        }
        while missed != 0 {
            let l = missed.trailing_zeros() as usize;
            missed &= missed - 1;
            if t.stuck[l] {
                fallback.push((x0 + l, (ci[l], cj[l])));
            } else {
                pending.push(((x0 + l) as u32, t.next_ci[l], t.next_cj[l], ci[l], cj[l]));
            }
        }
    }
    for x in groups * LANES..w {
        let n = y * w + x;
        (u[x], v[x]) = if dx[n] == 0.0 && dy[n] == 0.0 { (x as i32 as f32, yf) } else { walk_from(dx, dy, w, h, x, y, first_cell_guess(below, x, y, dx[n], dy[n], hi_x, hi_y)).0 };
    }
    // Round 2: the texels that missed try the next cell of their walk.
    for group in pending.chunks(LANES) {
        let mut xs = [0.0f32; LANES];
        let (mut ci, mut cj) = ([0i32; LANES], [0i32; LANES]);
        for (l, &(x, i, j, _, _)) in group.iter().enumerate() {
            (xs[l], ci[l], cj[l]) = (x as i32 as f32, i, j);
        }
        let t = try_cells::<false>(dx, dy, w, &xs, yf, &ci, &cj, hi_x, hi_y);
        for (l, &(x, _, _, i0, j0)) in group.iter().enumerate() {
            let x = x as usize;
            if t.found[l] {
                (u[x], v[x]) = (t.u[l], t.v[l]);
            } else {
                fallback.push((x, (i0, j0)));
            }
        }
    }
    // The same walk from the start: its first two steps are the rounds above.
    for (x, start) in fallback {
        (u[x], v[x]) = walk_from(dx, dy, w, h, x, y, start).0;
    }
    let (sw, sh) = (1.0 / w as f64, 1.0 / h as f64);
    for (x, o) in row.chunks_exact_mut(2).enumerate() {
        o[0] = offset.x + ((u[x] as f64 + 0.5) * sw) as f32;
        o[1] = offset.y + ((v[x] as f64 + 0.5) * sh) as f32;
    }
}

/// `(v as i32).clamp(0, hi)` (the first cell of a walk: truncation is the floor
/// once negatives are clamped to 0, and NaN gives 0), clamped as a float first
/// so that the conversion needs no saturation checks and vectorises.
#[inline(always)]
fn first_cell(v: f32, hi: i32) -> i32 {
    let v = if v > 0.0 { v } else { 0.0 };
    let v = if v < hi as f32 { v } else { hi as f32 };
    // SAFETY: `v` is finite and within [0, hi] here (NaN became 0 above).
    unsafe { v.to_int_unchecked::<i32>() }
}

/// What [`try_cells`] found for each lane.
struct Tried {
    found: [bool; LANES],
    /// Rest coordinates, where found.
    u: [f32; LANES],
    v: [f32; LANES],
    /// Where not found: the next cell of the walk, or `stuck` when the walk
    /// would stay in this cell (then [`walk_from`] falls back to its search).
    next_ci: [i32; LANES],
    next_cj: [i32; LANES],
    stuck: [bool; LANES],
}

/// One step of [`walk_from`]'s walk for each lane: the centre `(xs[l], yf)` in
/// cell `(ci[l], cj[l])`, with exactly its arithmetic (lanes past the group's
/// end hold cell (0, 0) and are ignored by the caller).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn try_cells<const FIRST: bool>(dx: &[f32], dy: &[f32], w: usize, xs: &[f32; LANES], yf: f32, ci: &[i32; LANES], cj: &[i32; LANES], hi_x: i32, hi_y: i32) -> Tried {
    let (mut ax, mut ay, mut bx, mut by) = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
    let (mut cx, mut cy, mut qx, mut qy) = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
    // Cells are clamped to columns 0..=w − 2 and rows 0..=h − 2, so node
    // a + w + 1 is at most w·h − 1.
    assert!(dx.len() == dy.len() && ci.iter().chain(cj).all(|&c| c >= 0) && ci.iter().all(|&c| c <= hi_x) && cj.iter().all(|&c| c <= hi_y) && ((hi_y as usize + 2) * w) <= dx.len() && hi_x as usize + 2 == w);
    for l in 0..LANES {
        let a = cj[l] as usize * w + ci[l] as usize;
        let (b, c, d) = (a + 1, a + w + 1, a + w);
        // SAFETY: a ≤ b, d ≤ c ≤ w·h − 1 < len (asserted above).
        let (fx, fy) = (|i: usize| unsafe { *dx.get_unchecked(i) }, |i: usize| unsafe { *dy.get_unchecked(i) });
        (ax[l], ay[l]) = (fx(a), fy(a));
        (bx[l], by[l]) = (1.0 + fx(b), fy(b));
        (cx[l], cy[l]) = (1.0 + fx(c), 1.0 + fy(c));
        (qx[l], qy[l]) = (fx(d), 1.0 + fy(d));
    }
    let mut t = Tried { found: [false; LANES], u: [0.0; LANES], v: [0.0; LANES], next_ci: [0; LANES], next_cj: [0; LANES], stuck: [false; LANES] };
    let cross = |o: (f32, f32), u: (f32, f32), v: (f32, f32)| (u.0 - o.0) * (v.1 - o.1) - (u.1 - o.1) * (v.0 - o.0);
    for l in 0..LANES {
        let (pa, pb, pc, pd) = ((ax[l], ay[l]), (bx[l], by[l]), (cx[l], cy[l]), (qx[l], qy[l]));
        let (cif, cjf) = (ci[l] as f32, cj[l] as f32);
        let p = (xs[l] - cif, yf - cjf);
        let area0 = cross(pa, pb, pc);
        let (ea, eb) = (cross(pb, pc, p), cross(pc, pa, p));
        let ec = area0 - ea - eb;
        let tol0 = -EDGE_TOLERANCE * area0;
        let up0 = area0 > 0.0;
        let hit0 = up0 & (ea >= tol0) & (eb >= tol0) & (ec >= tol0);
        let area1 = cross(pa, pc, pd);
        let (fa, fc) = (cross(pc, pd, p), cross(pd, pa, p));
        let fd = area1 - fa - fc;
        let tol1 = -EDGE_TOLERANCE * area1;
        let up1 = area1 > 0.0;
        let hit1 = up1 & (fa >= tol1) & (fc >= tol1) & (fd >= tol1);
        // `rest_point` of either triangle; the first that holds the centre wins.
        let (inv0, inv1) = (1.0 / area0, 1.0 / area1);
        let (l1, l2) = (eb * inv0, ec * inv0);
        let (m1, m2) = (fc * inv1, fd * inv1);
        t.u[l] = if hit0 { cif + l1 + l2 } else { cif + m1 };
        t.v[l] = if hit0 { cjf + l2 } else { cjf + m1 + m2 };
        t.found[l] = hit0 | hit1;
        let sx = (up0 & (ea < tol0)) as i32 - (up1 & (fc < tol1)) as i32;
        let sy = (up1 & (fa < tol1)) as i32 - (up0 & (ec < tol0)) as i32;
        t.next_ci[l] = (ci[l] + sx).clamp(0, hi_x);
        t.next_cj[l] = (cj[l] + sy).clamp(0, hi_y);
        if FIRST {
            // `walk`'s first step: the Newton jump, when it goes further than a neighbouring cell.
            let (gu, gv) = if up0 { (cif + l1 + l2, cjf + l2) } else { (cif + m1, cjf + m1 + m2) };
            let (gx, gy) = (first_cell(gu, hi_x), first_cell(gv, hi_y));
            let jump = (up0 | up1) & (((gx - ci[l]).abs() > 1) | ((gy - cj[l]).abs() > 1));
            t.next_ci[l] = if jump { gx } else { t.next_ci[l] };
            t.next_cj[l] = if jump { gy } else { t.next_cj[l] };
        }
        t.stuck[l] = (t.next_ci[l] == ci[l]) & (t.next_cj[l] == cj[l]);
    }
    t
}

/// Barycentric weights of `p` in triangle `(a, b, c)` (coordinates relative to
/// the cell's rest corner); `None` when the triangle is degenerate or folded.
#[inline(always)]
fn bary(a: (f32, f32), b: (f32, f32), c: (f32, f32), p: (f32, f32)) -> Option<[f32; 3]> {
    let cross = |o: (f32, f32), u: (f32, f32), v: (f32, f32)| (u.0 - o.0) * (v.1 - o.1) - (u.1 - o.1) * (v.0 - o.0);
    let area = cross(a, b, c);
    if !(area > 0.0) {
        return None;
    }
    let inv = 1.0 / area;
    let la = cross(b, c, p) * inv;
    let lb = cross(c, a, p) * inv;
    Some([la, lb, 1.0 - la - lb])
}

/// The warped corners of cell `(ci, cj)` — nodes `(i, j)`, `(i+1, j)`,
/// `(i+1, j+1)`, `(i, j+1)` — relative to the cell's rest corner, so that
/// everything is O(1) and f32 is exact enough at 16384².
#[inline(always)]
fn cell_corners(dx: &[f32], dy: &[f32], w: usize, ci: usize, cj: usize) -> [(f32, f32); 4] {
    let a = cj * w + ci;
    let (b, c, d) = (a + 1, a + w + 1, a + w);
    [(dx[a], dy[a]), (1.0 + dx[b], dy[b]), (1.0 + dx[c], 1.0 + dy[c]), (dx[d], 1.0 + dy[d])]
}

/// The warped triangles of cell `(ci, cj)` and their weights for the texel
/// centre `(x, y)` (node-lattice coordinates: node `(i, j)` rests at `(i, j)`):
/// `[lower-right (a, b, c), upper-left (a, c, d)]`.
#[inline(always)]
fn cell_weights(dx: &[f32], dy: &[f32], w: usize, ci: usize, cj: usize, x: usize, y: usize) -> [Option<[f32; 3]>; 2] {
    let [pa, pb, pc, pd] = cell_corners(dx, dy, w, ci, cj);
    let p = ((x as i32 as f32 - ci as i32 as f32), (y as i32 as f32 - cj as i32 as f32));
    [bary(pa, pb, pc, p), bary(pa, pc, pd, p)]
}

/// Rest coordinates (node lattice) of the point with weights `l` in triangle
/// `t` (0: a, b, c; 1: a, c, d) of cell `(ci, cj)`.
#[inline(always)]
fn rest_point(ci: usize, cj: usize, t: usize, l: [f32; 3]) -> (f32, f32) {
    let (ci, cj) = (ci as i32 as f32, cj as i32 as f32);
    if t == 0 {
        (ci + l[1] + l[2], cj + l[2])
    } else {
        (ci + l[1], cj + l[1] + l[2])
    }
}

/// [`walk_from`] the first cell [`invert`] tries without rows below (the
/// texel's own displacement, pointed back): the tests' count of walk lengths.
#[cfg(test)]
pub(crate) fn walk(dx: &[f32], dy: &[f32], w: usize, h: usize, x: usize, y: usize) -> ((f32, f32), usize) {
    let n = y * w + x;
    walk_from(dx, dy, w, h, x, y, first_cell_guess(None, x, y, dx[n], dy[n], (w - 2) as i32, (h - 2) as i32))
}

/// The walk from cell `start` (column, row; within the grid's cells) to the
/// warped triangle holding the centre of texel `(x, y)`; returns the rest
/// coordinates there and the number of cells tried (`usize::MAX` when it
/// ended in the local search). Inside tests use unnormalised edge functions
/// (compared with a tolerance scaled by the area), so the only division is the
/// one of the triangle finally taken.
///
/// The first step may jump by the missed triangle's extended affine map (see
/// [`walk_cells`]). Where the warp's compression changes quickly that jump
/// can overshoot by more than the walk has steps (at 4096², a cell squeezed
/// to a fifth of its area sent 30 texels 60 rows past their cell); such a
/// walk is taken again from the same first cell, one cell per step.
#[inline(always)]
pub(crate) fn walk_from(dx: &[f32], dy: &[f32], w: usize, h: usize, x: usize, y: usize, start: (i32, i32)) -> ((f32, f32), usize) {
    match walk_cells(dx, dy, w, h, x, y, start, true, MAX_WALK) {
        Ok(found) => found,
        Err(_) => retry_walk(dx, dy, w, h, x, y, start),
    }
}

/// [`walk_from`]'s second walk, cell by cell (no jump), with room to cross
/// the grid; the local search around where it stops if that fails too.
#[cold]
#[inline(never)]
fn retry_walk(dx: &[f32], dy: &[f32], w: usize, h: usize, x: usize, y: usize, start: (i32, i32)) -> ((f32, f32), usize) {
    match walk_cells(dx, dy, w, h, x, y, start, false, w + h) {
        Ok((found, steps)) => (found, MAX_WALK + steps),
        Err(last) => (search(dx, dy, w, h, x, y, last), usize::MAX),
    }
}

/// At most `max_steps` cells of the walk from `start`, stepping across the
/// cell edges the centre lies beyond; with `newton`, the first step instead
/// jumps to where the missed triangle's affine map, extended, puts the
/// centre's rest position, when that is further than a neighbour. The rest
/// coordinates and the cells tried, or the last cell when the walk did not
/// arrive.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn walk_cells(dx: &[f32], dy: &[f32], w: usize, h: usize, x: usize, y: usize, start: (i32, i32), newton: bool, max_steps: usize) -> Result<((f32, f32), usize), (usize, usize)> {
    // Grid coordinates fit in i32 (sides up to 16384), and conversions
    // between f32 and i32 are one instruction, those with usize a branchy
    // sequence (no unsigned 64-bit conversions before AVX-512).
    let (xf, yf) = (x as i32 as f32, y as i32 as f32);
    let (mut ci, mut cj) = (start.0 as usize, start.1 as usize);
    let cross = |o: (f32, f32), u: (f32, f32), v: (f32, f32)| (u.0 - o.0) * (v.1 - o.1) - (u.1 - o.1) * (v.0 - o.0);
    for step in 1..=max_steps {
        let [pa, pb, pc, pd] = cell_corners(dx, dy, w, ci, cj);
        let p = (xf - ci as i32 as f32, yf - cj as i32 as f32);
        // Lower-right triangle (a, b, c): edge functions = weights × area.
        let area0 = cross(pa, pb, pc);
        let (ea, eb) = (cross(pb, pc, p), cross(pc, pa, p));
        let ec = area0 - ea - eb;
        let tol0 = -EDGE_TOLERANCE * area0;
        if area0 > 0.0 && ea >= tol0 && eb >= tol0 && ec >= tol0 {
            let inv = 1.0 / area0;
            return Ok((rest_point(ci, cj, 0, [ea * inv, eb * inv, ec * inv]), step));
        }
        // Upper-left triangle (a, c, d).
        let area1 = cross(pa, pc, pd);
        let (fa, fc) = (cross(pc, pd, p), cross(pd, pa, p));
        let fd = area1 - fa - fc;
        let tol1 = -EDGE_TOLERANCE * area1;
        if area1 > 0.0 && fa >= tol1 && fc >= tol1 && fd >= tol1 {
            let inv = 1.0 / area1;
            return Ok((rest_point(ci, cj, 1, [fa * inv, fc * inv, fd * inv]), step));
        }
        // Step across the cell edges the centre lies beyond: in (a, b, c) the
        // weight of a is the side of the right edge b–c and that of c the
        // bottom edge a–b; in (a, c, d) the weight of a is the top edge c–d and
        // that of c the left edge d–a.
        let (mut sx, mut sy) = (0i64, 0i64);
        if area0 > 0.0 {
            sx += (ea < tol0) as i64;
            sy -= (ec < tol0) as i64;
        }
        if area1 > 0.0 {
            sy += (fa < tol1) as i64;
            sx -= (fc < tol1) as i64;
        }
        let mut nx = (ci as i64 + sx).clamp(0, w as i64 - 2) as usize;
        let mut ny = (cj as i64 + sy).clamp(0, h as i64 - 2) as usize;
        if newton && step == 1 && (area0 > 0.0 || area1 > 0.0) {
            // The first step jumps to the cell where the missed triangle's
            // affine map, extended, puts the centre's rest position (a Newton
            // step): the first guess is off by about the displacement times
            // its gradient, several cells where the warp compresses a large
            // grid, and a walk of one cell per step would take that many.
            let (cif, cjf) = (ci as i32 as f32, cj as i32 as f32);
            let (gu, gv) = if area0 > 0.0 {
                let inv = 1.0 / area0;
                let (l1, l2) = (eb * inv, ec * inv);
                (cif + l1 + l2, cjf + l2)
            } else {
                let inv = 1.0 / area1;
                let (m1, m2) = (fc * inv, fd * inv);
                (cif + m1, cjf + m1 + m2)
            };
            let (gx, gy) = (first_cell(gu, (w - 2) as i32), first_cell(gv, (h - 2) as i32));
            // Only far jumps: next to the cell, the edge step is the better guess.
            if (gx - ci as i32).abs() > 1 || (gy - cj as i32).abs() > 1 {
                (nx, ny) = (gx as usize, gy as usize);
            }
        }
        if (nx, ny) == (ci, cj) {
            break;
        }
        (ci, cj) = (nx, ny);
    }
    Err((ci, cj))
}

/// Fallback of [`walk_from`]: the best triangle of the cells around `around`
/// (largest smallest weight), its weights clamped into the triangle.
#[cold]
fn search(dx: &[f32], dy: &[f32], w: usize, h: usize, x: usize, y: usize, around: (usize, usize)) -> (f32, f32) {
    const R: usize = 6;
    let mut best = (f32::NEG_INFINITY, (around.0, around.1), 0usize, [1.0f32, 0.0, 0.0]);
    for cj in around.1.saturating_sub(R)..=(around.1 + R).min(h - 2) {
        for ci in around.0.saturating_sub(R)..=(around.0 + R).min(w - 2) {
            for (k, l) in cell_weights(dx, dy, w, ci, cj, x, y).iter().enumerate() {
                if let Some(l) = l {
                    let m = l[0].min(l[1]).min(l[2]);
                    if m > best.0 {
                        best = (m, (ci, cj), k, *l);
                    }
                }
            }
        }
    }
    let (_, (ci, cj), k, l) = best;
    let c = [l[0].max(0.0), l[1].max(0.0), l[2].max(0.0)];
    let s = (c[0] + c[1] + c[2]).max(1e-12);
    rest_point(ci, cj, k, [c[0] / s, c[1] / s, c[2] / s])
}

/// The reference inversion: the warped grid's triangles rasterised with the
/// watertight rasteriser at texel centres, carrying the nodes' rest
/// coordinates. Output bands are processed in parallel; each band rasterises
/// the cell rows whose warped extent reaches it.
pub fn invert_scatter(dx: &[f32], dy: &[f32], w: usize, h: usize, offset: Vec2, out: &mut [f32]) {
    let (sw, sh) = (1.0 / w as f64, 1.0 / h as f64);
    // Warped vertical extent of every cell row (between node rows j, j+1) and
    // whether any of its nodes moved.
    let extent: Vec<(f32, f32, bool)> = (0..h - 1)
        .into_par_iter()
        .map(|j| {
            let mut lo = f32::INFINITY;
            let mut hi = f32::NEG_INFINITY;
            let mut moved = false;
            for r in [j, j + 1] {
                for i in 0..w {
                    let (ddx, ddy) = (dx[r * w + i], dy[r * w + i]);
                    moved |= ddx != 0.0 || ddy != 0.0;
                    let y = r as f32 + 0.5 + ddy;
                    lo = lo.min(y);
                    hi = hi.max(y);
                }
            }
            (lo, hi, moved)
        })
        .collect();
    out.par_chunks_mut(2 * w * BAND).enumerate().for_each(|(band, chunk)| {
        let r0 = band * BAND;
        let r1 = r0 + chunk.len() / (2 * w);
        for y in r0..r1 {
            for x in 0..w {
                let o = 2 * ((y - r0) * w + x);
                chunk[o] = offset.x + ((x as f64 + 0.5) * sw) as f32;
                chunk[o + 1] = offset.y + ((y as f64 + 0.5) * sh) as f32;
            }
        }
        for (j, &(lo, hi, moved)) in extent.iter().enumerate() {
            if !moved || hi < r0 as f32 || lo > r1 as f32 {
                continue;
            }
            for i in 0..w - 1 {
                let a = j * w + i;
                let nodes = [a, a + 1, a + w + 1, a + w];
                if nodes.iter().all(|&n| dx[n] == 0.0 && dy[n] == 0.0) {
                    continue;
                }
                let rest = [[i as f64 + 0.5, j as f64 + 0.5], [i as f64 + 1.5, j as f64 + 0.5], [i as f64 + 1.5, j as f64 + 1.5], [i as f64 + 0.5, j as f64 + 1.5]];
                let warped: [[f64; 2]; 4] = std::array::from_fn(|k| [rest[k][0] + dx[nodes[k]] as f64, rest[k][1] + dy[nodes[k]] as f64]);
                for tri in [[0usize, 1, 2], [0, 2, 3]] {
                    let Some(prep) = Prepared::new([warped[tri[0]], warped[tri[1]], warped[tri[2]]]) else { continue };
                    prep.for_each(w, r0..r1, |x, y, b| {
                        let mut u = 0.0f64;
                        let mut v = 0.0f64;
                        for k in 0..3 {
                            u += rest[tri[k]][0] * b[k] as f64;
                            v += rest[tri[k]][1] * b[k] as f64;
                        }
                        let o = 2 * ((y - r0) * w + x);
                        chunk[o] = offset.x + (u * sw) as f32;
                        chunk[o + 1] = offset.y + (v * sh) as f32;
                    });
                }
            }
        }
    });
}

