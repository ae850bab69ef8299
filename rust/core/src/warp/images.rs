//! Per-texel images of mesh data over one UDIM tile, for the add-on's inputs
//! and pictures: per-corner values rasterised (rigidity from a vertex group),
//! an image resampled to the grid (a rigidity or mask image of another size)
//! and the stretch error of a warp as an image (the bake's heat map).
//!
//! Same grid convention as the rest of `warp`: `(height, width)`, row 0 = the
//! lowest v, texel `(j, i)` centred at `((i + 0.5) / width, (j + 0.5) / height)`
//! inside its tile. Unlike [`TileLayout`](super::TileLayout), whose triangle
//! ids reach past chart borders so that the solver has a surface everywhere,
//! these images are 0 where no triangle covers a texel centre: a texel outside
//! the charts carries no detail, so it is neither rigid nor stretched.

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::metrics::stretch_error;
use super::raster::{barycentric, Prepared};
use super::tiles::{check_corner_uvs, udim_offset};
use crate::error::{check_allocation, memory_limit};
use crate::mesh::{validate_positions, MeshInput};
use crate::{Error, Result};

/// "No triangle" in [`triangle_ids`].
pub const NO_TRIANGLE: u32 = u32::MAX;

/// The largest stretch error the heat map shows: `|ln σ²| / 2` for σ² = 10³⁰.
/// A folded or collapsed texel has σ = 0 (an infinite error), which an image
/// cannot hold; it gets this instead, far above any real stretch.
pub const MAX_STRETCH: f64 = 34.538_776_394_910_684;

/// Fan triangulation, in corner order, of polygons whose first-corner offsets
/// are `offsets` (polygon count + 1 entries), as [`super::UvMesh`] makes it.
fn fan(offsets: &[u32]) -> Vec<[u32; 3]> {
    let mut tris = Vec::with_capacity(offsets.last().copied().unwrap_or(0) as usize);
    for p in offsets.windows(2) {
        for k in p[0] + 1..p[1].saturating_sub(1) {
            tris.push([p[0], k, k + 1]);
        }
    }
    tris
}

/// The polygon checks of [`MeshInput::validate`] (sizes ≥ 3 adding up to the
/// corner count), with their messages, for data that has corners but no
/// vertices: one stand-in vertex that every corner uses.
fn polygon_offsets(polygon_sizes: &[i32], corners: usize) -> Result<Vec<u32>> {
    let stand_in = vec![0i32; corners];
    MeshInput { positions: &[Vec3::ZERO], corner_verts: &stand_in, polygon_sizes }.validate()
}

fn check_image_size(width: usize, height: usize) -> Result<()> {
    // Per texel: the output, a triangle id and (for the heat map) the input displacement.
    check_allocation::<[f32; 4]>(&format!("a {width}×{height} texel image"), (width as u64).saturating_mul(height as u64), memory_limit())
}

/// The corners of triangle `tri` in texel coordinates of tile `udim`
/// (texel `(i, j)` centred at `(i + 0.5, j + 0.5)`).
fn texel_triangle(corner_uvs: &[Vec2], tri: [u32; 3], udim: u32, width: usize, height: usize) -> [[f64; 2]; 3] {
    let o = udim_offset(udim);
    tri.map(|c| {
        let uv = corner_uvs[c as usize];
        [(uv.x as f64 - o.x as f64) * width as f64, (uv.y as f64 - o.y as f64) * height as f64]
    })
}

/// Index into `tris` of the triangle covering each texel centre of tile
/// `udim`, [`NO_TRIANGLE`] for none. Where triangles overlap (overlapping UV
/// islands) the later one wins; triangles sharing an edge never both claim a
/// texel (the rasteriser is watertight).
pub fn triangle_ids(corner_uvs: &[Vec2], tris: &[[u32; 3]], udim: u32, width: usize, height: usize) -> Vec<u32> {
    let mut ids = vec![NO_TRIANGLE; width * height];
    for (t, &tri) in tris.iter().enumerate() {
        if let Some(p) = Prepared::new(texel_triangle(corner_uvs, tri, udim, width, height)) {
            p.for_each(width, 0..height, |x, y, _| ids[y * width + x] = t as u32);
        }
    }
    ids
}

/// Per-corner `values` interpolated linearly over the fan-triangulated UV
/// polygons, at the texel centres of tile `udim`; 0 where no triangle is.
///
/// Coverage comes from the watertight fixed-point rasteriser; the weights are
/// recomputed in `f64` from the unsnapped corners, so a value is the exact
/// linear interpolation at the texel centre (the snapping only decides, to
/// 1/4096 texel, which triangle owns a texel on an edge), and never leaves
/// the range of its triangle's corner values.
pub fn rasterise_corner_values(corner_uvs: &[Vec2], polygon_sizes: &[i32], values: &[f32], udim: u32, width: usize, height: usize) -> Result<Vec<f32>> {
    let corners = values.len();
    check_corner_uvs(corner_uvs, corners)?;
    if let Some(c) = values.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(format!("corner_values: the value of corner {c} is not finite ({})", values[c])));
    }
    let offsets = polygon_offsets(polygon_sizes, corners)?;
    check_image_size(width, height)?;
    let tris = fan(&offsets);
    let ids = triangle_ids(corner_uvs, &tris, udim, width, height);
    let mut out = vec![0.0f32; width * height];
    if width == 0 {
        return Ok(out);
    }
    out.par_chunks_mut(width).enumerate().for_each(|(j, row)| {
        for (i, o) in row.iter_mut().enumerate() {
            let t = ids[j * width + i];
            if t == NO_TRIANGLE {
                continue;
            }
            let tri = tris[t as usize];
            let corners = texel_triangle(corner_uvs, tri, udim, width, height);
            if let Some(w) = barycentric(corners, [i as f64 + 0.5, j as f64 + 0.5]) {
                // A texel the snapped triangle covers may lie a hair outside
                // the exact one: clamped weights keep its value between the
                // corners' values (a rigidity of 1 stays ≤ 1).
                let w = w.map(|x| x.max(0.0));
                let sum = w[0] + w[1] + w[2];
                *o = ((0..3).map(|k| w[k] * values[tri[k] as usize] as f64).sum::<f64>() / sum) as f32;
            }
        }
    });
    Ok(out)
}

/// Bilinear resample of a `(src_height, src_width)` image (row 0 at the
/// bottom, pixel centres at `k + 0.5`) to the texel centres of a
/// `(height, width)` grid covering the same square; samples beyond the outer
/// pixel centres take the edge pixels' values.
pub fn resample_bilinear(pixels: &[f32], src_width: usize, src_height: usize, width: usize, height: usize) -> Result<Vec<f32>> {
    if src_width == 0 || src_height == 0 || pixels.len() != src_width * src_height {
        return Err(Error::invalid(format!(
            "pixels: expected a non-empty image of {src_height}×{src_width} = {} values, got {}",
            src_width * src_height,
            pixels.len()
        )));
    }
    check_image_size(width, height)?;
    if (src_width, src_height) == (width, height) {
        return Ok(pixels.to_vec());
    }
    // Per target column (row): the two source pixels and the weight of the second.
    let axis = |n: usize, src: usize| -> Vec<(usize, usize, f64)> {
        (0..n)
            .map(|k| {
                if src == 1 {
                    return (0, 0, 0.0);
                }
                let x = ((k as f64 + 0.5) * src as f64 / n as f64 - 0.5).clamp(0.0, (src - 1) as f64);
                let x0 = (x.floor() as usize).min(src - 2);
                (x0, x0 + 1, x - x0 as f64)
            })
            .collect()
    };
    let (xs, ys) = (axis(width, src_width), axis(height, src_height));
    let mut out = vec![0.0f32; width * height];
    if width == 0 {
        return Ok(out);
    }
    let p = |x: usize, y: usize| pixels[y * src_width + x] as f64;
    out.par_chunks_mut(width).zip(ys.par_iter()).for_each(|(row, &(y0, y1, fy))| {
        for (o, &(x0, x1, fx)) in row.iter_mut().zip(&xs) {
            let bottom = p(x0, y0) * (1.0 - fx) + p(x1, y0) * fx;
            let top = p(x0, y1) * (1.0 - fx) + p(x1, y1) * fx;
            *o = (bottom * (1.0 - fy) + top * fy) as f32;
        }
    });
    Ok(out)
}

/// `d position / d uv` (3×2, columns ∂/∂u and ∂/∂v) of every triangle, and
/// whether the triangle has UV area. A triangle without UV area gets the
/// edge vectors themselves (it covers no texel of any grid, so whatever it
/// holds is never read).
fn jacobians(positions: &[Vec3], corner_verts: &[i32], corner_uvs: &[Vec2], tris: &[[u32; 3]]) -> Vec<([[f64; 2]; 3], bool)> {
    tris.par_iter()
        .map(|tri| {
            let x = tri.map(|c| positions[corner_verts[c as usize] as usize].as_dvec3());
            let p = tri.map(|c| corner_uvs[c as usize].as_dvec2());
            let (e1, e2) = (x[1] - x[0], x[2] - x[0]);
            let (t1, t2) = (p[1] - p[0], p[2] - p[0]);
            let det = t1.x * t2.y - t2.x * t1.y;
            let ok = det.abs() > 1e-14;
            let d = if ok { det } else { 1.0 };
            // [e1 e2] · [t1 t2]⁻¹, with [t1 t2]⁻¹ = [[t2.y, −t2.x], [−t1.y, t1.x]] / det.
            let (a, b, c, e) = (t2.y / d, -t2.x / d, -t1.y / d, t1.x / d);
            let j = [0, 1, 2].map(|r| [e1[r] * a + e2[r] * c, e1[r] * b + e2[r] * e]);
            (j, ok)
        })
        .collect()
}

/// First fundamental form `[g00, g01, g11]` of `J` (3×2): `Jᵀ J`.
fn metric(j: &[[f64; 2]; 3]) -> [f64; 3] {
    let dot = |a: usize, b: usize| (0..3).map(|r| j[r][a] * j[r][b]).sum::<f64>();
    [dot(0, 0), dot(0, 1), dot(1, 1)]
}

/// One side of `np.gradient`: central differences inside, one-sided at the
/// two ends, 0 along an axis of one sample.
#[inline]
fn gradient(f: impl Fn(usize) -> f64, k: usize, n: usize) -> f64 {
    match n {
        0 | 1 => 0.0,
        _ if k == 0 => f(1) - f(0),
        _ if k == n - 1 => f(n - 1) - f(n - 2),
        _ => 0.5 * (f(k + 1) - f(k - 1)),
    }
}

/// Everything [`stretch_map`] reads.
pub struct StretchInput<'a> {
    pub rest: &'a [Vec3],
    pub deformed: &'a [Vec3],
    pub corner_verts: &'a [i32],
    pub polygon_sizes: &'a [i32],
    pub corner_uvs: &'a [Vec2],
    pub udim: u32,
    pub width: usize,
    pub height: usize,
    /// The warp's displacement of tile `udim` in texels, `(height, width, 2)`
    /// interleaved (x, y), as `UvWarp.displacement` gives it.
    pub displacement: &'a [f32],
}

/// Per-texel stretch error of texture detail under the warp, as an image.
///
/// Detail at texel centre `t` is drawn at `W(t) = t + d(t)`; it sits on the
/// rest surface at `X_rest(t)` and on the deformed surface at `X_def(W(t))`.
/// Its deformation gradient is `F = J_def(W(t)) · ∇W(t) · J_rest(t)⁻¹`, and the
/// error is [`stretch_error`] of `F` — the measure [`super::metrics::measure`]
/// aggregates over rigid texels, here for every texel inside a chart whose
/// detail lands inside a chart (0 elsewhere). `∇W` is taken by central
/// differences over the whole grid (one-sided on its border), `W(t)` is looked
/// up at the nearest texel. Capped at [`MAX_STRETCH`]; never NaN.
pub fn stretch_map(s: &StretchInput<'_>) -> Result<Vec<f32>> {
    let offsets = MeshInput { positions: s.rest, corner_verts: s.corner_verts, polygon_sizes: s.polygon_sizes }.validate()?;
    if s.deformed.len() != s.rest.len() {
        return Err(Error::Topology(format!(
            "deformed_positions has {} vertices but rest_positions has {}",
            s.deformed.len(),
            s.rest.len()
        )));
    }
    validate_positions("deformed_positions", s.deformed)?;
    check_corner_uvs(s.corner_uvs, s.corner_verts.len())?;
    check_image_size(s.width, s.height)?;
    let (w, h) = (s.width, s.height);
    if s.displacement.len() != 2 * w * h {
        return Err(Error::invalid(format!(
            "displacement has {} values but the grid is {w}×{h} (expected an array of shape (height={h}, width={w}, 2))",
            s.displacement.len()
        )));
    }
    if let Some(k) = s.displacement.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(format!(
            "displacement: texel (row {}, column {}) is not finite ({})",
            k / 2 / w.max(1),
            k / 2 % w.max(1),
            s.displacement[k]
        )));
    }
    let tris = fan(&offsets);
    let rest = jacobians(s.rest, s.corner_verts, s.corner_uvs, &tris);
    let deformed = jacobians(s.deformed, s.corner_verts, s.corner_uvs, &tris);
    let ids = triangle_ids(s.corner_uvs, &tris, s.udim, w, h);
    let mut out = vec![0.0f32; w * h];
    if w == 0 {
        return Ok(out);
    }
    // Warped position of texel (i, j) in texel-index units.
    let wx = |i: usize, j: usize| i as f64 + s.displacement[2 * (j * w + i)] as f64;
    let wy = |i: usize, j: usize| j as f64 + s.displacement[2 * (j * w + i) + 1] as f64;
    out.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
        for (i, o) in row.iter_mut().enumerate() {
            let here = ids[j * w + i];
            if here == NO_TRIANGLE {
                continue;
            }
            // Nearest texel to W(t), ties to even as numpy's rint.
            let near = |v: f64, n: usize| (v.round_ties_even().max(0.0) as usize).min(n - 1);
            let landed = ids[near(wy(i, j), h) * w + near(wx(i, j), w)];
            if landed == NO_TRIANGLE {
                continue;
            }
            let (j_rest, ok_rest) = &rest[here as usize];
            let g_rest = metric(j_rest);
            let det_g = g_rest[0] * g_rest[2] - g_rest[1] * g_rest[1];
            // Same threshold as a degenerate 3D triangle in the rest pose.
            if !*ok_rest || !(det_g > 1e-20) {
                continue;
            }
            // ∇W, columns ∂W/∂x and ∂W/∂y.
            let grad = [
                [gradient(|k| wx(k, j), i, w), gradient(|k| wx(i, k), j, h)],
                [gradient(|k| wy(k, j), i, w), gradient(|k| wy(i, k), j, h)],
            ];
            let j_def = &deformed[landed as usize].0;
            // m = J_def · ∇W (3×2): detail → deformed surface.
            let m = [0, 1, 2].map(|r| [0, 1].map(|c| j_def[r][0] * grad[0][c] + j_def[r][1] * grad[1][c]));
            if let Some(e) = stretch_error(metric(&m), g_rest) {
                *o = e.min(MAX_STRETCH) as f32;
            }
        }
    });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One quad over the square [u0, u1] × [v0, v1] of tile 1001.
    fn quad(u0: f32, v0: f32, u1: f32, v1: f32) -> Vec<Vec2> {
        vec![Vec2::new(u0, v0), Vec2::new(u1, v0), Vec2::new(u1, v1), Vec2::new(u0, v1)]
    }

    #[test]
    fn corner_values_interpolate_linearly_and_are_zero_outside() {
        let (w, h) = (16, 8);
        let uvs = quad(0.25, 0.25, 0.75, 0.75);
        // u as the value: a linear function, reproduced exactly by both triangles.
        let values: Vec<f32> = uvs.iter().map(|uv| uv.x).collect();
        let img = rasterise_corner_values(&uvs, &[4], &values, 1001, w, h).unwrap();
        for j in 0..h {
            for i in 0..w {
                let (u, v) = ((i as f32 + 0.5) / w as f32, (j as f32 + 0.5) / h as f32);
                let inside = (0.25..=0.75).contains(&u) && (0.25..=0.75).contains(&v);
                let want = if inside { u } else { 0.0 };
                assert!((img[j * w + i] - want).abs() < 1e-6, "texel ({i}, {j}): {} vs {want}", img[j * w + i]);
            }
        }
    }

    #[test]
    fn a_texel_a_hair_outside_the_exact_triangle_keeps_the_corner_range() {
        // The hypotenuse x + y = t lies 1/10000 texel beyond the centres of the texels on
        // x + y = 7 (texel units); snapped, it passes through them and owns them (top-left
        // rule), so they are covered while their exact weights extrapolate past the corners.
        let (w, h) = (8, 8);
        let t = 7.0001f32;
        let uvs = [[t, 0.0], [t, t], [0.0, t]].map(|[x, y]| Vec2::new(x / w as f32, y / h as f32));
        let img = rasterise_corner_values(&uvs, &[3], &[1.0, 0.0, 1.0], 1001, w, h).unwrap();
        assert!(img[3 * w + 3] > 0.99, "texel (3, 3) is covered: {img:?}");
        assert!(img.iter().all(|&v| (0.0..=1.0).contains(&v)), "{img:?}");
    }

    #[test]
    fn corner_values_of_another_tile_land_in_that_tile_only() {
        let uvs: Vec<Vec2> = quad(0.0, 0.0, 1.0, 1.0).iter().map(|uv| *uv + Vec2::new(1.0, 0.0)).collect();
        let ones = [1.0f32; 4];
        assert!(rasterise_corner_values(&uvs, &[4], &ones, 1002, 8, 8).unwrap().iter().all(|&v| (v - 1.0).abs() < 1e-6));
        assert!(rasterise_corner_values(&uvs, &[4], &ones, 1001, 8, 8).unwrap().iter().all(|&v| v == 0.0));
    }

    #[test]
    fn corner_value_errors_name_the_argument() {
        let uvs = quad(0.0, 0.0, 1.0, 1.0);
        let err = rasterise_corner_values(&uvs, &[4], &[0.0, 1.0, f32::NAN, 0.0], 1001, 8, 8).unwrap_err().to_string();
        assert!(err.contains("corner_values: the value of corner 2 is not finite"), "{err}");
        let err = rasterise_corner_values(&uvs, &[3], &[0.0; 4], 1001, 8, 8).unwrap_err().to_string();
        assert!(err.contains("polygon sizes add up to 3 corners"), "{err}");
        let err = rasterise_corner_values(&uvs[..3], &[4], &[0.0; 4], 1001, 8, 8).unwrap_err().to_string();
        assert!(err.contains("corner_uvs has 3 UVs"), "{err}");
    }

    #[test]
    fn resample_keeps_constants_and_linear_ramps() {
        let (sw, sh) = (5, 3);
        let ramp: Vec<f32> = (0..sw * sh).map(|k| (k % sw) as f32).collect();
        let out = resample_bilinear(&ramp, sw, sh, 10, 6).unwrap();
        // Target centre x = (i + 0.5)·5/10 − 0.5 in source pixels, clamped to [0, 4].
        for i in 0..10 {
            let want = ((i as f64 + 0.5) * 0.5 - 0.5).clamp(0.0, 4.0) as f32;
            assert!((out[i] - want).abs() < 1e-6 && (out[5 * 10 + i] - want).abs() < 1e-6);
        }
        let flat = resample_bilinear(&[0.3; 1], 1, 1, 4, 4).unwrap();
        assert!(flat.iter().all(|&v| v == 0.3));
        assert_eq!(resample_bilinear(&ramp, sw, sh, sw, sh).unwrap(), ramp);
        assert!(resample_bilinear(&[], 0, 0, 4, 4).unwrap_err().to_string().contains("pixels: expected a non-empty image"));
    }

    fn plane(scale_x: f32) -> (Vec<Vec3>, Vec<Vec3>, Vec<i32>, Vec<i32>, Vec<Vec2>) {
        let uvs = quad(0.0, 0.0, 1.0, 1.0);
        let rest: Vec<Vec3> = uvs.iter().map(|uv| Vec3::new(uv.x, uv.y, 0.0)).collect();
        let deformed: Vec<Vec3> = rest.iter().map(|p| Vec3::new(p.x * scale_x, p.y, 0.0)).collect();
        (rest, deformed, vec![0, 1, 2, 3], vec![4], uvs)
    }

    #[test]
    fn stretch_of_a_uniform_scale_is_half_its_log_squared() {
        let (w, h) = (8, 8);
        let (rest, deformed, corner_verts, polygon_sizes, corner_uvs) = plane(2.0);
        let zero = vec![0.0f32; 2 * w * h];
        let input = StretchInput {
            rest: &rest,
            deformed: &deformed,
            corner_verts: &corner_verts,
            polygon_sizes: &polygon_sizes,
            corner_uvs: &corner_uvs,
            udim: 1001,
            width: w,
            height: h,
            displacement: &zero,
        };
        let img = stretch_map(&input).unwrap();
        // σ = 2 along u, 1 along v: max(|ln 4|, 0) / 2 = ln 2.
        assert!(img.iter().all(|&e| (e as f64 - 2f64.ln()).abs() < 1e-6), "{img:?}");
        // A warp that shrinks the grid by half along x undoes the stretch inside.
        let half: Vec<f32> = (0..w * h).flat_map(|k| [-0.5 * (k % w) as f32 + 1.75, 0.0]).collect();
        let img = stretch_map(&StretchInput { displacement: &half, ..input }).unwrap();
        assert!(img.iter().all(|&e| e.abs() < 1e-6), "{img:?}");
        // A collapsed warp is capped, not infinite.
        let flat: Vec<f32> = (0..w * h).flat_map(|k| [3.5 - (k % w) as f32, 0.0]).collect();
        let img = stretch_map(&StretchInput { displacement: &flat, ..input }).unwrap();
        assert!(img.iter().all(|&e| e as f64 == MAX_STRETCH as f32 as f64), "{img:?}");
    }

    #[test]
    fn stretch_refuses_a_displacement_of_the_wrong_size() {
        let (rest, deformed, corner_verts, polygon_sizes, corner_uvs) = plane(1.0);
        let input = StretchInput {
            rest: &rest,
            deformed: &deformed[..3],
            corner_verts: &corner_verts,
            polygon_sizes: &polygon_sizes,
            corner_uvs: &corner_uvs,
            udim: 1001,
            width: 8,
            height: 8,
            displacement: &[0.0; 128],
        };
        assert!(stretch_map(&input).unwrap_err().to_string().contains("deformed_positions has 3 vertices"));
        let err = stretch_map(&StretchInput { deformed: &deformed, displacement: &[0.0; 10], ..input }).unwrap_err().to_string();
        assert!(err.contains("displacement has 10 values"), "{err}");
    }
}
