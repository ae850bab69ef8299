//! The UV layout of one tile rasterised into its grid: which triangle covers
//! each texel centre, the coverage and automatic warp mask (0 outside charts
//! and on chart borders), and per-triangle metrics of the surface.
//!
//! The UVs never change between frames, so the rasterisation of the layout is
//! done once. Per frame, the deformed surface enters the solver as the
//! first fundamental form `G = Jᵀ J` of each triangle (the exact derivative of
//! the barycentric interpolation `f_D` of positions over that triangle), looked
//! up through the per-texel triangle index; [`TileLayout::interpolate`] gives
//! the interpolated positions `f_O`, `f_D` themselves.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::raster::{barycentric, Prepared};
use super::tiles::{udim_offset, UvMesh};

/// Rows per parallel band.
const BAND: usize = 32;
/// How many texels triangle indices are extended past chart borders.
pub const DILATE: usize = 4;

/// One tile's rasterised layout.
#[derive(Debug, Clone)]
pub struct TileLayout {
    pub udim: u32,
    pub width: usize,
    pub height: usize,
    /// Global triangle index of each local triangle.
    pub tris: Vec<u32>,
    /// UV triangles in this tile's texel coordinates, by local triangle.
    pub tri_texel: Vec<[[f64; 2]; 3]>,
    /// Local triangle covering each texel (extended [`DILATE`] texels past
    /// chart borders); `tris.len()` where none.
    pub ids: Vec<u32>,
    /// 1 where a triangle covers the texel centre.
    pub covered: Vec<u8>,
    /// 1 inside a chart and not on its border (the automatic warp mask).
    pub interior: Vec<u8>,
    /// Texel centres claimed by more than one triangle (overlapping UVs).
    pub overlaps: usize,
}

impl TileLayout {
    pub fn new(mesh: &UvMesh, udim: u32, tris: &[u32], width: usize, height: usize) -> Self {
        let off = udim_offset(udim);
        let scale = [width as f64, height as f64];
        let tri_texel: Vec<[[f64; 2]; 3]> = tris
            .iter()
            .map(|&t| {
                let tri = mesh.tris[t as usize];
                let mut p = [[0.0; 2]; 3];
                for k in 0..3 {
                    let uv = mesh.corner_uvs[tri[k] as usize] - off;
                    p[k] = [uv.x as f64 * scale[0], uv.y as f64 * scale[1]];
                }
                p
            })
            .collect();
        let none = tris.len() as u32;
        let bands = height.div_ceil(BAND);
        let mut binned: Vec<Vec<(u32, Prepared)>> = vec![Vec::new(); bands];
        for (local, p) in tri_texel.iter().enumerate() {
            if let Some(prep) = Prepared::new(*p) {
                let (_, _, y0, y1) = prep.texel_bounds();
                let (y0, y1) = (y0.max(0), y1.min(height as i64 - 1));
                if y0 > y1 {
                    continue;
                }
                for band in (y0 as usize / BAND)..=(y1 as usize / BAND) {
                    binned[band].push((local as u32, prep));
                }
            }
        }
        let mut ids = vec![none; width * height];
        let overlaps: usize = ids
            .par_chunks_mut(BAND * width)
            .zip(binned.par_iter())
            .enumerate()
            .map(|(band, (chunk, list))| {
                let r0 = band * BAND;
                let rows = r0..(r0 + chunk.len() / width);
                let mut overlaps = 0;
                for (local, prep) in list {
                    prep.for_each(width, rows.clone(), |x, y, _| {
                        let slot = &mut chunk[(y - r0) * width + x];
                        if *slot == none {
                            *slot = *local;
                        } else {
                            overlaps += 1;
                        }
                    });
                }
                overlaps
            })
            .sum();
        let covered: Vec<u8> = ids.par_iter().map(|&i| (i != none) as u8).collect();
        // Automatic mask: covered, not at the grid edge, and every 8-neighbour
        // covered by the same chart.
        let chart_of = |i: u32| if i == none { u32::MAX } else { mesh.tri_chart[tris[i as usize] as usize] };
        let mut interior = vec![0u8; width * height];
        interior.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
            if y == 0 || y + 1 == height {
                return;
            }
            for x in 1..width - 1 {
                let c = chart_of(ids[y * width + x]);
                if c == u32::MAX {
                    continue;
                }
                let mut ok = true;
                'n: for dy in [-1i64, 0, 1] {
                    for dx in [-1i64, 0, 1] {
                        let q = (y as i64 + dy) as usize * width + (x as i64 + dx) as usize;
                        if chart_of(ids[q]) != c {
                            ok = false;
                            break 'n;
                        }
                    }
                }
                row[x] = ok as u8;
            }
        });
        // Extend triangle indices past chart borders so that lookups at
        // slightly warped positions near a border still find a triangle.
        for _ in 0..DILATE {
            let src = ids.clone();
            ids.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
                for x in 0..width {
                    if src[y * width + x] != none {
                        continue;
                    }
                    'n: for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1), (-1, -1), (1, -1), (-1, 1), (1, 1)] {
                        let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                        if nx >= 0 && ny >= 0 && (nx as usize) < width && (ny as usize) < height {
                            let v = src[ny as usize * width + nx as usize];
                            if v != none {
                                row[x] = v;
                                break 'n;
                            }
                        }
                    }
                }
            });
        }
        TileLayout { udim, width, height, tris: tris.to_vec(), tri_texel, ids, covered, interior, overlaps }
    }

    /// `G = Jᵀ J` per local triangle in this grid's texel units, `J` being the
    /// derivative of position with respect to texel coordinates; one extra zero
    /// entry at the end for texels without a triangle. Degenerate UV triangles
    /// get zero (their constraints are skipped).
    pub fn triangle_metrics(&self, mesh: &UvMesh, positions: &[Vec3]) -> Vec<[f32; 3]> {
        let mut out: Vec<[f32; 3]> = self
            .tris
            .par_iter()
            .zip(self.tri_texel.par_iter())
            .map(|(&t, uv)| {
                let tri = mesh.tris[t as usize];
                let p: [DVec3; 3] = std::array::from_fn(|k| positions[mesh.corner_verts[tri[k] as usize] as usize].as_dvec3());
                let (a, b) = ([uv[1][0] - uv[0][0], uv[1][1] - uv[0][1]], [uv[2][0] - uv[0][0], uv[2][1] - uv[0][1]]);
                let det = a[0] * b[1] - a[1] * b[0];
                if det.abs() < 1e-12 {
                    return [0.0; 3];
                }
                // J = [e1 e2] · inv([a b])
                let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
                let inv = [[b[1] / det, -b[0] / det], [-a[1] / det, a[0] / det]]; // rows of inverse
                let ju = e1 * inv[0][0] + e2 * inv[1][0];
                let jv = e1 * inv[0][1] + e2 * inv[1][1];
                [ju.dot(ju) as f32, ju.dot(jv) as f32, jv.dot(jv) as f32]
            })
            .collect();
        out.push([0.0; 3]);
        out
    }

    /// Positions interpolated at texel centres (barycentric over the covering
    /// triangle, linearly extrapolated in the [`DILATE`]-texel band past chart
    /// borders); `None` where no triangle is near.
    pub fn interpolate(&self, mesh: &UvMesh, positions: &[Vec3]) -> Vec<Option<Vec3>> {
        let w = self.width;
        (0..w * self.height)
            .into_par_iter()
            .map(|i| {
                let id = self.ids[i];
                if id as usize >= self.tris.len() {
                    return None;
                }
                let c = [(i % w) as f64 + 0.5, (i / w) as f64 + 0.5];
                let b = barycentric(self.tri_texel[id as usize], c)?;
                let tri = mesh.tris[self.tris[id as usize] as usize];
                let mut p = DVec3::ZERO;
                for k in 0..3 {
                    p += positions[mesh.corner_verts[tri[k] as usize] as usize].as_dvec3() * b[k];
                }
                Some(p.as_vec3())
            })
            .collect()
    }
}
