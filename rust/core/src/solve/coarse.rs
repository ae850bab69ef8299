//! A coarse-level correction of the local/global iteration (two-level
//! multigrid, with aggregation as in algebraic multigrid).
//!
//! With a diagonal global matrix one iteration is a Jacobi sweep: a change
//! travels one ring per iteration, and the smooth part of the error shrinks
//! by about `1 − closeness` per iteration (hundreds of iterations at a
//! closeness of 0.01). Anderson acceleration (see [`super::anderson`]) cannot
//! beat that locality either. What does is a correction of the smooth error
//! on a coarse mesh, solved exactly.
//!
//! Near the solution one iteration is an affine map `G(x) ≈ M x + b`, where
//! `M = D⁻¹ Σ w · (how the row targets move with the positions)`: the
//! constraints say how through [`super::Constraint::coupling`] (for pyramid
//! targets: the ring's mean-value weights; closeness: nothing). The error
//! `e = x_∞ − x` then satisfies `(I − M) e = r`, `r = G(x) − x` the residual,
//! and after the step `g = G(x)` the remaining error solves
//! `(I − M)(x_∞ − g) = M r`. Restricted to aggregates of vertices (`P`
//! piecewise constant, built greedily from the coupling graph by rounds of
//! one-ring aggregation), that is the small system
//! `Pᵀ(I − M)P e_c = Pᵀ M r`, symmetrised and factorised once by sparse
//! Cholesky; the step adds `P e_c` to `g`. The finer the aggregates the more
//! the correction does (one round, ~7 vertices each, nearly solves the
//! linear model in one step) and the more its solve costs: the rounds stop
//! at [`MAX_AGGREGATES`] unknowns.
//!
//! The correction is linear in the residual, so it vanishes at the fixed
//! point: the corrected iteration has the plain one's fixed points. Piecewise
//! constant aggregates overestimate the coarse stiffness, so the correction
//! is short of the full step by a factor near the aggregates' diameter;
//! [`super::anderson`] running on the corrected map finds the right
//! combination, which is why the two run together.
//!
//! Every loop writes disjoint outputs in a fixed order: results do not
//! depend on the thread count.

use std::sync::Arc;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{LltRef, SymbolicCholesky};
use faer::{Conj, MatMut, Par};
use glam::Vec3;
use rayon::prelude::*;

use super::system::{factorize_lower, RowBlock};
use crate::mesh::{aggregate_edges, aggregate_once};
use crate::Result;

/// Most coarse unknowns: rounds of one-ring aggregation (each divides the
/// count by ~7) run until the coarse level is at most this large, so that
/// its solve stays a small part of an iteration (~2k unknowns at 100k
/// vertices, ~1–2k below 28k vertices where one round suffices).
const MAX_AGGREGATES: usize = 4000;

/// At most this many rounds.
const MAX_ROUNDS: usize = 4;

/// Fewer coarse unknowns than this and the correction is not worth it.
const MIN_AGGREGATES: usize = 8;

/// The coarse level of one solver for one set of weights.
pub(super) struct Coarse {
    /// Aggregate of each vertex.
    aggregate: Vec<u32>,
    /// `Pᵀ M` by aggregate: offsets into `columns`/`values`.
    offsets: Vec<u32>,
    columns: Vec<u32>,
    values: Vec<f32>,
    symbolic: Arc<SymbolicCholesky<usize>>,
    factor: Vec<f64>,
    rhs: [Vec<f64>; 3],
    scratch: [MemBuffer; 3],
}

impl Coarse {
    /// Builds the coarse level from the linear model of the iteration, or
    /// `None` when there is nothing to gain (no coupling, too few vertices,
    /// or a coarse matrix that is not positive definite).
    ///
    /// `variable` and `couplings` go together: `couplings[b]` is the
    /// coupling rows of `variable[b]`'s constraint (same row count), if it
    /// has one. `inverse` is the diagonal global matrix's inverse.
    pub(super) fn build(
        n: usize,
        variable: &[RowBlock<'_>],
        couplings: &[Option<&super::Rows>],
        inverse: &[f32],
    ) -> Result<Option<Self>> {
        // M by vertex: (row vertex, column vertex, value).
        let mut m: Vec<(u32, u32, f32)> = Vec::new();
        for (block, coupling) in variable.iter().zip(couplings) {
            let Some(coupling) = coupling else { continue };
            if coupling.len() != block.rows.len() {
                continue;
            }
            for r in 0..block.rows.len() {
                let v = block.rows.row(r).0[0];
                let scale = inverse[v as usize] * block.weights[r];
                if scale == 0.0 {
                    continue;
                }
                let (vertices, coefficients) = coupling.row(r);
                for (&j, &a) in vertices.iter().zip(coefficients) {
                    if (j as usize) < n && j != v {
                        m.push((v, j, scale * a));
                    }
                }
            }
        }
        if m.is_empty() {
            return Ok(None);
        }
        m.par_sort_by_key(|&(i, j, _)| (i, j));
        let aggregate = aggregates(n, &m);
        let count = aggregate.iter().map(|&a| a as usize + 1).max().unwrap_or(0);
        if count < MIN_AGGREGATES || count * 4 > n {
            return Ok(None);
        }

        // Pᵀ M by aggregate, duplicates summed in order.
        let mut q: Vec<(u32, u32, f32)> = m.iter().map(|&(i, j, v)| (aggregate[i as usize], j, v)).collect();
        q.par_sort_by_key(|&(a, j, _)| (a, j));
        let mut offsets = vec![0u32; count + 1];
        let (mut columns, mut values) = (Vec::new(), Vec::new());
        for group in q.chunk_by(|a, b| a.0 == b.0 && a.1 == b.1) {
            offsets[group[0].0 as usize + 1] += 1;
            columns.push(group[0].1);
            values.push(group.iter().map(|e| e.2).sum());
        }
        for a in 0..count {
            offsets[a + 1] += offsets[a];
        }

        // Pᵀ(I − M)P, symmetrised, lower triangle.
        let mut entries: Vec<(u32, u32, f64)> = Vec::with_capacity(n + 2 * m.len());
        for &a in &aggregate {
            entries.push((a, a, 1.0));
        }
        for &(i, j, v) in &m {
            let (a, b) = (aggregate[i as usize], aggregate[j as usize]);
            let (col, row) = if a <= b { (a, b) } else { (b, a) };
            entries.push((col, row, if a == b { -(v as f64) } else { -0.5 * v as f64 }));
        }
        let Ok((symbolic, factor)) = factorize_lower(count, entries, None) else {
            return Ok(None);
        };
        let req = symbolic.solve_in_place_scratch::<f64>(1, Par::Seq);
        Ok(Some(Coarse {
            aggregate,
            offsets,
            columns,
            values,
            symbolic,
            factor,
            rhs: [vec![0.0; count], vec![0.0; count], vec![0.0; count]],
            scratch: [MemBuffer::new(req), MemBuffer::new(req), MemBuffer::new(req)],
        }))
    }

    /// Number of coarse unknowns.
    pub(super) fn len(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Given the iterate `x` and its image `g = G(x)`, adds the coarse
    /// correction `P (Pᵀ(I − M)P)⁻¹ Pᵀ M (g − x)` to `g`.
    pub(super) fn correct(&mut self, x: &[Vec3], g: &mut [Vec3]) {
        let count = self.len();
        let [rx, ry, rz] = &mut self.rhs;
        let (offsets, columns, values) = (&self.offsets, &self.columns, &self.values);
        {
            let g = &*g;
            rx.par_iter_mut()
                .zip(ry.par_iter_mut())
                .zip(rz.par_iter_mut())
                .enumerate()
                .with_min_len(64)
                .for_each(|(a, ((bx, by), bz))| {
                    let mut sum = glam::DVec3::ZERO;
                    for k in offsets[a] as usize..offsets[a + 1] as usize {
                        let j = columns[k] as usize;
                        sum += ((g[j] - x[j]) * values[k]).as_dvec3();
                    }
                    (*bx, *by, *bz) = (sum.x, sum.y, sum.z);
                });
        }
        let llt = LltRef::<usize, f64>::new(&self.symbolic, &self.factor);
        self.rhs.par_iter_mut().zip(self.scratch.par_iter_mut()).for_each(|(column, buffer)| {
            let rhs = MatMut::from_column_major_slice_mut(column.as_mut_slice(), count, 1);
            llt.solve_in_place_with_conj(Conj::No, rhs, Par::Seq, MemStack::new(buffer));
        });
        let [cx, cy, cz] = &self.rhs;
        let aggregate = &self.aggregate;
        g.par_iter_mut().enumerate().with_min_len(4096).for_each(|(i, gi)| {
            let a = aggregate[i] as usize;
            *gi += Vec3::new(cx[a] as f32, cy[a] as f32, cz[a] as f32);
        });
    }
}

/// Aggregates of the graph of `m` (sorted by row): rounds of greedy
/// one-ring aggregation, each on the graph of the previous round's
/// aggregates, until at most [`MAX_AGGREGATES`] remain. Sequential, in vertex order: deterministic.
fn aggregates(n: usize, m: &[(u32, u32, f32)]) -> Vec<u32> {
    // Symmetric adjacency of the vertices.
    let mut edges: Vec<(u32, u32)> = m.iter().flat_map(|&(i, j, _)| [(i, j), (j, i)]).collect();
    edges.par_sort_unstable();
    edges.dedup();
    let mut map: Vec<u32> = (0..n as u32).collect();
    let mut nodes = n;
    for _ in 0..MAX_ROUNDS {
        if nodes <= MAX_AGGREGATES && nodes < n {
            break;
        }
        let (of, count) = aggregate_once(nodes, &edges);
        for v in &mut map {
            *v = of[*v as usize];
        }
        edges = aggregate_edges(&edges, &of);
        nodes = count;
    }
    map
}
