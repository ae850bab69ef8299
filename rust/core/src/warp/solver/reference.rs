//! The reference path: one constraint at a time through float midpoints.
//! The fast sweeps ([`crate::warp::sweep`]) reproduce its arithmetic bit for
//! bit; it alone serves `sample_warped` and per-chart metric look-ups.

use rayon::prelude::*;

use super::Level;
use crate::warp::{WarpSettings, RELAXATION};

/// How a level finds the metric of a texel.
pub(super) trait Lookup: Sync + Copy {
    fn at(&self, texel: usize) -> usize;
    /// Whether two metric entries belong to the same UV chart.
    fn same_chart(&self, a: usize, b: usize) -> bool;
}
#[derive(Clone, Copy)]
pub(super) struct Direct;
impl Lookup for Direct {
    #[inline(always)]
    fn at(&self, texel: usize) -> usize {
        texel
    }
    #[inline(always)]
    fn same_chart(&self, a: usize, b: usize) -> bool {
        a == b
    }
}
#[derive(Clone, Copy)]
pub(super) struct Indexed<'a>(pub(super) &'a [u32], pub(super) &'a [u32]);
impl Lookup for Indexed<'_> {
    #[inline(always)]
    fn at(&self, texel: usize) -> usize {
        self.0[texel] as usize
    }
    #[inline(always)]
    fn same_chart(&self, a: usize, b: usize) -> bool {
        self.1[a] == self.1[b]
    }
}

pub(super) struct Ctx<'a, L: Lookup> {
    w: usize,
    h: usize,
    rig: &'a [u8],
    mask: &'a [u8],
    look: L,
    go: &'a [[f32; 3]],
    gd: &'a [[f32; 3]],
    orientation: f32,
    sample_warped: bool,
}

impl<L: Lookup> Ctx<'_, L> {
    /// Projects the constraint between local nodes `la`, `lb` (global `ga`,
    /// `gb`) whose rest segment is `(ex, ey)`; node a's centre is `(ax, ay)`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn project(&self, dx: &mut [f32], dy: &mut [f32], la: usize, lb: usize, ga: usize, gb: usize, ex: f32, ey: f32, ax: f32, ay: f32) {
        let k8 = self.rig[ga].max(self.rig[gb]);
        if k8 == 0 {
            return;
        }
        // Inverse masses: the mask value, and rigid nodes 10× heavier than
        // elastic ones so that at a feature's edge the elastic side yields.
        let ma = self.mask[ga] as f32 * (1.0 - 0.9 / 255.0 * self.rig[ga] as f32);
        let mb = self.mask[gb] as f32 * (1.0 - 0.9 / 255.0 * self.rig[gb] as f32);
        let ms = ma + mb;
        if ms == 0.0 {
            return;
        }
        let k = k8 as f32 * (1.0 / 255.0);
        let (dax, day, dbx, dby) = (dx[la], dy[la], dx[lb], dy[lb]);
        let vx = ex + dbx - dax;
        let vy = ey + dby - day;
        let mx = ax + 0.5 * (ex + dax + dbx);
        let my = ay + 0.5 * (ey + day + dby);
        let ix = (mx.max(0.0) as usize).min(self.w - 1);
        let iy = (my.max(0.0) as usize).min(self.h - 1);
        // Rest length: the rest metric at the rest midpoint's texel, found by
        // the same rule as the deformed one, so that rest = deformed gives
        // exactly the identity.
        let rx = ((ax + 0.5 * ex).max(0.0) as usize).min(self.w - 1);
        let ry = ((ay + 0.5 * ey).max(0.0) as usize).min(self.h - 1);
        let rest_id = self.look.at(ry * self.w + rx);
        // Deformed length: the deformed surface where the warped segment now
        // lies (seed eq. 1: f_D(W(p))), as long as that is the same UV chart;
        // across a chart border (or on coarse levels, whose averaged metrics
        // know no charts) the surface under the rest midpoint is used.
        let g = if self.sample_warped {
            let warped_id = self.look.at(iy * self.w + ix);
            if self.look.same_chart(warped_id, rest_id) {
                self.gd[warped_id]
            } else {
                self.gd[rest_id]
            }
        } else {
            self.gd[rest_id]
        };
        let ld2 = g[0] * vx * vx + 2.0 * g[1] * vx * vy + g[2] * vy * vy;
        let o = self.go[rest_id];
        let l02 = o[0] * ex * ex + 2.0 * o[1] * ex * ey + o[2] * ey * ey;
        if !(l02 > 0.0) || !(ld2 > l02 * 1e-6) {
            return;
        }
        let ratio = (l02 / ld2).sqrt().clamp(0.25, 4.0);
        let s = 1.0 + RELAXATION * k * (ratio - 1.0);
        let (mut tx, mut ty) = (vx * s, vy * s);
        if self.orientation > 0.0 {
            // The blend of the unit directions, `t/|t|·(1−o) + e/|e|·o`, scaled
            // by `|t|` (same direction, one division fewer), then set to length `|t|`.
            let o = self.orientation * k;
            let t2 = tx * tx + ty * ty;
            let len = t2.sqrt();
            let el = (ex * ex + ey * ey).sqrt();
            let (ux, uy) = (tx * (1.0 - o) + ex / el * (o * len), ty * (1.0 - o) + ey / el * (o * len));
            let u2 = ux * ux + uy * uy;
            if len > 1e-12 && u2 > 1e-24 * t2 {
                let f = (t2 / u2).sqrt();
                tx = ux * f;
                ty = uy * f;
            }
        }
        let (cx, cy) = (tx - vx, ty - vy);
        let (fa, fb) = (ma / ms, mb / ms);
        dx[la] -= cx * fa;
        dy[la] -= cy * fa;
        dx[lb] += cx * fb;
        dy[lb] += cy * fb;
    }

    /// Phase A on rows `j`, `j+1` (`rows` = 1 or 2 rows held in `dx`, `dy`).
    fn phase_a(&self, j: usize, rows: usize, dx: &mut [f32], dy: &mut [f32]) {
        let w = self.w;
        for r in 0..rows {
            let y = (j + r) as f32 + 0.5;
            for parity in 0..2 {
                let mut i = parity;
                while i + 1 < w {
                    let (l, g) = (r * w + i, (j + r) * w + i);
                    self.project(dx, dy, l, l + 1, g, g + 1, 1.0, 0.0, i as f32 + 0.5, y);
                    i += 2;
                }
            }
        }
        if rows == 2 {
            self.between(j, dx, dy);
        }
    }

    /// Vertical and both diagonal sets between rows `j` and `j+1`.
    fn between(&self, j: usize, dx: &mut [f32], dy: &mut [f32]) {
        let w = self.w;
        let y = j as f32 + 0.5;
        let g0 = j * w;
        for i in 0..w {
            self.project(dx, dy, i, w + i, g0 + i, g0 + w + i, 0.0, 1.0, i as f32 + 0.5, y);
        }
        for i in 0..w - 1 {
            self.project(dx, dy, i, w + i + 1, g0 + i, g0 + w + i + 1, 1.0, 1.0, i as f32 + 0.5, y);
        }
        for i in 0..w - 1 {
            self.project(dx, dy, i + 1, w + i, g0 + i + 1, g0 + w + i, -1.0, 1.0, i as f32 + 1.5, y);
        }
    }
}


/// The reference iteration: one constraint at a time, through float
/// midpoints (needed for `sample_warped`, and the yardstick of [`sweep`]).
pub(super) fn iterate_reference<L: Lookup>(lv: &mut Level, look: L, go: &[[f32; 3]], gd: &[[f32; 3]], n: usize, s: &WarpSettings) {
    let (w, h) = (lv.w, lv.h);
    for _ in 0..n {
        {
            let ctx = Ctx { w, h, rig: &lv.rig, mask: &lv.mask, look, go, gd, orientation: s.orientation, sample_warped: s.sample_warped };
            let active = &lv.active;
            lv.dx.par_chunks_mut(2 * w).zip(lv.dy.par_chunks_mut(2 * w)).enumerate().for_each(|(p, (cx, cy))| {
                let j = 2 * p;
                let rows = cx.len() / w;
                if active.any(j, false) || (rows == 2 && active.any(j + 1, false)) {
                    ctx.phase_a(j, rows, cx, cy);
                }
            });
            lv.dx[w..].par_chunks_mut(2 * w).zip(lv.dy[w..].par_chunks_mut(2 * w)).enumerate().for_each(|(p, (cx, cy))| {
                let j = 2 * p + 1;
                if cx.len() == 2 * w && active.any(j, true) {
                    ctx.between(j, cx, cy);
                }
            });
        }
        regularise_reference(lv, s.smoothing);
        std::mem::swap(&mut lv.dx, &mut lv.sx);
        std::mem::swap(&mut lv.dy, &mut lv.sy);
    }
}

/// The reference regularisation (see [`regularise`]).
pub(super) fn regularise_reference(lv: &mut Level, smoothing: f32) {
    let (w, h) = (lv.w, lv.h);
    let (dx, dy, rig, mask) = (&lv.dx, &lv.dy, &lv.rig, &lv.mask);
    lv.sx.par_chunks_mut(w).zip(lv.sy.par_chunks_mut(w)).enumerate().for_each(|(y, (ox, oy))| {
        let row = y * w;
        if y == 0 || y + 1 == h {
            ox.copy_from_slice(&dx[row..row + w]);
            oy.copy_from_slice(&dy[row..row + w]);
            return;
        }
        ox[0] = dx[row];
        oy[0] = dy[row];
        ox[w - 1] = dx[row + w - 1];
        oy[w - 1] = dy[row + w - 1];
        for x in 1..w - 1 {
            let g = row + x;
            let m = mask[g];
            if m == 0 {
                ox[x] = dx[g];
                oy[x] = dy[g];
                continue;
            }
            let r = rig[g] as f32 * (1.0 / 255.0);
            let b = m as f32 * (1.0 / 255.0) * ((1.0 - r) + r * smoothing);
            let (up, dn) = (g - w, g + w);
            let gx = (dx[up - 1] + dx[up + 1] + dx[dn - 1] + dx[dn + 1] + 2.0 * (dx[up] + dx[dn] + dx[g - 1] + dx[g + 1]) + 4.0 * dx[g]) * (1.0 / 16.0);
            let gy = (dy[up - 1] + dy[up + 1] + dy[dn - 1] + dy[dn + 1] + 2.0 * (dy[up] + dy[dn] + dy[g - 1] + dy[g + 1]) + 4.0 * dy[g]) * (1.0 / 16.0);
            let nx = (1.0 - b) * dx[g] + b * gx;
            let ny = (1.0 - b) * dy[g] + b * gy;
            // Bounding box of the 8 neighbours, relative to this node's rest position.
            let bx0 = (-1.0 + dx[up - 1]).min(-1.0 + dx[g - 1]).min(-1.0 + dx[dn - 1]).min(dx[up]).min(dx[dn]);
            let bx1 = (1.0 + dx[up + 1]).max(1.0 + dx[g + 1]).max(1.0 + dx[dn + 1]).max(dx[up]).max(dx[dn]);
            let by0 = (-1.0 + dy[up - 1]).min(-1.0 + dy[up]).min(-1.0 + dy[up + 1]).min(dy[g - 1]).min(dy[g + 1]);
            let by1 = (1.0 + dy[dn - 1]).max(1.0 + dy[dn]).max(1.0 + dy[dn + 1]).max(dy[g - 1]).max(dy[g + 1]);
            ox[x] = nx.max(bx0).min(bx1);
            oy[x] = ny.max(by0).min(by1);
        }
    });
}
