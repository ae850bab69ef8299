//! Closeness: each selected vertex is pulled towards its input position.
//!
//! Pyramid rows (and strain rows) only see differences between vertices, so
//! without closeness the global matrix is singular and nothing ties the result
//! to the upstream deformation. Painted per-vertex closeness weights are how an
//! artist says "here, follow the rig".

use glam::Vec3;

use super::constraint::{Constraint, Context, Rows};

/// Identity rows over a set of vertices, projecting to the solve's input.
#[derive(Debug, Clone)]
pub struct Closeness {
    rows: Rows,
    vertices: Vec<u32>,
}

impl Closeness {
    pub fn new(vertices: Vec<u32>) -> Self {
        Closeness {
            rows: Rows::identity(&vertices),
            vertices,
        }
    }

    /// Closeness on every vertex of a mesh of `vertex_count` vertices.
    pub fn all(vertex_count: usize) -> Self {
        Self::new((0..vertex_count as u32).collect())
    }
}

impl Constraint for Closeness {
    fn name(&self) -> &str {
        "closeness"
    }

    fn rows(&self) -> &Rows {
        &self.rows
    }

    fn is_constant(&self) -> bool {
        true
    }

    #[inline]
    fn project_row(&self, context: &Context<'_>, row: usize) -> Vec3 {
        context.input[self.vertices[row] as usize]
    }

    /// A plain gather by chunks: the default's per-row dynamic call cost more
    /// than the copy itself (it runs once per solve, over every vertex).
    fn project(&self, context: &Context<'_>, out: &mut [Vec3]) {
        use rayon::prelude::*;
        out.par_chunks_mut(4096).zip(self.vertices.par_chunks(4096)).for_each(|(out, vertices)| {
            for (o, &v) in out.iter_mut().zip(vertices) {
                *o = context.input[v as usize];
            }
        });
    }
}
