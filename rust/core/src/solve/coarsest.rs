//! The coarsest level of the multilevel correction ([`super::coarse`]),
//! solved exactly: a sparse Cholesky factor computed once per set of
//! weights, and a triangular solve of the three coordinates at once every
//! iteration.
//!
//! The level has a few hundred to a few thousand unknowns (~2k on a 13k
//! character), and its solve runs every accelerated iteration. faer's
//! general solve (column-major right-hand sides, a permuted copy in and out,
//! a supernodal-or-simplicial dispatch) took 1.02 M instructions a solve on
//! the MakeHuman body, a quarter of an accelerated iteration there
//! (callgrind). The factor is simplicial here (compressed columns, the
//! diagonal first in each) and solved by its own loop over three-vectors,
//! one pass over the factor forward and one backward: 0.68 M instructions,
//! the same result to rounding.
//!
//! A contact's held set changes the coarse problem several times a step, and
//! each new one is factorised afresh; its coarsest pattern is often one seen
//! before (the free problem's, or the last held set's), and then the
//! symbolic analysis (the fill-reducing order, ~40 % of a factorisation
//! on the 100k flesh bench) is that one's ([`Analysis`]).

use std::sync::Arc;

use faer::sparse::linalg::cholesky::SymbolicCholesky;
use glam::{DVec3, Vec3};

use super::system::{factorize_columns, LowerColumns};

/// A coarsest matrix's pattern (its lower triangle by columns) and its
/// symbolic analysis. The analysis is a function of the pattern alone, so a
/// matrix of the same pattern factorised on it gets the factor a fresh
/// analysis would give, to the bit.
pub(super) struct Analysis {
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    symbolic: Arc<SymbolicCholesky<usize>>,
}

impl Analysis {
    fn fits(&self, lower: &LowerColumns) -> bool {
        self.col_ptr == lower.col_ptr && self.row_idx == lower.row_idx
    }
}

/// `A = Pᵀ L Lᵀ P`: the fill-reducing permutation and the lower factor.
pub(super) struct Coarsest {
    /// The pattern's analysis, for the next matrix of the same pattern.
    analysis: Arc<Analysis>,
    /// `order[i]`: the unknown that is row `i` of the permuted system.
    order: Vec<u32>,
    /// Column `j` of `L` at `starts[j]..starts[j + 1]`, its diagonal first.
    starts: Vec<u32>,
    rows: Vec<u32>,
    values: Vec<f64>,
    /// The permuted right-hand side, then the solution.
    work: Vec<DVec3>,
}

impl Coarsest {
    /// Factorises the symmetric matrix given by its lower-triangle entries
    /// `(column, row, value)` (duplicates summed), on the first of `known`
    /// analyses made for its pattern, if any, else on a fresh one; `None`
    /// if it is not positive definite.
    pub(super) fn new<'a>(n: usize, lower: Vec<(u32, u32, f64)>, known: impl IntoIterator<Item = &'a Arc<Analysis>>) -> Option<Self> {
        let lower = LowerColumns::new(n, lower);
        let known = known.into_iter().find(|a| a.fits(&lower)).cloned();
        let (symbolic, values) = factorize_columns(&lower, known.as_ref().map(|a| Arc::clone(&a.symbolic)), true).ok()?;
        let analysis = match known {
            Some(analysis) => analysis,
            None => Arc::new(Analysis { col_ptr: lower.col_ptr, row_idx: lower.row_idx, symbolic: Arc::clone(&symbolic) }),
        };
        let faer::sparse::linalg::cholesky::SymbolicCholeskyRaw::Simplicial(factor) = symbolic.raw() else {
            return None;
        };
        let order = match symbolic.perm() {
            Some(perm) => perm.arrays().0.iter().map(|&i| i as u32).collect(),
            None => (0..n as u32).collect(),
        };
        let starts: Vec<u32> = factor.col_ptr().iter().map(|&k| k as u32).collect();
        let rows: Vec<u32> = factor.row_idx().iter().map(|&k| k as u32).collect();
        // The solve indexes by these without checks: the diagonal first, then
        // rows below it, all in range.
        let columns_fit = starts.len() == n + 1 && rows.len() == values.len() && starts[n] as usize == rows.len();
        if !columns_fit
            || !(0..n).all(|j| {
                let column = &rows[starts[j] as usize..starts[j + 1] as usize];
                column.first() == Some(&(j as u32)) && column[1..].iter().all(|&i| (j as u32) < i && (i as usize) < n)
            })
        {
            return None;
        }
        Some(Coarsest { analysis, order, starts, rows, values, work: vec![DVec3::ZERO; n] })
    }

    pub(super) fn len(&self) -> usize {
        self.order.len()
    }

    /// The analysis this was factorised on, for [`Self::new`]'s `known`.
    pub(super) fn analysis(&self) -> &Arc<Analysis> {
        &self.analysis
    }

    /// Solves `A e = b` for the three coordinates.
    pub(super) fn solve(&mut self, b: &[Vec3], e: &mut [Vec3]) {
        let (starts, rows, values, work) = (&self.starts, &self.rows, &self.values, &mut self.work);
        let n = work.len();
        for (w, &i) in work.iter_mut().zip(&self.order) {
            *w = b[i as usize].as_dvec3();
        }
        // L z = P b, column by column.
        for j in 0..n {
            let (start, end) = (starts[j] as usize, starts[j + 1] as usize);
            let z = work[j] / values[start];
            work[j] = z;
            for (&i, &l) in rows[start + 1..end].iter().zip(&values[start + 1..end]) {
                // SAFETY: `new` checked every row index of the factor against `n`.
                let w = unsafe { work.get_unchecked_mut(i as usize) };
                *w -= z * l;
            }
        }
        // Lᵀ w = z, a column's entries as a dot product.
        for j in (0..n).rev() {
            let (start, end) = (starts[j] as usize, starts[j + 1] as usize);
            let mut sum = work[j];
            for (&i, &l) in rows[start + 1..end].iter().zip(&values[start + 1..end]) {
                // SAFETY: as above.
                sum -= unsafe { *work.get_unchecked(i as usize) } * l;
            }
            work[j] = sum / values[start];
        }
        for (w, &i) in work.iter().zip(&self.order) {
            e[i as usize] = w.as_vec3();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_symmetric_positive_definite_system_for_three_coordinates() {
        // A 2D grid Laplacian plus a diagonal shift: sparse, with fill, and
        // a permutation that is not the identity.
        let side = 12usize;
        let n = side * side;
        let mut lower = Vec::new();
        for y in 0..side {
            for x in 0..side {
                let i = (y * side + x) as u32;
                lower.push((i, i, 4.1 + (i % 5) as f64 * 0.1));
                if x + 1 < side {
                    lower.push((i, i + 1, -1.0));
                }
                if y + 1 < side {
                    lower.push((i, i + side as u32, -1.0));
                }
            }
        }
        let mut coarsest = Coarsest::new(n, lower.clone(), []).expect("positive definite");
        let truth: Vec<Vec3> = (0..n).map(|i| Vec3::new((i as f32 * 0.37).sin(), (i as f32 * 0.11).cos(), i as f32 / n as f32)).collect();
        // b = A · truth, from the lower triangle.
        let mut b = vec![DVec3::ZERO; n];
        for &(j, i, v) in &lower {
            let (i, j) = (i as usize, j as usize);
            b[i] += truth[j].as_dvec3() * v;
            if i != j {
                b[j] += truth[i].as_dvec3() * v;
            }
        }
        let b: Vec<Vec3> = b.iter().map(|v| v.as_vec3()).collect();
        let mut e = vec![Vec3::ZERO; n];
        coarsest.solve(&b, &mut e);
        let worst = e.iter().zip(&truth).map(|(a, t)| (*a - *t).abs().max_element()).fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "largest error {worst}");
    }

    #[test]
    fn refuses_a_matrix_that_is_not_positive_definite() {
        let lower = vec![(0, 0, 1.0), (0, 1, 2.0), (1, 1, 1.0)];
        assert!(Coarsest::new(2, lower, []).is_none());
    }
}
