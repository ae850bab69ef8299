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

/// Walk steps before the local search takes over (never needed on fold-free
/// warps of the test fixtures; a safety net for pathological ones).
const MAX_WALK: usize = 48;
/// A centre this far outside a triangle (in barycentric units) still counts as
/// inside: it lies on the shared edge, where both sides interpolate the same.
const EDGE_TOLERANCE: f32 = 1e-5;

/// Writes the redirection (absolute UVs, interleaved `u, v`, row 0 = lowest
/// `v`) of a `w × h` tile whose lower-left corner is at `offset`.
pub fn invert(dx: &[f32], dy: &[f32], w: usize, h: usize, offset: Vec2, out: &mut [f32]) {
    let (sw, sh) = (1.0 / w as f64, 1.0 / h as f64);
    out.par_chunks_mut(2 * w * GATHER_ROWS).enumerate().for_each(|(band, chunk)| {
        let r0 = band * GATHER_ROWS;
        for (k, row) in chunk.chunks_mut(2 * w).enumerate() {
            let y = r0 + k;
            for x in 0..w {
                let n = y * w + x;
                let (u, v) = if dx[n] == 0.0 && dy[n] == 0.0 {
                    (x as i32 as f64, y as i32 as f64)
                } else {
                    let (u, v) = locate(dx, dy, w, h, x, y);
                    (u as f64, v as f64)
                };
                row[2 * x] = offset.x + ((u + 0.5) * sw) as f32;
                row[2 * x + 1] = offset.y + ((v + 0.5) * sh) as f32;
            }
        }
    });
}

const GATHER_ROWS: usize = 8;

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

/// The warped triangles of cell `(ci, cj)` and their weights for the texel
/// centre `(x, y)` (node-lattice coordinates: node `(i, j)` rests at `(i, j)`):
/// `[lower-right (a, b, c), upper-left (a, c, d)]`.
#[inline(always)]
fn cell_weights(dx: &[f32], dy: &[f32], w: usize, ci: usize, cj: usize, x: usize, y: usize) -> [Option<[f32; 3]>; 2] {
    let a = cj * w + ci;
    let (b, c, d) = (a + 1, a + w + 1, a + w);
    // Relative to the cell's rest corner, so that everything is O(1) and f32 is exact enough at 16384².
    let pa = (dx[a], dy[a]);
    let pb = (1.0 + dx[b], dy[b]);
    let pc = (1.0 + dx[c], 1.0 + dy[c]);
    let pd = (dx[d], 1.0 + dy[d]);
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

/// Finds the warped triangle holding the centre of texel `(x, y)`; returns the
/// rest coordinates there. Inside tests use unnormalised edge functions
/// (compared with a tolerance scaled by the area), so the only division is the
/// one of the triangle finally taken.
#[inline]
fn locate(dx: &[f32], dy: &[f32], w: usize, h: usize, x: usize, y: usize) -> (f32, f32) {
    let n = y * w + x;
    // Grid coordinates fit in i32 (sides up to 16384), and conversions
    // between f32 and i32 are one instruction, those with usize a branchy
    // sequence (no unsigned 64-bit conversions before AVX-512).
    let (xf, yf) = (x as i32 as f32, y as i32 as f32);
    // Truncation is the floor once negatives are clamped to 0 (and unlike
    // `floor`, not a libm call without SSE4.1); NaN truncates to 0.
    let clamp_cell = |v: f32, hi: usize| (v as i32).clamp(0, hi as i32) as usize;
    // First guess: the rest position the texel's own node displacement points back to.
    let (mut ci, mut cj) = (clamp_cell(xf - dx[n], w - 2), clamp_cell(yf - dy[n], h - 2));
    let cross = |o: (f32, f32), u: (f32, f32), v: (f32, f32)| (u.0 - o.0) * (v.1 - o.1) - (u.1 - o.1) * (v.0 - o.0);
    for _ in 0..MAX_WALK {
        let a = cj * w + ci;
        let (b, c, d) = (a + 1, a + w + 1, a + w);
        // Relative to the cell's rest corner, so that everything is O(1) and f32 is exact enough at 16384².
        let pa = (dx[a], dy[a]);
        let pb = (1.0 + dx[b], dy[b]);
        let pc = (1.0 + dx[c], 1.0 + dy[c]);
        let pd = (dx[d], 1.0 + dy[d]);
        let p = (xf - ci as i32 as f32, yf - cj as i32 as f32);
        // Lower-right triangle (a, b, c): edge functions = weights × area.
        let area0 = cross(pa, pb, pc);
        let (ea, eb) = (cross(pb, pc, p), cross(pc, pa, p));
        let ec = area0 - ea - eb;
        let tol0 = -EDGE_TOLERANCE * area0;
        if area0 > 0.0 && ea >= tol0 && eb >= tol0 && ec >= tol0 {
            let inv = 1.0 / area0;
            return rest_point(ci, cj, 0, [ea * inv, eb * inv, ec * inv]);
        }
        // Upper-left triangle (a, c, d).
        let area1 = cross(pa, pc, pd);
        let (fa, fc) = (cross(pc, pd, p), cross(pd, pa, p));
        let fd = area1 - fa - fc;
        let tol1 = -EDGE_TOLERANCE * area1;
        if area1 > 0.0 && fa >= tol1 && fc >= tol1 && fd >= tol1 {
            let inv = 1.0 / area1;
            return rest_point(ci, cj, 1, [fa * inv, fc * inv, fd * inv]);
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
        let nx = (ci as i64 + sx).clamp(0, w as i64 - 2) as usize;
        let ny = (cj as i64 + sy).clamp(0, h as i64 - 2) as usize;
        if (nx, ny) == (ci, cj) {
            break;
        }
        (ci, cj) = (nx, ny);
    }
    search(dx, dy, w, h, x, y, (ci, cj))
}

/// Fallback of [`locate`]: the best triangle of the cells around `around`
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
