//! The global step: `(Σ w AᵀA) x = Σ w Aᵀ p`, factorised once per set of weights.
//!
//! Two shapes of matrix occur. When every row selects a single vertex (closeness,
//! per-vertex targets, inertia) the matrix is diagonal and the global step is a
//! weighted average: no factorisation, one fused pass. When some row couples
//! vertices (the linearised pyramid row, strain limits) the matrix is a sparse
//! SPD matrix: `faer`'s sparse Cholesky (AMD ordering) is computed once, and
//! each iteration is one back-substitution per coordinate, the three running in
//! parallel. The symbolic analysis depends only on the rows, so changing
//! weights (closeness painted differently) only redoes the numeric part.

// `!(x > limit)` on purpose throughout: a NaN must fail these checks, not pass them.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::sync::Arc;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use glam::Vec3;
use rayon::prelude::*;

use super::constraint::{Constraint, Context, DiagonalChunk, Rows};
use crate::{Error, Result};

/// Which global step a solver runs: reported so that benchmarks and tests can
/// tell the two apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SystemKind {
    /// Every row selects one vertex: the global step is a weighted average.
    Diagonal,
    /// Some rows couple vertices: prefactored sparse Cholesky.
    Cholesky,
}

/// One constraint's rows as the system sees them.
pub(crate) struct RowBlock<'a> {
    pub rows: &'a Rows,
    pub weights: &'a [f32],
    /// Index of the block's first row among all rows of its kind.
    pub offset: usize,
}

/// `AᵀW` stored by vertex: for vertex `k`, the rows that touch it and `w·a`.
/// The global right-hand side is then a gather per vertex in a fixed order,
/// which keeps it deterministic without atomics or per-thread buffers.
#[derive(Debug, Clone, Default)]
pub(crate) struct Gather {
    offsets: Vec<u32>,
    rows: Vec<u32>,
    coefficients: Vec<f32>,
}

impl Gather {
    pub fn build(vertex_count: usize, blocks: &[RowBlock<'_>]) -> Self {
        let mut offsets = vec![0u32; vertex_count + 1];
        for block in blocks {
            for r in 0..block.rows.len() {
                for &v in block.rows.row(r).0 {
                    offsets[v as usize + 1] += 1;
                }
            }
        }
        for k in 0..vertex_count {
            offsets[k + 1] += offsets[k];
        }
        let total = offsets[vertex_count] as usize;
        let mut fill = offsets.clone();
        let mut rows = vec![0u32; total];
        let mut coefficients = vec![0f32; total];
        // Blocks, then rows, in order: the per-vertex sums below always add in
        // this order, whatever the thread count.
        for block in blocks {
            for r in 0..block.rows.len() {
                let (vertices, coeffs) = block.rows.row(r);
                for (&v, &a) in vertices.iter().zip(coeffs) {
                    let at = fill[v as usize] as usize;
                    rows[at] = (block.offset + r) as u32;
                    coefficients[at] = a * block.weights[r];
                    fill[v as usize] += 1;
                }
            }
        }
        Gather {
            offsets,
            rows,
            coefficients,
        }
    }

    /// `(AᵀW p)_k`.
    #[inline(always)]
    pub fn apply(&self, k: usize, projections: &[Vec3]) -> Vec3 {
        let range = self.offsets[k] as usize..self.offsets[k + 1] as usize;
        let mut sum = Vec3::ZERO;
        for (&r, &c) in self.rows[range.clone()]
            .iter()
            .zip(&self.coefficients[range])
        {
            sum += projections[r as usize] * c;
        }
        sum
    }
}

/// Vertices per task of the fused diagonal step: fixed, so that the work
/// split (and nothing else) depends on the thread count; small enough that
/// a chunk's positions and targets stay in L1/L2, and that a character's
/// 13k vertices make enough tasks to share evenly between two threads (at
/// 4096, four tasks split 8192 : 5188 vertices, a fifth of the step idle).
pub(crate) const CHUNK: usize = 1024;

thread_local! {
    /// Each worker's target buffer for the fused step, kept between chunks and
    /// iterations: allocating and zero-filling one per chunk cost several
    /// percent of an iteration. Every row's target is written before it is read.
    static TARGETS: std::cell::RefCell<Vec<Vec3>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// One variable identity block of a diagonal system, by rows: the vertex of
/// each row, its weight, and where each vertex chunk's rows start. Only built
/// when the rows' vertices are strictly ascending, so that a chunk of
/// vertices is a contiguous range of rows.
struct BatchedBlock {
    vertex: Vec<u32>,
    weight: Vec<f32>,
    /// `chunks + 1` row boundaries.
    chunk_rows: Vec<u32>,
}

/// The factorised global matrix.
enum Factor {
    Diagonal {
        inverse: Vec<f32>,
        /// Per variable block, when every block allows it (see [`BatchedBlock`]).
        batched: Option<Vec<BatchedBlock>>,
    },
    Cholesky {
        symbolic: Arc<SymbolicCholesky<usize>>,
        values: Vec<f64>,
        /// Right-hand sides, one column per coordinate.
        columns: [Vec<f64>; 3],
        /// Solve scratch, one per column so the three solves run at once
        /// without allocating per iteration.
        scratch: [MemBuffer; 3],
    },
}

/// The global step of one solver for one set of weights.
pub(crate) struct System {
    vertex_count: usize,
    /// `AᵀW` over the rows whose projection changes every iteration.
    variable: Gather,
    /// `AᵀW` over the rows whose projection is fixed within a solve.
    constant: Gather,
    factor: Factor,
}

impl System {
    /// Assembles and factorises. `symbolic` is a previous analysis of the same
    /// rows (weights may differ), reused when given.
    pub fn build(
        vertex_count: usize,
        variable: &[RowBlock<'_>],
        constant: &[RowBlock<'_>],
        symbolic: Option<Arc<SymbolicCholesky<usize>>>,
    ) -> Result<Self> {
        let diagonal = variable
            .iter()
            .chain(constant)
            .all(|b| b.rows.is_identity());
        let factor = if diagonal {
            let mut sum = vec![0f32; vertex_count];
            for block in variable.iter().chain(constant) {
                for r in 0..block.rows.len() {
                    sum[block.rows.row(r).0[0] as usize] += block.weights[r];
                }
            }
            if let Some(v) = sum.iter().position(|&s| !(s > 0.0)) {
                return Err(Error::Numerical(format!(
                    "vertex {v} has no weight in the solve: no constraint and no closeness holds it"
                )));
            }
            Factor::Diagonal {
                inverse: sum.iter().map(|s| 1.0 / s).collect(),
                batched: batched(vertex_count, variable),
            }
        } else {
            cholesky(vertex_count, variable.iter().chain(constant), symbolic)?
        };
        Ok(System {
            vertex_count,
            variable: Gather::build(vertex_count, variable),
            constant: Gather::build(vertex_count, constant),
            factor,
        })
    }

    pub fn kind(&self) -> SystemKind {
        match self.factor {
            Factor::Diagonal { .. } => SystemKind::Diagonal,
            Factor::Cholesky { .. } => SystemKind::Cholesky,
        }
    }

    pub fn symbolic(&self) -> Option<Arc<SymbolicCholesky<usize>>> {
        match &self.factor {
            Factor::Cholesky { symbolic, .. } => Some(symbolic.clone()),
            Factor::Diagonal { .. } => None,
        }
    }

    /// `1 / Σ w` per vertex of a diagonal system; `None` for a coupled one.
    pub fn diagonal_inverse(&self) -> Option<&[f32]> {
        match &self.factor {
            Factor::Diagonal { inverse, .. } => Some(inverse),
            Factor::Cholesky { .. } => None,
        }
    }

    /// Number of stored entries of the Cholesky factor (0 for a diagonal system).
    pub fn factor_nnz(&self) -> usize {
        match &self.factor {
            Factor::Cholesky { values, .. } => values.len(),
            Factor::Diagonal { .. } => 0,
        }
    }

    /// `AᵀW p` over the constant rows, once per solve.
    pub fn constant_rhs(&self, projections: &[Vec3], out: &mut [Vec3]) {
        // By chunks, like the fused step: per-vertex tasks cost more than the sums.
        out.par_chunks_mut(CHUNK).enumerate().for_each(|(c, o)| {
            for (i, o) in o.iter_mut().enumerate() {
                *o = self.constant.apply(c * CHUNK + i, projections);
            }
        });
    }

    /// One fused local + global step for a diagonal system: every row
    /// touches one vertex, so each vertex projects its own rows, sums them
    /// and divides, in one pass, without a projection buffer. Returns false
    /// (doing nothing) for a coupled system.
    pub fn solve_fused(
        &self,
        rhs_constant: &[Vec3],
        constraints: &[(&dyn Constraint, usize)],
        context: &Context<'_>,
        out: &mut [Vec3],
    ) -> bool {
        let Factor::Diagonal { inverse, batched } = &self.factor else {
            return false;
        };
        if let Some(blocks) = batched {
            // By chunks of vertices: start from the constant right-hand side,
            // add each constraint's weighted targets (batched projection, in
            // block then row order: the same sums as the gather below), divide.
            out.par_chunks_mut(CHUNK).enumerate().for_each(|(c, o)| {
                let base = c * CHUNK;
                if let (Some((block, others)), Some(((constraint, _), other_constraints))) =
                    (blocks.split_first(), constraints.split_first())
                {
                    // The first varying constraint may run the whole step itself;
                    // the rows of the others (few: ring fits of irregular
                    // vertices) are then added on top, `w·t·(1/Σw)` each, which
                    // keeps the fast kernel for the mesh's bulk.
                    let rows = block.chunk_rows[c] as usize..block.chunk_rows[c + 1] as usize;
                    let chunk = DiagonalChunk {
                        base,
                        constant: &rhs_constant[base..base + o.len()],
                        inverse: &inverse[base..base + o.len()],
                        weights: &block.weight[rows.clone()],
                    };
                    if constraint.solve_chunk(context, rows, &chunk, o) {
                        for (block, &(constraint, _)) in others.iter().zip(other_constraints) {
                            for r in block.chunk_rows[c] as usize..block.chunk_rows[c + 1] as usize {
                                let v = block.vertex[r] as usize;
                                o[v - base] += constraint.project_row(context, r) * (block.weight[r] * inverse[v]);
                            }
                        }
                        return;
                    }
                }
                o.copy_from_slice(&rhs_constant[base..base + o.len()]);
                let mut accumulate = |targets: &mut Vec<Vec3>| {
                    for (block, &(constraint, _)) in blocks.iter().zip(constraints) {
                        let rows = block.chunk_rows[c] as usize..block.chunk_rows[c + 1] as usize;
                        if targets.len() < rows.len() {
                            targets.resize(rows.len(), Vec3::ZERO);
                        }
                        let targets = &mut targets[..rows.len()];
                        constraint.project_rows(context, rows.clone(), targets);
                        for ((t, &v), &w) in targets.iter().zip(&block.vertex[rows.clone()]).zip(&block.weight[rows]) {
                            let o = &mut o[v as usize - base];
                            *o += *t * w;
                        }
                    }
                };
                // A projection that itself runs parallel work could let this
                // thread start another chunk while the buffer is lent out:
                // that chunk gets its own.
                TARGETS.with(|cell| match cell.try_borrow_mut() {
                    Ok(mut targets) => accumulate(&mut targets),
                    Err(_) => accumulate(&mut Vec::new()),
                });
                for (o, &inv) in o.iter_mut().zip(&inverse[base..]) {
                    *o *= inv;
                }
            });
            return true;
        }
        let variable = &self.variable;
        out.par_iter_mut().enumerate().with_min_len(512).for_each(|(k, o)| {
            let mut sum = rhs_constant[k];
            let range = variable.offsets[k] as usize..variable.offsets[k + 1] as usize;
            for (&r, &c) in variable.rows[range.clone()].iter().zip(&variable.coefficients[range]) {
                let r = r as usize;
                // Constraints are few and sorted by first row: find the owner.
                let owner = constraints.iter().rposition(|&(_, start)| start <= r).unwrap_or(0);
                let (constraint, start) = constraints[owner];
                sum += constraint.project_row(context, r - start) * c;
            }
            *o = sum * inverse[k];
        });
        true
    }

    /// One global step: `x = N⁻¹ (rhs_constant + AᵀW p)`.
    pub fn solve(&mut self, rhs_constant: &[Vec3], projections: &[Vec3], out: &mut [Vec3]) {
        let variable = &self.variable;
        match &mut self.factor {
            Factor::Diagonal { inverse, .. } => {
                // Fused gather and divide: one pass over the vertices.
                out.par_iter_mut()
                    .enumerate()
                    .with_min_len(1024)
                    .for_each(|(k, o)| {
                        *o = (rhs_constant[k] + variable.apply(k, projections)) * inverse[k];
                    });
            }
            Factor::Cholesky {
                symbolic,
                values,
                columns,
                scratch,
            } => {
                let [cx, cy, cz] = columns;
                cx.par_iter_mut()
                    .zip(cy.par_iter_mut())
                    .zip(cz.par_iter_mut())
                    .enumerate()
                    .with_min_len(1024)
                    .for_each(|(k, ((x, y), z))| {
                        let b = rhs_constant[k] + variable.apply(k, projections);
                        (*x, *y, *z) = (b.x as f64, b.y as f64, b.z as f64);
                    });
                let llt = LltRef::<usize, f64>::new(symbolic, values);
                let n = self.vertex_count;
                // One back-substitution per coordinate, in parallel; each is
                // sequential inside, so the result does not depend on threads.
                columns
                    .par_iter_mut()
                    .zip(scratch.par_iter_mut())
                    .for_each(|(column, buffer)| {
                        let rhs = MatMut::from_column_major_slice_mut(column.as_mut_slice(), n, 1);
                        llt.solve_in_place_with_conj(
                            Conj::No,
                            rhs,
                            Par::Seq,
                            MemStack::new(buffer),
                        );
                    });
                let [cx, cy, cz] = columns;
                out.par_iter_mut()
                    .enumerate()
                    .with_min_len(1024)
                    .for_each(|(k, o)| {
                        *o = Vec3::new(cx[k] as f32, cy[k] as f32, cz[k] as f32);
                    });
            }
        }
    }
}

/// The by-chunk layout of the variable blocks of a diagonal system, if every
/// block's rows select strictly ascending vertices.
fn batched(vertex_count: usize, variable: &[RowBlock<'_>]) -> Option<Vec<BatchedBlock>> {
    let chunks = vertex_count.div_ceil(CHUNK);
    variable
        .iter()
        .map(|block| {
            let vertex: Vec<u32> = (0..block.rows.len()).map(|r| block.rows.row(r).0[0]).collect();
            if vertex.windows(2).any(|p| p[0] >= p[1]) {
                return None;
            }
            let chunk_rows = (0..=chunks)
                .map(|c| vertex.partition_point(|&v| (v as usize) < c * CHUNK) as u32)
                .collect();
            // Identity rows have coefficient 1: the gather's `1 · w` is `w`.
            let weight = block.weights.to_vec();
            Some(BatchedBlock { vertex, weight, chunk_rows })
        })
        .collect()
}

/// Assembles the lower triangle of `Σ w AᵀA` and factorises it.
fn cholesky<'a>(
    n: usize,
    blocks: impl Iterator<Item = &'a RowBlock<'a>>,
    symbolic: Option<Arc<SymbolicCholesky<usize>>>,
) -> Result<Factor> {
    // (column, row, value) with row ≥ column; every diagonal entry present so
    // the pattern never depends on which weights happen to be zero.
    let mut entries: Vec<(u32, u32, f64)> = (0..n as u32).map(|k| (k, k, 0.0)).collect();
    for block in blocks {
        for r in 0..block.rows.len() {
            let (vertices, coeffs) = block.rows.row(r);
            let w = block.weights[r] as f64;
            for (i, (&a, &ca)) in vertices.iter().zip(coeffs).enumerate() {
                for (&b, &cb) in vertices[..=i].iter().zip(&coeffs[..=i]) {
                    let (row, col) = if a >= b { (a, b) } else { (b, a) };
                    // Each unordered pair once: exactly the lower-triangle
                    // entry of the symmetric w·aᵀa.
                    entries.push((col, row, w * ca as f64 * cb as f64));
                }
            }
        }
    }
    let (symbolic, values) = factorize_lower(n, entries, symbolic, false)?;
    let req = symbolic.solve_in_place_scratch::<f64>(1, Par::Seq);
    let scratch = [
        MemBuffer::new(req),
        MemBuffer::new(req),
        MemBuffer::new(req),
    ];
    Ok(Factor::Cholesky {
        symbolic,
        values,
        columns: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
        scratch,
    })
}

/// Sums the duplicates of the lower-triangle entries `(column, row, value)`
/// (in insertion order: deterministic) and factorises the matrix by sparse
/// Cholesky, reusing `symbolic` when it fits. `simplicial` forces a
/// simplicial factor (compressed columns, the diagonal first), whose
/// structure a caller can walk itself; otherwise faer chooses.
pub(crate) fn factorize_lower(
    n: usize,
    entries: Vec<(u32, u32, f64)>,
    symbolic: Option<Arc<SymbolicCholesky<usize>>>,
    simplicial: bool,
) -> Result<(Arc<SymbolicCholesky<usize>>, Vec<f64>)> {
    let lower = LowerColumns::new(n, entries);
    factorize_columns(&lower, symbolic, simplicial)
}

/// A symmetric matrix's lower triangle in compressed columns, rows ascending
/// in each column, duplicates summed.
pub(crate) struct LowerColumns {
    pub n: usize,
    pub col_ptr: Vec<usize>,
    pub row_idx: Vec<usize>,
    pub values: Vec<f64>,
}

impl LowerColumns {
    /// From the lower-triangle entries `(column, row, value)`, duplicates
    /// summed in insertion order (deterministic).
    pub(crate) fn new(n: usize, mut entries: Vec<(u32, u32, f64)>) -> Self {
        // Stable sort: duplicates are summed in insertion order, deterministically.
        entries.par_sort_by_key(|&(col, row, _)| (col, row));
        let mut col_ptr = vec![0usize; n + 1];
        let mut row_idx = Vec::with_capacity(entries.len());
        let mut values = Vec::with_capacity(entries.len());
        for group in entries.chunk_by(|a, b| a.0 == b.0 && a.1 == b.1) {
            let sum: f64 = group.iter().map(|e| e.2).sum();
            col_ptr[group[0].0 as usize + 1] += 1;
            row_idx.push(group[0].1 as usize);
            values.push(sum);
        }
        for k in 0..n {
            col_ptr[k + 1] += col_ptr[k];
        }
        LowerColumns { n, col_ptr, row_idx, values }
    }
}

/// Factorises `lower` by sparse Cholesky, on `symbolic` when given (which
/// must be the analysis of `lower`'s pattern, or at least of its size: the
/// caller answers for the fit), else on a fresh analysis. `simplicial` as
/// in [`factorize_lower`].
pub(crate) fn factorize_columns(
    lower: &LowerColumns,
    symbolic: Option<Arc<SymbolicCholesky<usize>>>,
    simplicial: bool,
) -> Result<(Arc<SymbolicCholesky<usize>>, Vec<f64>)> {
    let n = lower.n;
    let pattern = SymbolicSparseColMatRef::new_checked(n, n, &lower.col_ptr, None, &lower.row_idx);
    let symbolic = match symbolic {
        Some(s) if s.nrows() == n => s,
        _ => Arc::new(
            factorize_symbolic_cholesky(
                pattern,
                Side::Lower,
                SymmetricOrdering::Amd,
                CholeskySymbolicParams {
                    supernodal_flop_ratio_threshold: if simplicial {
                        SupernodalThreshold::FORCE_SIMPLICIAL
                    } else {
                        SupernodalThreshold::AUTO
                    },
                    ..Default::default()
                },
            )
            .map_err(|e| {
                Error::Numerical(format!(
                    "symbolic Cholesky analysis of the global matrix failed: {e:?}"
                ))
            })?,
        ),
    };
    let mut values = Vec::new();
    values
        .try_reserve_exact(symbolic.len_val())
        .map_err(|_| Error::TooLarge {
            what: format!(
                "the Cholesky factor of a {n}-vertex global matrix ({} entries)",
                symbolic.len_val()
            ),
            needed_bytes: symbolic.len_val() as u64 * 8,
            limit_bytes: 0,
        })?;
    values.resize(symbolic.len_val(), 0.0);
    let mut stack =
        MemBuffer::new(symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()));
    symbolic
        .factorize_numeric_llt::<f64>(
            &mut values,
            SparseColMatRef::new(pattern, &lower.values),
            Side::Lower,
            LltRegularization { dynamic_regularization_delta: 0.0, dynamic_regularization_epsilon: 0.0 },
            Par::Seq,
            MemStack::new(&mut stack),
            Default::default(),
        )
        .map_err(|_| {
            Error::Numerical(
                "the global matrix is not positive definite: some part of the mesh has neither closeness nor pinned vertices to hold it"
                    .to_string(),
            )
        })?;
    Ok((symbolic, values))
}
