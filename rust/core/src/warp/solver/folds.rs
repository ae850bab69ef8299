//! Fold-overs of the finest level: counting them per cell, and repairing
//! them (local relaxation, then a scale towards the identity, which is always
//! fold-free).

use rayon::prelude::*;

use super::Level;

/// Triangles of the warped grid with a doubled area below this (in texel²,
/// identity = 1) are treated as folded by the repair.
pub(super) const FOLD_MARGIN: f32 = 0.02;


/// Doubled signed areas of the two triangles of cell `(i, j)` — split along
/// the diagonal from node `(i, j)` to `(i+1, j+1)` — in texel² (identity: 1).
#[inline]
pub fn cell_dets(dx: &[f32], dy: &[f32], w: usize, i: usize, j: usize) -> [f32; 2] {
    let a = j * w + i;
    let (b, c, d) = (a + 1, a + w + 1, a + w);
    let p = |n: usize, ox: f32, oy: f32| (ox + dx[n], oy + dy[n]);
    let pa = p(a, 0.0, 0.0);
    let pb = p(b, 1.0, 0.0);
    let pc = p(c, 1.0, 1.0);
    let pd = p(d, 0.0, 1.0);
    let cross = |o: (f32, f32), u: (f32, f32), v: (f32, f32)| (u.0 - o.0) * (v.1 - o.1) - (u.1 - o.1) * (v.0 - o.0);
    [cross(pa, pb, pc), cross(pa, pc, pd)]
}

/// Counts triangles of the warped grid whose doubled area is at most `margin`.
pub fn count_folds(dx: &[f32], dy: &[f32], w: usize, h: usize, margin: f32) -> usize {
    (0..h - 1).into_par_iter().map(|j| row_folds(dx, dy, w, j, margin)).sum()
}

/// [`count_folds`] of cell row `j`: [`cell_dets`]' arithmetic over slices of
/// equal length, so that the compiler vectorises it (it runs every frame).
pub(super) fn row_folds(dx: &[f32], dy: &[f32], w: usize, j: usize, margin: f32) -> usize {
    let n = w - 1;
    let (r0, r1) = (j * w, (j + 1) * w);
    let (xa, xb, xc, xd) = (&dx[r0..r0 + n], &dx[r0 + 1..r0 + 1 + n], &dx[r1 + 1..r1 + 1 + n], &dx[r1..r1 + n]);
    let (ya, yb, yc, yd) = (&dy[r0..r0 + n], &dy[r0 + 1..r0 + 1 + n], &dy[r1 + 1..r1 + 1 + n], &dy[r1..r1 + n]);
    let mut folds = 0u32;
    for i in 0..n {
        let pa = (0.0 + xa[i], 0.0 + ya[i]);
        let pb = (1.0 + xb[i], 0.0 + yb[i]);
        let pc = (1.0 + xc[i], 1.0 + yc[i]);
        let pd = (0.0 + xd[i], 1.0 + yd[i]);
        let cross = |o: (f32, f32), u: (f32, f32), v: (f32, f32)| (u.0 - o.0) * (v.1 - o.1) - (u.1 - o.1) * (v.0 - o.0);
        folds += (cross(pa, pb, pc) <= margin) as u32 + (cross(pa, pc, pd) <= margin) as u32;
    }
    folds as usize
}

/// Smallest doubled area (texel², identity 1) every iteration leaves a
/// warped grid triangle: the fold-prevention constraint of [`keep_areas`].
pub(super) const MIN_AREA: f32 = 0.05;

/// Cells (named by their lower-left node) with a triangle whose doubled
/// area is below `margin`, in row order. The scan is [`row_folds`]' (the
/// vectorised count): rows without such a cell cost one pass of it. `thin`:
/// the cell rows where [`row_folds`] with this margin counts a cell, already
/// found (in increasing order, see [`ThinRows`]); only those are searched.
fn cells_below(dx: &[f32], dy: &[f32], w: usize, h: usize, margin: f32, thin: Option<&ThinRows>) -> Vec<usize> {
    let in_row = |j: usize| (0..w - 1).map(move |i| j * w + i);
    let below = |&c: &usize| cell_dets(dx, dy, w, c % w, c / w).iter().any(|&d| d < margin);
    match thin {
        Some(rows) => rows.0.par_iter().flat_map_iter(|&j| in_row(j)).filter(below).collect(),
        None => (0..h - 1).into_par_iter().filter(|&j| row_folds(dx, dy, w, j, margin) > 0).flat_map_iter(in_row).filter(below).collect(),
    }
}

/// The cell rows of an iterate in which [`row_folds`] counts a grid
/// triangle below [`MIN_AREA`], in increasing order: what [`keep_areas`]'s
/// scan would find. The iteration finds them while the rows it wrote are
/// still in cache (`super::iteration`), so that the constraint does not
/// stream the whole grid again (issue 28: the warm frame is memory-bound).
#[derive(Debug, Clone, Default)]
pub(super) struct ThinRows(pub(super) Vec<usize>);

impl ThinRows {
    /// The listed cell rows among the `rows − 1` between the `rows` node rows
    /// held in `dx`, `dy`, numbered from grid row `first` (a band of the grid).
    pub(super) fn in_band(dx: &[f32], dy: &[f32], w: usize, first: usize) -> Vec<usize> {
        let rows = dx.len() / w;
        (0..rows.saturating_sub(1)).filter(|&r| row_folds(dx, dy, w, r, MIN_AREA) > 0).map(|r| first + r).collect()
    }
}

/// Projects triangle `(p, q, r)` (node indices, corner offsets in texels)
/// onto doubled area `target` if it is below: one linearised PBD step on the
/// area constraint, each node weighted by its mask value (fixed nodes stay).
#[inline]
fn project_area(lv: &mut Level, nodes: [usize; 3], offsets: [(f32, f32); 3], target: f32) {
    let pos = |k: usize| (offsets[k].0 + lv.dx[nodes[k]], offsets[k].1 + lv.dy[nodes[k]]);
    let (p0, p1, p2) = (pos(0), pos(1), pos(2));
    let c = (p1.0 - p0.0) * (p2.1 - p0.1) - (p1.1 - p0.1) * (p2.0 - p0.0);
    if c >= target {
        return;
    }
    // ∂c/∂p1 = (y2 − y0, x0 − x2), ∂c/∂p2 = (y0 − y1, x1 − x0), ∂c/∂p0 = −both.
    let g1 = (p2.1 - p0.1, p0.0 - p2.0);
    let g2 = (p0.1 - p1.1, p1.0 - p0.0);
    let g0 = (-g1.0 - g2.0, -g1.1 - g2.1);
    let grads = [g0, g1, g2];
    let wt = nodes.map(|n| lv.mask[n] as f32 * (1.0 / 255.0));
    let denom: f32 = (0..3).map(|k| wt[k] * (grads[k].0 * grads[k].0 + grads[k].1 * grads[k].1)).sum();
    if !(denom > 1e-12) {
        return;
    }
    let lambda = (target - c) / denom;
    for k in 0..3 {
        lv.dx[nodes[k]] += lambda * wt[k] * grads[k].0;
        lv.dy[nodes[k]] += lambda * wt[k] * grads[k].1;
    }
}

/// Most passes of [`keep_areas`] while a cell is still folded (or, settling,
/// below [`SETTLED`] of the limit).
const UNFOLD_PASSES: usize = 64;
/// After its first passes, a settling [`keep_areas`] (the multigrid's) goes
/// on while a cell is below this fraction of [`MIN_AREA`]; the cascade's
/// stops as soon as nothing is folded, as before issue 28's multigrid.
/// Stopping as soon as nothing was folded left
/// cells just under the limit, which the next iteration's regularisation
/// pushed further and the constraint back: the iteration never settled
/// (on the benchmark cylinder's strongest bend at 256², nodes kept moving
/// by 5e-4 texel an iteration, 20 times the convergence tolerance).
const SETTLED: f32 = 0.999;

/// The fold-prevention constraint, run at the end of every iteration of
/// every level: the grid triangles of cells whose doubled area fell below
/// [`MIN_AREA`] are projected back to it (Gauss–Seidel in row order, up to
/// `passes` passes over those cells and the cells around them, and on while
/// one of them is still folded, up to [`UNFOLD_PASSES`]: on the tests'
/// squares scene at 4096² four passes left one folded cell in the skin,
/// which the end-of-solve repair could only flatten, rigid stretch 0.09 →
/// 0.37). Deterministic (sequential over
/// a sorted list). `settle`: go on past `passes` until every cell is at
/// [`SETTLED`] of the limit, not just unfolded (see there). `thin`: the
/// iterate's rows with cells below the limit, if already found.
///
/// Returns whether a cell is still folded (a doubled area ≤ 0, what
/// [`count_folds`] with margin 0 counts): every cell outside the final list
/// is at the limit or above (it was when the scan found none there, and no
/// pass moved a node of it since), so the list alone answers, without
/// another pass over the grid.
pub(super) fn keep_areas(lv: &mut Level, passes: usize, settle: bool, thin: Option<&ThinRows>) -> bool {
    let (w, h) = (lv.w, lv.h);
    let min_area = MIN_AREA;
    let mut bad = cells_below(&lv.dx, &lv.dy, w, h, min_area, thin);
    for pass in 0..passes.max(UNFOLD_PASSES) {
        if bad.is_empty() {
            break;
        }
        let unsettled = |d: f32| if settle { d < SETTLED * min_area } else { d <= 0.0 };
        if pass >= passes && !bad.iter().any(|&c| cell_dets(&lv.dx, &lv.dy, w, c % w, c / w).iter().any(|&d| unsettled(d))) {
            break;
        }
        for &c in &bad {
            let (a, b, cc, d) = (c, c + 1, c + w + 1, c + w);
            project_area(lv, [a, b, cc], [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)], min_area);
            project_area(lv, [a, cc, d], [(0.0, 0.0), (1.0, 1.0), (0.0, 1.0)], min_area);
        }
        // The cells a pass can change: those sharing a node with a bad cell.
        let mut candidates: Vec<usize> = Vec::with_capacity(9 * bad.len());
        for &c in &bad {
            let (i, j) = (c % w, c / w);
            for nj in j.saturating_sub(1)..(j + 2).min(h - 1) {
                for ni in i.saturating_sub(1)..(i + 2).min(w - 1) {
                    candidates.push(nj * w + ni);
                }
            }
        }
        candidates.sort_unstable();
        candidates.dedup();
        bad = candidates.into_iter().filter(|&c| cell_dets(&lv.dx, &lv.dy, w, c % w, c / w).iter().any(|&d| d < min_area)).collect();
    }
    bad.iter().any(|&c| cell_dets(&lv.dx, &lv.dy, w, c % w, c / w).iter().any(|&d| d <= 0.0))
}

/// Removes fold-overs of the finest level; returns (relaxation passes, global scale).
///
/// Each relaxation pass moves every movable node that touches a bad cell
/// towards its neighbours' mean, shrunk (Jacobi: all new positions from the
/// old ones). Only the bad cells and the nodes around them are visited: the
/// cells a pass can change are the ones around the nodes it moved, so the bad
/// set after a pass is found among those and the bad cells it could not move.
/// A strong bend can take tens of passes over a few hundred cells; passes over
/// the whole grid made such a frame ten times slower than a clean one.
pub(super) fn repair_folds(lv: &mut Level) -> (usize, f32) {
    match relax_folds(lv) {
        Ok(passes) => (passes, 1.0),
        // A few cells the relaxation cannot untangle should not cost the whole
        // warp: shrink the displacements around them first.
        Err(bad) => (32, scale_around(lv, &bad).unwrap_or_else(|| scale_until_unfolded(lv))),
    }
}

/// The repair's relaxation: up to 32 passes over the nodes of folded cells.
/// The passes it took, or the cells still folded after the last.
pub(super) fn relax_folds(lv: &mut Level) -> Result<usize, Vec<usize>> {
    let (w, h) = (lv.w, lv.h);
    let bad_cell = |dx: &[f32], dy: &[f32], c: usize| cell_dets(dx, dy, w, c % w, c / w).iter().any(|&d| d <= FOLD_MARGIN);
    if count_folds(&lv.dx, &lv.dy, w, h, FOLD_MARGIN) == 0 {
        return Ok(0);
    }
    // Cells are named by their lower-left node.
    let mut bad: Vec<usize> = (0..h - 1).into_par_iter().flat_map_iter(|j| (0..w - 1).map(move |i| j * w + i)).filter(|&c| bad_cell(&lv.dx, &lv.dy, c)).collect();
    let mut moved: Vec<(usize, f32, f32)> = Vec::new();
    for pass in 1..=32 {
        let mut nodes: Vec<usize> = bad.iter().flat_map(|&c| [c, c + 1, c + w, c + w + 1]).collect();
        nodes.sort_unstable();
        nodes.dedup();
        let (dx, dy, mask) = (&lv.dx, &lv.dy, &lv.mask);
        moved.clear();
        for &g in &nodes {
            let (i, j) = (g % w, g / w);
            if mask[g] == 0 || i == 0 || j == 0 || i + 1 == w || j + 1 == h {
                continue;
            }
            let (x, y) = relaxed(dx, dy, w, g);
            moved.push((g, x, y));
        }
        for &(g, x, y) in &moved {
            lv.dx[g] = x;
            lv.dy[g] = y;
        }
        // The bad cells no pass can move, and every cell around a moved node.
        let mut candidates = bad.clone();
        for &(g, _, _) in &moved {
            // Moved nodes are interior, so all four cells exist.
            candidates.extend([g - w - 1, g - w, g - 1, g]);
        }
        candidates.sort_unstable();
        candidates.dedup();
        bad = candidates.into_iter().filter(|&c| bad_cell(&lv.dx, &lv.dy, c)).collect();
        if bad.is_empty() {
            return Ok(pass);
        }
    }
    Err(bad)
}

/// The repair's second resort: the displacements shrunk towards the identity
/// around the cells `bad` only, by a factor `s` inside their bounding box
/// grown by a margin (the box's size, at least 16 texels) and blending back
/// to 1 over as many texels again, for `s` = ½, ¼, … and finally 0. Returns
/// the first `s` that leaves no fold, or `None` (nothing changed) when even
/// 0 does not: the folds are not local, and the whole grid is scaled.
///
/// (In the benchmark's cold 2048² solve at its strongest bend, 18 folded
/// cells in a 70 × 166 texel patch used to shrink the whole warp to 1/8,
/// leaving a rigid stretch error of 0.33 against the identity's 0.37.)
pub(super) fn scale_around(lv: &mut Level, bad: &[usize]) -> Option<f32> {
    let (w, h) = (lv.w, lv.h);
    if bad.is_empty() {
        return None;
    }
    let (mut x0, mut x1, mut y0, mut y1) = (w, 0, h, 0);
    for &c in bad {
        let (i, j) = (c % w, c / w);
        (x0, x1, y0, y1) = (x0.min(i), x1.max(i + 1), y0.min(j), y1.max(j + 1));
    }
    let margin = (x1 - x0).max(y1 - y0).max(16);
    // The nodes any factor below 1 reaches, and their displacements before.
    let (rx0, rx1, ry0, ry1) = (x0.saturating_sub(2 * margin), (x1 + 2 * margin).min(w - 1), y0.saturating_sub(2 * margin), (y1 + 2 * margin).min(h - 1));
    let saved: Vec<(f32, f32)> = (ry0..=ry1).flat_map(|j| (rx0..=rx1).map(move |i| j * w + i)).map(|g| (lv.dx[g], lv.dy[g])).collect();
    let outside = |v: usize, lo: usize, hi: usize| if v + margin < lo { lo - margin - v } else if v > hi + margin { v - hi - margin } else { 0 };
    for k in 1..=6 {
        let s = if k == 6 { 0.0 } else { 0.5f32.powi(k) };
        let mut at = 0;
        for j in ry0..=ry1 {
            for i in rx0..=rx1 {
                let d = outside(i, x0, x1).max(outside(j, y0, y1)) as f32;
                let t = (d / margin as f32).min(1.0);
                let f = s + (1.0 - s) * t * t * (3.0 - 2.0 * t);
                let g = j * w + i;
                (lv.dx[g], lv.dy[g]) = (saved[at].0 * f, saved[at].1 * f);
                at += 1;
            }
        }
        if count_folds(&lv.dx, &lv.dy, w, h, 0.0) == 0 {
            return Some(s);
        }
    }
    let mut at = 0;
    for j in ry0..=ry1 {
        for i in rx0..=rx1 {
            (lv.dx[j * w + i], lv.dy[j * w + i]) = saved[at];
            at += 1;
        }
    }
    None
}

/// The repair's new position of interior node `g`: its 8 neighbours' mean, shrunk.
#[inline]
pub(super) fn relaxed(dx: &[f32], dy: &[f32], w: usize, g: usize) -> (f32, f32) {
    let mut sx = 0.0;
    let mut sy = 0.0;
    for q in [g - w - 1, g - w, g - w + 1, g - 1, g + 1, g + w - 1, g + w, g + w + 1] {
        sx += dx[q];
        sy += dy[q];
    }
    (0.8 * sx / 8.0, 0.8 * sy / 8.0)
}

/// The repair's last resort: halves the warp until nothing folds (the
/// identity never does); returns the scale applied.
pub(super) fn scale_until_unfolded(lv: &mut Level) -> f32 {
    let mut scale = 1.0f32;
    while count_folds(&lv.dx, &lv.dy, lv.w, lv.h, 0.0) > 0 {
        scale *= 0.5;
        let f = if scale < 1e-4 { 0.0 } else { 0.5 };
        lv.dx.par_iter_mut().for_each(|d| *d *= f);
        lv.dy.par_iter_mut().for_each(|d| *d *= f);
        if f == 0.0 {
            scale = 0.0;
            break;
        }
    }
    scale
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The repair as it was first written: every pass over the whole grid.
    /// The local repair must give the same result, bit for bit.
fn repair_folds_whole_grid(lv: &mut Level) -> (usize, f32) {
    let (w, h) = (lv.w, lv.h);
    if count_folds(&lv.dx, &lv.dy, w, h, FOLD_MARGIN) == 0 {
        return (0, 1.0);
    }
    for pass in 1..=32 {
        // Nodes touching a bad triangle move towards their neighbours' mean, shrunk.
        let (dx, dy, mask) = (&lv.dx, &lv.dy, &lv.mask);
        let bad_node = |i: usize, j: usize| {
            for (cj, ci) in [(j.wrapping_sub(1), i.wrapping_sub(1)), (j.wrapping_sub(1), i), (j, i.wrapping_sub(1)), (j, i)] {
                if ci < w - 1 && cj < h - 1 && cell_dets(dx, dy, w, ci, cj).iter().any(|&d| d <= FOLD_MARGIN) {
                    return true;
                }
            }
            false
        };
        lv.sx.par_chunks_mut(w).zip(lv.sy.par_chunks_mut(w)).enumerate().for_each(|(j, (ox, oy))| {
            for i in 0..w {
                let g = j * w + i;
                ox[i] = dx[g];
                oy[i] = dy[g];
                if mask[g] == 0 || i == 0 || j == 0 || i + 1 == w || j + 1 == h || !bad_node(i, j) {
                    continue;
                }
                (ox[i], oy[i]) = relaxed(dx, dy, w, g);
            }
        });
        std::mem::swap(&mut lv.dx, &mut lv.sx);
        std::mem::swap(&mut lv.dy, &mut lv.sy);
        if count_folds(&lv.dx, &lv.dy, w, h, FOLD_MARGIN) == 0 {
            return (pass, 1.0);
        }
    }
    let bad: Vec<usize> = (0..h - 1).flat_map(|j| (0..w - 1).map(move |i| j * w + i)).filter(|&c| cell_dets(&lv.dx, &lv.dy, w, c % w, c / w).iter().any(|&d| d <= FOLD_MARGIN)).collect();
    (32, scale_around(lv, &bad).unwrap_or_else(|| scale_until_unfolded(lv)))
}

    /// Folded warps of three strengths: the local repair equals the
    /// whole-grid one, node for node and in its pass count and scale.
    #[test]
    fn local_fold_repair_equals_the_whole_grid_repair() {
        let (w, h) = (61, 47);
        let mut outcomes = Vec::new();
        for strength in [0.9f32, 4.0, 9.0, 20.0] {
            let mut lv = Level::new(w, h, vec![0; w * h], vec![255; w * h]);
            for j in 0..h {
                for i in 0..w {
                    // A swirl around (30, 23): its centre folds when strong enough.
                    let (u, v) = (i as f32 - 30.0, j as f32 - 23.0);
                    let a = strength * (-(u * u + v * v) / 40.0).exp();
                    lv.dx[j * w + i] = u * a.cos() - v * a.sin() - u;
                    lv.dy[j * w + i] = u * a.sin() + v * a.cos() - v;
                }
            }
            for k in 0..w {
                lv.mask[k] = 0;
            }
            if strength > 10.0 {
                // Fixed nodes inside the folded swirl: relaxation alone cannot unfold it.
                for j in 20..27 {
                    for i in 27..34 {
                        lv.mask[j * w + i] = 0;
                    }
                }
            }
            let folds = count_folds(&lv.dx, &lv.dy, w, h, FOLD_MARGIN);
            let mut whole = lv.clone();
            let (a, b) = (repair_folds(&mut lv), repair_folds_whole_grid(&mut whole));
            assert_eq!(a, b, "strength {strength}");
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&lv.dx), bits(&whole.dx), "strength {strength}");
            assert_eq!(bits(&lv.dy), bits(&whole.dy), "strength {strength}");
            assert_eq!(count_folds(&lv.dx, &lv.dy, w, h, 0.0), 0);
            outcomes.push((folds, a));
        }
        eprintln!("(folded cells, (passes, scale)) per strength: {outcomes:?}");
        // No fold; folds the relaxation removes; folds that need the global scale.
        assert_eq!(outcomes[0].0, 0, "{outcomes:?}");
        assert!(outcomes[1..3].iter().all(|o| o.0 > 0 && o.1 .0 < 32), "{outcomes:?}");
        assert!(outcomes[3].1 .1 < 1.0, "{outcomes:?}");
    }

    /// Folds the relaxation cannot undo (fixed nodes inside a strong swirl)
    /// are removed by shrinking the warp around them only: a smooth shift
    /// elsewhere on the grid keeps every bit.
    #[test]
    fn stubborn_folds_shrink_the_warp_only_around_them() {
        let (w, h) = (240, 200);
        let mut lv = Level::new(w, h, vec![0; w * h], vec![255; w * h]);
        // Smooth, and vanishing at the grid's fixed border.
        let window = |i: usize, j: usize| (std::f32::consts::PI * i as f32 / (w - 1) as f32).sin() * (std::f32::consts::PI * j as f32 / (h - 1) as f32).sin();
        let shift = |i: usize, j: usize| (3.0 * window(i, j) * ((i as f32) * 0.02).cos(), 2.0 * window(i, j) * ((j as f32) * 0.03).sin());
        for j in 1..h - 1 {
            for i in 1..w - 1 {
                let (sx, sy) = shift(i, j);
                let (u, v) = (i as f32 - 50.0, j as f32 - 50.0);
                let a = 20.0 * (-(u * u + v * v) / 40.0).exp();
                lv.dx[j * w + i] = sx + u * a.cos() - v * a.sin() - u;
                lv.dy[j * w + i] = sy + u * a.sin() + v * a.cos() - v;
            }
        }
        for g in (0..w).chain((h - 1) * w..h * w).chain((0..h).flat_map(|j| [j * w, j * w + w - 1])) {
            lv.mask[g] = 0;
        }
        for j in 47..54 {
            for i in 47..54 {
                lv.mask[j * w + i] = 0;
            }
        }
        assert!(count_folds(&lv.dx, &lv.dy, w, h, 0.0) > 0);
        let before = lv.clone();
        let (passes, scale) = repair_folds(&mut lv);
        assert_eq!(count_folds(&lv.dx, &lv.dy, w, h, 0.0), 0);
        assert!(passes == 32 && scale < 1.0, "the relaxation alone must fail here: {passes}, {scale}");
        let kept = (150..h - 1).flat_map(|j| (150..w - 1).map(move |i| j * w + i)).all(|g| lv.dx[g].to_bits() == before.dx[g].to_bits() && lv.dy[g].to_bits() == before.dy[g].to_bits());
        assert!(kept, "the far corner of the grid must keep its displacements (passes {passes}, scale {scale})");
    }

    /// The row-vectorised fold count agrees with [`cell_dets`] cell by cell,
    /// on a warp with folded and nearly folded cells.
    #[test]
    fn fold_count_matches_the_cell_determinants() {
        let (w, h) = (37, 23);
        let mut dx = vec![0.0f32; w * h];
        let mut dy = vec![0.0f32; w * h];
        for (k, (x, y)) in dx.iter_mut().zip(dy.iter_mut()).enumerate() {
            let t = k as f32 * 0.7;
            *x = 0.9 * t.sin() * (k % 5) as f32 * 0.3;
            *y = 0.9 * (1.3 * t).cos() * (k % 7) as f32 * 0.2;
        }
        for margin in [0.0, FOLD_MARGIN, 0.5] {
            let naive: usize = (0..h - 1).flat_map(|j| (0..w - 1).map(move |i| (i, j))).map(|(i, j)| cell_dets(&dx, &dy, w, i, j).iter().filter(|&&d| d <= margin).count()).sum();
            assert!(naive > 0 && naive < 2 * (w - 1) * (h - 1));
            assert_eq!(count_folds(&dx, &dy, w, h, margin), naive, "margin {margin}");
        }
    }
}
