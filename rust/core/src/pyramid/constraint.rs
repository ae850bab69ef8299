//! The two formulations of the pyramid constraint, as solver constraints.
//!
//! * [`PyramidTargets`] (the seed's): one identity row per vertex projecting
//!   to its full target `m + s n`. Together with closeness the global matrix
//!   is diagonal: each iteration is a Jacobi sweep, cheap but local (a change
//!   travels one ring per iteration).
//! * [`PyramidLaplacian`]: the constant mean-value Laplacian row
//!   `x_i − Σ w_j x_j` projecting to `s n`. The matrix couples neighbours and
//!   is prefactored; each iteration is a global solve that propagates
//!   everywhere at once, at the price of back-substitutions.

use std::sync::Arc;

use glam::Vec3;

use super::encoding::Encoding;
use super::kernel::{Packed, Width};
use super::project::frame;
use crate::solve::{Constraint, Context, DiagonalChunk, Rows};

/// Per-vertex targets: row `e_i`, projection `m + s n`.
pub struct PyramidTargets {
    encoding: Arc<Encoding>,
    rows: Rows,
    /// The encoding laid out for the kernel (`project_rows`, `solve_chunk`).
    packed: Packed,
    /// Row `e`: the ring's mean-value weights, how the target's ring mean
    /// moves with the neighbours (see [`Constraint::coupling`]).
    coupling: Rows,
}

impl PyramidTargets {
    pub fn new(encoding: Arc<Encoding>) -> Self {
        PyramidTargets::with_width(encoding, Width::best())
    }

    /// With the kernel's lanes chosen (tests compare the widths this CPU has).
    pub(crate) fn with_width(encoding: Arc<Encoding>, width: Width) -> Self {
        let rows = Rows::identity(encoding.vertices());
        let packed = Packed::with_width(&encoding, width);
        let mut coupling = Rows::new();
        for e in 0..encoding.len() {
            coupling.push(encoding.ring(e).iter().copied().zip(encoding.weights(e).iter().copied()));
        }
        PyramidTargets { encoding, rows, packed, coupling }
    }
}

impl Constraint for PyramidTargets {
    fn name(&self) -> &str {
        "pyramid (per-vertex targets)"
    }

    fn rows(&self) -> &Rows {
        &self.rows
    }

    #[inline]
    fn project_row(&self, context: &Context<'_>, e: usize) -> Vec3 {
        let (encoding, x) = (&*self.encoding, context.positions);
        // No frame: stay put, which makes the row neutral.
        frame(encoding, e, x).map_or(x[encoding.vertices()[e] as usize], |f| f.target())
    }

    /// The same targets, four rows at a time (see [`super::kernel`]).
    fn project_rows(&self, context: &Context<'_>, rows: std::ops::Range<usize>, out: &mut [Vec3]) {
        self.packed.targets(context.positions, rows, out);
    }

    fn solve_chunk(
        &self,
        context: &Context<'_>,
        rows: std::ops::Range<usize>,
        chunk: &DiagonalChunk<'_>,
        out: &mut [Vec3],
    ) -> bool {
        self.packed.solve_chunk(context.positions, rows, chunk, out);
        true
    }

    fn coupling(&self) -> Option<&Rows> {
        Some(&self.coupling)
    }
}

/// Linearised: row `e_i − Σ w_j e_j`, projection `s n`.
pub struct PyramidLaplacian {
    encoding: Arc<Encoding>,
    rows: Rows,
}

impl PyramidLaplacian {
    pub fn new(encoding: Arc<Encoding>) -> Self {
        let mut rows = Rows::new();
        for (e, &v) in encoding.vertices().iter().enumerate() {
            let neighbours = encoding
                .ring(e)
                .iter()
                .zip(encoding.weights(e))
                .map(|(&j, &w)| (j, -w));
            rows.push(std::iter::once((v, 1.0)).chain(neighbours));
        }
        PyramidLaplacian { encoding, rows }
    }
}

impl Constraint for PyramidLaplacian {
    fn name(&self) -> &str {
        "pyramid (linearised Laplacian rows)"
    }

    fn rows(&self) -> &Rows {
        &self.rows
    }

    #[inline]
    fn project_row(&self, context: &Context<'_>, e: usize) -> Vec3 {
        let (encoding, x) = (&*self.encoding, context.positions);
        match frame(encoding, e, x) {
            Some(f) => f.lift,
            // Neutral: the row's current value.
            None => {
                let mut mean = Vec3::ZERO;
                for (&j, &w) in encoding.ring(e).iter().zip(encoding.weights(e)) {
                    mean += w * x[j as usize];
                }
                x[encoding.vertices()[e] as usize] - mean
            }
        }
    }
}
