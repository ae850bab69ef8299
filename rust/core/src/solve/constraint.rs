//! What a constraint is to the solver: fixed rows plus a projection.

use glam::Vec3;
use rayon::prelude::*;

use crate::{Error, Result};

/// The fixed rows of a constraint's selection matrix `A`, in compressed form:
/// row `r` is `Σ_k coefficients[k] · e_{vertices[k]}` over
/// `offsets[r]..offsets[r + 1]`. One row acts on all three coordinates alike,
/// which is what lets the global step solve x, y and z with one factorisation.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Rows {
    offsets: Vec<u32>,
    vertices: Vec<u32>,
    coefficients: Vec<f32>,
}

impl Rows {
    pub fn new() -> Self {
        Rows {
            offsets: vec![0],
            vertices: Vec::new(),
            coefficients: Vec::new(),
        }
    }

    /// One row `e_v` per listed vertex: closeness, per-vertex targets, inertia.
    pub fn identity(vertices: &[u32]) -> Self {
        Rows {
            offsets: (0..=vertices.len() as u32).collect(),
            vertices: vertices.to_vec(),
            coefficients: vec![1.0; vertices.len()],
        }
    }

    /// Appends one row. A vertex may not appear twice in a row: the global
    /// matrix is assembled from the entries as given.
    pub fn push(&mut self, entries: impl IntoIterator<Item = (u32, f32)>) {
        if self.offsets.is_empty() {
            self.offsets.push(0);
        }
        for (vertex, coefficient) in entries {
            self.vertices.push(vertex);
            self.coefficients.push(coefficient);
        }
        self.offsets.push(self.vertices.len() as u32);
    }

    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Vertices and coefficients of row `r`.
    pub fn row(&self, r: usize) -> (&[u32], &[f32]) {
        let range = self.offsets[r] as usize..self.offsets[r + 1] as usize;
        (&self.vertices[range.clone()], &self.coefficients[range])
    }

    /// True when every row selects exactly one vertex with coefficient 1: the
    /// constraint then only adds to the diagonal of the global matrix.
    pub fn is_identity(&self) -> bool {
        (0..self.len()).all(|r| {
            let (v, c) = self.row(r);
            v.len() == 1 && c[0] == 1.0
        })
    }

    /// Checks indices, duplicate vertices within a row and finiteness.
    pub fn validate(&self, name: &str, vertex_count: usize) -> Result<()> {
        for r in 0..self.len() {
            let (vertices, coefficients) = self.row(r);
            for (i, (&v, &c)) in vertices.iter().zip(coefficients).enumerate() {
                if v as usize >= vertex_count {
                    return Err(Error::invalid(format!(
                        "constraint {name}: row {r} refers to vertex {v}, but there are {vertex_count} vertices"
                    )));
                }
                if !c.is_finite() {
                    return Err(Error::invalid(format!(
                        "constraint {name}: row {r} has a non-finite coefficient"
                    )));
                }
                if vertices[..i].contains(&v) {
                    return Err(Error::invalid(format!(
                        "constraint {name}: row {r} lists vertex {v} twice"
                    )));
                }
            }
        }
        Ok(())
    }
}

/// What a projection may look at.
#[derive(Debug, Clone, Copy)]
pub struct Context<'a> {
    /// The positions of the current iteration.
    pub positions: &'a [Vec3],
    /// This solve's input (the upstream deformation, after the first collision
    /// pass): what closeness pulls towards.
    pub input: &'a [Vec3],
}

/// One chunk of vertices of the fused diagonal global step (see
/// [`Constraint::solve_chunk`]): the vertices `base..base + constant.len()`.
#[derive(Debug, Clone, Copy)]
pub struct DiagonalChunk<'a> {
    /// First vertex of the chunk.
    pub base: usize,
    /// `Σ w·p` over the constant rows, per vertex of the chunk.
    pub constant: &'a [Vec3],
    /// `1 / Σ w` (the inverse of the diagonal matrix), per vertex of the chunk.
    pub inverse: &'a [f32],
    /// The constraint's weights of the rows it is given, in row order.
    pub weights: &'a [f32],
}

/// A projective constraint. Implementations must be deterministic and must not
/// depend on the thread count (write each row's projection independently).
pub trait Constraint: Send + Sync {
    /// Short name used in error messages.
    fn name(&self) -> &str;

    /// The fixed selection rows. They must not change once the constraint is
    /// added to a solver (the global matrix is factorised from them).
    fn rows(&self) -> &Rows;

    /// True when the projection does not depend on `Context::positions`
    /// (closeness, inertia): the solver then projects once per solve instead of
    /// once per iteration.
    fn is_constant(&self) -> bool {
        false
    }

    /// Called once at the start of every solve with that solve's input, before
    /// any projection: the place for per-frame state (dynamics: the predicted
    /// position from last frame's velocity).
    fn begin_solve(&mut self, _input: &[Vec3]) -> Result<()> {
        Ok(())
    }

    /// Called once at the end of every solve with the result (dynamics: update
    /// velocities).
    fn end_solve(&mut self, _output: &[Vec3]) -> Result<()> {
        Ok(())
    }

    /// The local step for one row: where row `row` would like `A_r x` to be.
    /// A row that has no opinion (a degenerate configuration) returns the
    /// row's current value `A_r x`, which makes it neutral.
    ///
    /// The solver calls this directly, fused with the global step, when the
    /// global matrix is diagonal; otherwise through [`Constraint::project`].
    fn project_row(&self, context: &Context<'_>, row: usize) -> Vec3;

    /// The local step for the contiguous rows `rows`, one target per row
    /// into `out[..rows.len()]`. The fused diagonal path calls this once per
    /// chunk of vertices, so a constraint with a batched (vectorised) kernel
    /// overrides it; it must give what [`Constraint::project_row`] gives (up
    /// to the sign of an exact zero).
    fn project_rows(&self, context: &Context<'_>, rows: std::ops::Range<usize>, out: &mut [Vec3]) {
        for (o, r) in out.iter_mut().zip(rows) {
            *o = self.project_row(context, r);
        }
    }

    /// The whole fused global step of one chunk, for a constraint whose
    /// identity rows are the only varying ones of a diagonal system: every
    /// vertex `v` of the chunk gets `(constant_v + w_r · target_r) · inverse_v`
    /// where row `r` of `rows` selects it, and `constant_v · inverse_v` where
    /// none does (the rows' vertices ascend). Exactly those operations in that
    /// order, so the result equals the general path (project into a buffer,
    /// add, divide) to the bit. A kernel that can produce its targets in
    /// registers overrides this to skip the buffer and the two extra passes
    /// over the chunk; the default returns false and the solver takes the
    /// general path.
    fn solve_chunk(
        &self,
        _context: &Context<'_>,
        _rows: std::ops::Range<usize>,
        _chunk: &DiagonalChunk<'_>,
        _out: &mut [Vec3],
    ) -> bool {
        false
    }

    /// How the projection of each row moves with the positions, to first
    /// order, as rows (row `r`: `∂p_r/∂x ≈ Σ a_j e_j`; same row count as
    /// [`Constraint::rows`]), for the coarse correction (`solve::coarse`).
    /// Only the part that couples vertices matters and it may be
    /// approximate (pyramid targets: the ring's mean-value weights, leaving
    /// out the turning of the normal). `None` (the default): the projection
    /// does not follow other vertices, or the constraint does not say.
    fn coupling(&self) -> Option<&Rows> {
        None
    }

    /// Replaces the targets of a constraint whose rows project to settable
    /// fixed targets (`solve::Targets`): how a caller holding only a
    /// `ConstraintId` updates an inertia term. `None` when the constraint
    /// has no such targets. (A method rather than a downcast to the type, so
    /// that this trait does not depend on one of its implementations.)
    fn replace_targets(&mut self, _targets: &[Vec3]) -> Option<Result<()>> {
        None
    }

    /// The local step for all rows: writes one target per row into `out`
    /// (`out.len()` is the number of rows). Parallel by default.
    fn project(&self, context: &Context<'_>, out: &mut [Vec3]) {
        out.par_iter_mut().enumerate().with_min_len(512).for_each(|(r, o)| *o = self.project_row(context, r));
    }
}
