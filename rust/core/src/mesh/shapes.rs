//! Procedural meshes in Blender's layout, for tests, benchmarks and demos.
//!
//! Every shape is a [`PolyMesh`]: owned arrays that borrow as a [`MeshInput`].

use glam::Vec3;

use super::MeshInput;

/// An owned polygon mesh in Blender's layout.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PolyMesh {
    pub positions: Vec<Vec3>,
    pub corner_verts: Vec<i32>,
    pub polygon_sizes: Vec<i32>,
}

impl PolyMesh {
    pub fn input(&self) -> MeshInput<'_> {
        MeshInput { positions: &self.positions, corner_verts: &self.corner_verts, polygon_sizes: &self.polygon_sizes }
    }

    pub fn push_polygon(&mut self, corners: &[usize]) {
        self.corner_verts.extend(corners.iter().map(|&c| c as i32));
        self.polygon_sizes.push(corners.len() as i32);
    }
}

/// Blender's default cube: 8 vertices, 6 outward-facing quads, side 2.
pub fn cube() -> PolyMesh {
    let mut mesh = PolyMesh::default();
    for i in 0..8 {
        mesh.positions.push(Vec3::new(
            if i & 1 != 0 { 1.0 } else { -1.0 },
            if i & 2 != 0 { 1.0 } else { -1.0 },
            if i & 4 != 0 { 1.0 } else { -1.0 },
        ));
    }
    for quad in [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]] {
        mesh.push_polygon(&quad);
    }
    mesh
}

/// Blender's UV sphere (`primitive_uv_sphere_add`), already triangulated:
/// a pole at ±z, `segments` vertices around each of `rings − 1` rings,
/// outward-wound triangles. Returns the positions and the triangles.
pub fn uv_sphere_triangles(segments: usize, rings: usize, radius: f32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut points = vec![Vec3::new(0.0, 0.0, radius)];
    for i in 1..rings {
        let theta = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..segments {
            let phi = 2.0 * std::f32::consts::PI * j as f32 / segments as f32;
            points.push(radius * Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()));
        }
    }
    points.push(Vec3::new(0.0, 0.0, -radius));
    let (top, bottom) = (0u32, points.len() as u32 - 1);
    let ring = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
    let mut tris = Vec::new();
    for j in 0..segments {
        tris.push([top, ring(1, j), ring(1, j + 1)]);
        tris.push([bottom, ring(rings - 1, j + 1), ring(rings - 1, j)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            let (a, b, c, d) = (ring(i, j), ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j));
            tris.push([a, d, c]);
            tris.push([a, c, b]);
        }
    }
    (points, tris)
}

/// A flat grid of `nx` × `ny` quads in the XY plane, facing +Z, of size `size`.
pub fn grid(nx: usize, ny: usize, size: f32) -> PolyMesh {
    let mut mesh = PolyMesh::default();
    for j in 0..=ny {
        for i in 0..=nx {
            mesh.positions.push(Vec3::new(
                size * (i as f32 / nx as f32 - 0.5),
                size * (j as f32 / ny as f32 - 0.5),
                0.0,
            ));
        }
    }
    let at = |i: usize, j: usize| j * (nx + 1) + i;
    for j in 0..ny {
        for i in 0..nx {
            mesh.push_polygon(&[at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    mesh
}

/// An open cylinder along +Z: `around` segments, `along` rings of quads,
/// outward-facing.
pub fn cylinder(around: usize, along: usize, radius: f32, length: f32) -> PolyMesh {
    let mut mesh = PolyMesh::default();
    for j in 0..=along {
        for i in 0..around {
            let angle = std::f32::consts::TAU * i as f32 / around as f32;
            mesh.positions.push(Vec3::new(
                radius * angle.cos(),
                radius * angle.sin(),
                length * j as f32 / along as f32,
            ));
        }
    }
    let at = |i: usize, j: usize| j * around + i % around;
    for j in 0..along {
        for i in 0..around {
            mesh.push_polygon(&[at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    mesh
}

/// A closed tube along +Z: [`cylinder`] with a triangle fan closing each
/// end around a pole on the axis (Blender's Cylinder with Triangle Fan caps).
/// The poles are the last two vertices.
pub fn capped_tube(around: usize, along: usize, radius: f32, length: f32) -> PolyMesh {
    let mut mesh = cylinder(around, along, radius, length);
    let (bottom, top) = (mesh.positions.len(), mesh.positions.len() + 1);
    mesh.positions.push(Vec3::ZERO);
    mesh.positions.push(Vec3::new(0.0, 0.0, length));
    let at = |i: usize, j: usize| j * around + i % around;
    for i in 0..around {
        mesh.push_polygon(&[bottom, at(i + 1, 0), at(i, 0)]);
        mesh.push_polygon(&[top, at(i, along), at(i + 1, along)]);
    }
    mesh
}

/// A closed quad sphere: a cube with `n` × `n` quads per side projected on
/// the sphere of `radius`. `6n² + 2` vertices.
pub fn quad_sphere(n: usize, radius: f32) -> PolyMesh {
    // Build each face of the cube as a grid, then weld by position key.
    let mut mesh = PolyMesh::default();
    let mut index_of = std::collections::HashMap::new();
    let faces: [(Vec3, Vec3, Vec3); 6] = [
        (Vec3::X, Vec3::Y, Vec3::Z),
        (-Vec3::X, Vec3::Z, Vec3::Y),
        (Vec3::Y, Vec3::Z, Vec3::X),
        (-Vec3::Y, Vec3::X, Vec3::Z),
        (Vec3::Z, Vec3::X, Vec3::Y),
        (-Vec3::Z, Vec3::Y, Vec3::X),
    ];
    for (normal, u, v) in faces {
        let mut ids = vec![0usize; (n + 1) * (n + 1)];
        for j in 0..=n {
            for i in 0..=n {
                // Integer lattice key on the cube surface welds shared edges exactly.
                let lattice = normal.as_ivec3() * n as i32
                    + u.as_ivec3() * (2 * i as i32 - n as i32)
                    + v.as_ivec3() * (2 * j as i32 - n as i32);
                let id = *index_of.entry(lattice.to_array()).or_insert_with(|| {
                    let p = lattice.as_vec3().normalize() * radius;
                    mesh.positions.push(p);
                    mesh.positions.len() - 1
                });
                ids[j * (n + 1) + i] = id;
            }
        }
        for j in 0..n {
            for i in 0..n {
                let at = |i: usize, j: usize| ids[j * (n + 1) + i];
                mesh.push_polygon(&[at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
    }
    mesh
}
