//! Inversion of the warp (seed 001 §5, eq. 9): the warped grid's triangles
//! are rasterised at texel centres carrying the nodes' original coordinates,
//! giving the "UV redirection" texture: for a surface point whose UV is `t`,
//! sample the texture at `redirection(t)`.
//!
//! Nodes sit at texel centres, so where a node has not moved its texel maps to
//! itself; the output is first filled with the identity and only cells with a
//! moved corner are rasterised. Output rows are split into bands processed in
//! parallel; each band rasterises the cell rows whose warped extent reaches
//! it and writes only its own rows, and the top-left rule gives every texel
//! centre to exactly one triangle — the result does not depend on threads.

use glam::Vec2;
use rayon::prelude::*;

use super::raster::Prepared;

const BAND: usize = 64;

/// Writes the redirection (absolute UVs, interleaved `u, v`, row 0 = lowest
/// `v`) of a `w × h` tile whose lower-left corner is at `offset`.
pub fn invert(dx: &[f32], dy: &[f32], w: usize, h: usize, offset: Vec2, out: &mut [f32]) {
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
