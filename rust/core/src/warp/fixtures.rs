//! Procedural UV-mapped meshes, deformations and rigidity maps for tests,
//! benchmarks and demos of the UV warp.

use glam::{Vec2, Vec3};

/// A polygon mesh with one UV per face corner.
#[derive(Debug, Clone, Default)]
pub struct UvPolyMesh {
    pub positions: Vec<Vec3>,
    pub corner_verts: Vec<i32>,
    pub polygon_sizes: Vec<i32>,
    pub corner_uvs: Vec<Vec2>,
}

impl UvPolyMesh {
    pub fn input(&self) -> crate::MeshInput<'_> {
        crate::MeshInput { positions: &self.positions, corner_verts: &self.corner_verts, polygon_sizes: &self.polygon_sizes }
    }
}

/// An open cylinder along +Z, `around × along` quads, unrolled into one UV
/// chart filling `[margin, 1 − margin]²` (u around, v along), with its seam on
/// the +Y side. With `2π·radius = length` the UV map is isometric up to scale.
pub fn uv_cylinder(around: usize, along: usize, radius: f32, length: f32, margin: f32) -> UvPolyMesh {
    let mut m = UvPolyMesh::default();
    for j in 0..=along {
        for i in 0..around {
            let phi = std::f32::consts::TAU * i as f32 / around as f32 + std::f32::consts::FRAC_PI_2;
            m.positions.push(Vec3::new(radius * phi.cos(), radius * phi.sin(), length * j as f32 / along as f32));
        }
    }
    let span = 1.0 - 2.0 * margin;
    let uv = |i: usize, j: usize| Vec2::new(margin + span * i as f32 / around as f32, margin + span * j as f32 / along as f32);
    for j in 0..along {
        for i in 0..around {
            for (ci, cj) in [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)] {
                m.corner_verts.push((cj * around + ci % around) as i32);
                m.corner_uvs.push(uv(ci, cj));
            }
            m.polygon_sizes.push(4);
        }
    }
    m
}

/// Bends along `axis` (0 = x, 1 = y, 2 = z) in the plane of `axis` and
/// `side`: the line `side = centre` becomes an arc of curvature `kappa`;
/// material at signed distance `o` from it is stretched along the axis by
/// `1 + kappa·o` (so `kappa·o = −0.5` squashes to half).
pub fn bend(positions: &[Vec3], axis: usize, side: usize, centre: f32, start: f32, kappa: f32) -> Vec<Vec3> {
    positions
        .iter()
        .map(|p| {
            if kappa == 0.0 {
                return *p;
            }
            let rho = 1.0 / kappa;
            let s = p[axis] - start;
            let o = p[side] - centre;
            let th = s * kappa;
            let mut q = *p;
            q[side] = centre - rho + (rho + o) * th.cos();
            q[axis] = start + (rho + o) * th.sin();
            q
        })
        .collect()
}

/// A `(height, width)` rigidity map with value 1 inside axis-aligned
/// rectangles given in UV as `(u0, v0, u1, v1)`, 0 elsewhere.
pub fn rectangles(width: usize, height: usize, rects: &[(f32, f32, f32, f32)]) -> Vec<f32> {
    let mut r = vec![0.0; width * height];
    for y in 0..height {
        for x in 0..width {
            let (u, v) = ((x as f32 + 0.5) / width as f32, (y as f32 + 0.5) / height as f32);
            if rects.iter().any(|&(u0, v0, u1, v1)| u >= u0 && u < u1 && v >= v0 && v < v1) {
                r[y * width + x] = 1.0;
            }
        }
    }
    r
}

/// The benchmark and demo scene: a UV cylinder (radius 1, length 2π) with a
/// regular pattern of rigid square "scales" over 25% of its surface.
pub fn scales_map(width: usize, height: usize, count: usize) -> Vec<f32> {
    let mut rects = Vec::new();
    let cell = 0.8 / count as f32;
    for j in 0..count {
        for i in 0..count {
            let (u, v) = (0.1 + cell * i as f32, 0.1 + cell * j as f32);
            rects.push((u + 0.25 * cell, v + 0.25 * cell, u + 0.75 * cell, v + 0.75 * cell));
        }
    }
    rectangles(width, height, &rects)
}
