//! Rigidity and warp-mask maps and their hierarchies (seed 001 eqs. 7–8):
//! rigidity blurred with a 3×3 Gaussian per level, mask eroded by a 3×3
//! minimum per level, each then reduced 2×2 to the next level's size. Also
//! the 2×2 averaging of surface metrics for the coarse levels.

use rayon::prelude::*;

use crate::{Error, Result};

/// Checks an image given as a flat `(height, width)` array of values in [0, 1].
pub fn check_image(what: &str, udim: u32, values: &[f32], width: usize, height: usize) -> Result<()> {
    if values.len() != width * height {
        return Err(Error::invalid(format!(
            "{what} for UDIM tile {udim} has {} values but the warp grid is {width}×{height} = {} texels (expected an array of shape (height={height}, width={width}))",
            values.len(),
            width * height
        )));
    }
    if let Some(i) = values.iter().position(|v| !v.is_finite() || *v < 0.0 || *v > 1.0) {
        return Err(Error::invalid(format!(
            "{what} for UDIM tile {udim}: texel (row {}, column {}) is {}, but values must be finite and in [0, 1]",
            i / width,
            i % width,
            values[i]
        )));
    }
    Ok(())
}

pub fn quantise(values: &[f32]) -> Vec<u8> {
    values.par_iter().map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect()
}

/// 3×3 Gaussian (1 2 1 ⊗ 1 2 1 / 16), edges replicated.
pub fn gaussian3(src: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = vec![0.0; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let ys = [y.saturating_sub(1), y, (y + 1).min(h - 1)];
        for x in 0..w {
            let xs = [x.saturating_sub(1), x, (x + 1).min(w - 1)];
            let mut s = 0.0;
            for (a, &yy) in ys.iter().enumerate() {
                for (b, &xx) in xs.iter().enumerate() {
                    s += src[yy * w + xx] * [1.0, 2.0, 1.0][a] * [1.0, 2.0, 1.0][b];
                }
            }
            row[x] = s / 16.0;
        }
    });
    out
}

/// 2×2 average to half size.
pub fn reduce_mean(src: &[f32], w: usize, h: usize) -> Vec<f32> {
    let (cw, ch) = (w / 2, h / 2);
    let mut out = vec![0.0; cw * ch];
    out.par_chunks_mut(cw).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let i = 2 * y * w + 2 * x;
            *o = 0.25 * (src[i] + src[i + 1] + src[i + w] + src[i + w + 1]);
        }
    });
    out
}

/// 3×3 minimum (erosion); outside the grid counts as 0 (fixed).
pub fn erode3(src: &[u8], w: usize, h: usize) -> Vec<u8> {
    let mut out = vec![0u8; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for x in 0..w {
            if x == 0 || y == 0 || x + 1 == w || y + 1 == h {
                row[x] = 0;
                continue;
            }
            let mut m = 255u8;
            for yy in y - 1..=y + 1 {
                for xx in x - 1..=x + 1 {
                    m = m.min(src[yy * w + xx]);
                }
            }
            row[x] = m;
        }
    });
    out
}

/// 2×2 minimum to half size.
pub fn reduce_min(src: &[u8], w: usize, h: usize) -> Vec<u8> {
    let (cw, ch) = (w / 2, h / 2);
    let mut out = vec![0u8; cw * ch];
    out.par_chunks_mut(cw).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let i = 2 * y * w + 2 * x;
            *o = src[i].min(src[i + 1]).min(src[i + w]).min(src[i + w + 1]);
        }
    });
    out
}

/// 2×2 average of metrics looked up through `ids` (or directly when `ids` is
/// `None`), ignoring texels with no surface (zero metric).
pub fn reduce_metric(table: &[[f32; 3]], ids: Option<&[u32]>, w: usize, h: usize) -> Vec<[f32; 3]> {
    let mut out = Vec::new();
    reduce_metric_into(table, ids, w, h, &mut out);
    out
}

/// [`reduce_metric`] into `out`, whose allocation is reused (the solver
/// reduces the deformed metric every frame).
pub fn reduce_metric_into(table: &[[f32; 3]], ids: Option<&[u32]>, w: usize, h: usize, out: &mut Vec<[f32; 3]>) {
    let (cw, ch) = (w / 2, h / 2);
    out.clear();
    out.resize(cw * ch, [0.0f32; 3]);
    let get = |i: usize| match ids {
        Some(ids) => table[ids[i] as usize],
        None => table[i],
    };
    out.par_chunks_mut(cw).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let i = 2 * y * w + 2 * x;
            let mut s = [0.0f32; 3];
            let mut n = 0.0f32;
            for j in [i, i + 1, i + w, i + w + 1] {
                let g = get(j);
                if g[0] + g[2] > 0.0 {
                    s[0] += g[0];
                    s[1] += g[1];
                    s[2] += g[2];
                    n += 1.0;
                }
            }
            if n > 0.0 {
                *o = [s[0] / n, s[1] / n, s[2] / n];
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erosion_shrinks_and_reduction_keeps_fixed_texels_fixed() {
        let (w, h) = (8, 8);
        let mut m = vec![255u8; w * h];
        m[3 * w + 4] = 0;
        let e = erode3(&m, w, h);
        assert_eq!(e[2 * w + 3], 0);
        assert_eq!(e[4 * w + 5], 0);
        assert_eq!(e[7 * w + 6], 0, "the grid edge ring is fixed");
        assert_eq!(e[5 * w + 2], 255);
        let r = reduce_min(&e, w, h);
        assert_eq!(r[w / 2 + 2], 0);
    }

    #[test]
    fn gaussian_preserves_constants_and_mass_in_interior() {
        let (w, h) = (6, 5);
        let g = gaussian3(&vec![0.7; w * h], w, h);
        assert!(g.iter().all(|v| (v - 0.7).abs() < 1e-6));
        let mut d = vec![0.0; w * h];
        d[2 * w + 2] = 16.0;
        let g = gaussian3(&d, w, h);
        assert!((g[2 * w + 2] - 4.0).abs() < 1e-6 && (g[w + 1] - 1.0).abs() < 1e-6);
        assert!((g.iter().sum::<f32>() - 16.0).abs() < 1e-5);
    }
}
