//! Watertight triangle rasterisation at texel centres.
//!
//! Coordinates are in texel units of a grid: texel `(x, y)` (column `x`, row
//! `y`) has its centre at `(x + 0.5, y + 0.5)`; row 0 is `v ∈ [0, 1/height)`.
//! Vertices are snapped to a fixed-point lattice of 1/2^[`SUB_BITS`] texel and
//! edge functions are evaluated exactly in `i64`, with a top-left rule for
//! samples lying exactly on an edge. Two triangles that share an edge (same
//! two vertices) therefore never both claim a texel and never both miss one:
//! every texel centre inside a watertight triangulation is covered exactly once.

/// Sub-texel bits of the fixed-point lattice.
pub const SUB_BITS: u32 = 12;
const ONE: i64 = 1 << SUB_BITS;
const HALF: i64 = ONE / 2;
/// Coordinates are clamped to ±2^18 texels before snapping so that products of
/// edge vectors stay far inside `i64` (2 · 2^31 · 2^31 < 2^63).
const LIMIT: f64 = (1u64 << 18) as f64;

#[inline]
fn snap(v: f64) -> i64 {
    (v.clamp(-LIMIT, LIMIT) * ONE as f64).round() as i64
}

/// A triangle prepared for rasterisation: snapped, counter-clockwise.
#[derive(Debug, Clone, Copy)]
pub struct Prepared {
    v: [[i64; 2]; 3],
    /// `order[k]` = which input vertex sits at prepared slot `k`.
    order: [usize; 3],
    area2: i64,
}

impl Prepared {
    /// Snaps and orients a triangle; `None` when its snapped area is zero.
    #[inline]
    pub fn new(p: [[f64; 2]; 3]) -> Option<Self> {
        let mut v = [[snap(p[0][0]), snap(p[0][1])], [snap(p[1][0]), snap(p[1][1])], [snap(p[2][0]), snap(p[2][1])]];
        let mut order = [0, 1, 2];
        let mut area2 = (v[1][0] - v[0][0]) * (v[2][1] - v[0][1]) - (v[1][1] - v[0][1]) * (v[2][0] - v[0][0]);
        if area2 == 0 {
            return None;
        }
        if area2 < 0 {
            v.swap(1, 2);
            order.swap(1, 2);
            area2 = -area2;
        }
        Some(Prepared { v, order, area2 })
    }

    /// Inclusive texel bounds `(x0, x1, y0, y1)` of the centres that may be
    /// inside, before clipping.
    #[inline]
    pub fn texel_bounds(&self) -> (i64, i64, i64, i64) {
        let minx = self.v.iter().map(|p| p[0]).min().unwrap_or(0);
        let maxx = self.v.iter().map(|p| p[0]).max().unwrap_or(0);
        let miny = self.v.iter().map(|p| p[1]).min().unwrap_or(0);
        let maxy = self.v.iter().map(|p| p[1]).max().unwrap_or(0);
        // centre c = x*ONE + HALF; need minx <= c <= maxx
        let lo = |m: i64| (m - HALF + ONE - 1).div_euclid(ONE);
        let hi = |m: i64| (m - HALF).div_euclid(ONE);
        (lo(minx), hi(maxx), lo(miny), hi(maxy))
    }

    /// Calls `f(x, y, bary)` for every texel centre inside the triangle with
    /// `x ∈ [0, width)` and `y ∈ rows`. `bary[k]` is the weight of input vertex `k`.
    #[inline]
    pub fn for_each(&self, width: usize, rows: std::ops::Range<usize>, mut f: impl FnMut(usize, usize, [f32; 3])) {
        let (x0, x1, y0, y1) = self.texel_bounds();
        let x0 = x0.max(0);
        let x1 = x1.min(width as i64 - 1);
        let y0 = y0.max(rows.start as i64);
        let y1 = y1.min(rows.end as i64 - 1);
        if x0 > x1 || y0 > y1 {
            return;
        }
        let v = &self.v;
        // Edge k goes from v[k+1] to v[k+2]; its function is the weight of v[k].
        let mut a = [0i64; 3];
        let mut b = [0i64; 3];
        let mut bias = [0i64; 3];
        for k in 0..3 {
            let p = v[(k + 1) % 3];
            let q = v[(k + 2) % 3];
            let dx = q[0] - p[0];
            let dy = q[1] - p[1];
            // E(s) = dx*(s.y - p.y) - dy*(s.x - p.x) ≥ 0 inside (counter-clockwise).
            a[k] = -dy;
            b[k] = dx;
            // Top-left rule: a sample exactly on the edge belongs to the
            // triangle only if the edge is a "left" (going down) or "top"
            // (horizontal, going left) edge. Opposite directions disagree, so
            // a shared edge is owned by exactly one side.
            let owns = dy < 0 || (dy == 0 && dx < 0);
            bias[k] = if owns { 0 } else { -1 };
        }
        let inv_area = 1.0 / self.area2 as f64;
        for y in y0..=y1 {
            let sy = y * ONE + HALF;
            let sx0 = x0 * ONE + HALF;
            let mut e = [0i64; 3];
            for k in 0..3 {
                let p = v[(k + 1) % 3];
                e[k] = b[k] * (sy - p[1]) + a[k] * (sx0 - p[0]);
            }
            for x in x0..=x1 {
                if e[0] + bias[0] >= 0 && e[1] + bias[1] >= 0 && e[2] + bias[2] >= 0 {
                    let mut bary = [0f32; 3];
                    for k in 0..3 {
                        bary[self.order[k]] = (e[k] as f64 * inv_area) as f32;
                    }
                    f(x as usize, y as usize, bary);
                }
                for k in 0..3 {
                    e[k] += a[k] * ONE;
                }
            }
        }
    }
}

/// Barycentric coordinates of `p` with respect to triangle `t` (extrapolated
/// outside it); `None` for a degenerate triangle.
#[inline]
pub fn barycentric(t: [[f64; 2]; 3], p: [f64; 2]) -> Option<[f64; 3]> {
    let d = (t[1][0] - t[0][0]) * (t[2][1] - t[0][1]) - (t[1][1] - t[0][1]) * (t[2][0] - t[0][0]);
    if d.abs() < 1e-300 {
        return None;
    }
    let w1 = ((p[0] - t[0][0]) * (t[2][1] - t[0][1]) - (p[1] - t[0][1]) * (t[2][0] - t[0][0])) / d;
    let w2 = ((t[1][0] - t[0][0]) * (p[1] - t[0][1]) - (t[1][1] - t[0][1]) * (p[0] - t[0][0])) / d;
    Some([1.0 - w1 - w2, w1, w2])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn coverage(tris: &[[[f64; 2]; 3]], w: usize, h: usize) -> Vec<u32> {
        let mut count = vec![0u32; w * h];
        for t in tris {
            if let Some(p) = Prepared::new(*t) {
                p.for_each(w, 0..h, |x, y, bary| {
                    assert!((bary.iter().sum::<f32>() - 1.0).abs() < 1e-5);
                    assert!(bary.iter().all(|&b| (-1e-6..=1.0 + 1e-6).contains(&b)));
                    count[y * w + x] += 1;
                });
            }
        }
        count
    }

    #[test]
    fn fan_of_triangles_through_texel_centres_covers_every_texel_once() {
        // A fan around a vertex placed exactly on a texel centre, with edges
        // through texel centres: the hardest case for tie-breaking.
        let c = [8.5, 8.5];
        let ring = [[0.5, 0.5], [8.5, 0.5], [16.0, 0.0], [16.0, 8.5], [16.0, 16.0], [8.5, 16.0], [0.0, 16.0], [0.0, 8.5]];
        let mut tris = Vec::new();
        for i in 0..ring.len() {
            tris.push([c, ring[i], ring[(i + 1) % ring.len()]]);
        }
        let count = coverage(&tris, 16, 16);
        // The polygon's boundary passes through the centres of row 0 and
        // column 0 only partially; check the strict interior.
        for y in 1..16 {
            for x in 1..16 {
                assert_eq!(count[y * 16 + x], 1, "texel ({x}, {y})");
            }
        }
        assert!(count.iter().all(|&c| c <= 1));
    }

    #[test]
    fn random_triangulated_grid_is_watertight() {
        // A jittered grid of vertices, both triangle orientations mixed.
        let n = 9;
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 33) as f64 / (1u64 << 31) as f64) - 0.5
        };
        let mut pts = vec![[0.0; 2]; (n + 1) * (n + 1)];
        for j in 0..=n {
            for i in 0..=n {
                let jitter = i > 0 && i < n && j > 0 && j < n;
                let (jx, jy) = if jitter { (rnd() * 2.0, rnd() * 2.0) } else { (0.0, 0.0) };
                pts[j * (n + 1) + i] = [i as f64 * 4.0 + jx, j as f64 * 4.0 + jy];
            }
        }
        let mut tris = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let a = pts[j * (n + 1) + i];
                let b = pts[j * (n + 1) + i + 1];
                let c = pts[(j + 1) * (n + 1) + i + 1];
                let d = pts[(j + 1) * (n + 1) + i];
                if (i + j) % 2 == 0 {
                    tris.push([a, b, c]);
                    tris.push([a, d, c]); // clockwise on purpose
                } else {
                    tris.push([a, b, d]);
                    tris.push([b, c, d]);
                }
            }
        }
        let count = coverage(&tris, 36, 36);
        assert!(count.iter().all(|&c| c == 1), "{:?}", count.iter().enumerate().filter(|(_, &c)| c != 1).collect::<Vec<_>>());
    }
}
