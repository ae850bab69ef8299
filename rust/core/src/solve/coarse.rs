//! A multilevel correction of the local/global iteration (multigrid with
//! aggregation, as in algebraic multigrid).
//!
//! With a diagonal global matrix one iteration is a Jacobi sweep: a change
//! travels one ring per iteration, and the smooth part of the error shrinks
//! by about `1 − closeness` per iteration (hundreds of iterations at a
//! closeness of 0.01). What beats that locality is a correction of the
//! smooth error on coarser meshes.
//!
//! Near the solution one iteration is an affine map `G(x) ≈ M x + b`, where
//! `M = D⁻¹ Σ w · (how the row targets move with the positions)`: the
//! constraints say how through [`super::Constraint::coupling`] (for pyramid
//! targets: the ring's mean-value weights; closeness: nothing). The error
//! `e = x_∞ − x` then satisfies `(I − M) e = r`, `r = G(x) − x` the residual.
//! The accelerated step is under-relaxed, `x' = x + ω r` ([`RELAXATION`]),
//! and the error left after it solves `(I − M)(x_∞ − x') = ((1 − ω) I + ω M) r`.
//! Restricted to aggregates of vertices (`P` piecewise constant, one round
//! of greedy one-ring aggregation of the coupling graph, ~7 vertices each),
//! the correction solves `A₁ e₁ = ω Pᵀ M r` with `A₁ = Pᵀ(I − M)P`
//! symmetrised and adds `P e₁` to `x'`. It leaves out the `(1 − ω) r` term:
//! with it the 100k tube converges a little faster (2.0 % against 2.5 % after
//! 6 iterations at closeness 0.01), but on the MakeHuman body the corrected
//! iteration then ends in a two-cycle 8.7 % away from the fixed point.
//!
//! `A₁` (~n/7 unknowns) is too large to solve exactly every iteration (a
//! direct solve at 100k vertices costs several plain iterations) and one
//! round is what makes the correction work (a coarser first level, ~50
//! vertices an aggregate, leaves most of the error between the scales), so
//! it is solved approximately by one cycle through coarser levels: on each
//! level the correction from the next one (the same aggregation again),
//! then Gauss–Seidel smoothing ([`SWEEPS`]), down to a level of at most
//! [`MAX_AGGREGATES`] unknowns solved by sparse Cholesky, factorised once
//! ([`super::coarsest`]). Piecewise constant aggregates make a coarse level
//! stiffer than the level above, so its correction falls short; it is scaled
//! by [`OVERCORRECTION`] between coarse levels (not onto the mesh, where the
//! nonlinear step smooths: there it overshoots).
//!
//! The correction is linear in the residual, so it vanishes at the fixed
//! point: the corrected iteration has the plain one's fixed points. With an
//! iteration hook that holds vertices (the stepper's contact passes), the
//! held vertices are fixed (Dirichlet) rows of the coarse problem for that
//! iteration: their correction is 0, `P` loses their rows (`A₁ =
//! P_fᵀ(I − M)P_f` over the free vertices, assembled and factorised again
//! whenever the held set changes, on the aggregations of the free problem),
//! and their residual leaves the right-hand side. So the correction moves
//! the free vertices as the held ones stay, and it also vanishes where the
//! hook holds the iteration. (Before, the held vertices' residual was left
//! out but `A₁` took them as free and their whole aggregates went
//! uncorrected.) A held vertex the hook reports sliding along a surface
//! (kinetic friction or none, [`super::IterationHook::sliding`]) is not
//! fixed: it stays an unknown whose residual and correction keep only their
//! part along that surface, its residual shortened by friction as the hook
//! shortens a step ([`super::contacts`]), so the correction moves a sliding
//! contact patch along the collider.
//!
//! Why the relaxation: on a real character (the MakeHuman body's fingers,
//! strongly bent) the undamped iteration, plain or corrected, can fall into
//! a two-cycle, alternating between two shapes from one iteration to the
//! next. Damping by 0.9 removes it and costs little (the coarse levels carry
//! the smooth error the damping slows).
//!
//! The smoothing runs Gauss–Seidel inside fixed blocks of rows (in parallel,
//! Jacobi between the blocks) and the other loops write disjoint outputs in a
//! fixed order: results do not depend on the thread count.

use std::sync::Arc;

use glam::Vec3;
use rayon::prelude::*;

use super::coarsest::{Analysis, Coarsest};
use super::contacts::MovedVertices;
use super::system::RowBlock;
use crate::mesh::{aggregate_once, group_members};
use crate::Result;

/// Most unknowns of the coarsest level, which is solved exactly: rounds of
/// one-ring aggregation (each divides the count by ~7) run until a level is
/// at most this large (~2k unknowns at 100k vertices).
const MAX_AGGREGATES: usize = 4000;

/// At most this many rounds of aggregation (levels below the mesh).
const MAX_ROUNDS: usize = 4;

/// Fewer unknowns than this on the first level and the correction is not worth it.
const MIN_AGGREGATES: usize = 8;

/// Gauss–Seidel sweeps on a level after the correction from the next one
/// (none before it: the cycle starts from a zero error). With the Chebyshev
/// extrapolation, on the 100k tube, error after 6 iterations from a cold
/// start at closeness 0.05 / 0.01: 1 sweep 1.7 / 2.6 %, 2 sweeps 1.7 / 1.8 %;
/// a sweep before the correction as well (a V-cycle) 1.7 / 1.8 %. Each sweep
/// costs about a tenth of an accelerated iteration: the time buys more as
/// iterations.
const SWEEPS: usize = 1;

/// Vertices of a block of the last pass (see [`Coarse::correct`]).
const APPLY_BLOCK: usize = 4096;

/// Rows of a block of the smoothing sweeps (see [`Csr::sweep`]).
const BLOCK: usize = 1024;

/// Scale of the correction from a coarser level (see the module documentation).
/// 1.5 against 1: 3.8 % against 5.3 % after 5 iterations in the case of
/// [`SWEEPS`] (2 sweeps, measured before the relaxation); 2 is about as good.
const OVERCORRECTION: f32 = 1.5;

/// Coarse problems with held vertices kept, for the last held sets: a
/// contact patch's rim flickers, so the held set often returns to one it
/// had an iteration or two before, and each new set costs an assembly and
/// a factorisation of the coarse levels.
const HELD_CACHED: usize = 4;

/// Under-relaxation of the accelerated step (see the module documentation).
pub(super) const RELAXATION: f32 = 0.9;

/// A symmetric matrix in compressed rows, diagonal included.
struct Csr {
    offsets: Vec<u32>,
    columns: Vec<u32>,
    values: Vec<f32>,
    diagonal: Vec<f32>,
    inverse_diagonal: Vec<f32>,
}

impl Csr {
    /// From `(row, column, value)` entries (both triangles), duplicates
    /// summed in a fixed order.
    fn from_entries(n: usize, mut entries: Vec<(u32, u32, f64)>) -> Self {
        entries.par_sort_by_key(|&(i, j, _)| (i, j));
        let mut offsets = vec![0u32; n + 1];
        let (mut columns, mut values) = (Vec::with_capacity(entries.len()), Vec::with_capacity(entries.len()));
        let mut inverse_diagonal = vec![0.0f32; n];
        let mut diagonal = vec![0.0f32; n];
        for group in entries.chunk_by(|a, b| a.0 == b.0 && a.1 == b.1) {
            let (i, j) = (group[0].0, group[0].1);
            let sum: f64 = group.iter().map(|e| e.2).sum();
            if i == j {
                diagonal[i as usize] = sum as f32;
                inverse_diagonal[i as usize] = if sum > 0.0 { (1.0 / sum) as f32 } else { 0.0 };
            }
            offsets[i as usize + 1] += 1;
            columns.push(j);
            values.push(sum as f32);
        }
        for a in 0..n {
            offsets[a + 1] += offsets[a];
        }
        Csr { offsets, columns, values, diagonal, inverse_diagonal }
    }

    fn len(&self) -> usize {
        self.offsets.len() - 1
    }

    fn row(&self, i: usize) -> impl Iterator<Item = (usize, f32)> + '_ {
        let range = self.offsets[i] as usize..self.offsets[i + 1] as usize;
        self.columns[range.clone()].iter().map(|&j| j as usize).zip(self.values[range].iter().copied())
    }

    /// The off-diagonal pattern as both-way edges, sorted.
    fn edges(&self) -> Vec<(u32, u32)> {
        (0..self.len())
            .flat_map(|i| self.row(i).filter(move |&(j, _)| j != i).map(move |(j, _)| (i as u32, j as u32)))
            .collect()
    }

    /// `Pᵀ A P` for the piecewise constant `P` of the aggregates `of`.
    fn restricted(&self, of: &[u32], count: usize) -> Csr {
        let entries = (0..self.len())
            .flat_map(|i| self.row(i).map(move |(j, v)| (of[i], of[j], v as f64)))
            .collect();
        Csr::from_entries(count, entries)
    }

    /// One sweep of `A e = b`: Gauss–Seidel inside fixed blocks of
    /// [`BLOCK`] rows, run in parallel, each reading the other blocks'
    /// values from before the sweep (hybrid Gauss–Seidel). The blocks do not
    /// depend on the thread count, so neither does the result. `before` is
    /// scratch of `e`'s length.
    fn sweep(&self, b: &[Vec3], e: &mut [Vec3], before: &mut [Vec3], forwards: bool) {
        before.copy_from_slice(e);
        let before = &*before;
        let (offsets, columns, values) = (&self.offsets[..], &self.columns[..], &self.values[..]);
        e.par_chunks_mut(BLOCK).enumerate().for_each(|(c, block)| {
            let base = c * BLOCK;
            let len = block.len();
            for k in 0..len {
                let k = if forwards { k } else { len - 1 - k };
                let i = base + k;
                let mut sum = b[i];
                let (start, end) = (offsets[i] as usize, offsets[i + 1] as usize);
                for (&j, &a) in columns[start..end].iter().zip(&values[start..end]) {
                    let j = j as usize;
                    // In-block rows see this sweep's values (the diagonal's
                    // own term is cancelled below), others the sweep's start.
                    let inside = j.wrapping_sub(base);
                    let value = if inside < len { block[inside] } else { before[j] };
                    sum -= a * value;
                }
                // The loop subtracted the diagonal term with the old value: add it back.
                sum += block[k] * self.diagonal[i];
                block[k] = sum * self.inverse_diagonal[i];
            }
        });
    }

}

/// A level between the mesh and the coarsest one: smoothed, not solved.
struct Level {
    matrix: Csr,
    /// Aggregate of each of this level's nodes on the next level.
    down: Vec<u32>,
    rhs: Vec<Vec3>,
    error: Vec<Vec3>,
    /// The sweeps' copy of `error`.
    scratch: Vec<Vec3>,
}

/// Squared norms over the vertices, from [`Coarse::correct`].
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Sums {
    /// `Σ |G(x) − x|²`: the plain iteration's residual.
    pub residual: f64,
    /// `Σ |x' − x|²`: the accelerated step.
    pub step: f64,
    /// `Σ |x' − input|²`: how far the new iterate is from the input.
    pub offset: f64,
}

/// The levels below the mesh for one first-level matrix: one V-cycle
/// solves it approximately.
struct Hierarchy {
    /// Levels smoothed by Gauss–Seidel, finest first; empty when the first
    /// level is the coarsest.
    levels: Vec<Level>,
    /// The coarsest level (the first one when `levels` is empty), its
    /// right-hand side and its solution.
    coarsest: Coarsest,
    coarsest_rhs: Vec<Vec3>,
    coarsest_error: Vec<Vec3>,
}

/// The coarse problem with the vertices a hook holds fixed (see
/// [`Coarse::correct`]), for the set it was built for.
struct Held {
    /// The held vertices, ascending.
    vertices: Vec<u32>,
    /// The cycle of `A₁` with the held vertices' rows and columns of `P`
    /// removed; `None` if that matrix could not be factorised (then the
    /// iteration takes the plain step).
    hierarchy: Option<Hierarchy>,
}

/// The coarse levels of one solver for one set of weights.
pub(super) struct Coarse {
    /// Aggregate of each vertex on the first level.
    aggregate: Vec<u32>,
    /// The vertices of each first-level aggregate: `members[member_offsets[a]..member_offsets[a + 1]]`.
    member_offsets: Vec<u32>,
    members: Vec<u32>,
    /// `ω Pᵀ M` by first-level aggregate: offsets into `columns`/`values`.
    offsets: Vec<u32>,
    columns: Vec<u32>,
    values: Vec<f32>,
    /// `M` by vertex (compressed rows, no diagonal), for the coarse problem
    /// with held vertices.
    m: VertexRows,
    /// Every level's pattern, for the coarse problems with held vertices
    /// and for new values of the same pattern.
    pattern: Arc<HierarchyPattern>,
    /// How `M` was generated, for new values of the same pattern.
    sequence: Arc<Sequence>,
    /// The cycle of `A₁` (nothing held).
    free: Hierarchy,
    /// The cycles with held vertices fixed for the last [`HELD_CACHED`]
    /// held sets, the most recent first.
    held: Vec<Held>,
    /// How many coarse problems with held vertices were assembled.
    held_assemblies: usize,
    /// The first level's sums by slot with nothing held, made at the first
    /// held assembly, from which the held ones are summed again where they differ.
    free_first: Option<SlotSums>,
}

/// A sparse matrix by vertex rows, `M`'s pattern.
struct VertexRows {
    offsets: Vec<u32>,
    columns: Vec<u32>,
    values: Vec<f32>,
}

impl VertexRows {
    /// From `(row, column, value)` entries sorted by row.
    fn from_sorted(n: usize, entries: &[(u32, u32, f32)]) -> Self {
        let mut offsets = vec![0u32; n + 1];
        for &(i, _, _) in entries {
            offsets[i as usize + 1] += 1;
        }
        for v in 0..n {
            offsets[v + 1] += offsets[v];
        }
        VertexRows { offsets, columns: entries.iter().map(|e| e.1).collect(), values: entries.iter().map(|e| e.2).collect() }
    }

    fn row(&self, i: usize) -> impl Iterator<Item = (usize, f32)> + '_ {
        let range = self.offsets[i] as usize..self.offsets[i + 1] as usize;
        self.columns[range.clone()].iter().map(|&j| j as usize).zip(self.values[range].iter().copied())
    }
}

impl Coarse {
    /// Builds the coarse levels from the linear model of the iteration, or
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
        Self::assemble(n, variable, couplings, inverse, None)
    }

    /// [`Self::build`] for new values of the pattern this was built for:
    /// the same variable constraints with the same weights, the diagonal
    /// changed (a constant constraint's weights changed, as compliant
    /// colliders' target rows do every substep). The aggregations depend on
    /// the pattern only, so they are kept and only the numbers are built
    /// again: the same levels as [`Self::build`] would make, for less (on
    /// the compliant flesh bench the aggregation was most of the solver's
    /// rebuild every frame, issue 29). Checks that the pattern still matches
    /// and aggregates afresh if not.
    pub(super) fn with_values(
        &self,
        n: usize,
        variable: &[RowBlock<'_>],
        couplings: &[Option<&super::Rows>],
        inverse: &[f32],
    ) -> Result<Option<Self>> {
        Self::assemble(n, variable, couplings, inverse, Some(self))
    }

    fn assemble(
        n: usize,
        variable: &[RowBlock<'_>],
        couplings: &[Option<&super::Rows>],
        inverse: &[f32],
        kept: Option<&Coarse>,
    ) -> Result<Option<Self>> {
        // M by vertex: (row vertex, column vertex, value), in generation order.
        let mut generated: Vec<(u32, u32, f32)> = Vec::new();
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
                        generated.push((v, j, scale * a));
                    }
                }
            }
        }
        if generated.is_empty() {
            return Ok(None);
        }
        if let Some(k) = kept.filter(|k| k.aggregate.len() == n && k.sequence.is_of(&generated)) {
            return Ok(k.revalued(&generated));
        }
        // Sorted by (row, column), stably: `order` is the permutation, kept
        // so that new values of the same sequence need no sort.
        let mut keyed: Vec<(u32, u32, u32)> = generated.iter().enumerate().map(|(k, &(i, j, _))| (i, j, k as u32)).collect();
        keyed.par_sort_unstable();
        let order: Vec<u32> = keyed.into_iter().map(|e| e.2).collect();
        let m: Vec<(u32, u32, f32)> = order.iter().map(|&k| generated[k as usize]).collect();
        let kept = kept.filter(|k| k.aggregate.len() == n && k.m.offsets.len() == n + 1 && same_pattern(&m, &k.m));

        // First level: one round of aggregation of the vertices.
        let (aggregate, count) = match kept {
            Some(k) => (k.aggregate.clone(), k.member_offsets.len() - 1),
            None => {
                let mut edges: Vec<(u32, u32)> = m.iter().flat_map(|&(i, j, _)| [(i, j), (j, i)]).collect();
                edges.par_sort_unstable();
                edges.dedup();
                aggregate_once(n, &edges)
            }
        };
        if count < MIN_AGGREGATES || count * 4 > n {
            return Ok(None);
        }

        // ω Pᵀ M by aggregate, duplicates summed in order (see the module
        // documentation for the term left out).
        let mut q: Vec<(u32, u32, f32)> = m.iter().map(|&(i, j, v)| (aggregate[i as usize], j, RELAXATION * v)).collect();
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
        let q_slots = m
            .iter()
            .map(|&(i, j, _)| {
                let a = aggregate[i as usize] as usize;
                let (start, end) = (offsets[a] as usize, offsets[a + 1] as usize);
                (start + columns[start..end].binary_search(&j).expect("every entry of M has a slot")) as u32
            })
            .collect();
        let sequence = Arc::new(Sequence { pairs: generated.iter().map(|&(i, j, _)| (i, j)).collect(), order, q_slots });

        let m = VertexRows::from_sorted(n, &m);
        let downs: Option<Vec<&[u32]>> = kept.map(|k| k.free.levels.iter().map(|l| &l.down[..]).collect());
        let first = first_level(&aggregate, count, &m, None);
        let (matrices, downs) = Hierarchy::chain(first, downs.as_deref());
        let pattern = Arc::new(HierarchyPattern::new(&aggregate, &m, &matrices, &downs));
        // New weights often keep the coarsest pattern: then its analysis too.
        let Some(free) = Hierarchy::from_chain(matrices, downs, kept.map(|k| k.free.coarsest.analysis())) else {
            return Ok(None);
        };

        let (member_offsets, members) = match kept {
            Some(k) => (k.member_offsets.clone(), k.members.clone()),
            None => group_members(&aggregate, count),
        };
        Ok(Some(Coarse { aggregate, member_offsets, members, offsets, columns, values, m, pattern, sequence, free, held: Vec::new(), held_assemblies: 0, free_first: None }))
    }

    /// These coarse levels for `generated`, an `M` generated in the same
    /// sequence of (row, column) as this one (new weights on the same
    /// pattern), by slot: what [`Self::assemble`] would build by sorting, to
    /// the bit (the sorts are stable, so each slot sums its entries in
    /// generation order either way). `None` where it would give `None`
    /// (the new free problem cannot be factorised).
    fn revalued(&self, generated: &[(u32, u32, f32)]) -> Option<Self> {
        let order = &self.sequence.order;
        let sorted: Vec<f32> = order.par_iter().map(|&k| generated[k as usize].2).collect();
        // The value `Iterator::sum` starts from, as in the sorted assembly.
        let start: f32 = std::iter::empty::<f32>().sum();
        let mut values = vec![start; self.columns.len()];
        for (&slot, &v) in self.sequence.q_slots.iter().zip(&sorted) {
            values[slot as usize] += RELAXATION * v;
        }
        let m = VertexRows { offsets: self.m.offsets.clone(), columns: self.m.columns.clone(), values: sorted };
        let matrices = self.pattern.chain(&self.aggregate, &m, None);
        let downs = self.free.levels.iter().map(|l| l.down.clone()).collect();
        let free = Hierarchy::from_chain(matrices, downs, [self.free.coarsest.analysis()])?;
        Some(Coarse {
            aggregate: self.aggregate.clone(),
            member_offsets: self.member_offsets.clone(),
            members: self.members.clone(),
            offsets: self.offsets.clone(),
            columns: self.columns.clone(),
            values,
            m,
            pattern: Arc::clone(&self.pattern),
            sequence: Arc::clone(&self.sequence),
            free,
            held: Vec::new(),
            held_assemblies: 0,
            free_first: None,
        })
    }

    /// Builds the coarse problem with the vertices `held` (ascending;
    /// `mask` per vertex) fixed, unless one of the last [`HELD_CACHED`] was
    /// built for them (then it becomes the most recent).
    fn prepare_held(&mut self, vertices: &[u32], mask: &[bool]) {
        if let Some(k) = self.held.iter().position(|h| h.vertices == vertices) {
            self.held[..=k].rotate_right(1);
            return;
        }
        if self.free_first.is_none() {
            self.free_first = Some(self.pattern.first.sums(&self.aggregate, &self.m, None));
        }
        let free_first = self.free_first.as_ref().expect("made above");
        let first = self.pattern.first.held_sums(free_first, &self.aggregate, &self.m, mask, vertices);
        let matrices = self.pattern.chain_from(first);
        let downs = self.free.levels.iter().map(|l| l.down.clone()).collect();
        // The coarsest pattern changes only where a held set empties a
        // coarsest node or all the links between two: mostly it is one of
        // the cached sets' or the free problem's.
        let known = self.held.iter().filter_map(|h| h.hierarchy.as_ref()).chain([&self.free]).map(|h| h.coarsest.analysis());
        let hierarchy = Hierarchy::from_chain(matrices, downs, known);
        self.held.insert(0, Held { vertices: vertices.to_vec(), hierarchy });
        self.held.truncate(HELD_CACHED);
        self.held_assemblies += 1;
    }

    /// How many coarse problems with held vertices were assembled and
    /// factorised (one per held set not among the last [`HELD_CACHED`]).
    pub(super) fn held_assemblies(&self) -> usize {
        self.held_assemblies
    }

    /// Given the iterate `x` and its image `g = G(x)`, overwrites `g` with
    /// the accelerated next iterate: `x + ω (g − x)` plus the correction
    /// `P e₁`, `e₁` from one V-cycle on `A₁ e₁ = ω Pᵀ M (g − x)`, extrapolated
    /// from the iterate before, `previous + weight · (that − previous)`
    /// (see [`super::chebyshev`]; weight 1 = none), except at the vertices
    /// `extrapolation.1` marks, which get neither the extrapolation nor the
    /// correction (rows that carry a vertex from its neighbour: the next
    /// plain step carries the correction of the neighbour to them; corrected
    /// themselves, a chain of them, a fan cap's rim, passed a wave along the
    /// rim that grew ~8 % an iteration on the 5M bake tube's warm frames);
    /// `previous` then holds `x`.
    /// Returns the squared norms of the residual (`g − x` before all that),
    /// of the accelerated step and of the new iterate's offset from `input`.
    ///
    /// `contacts` gives the vertices the hook moved in the last iteration.
    /// Those it left sliding along a surface are free unknowns: their step
    /// enters the right-hand side as their contact admits it (along the
    /// surface, less kinetic friction) and their row and correction keep
    /// only their part along the surface. The others (`held`, stuck) have
    /// their correction fixed at 0, a Dirichlet
    /// condition of the coarse problem. Their rows and columns leave `P`
    /// (`A₁` becomes `P_fᵀ(I − M)P_f` over the free vertices, factorised
    /// again when the held set changes), and their residual leaves the
    /// right-hand side (the hook, not the step, decides where they go). So
    /// the correction moves the free vertices as the held ones stay, and it
    /// still vanishes at the held iteration's fixed point.
    pub(super) fn correct(
        &mut self,
        x: &[Vec3],
        g: &mut [Vec3],
        contacts: &MovedVertices,
        previous: &mut [Vec3],
        extrapolation: (f32, Option<&[bool]>),
        input: &[Vec3],
    ) -> Sums {
        let (weight, unextrapolated) = extrapolation;
        let stuck = contacts.held();
        let with_contacts = stuck.is_some() || contacts.any_sliding();
        let error: Option<&[Vec3]> = if !with_contacts {
            let (offsets, columns, values) = (&self.offsets, &self.columns, &self.values);
            let g = &*g;
            self.free.first_rhs().par_iter_mut().enumerate().with_min_len(256).for_each(|(a, b)| {
                let mut sum = Vec3::ZERO;
                for k in offsets[a] as usize..offsets[a + 1] as usize {
                    let j = columns[k] as usize;
                    sum += (g[j] - x[j]) * values[k];
                }
                *b = sum;
            });
            Some(self.free.solve())
        } else {
            if let Some((vertices, mask)) = stuck {
                self.prepare_held(vertices, mask);
            }
            let Coarse { member_offsets, members, m, held, free, .. } = self;
            let hierarchy = match stuck {
                Some(_) => held.first_mut().and_then(|h| h.hierarchy.as_mut()),
                None => Some(free),
            };
            match hierarchy {
                // ω P_fᵀ M_ff r over the free rows and columns, each sliding
                // vertex's step as its contact admits it and its row along its surface.
                Some(hierarchy) => {
                    let g = &*g;
                    hierarchy.first_rhs().par_iter_mut().enumerate().with_min_len(256).for_each(|(a, b)| {
                        let mut sum = Vec3::ZERO;
                        for &i in &members[member_offsets[a] as usize..member_offsets[a + 1] as usize] {
                            let mut row = Vec3::ZERO;
                            for (j, v) in m.row(i as usize) {
                                row += contacts.admitted_step(j, g[j] - x[j]) * v;
                            }
                            sum += contacts.admitted_correction(i as usize, row);
                        }
                        *b = sum * RELAXATION;
                    });
                    Some(hierarchy.solve())
                }
                None => None,
            }
        };
        let aggregate = &self.aggregate;
        // One pass for the step, the correction and the extrapolation, and
        // the norms, summed by fixed blocks in order.
        let extrapolate = weight != 1.0;
        let sums: Vec<Sums> = g
            .par_chunks_mut(APPLY_BLOCK)
            .enumerate()
            .zip(x.par_chunks(APPLY_BLOCK))
            .zip(previous.par_chunks_mut(APPLY_BLOCK))
            .zip(input.par_chunks(APPLY_BLOCK))
            .zip(aggregate.par_chunks(APPLY_BLOCK))
            .map(|(((((block, g), x), previous), input), aggregate)| {
                let (mut residual, mut step, mut offset) = (0.0f32, 0.0f32, 0.0f32);
                let left_out = unextrapolated.map(|mask| &mask[block * APPLY_BLOCK..]);
                for (k, ((((gi, xi), pi), ii), &a)) in g.iter_mut().zip(x).zip(previous).zip(input).zip(aggregate).enumerate() {
                    let plain = *gi - *xi;
                    residual += plain.length_squared();
                    let carried = left_out.is_some_and(|mask| mask[k]);
                    let correction = match error {
                        Some(error) if !carried && with_contacts => contacts.admitted_correction(block * APPLY_BLOCK + k, error[a as usize]),
                        Some(error) if !carried => error[a as usize],
                        _ => Vec3::ZERO,
                    };
                    let corrected = *xi + plain * RELAXATION + correction;
                    // Weight 1 exactly: `p + (c − p)` can differ from `c` in
                    // the last bit, which would make a solve depend on the
                    // solve before it (the previous iterate it left behind).
                    let next = if extrapolate && !carried {
                        *pi + (corrected - *pi) * weight
                    } else {
                        corrected
                    };
                    step += (next - *xi).length_squared();
                    offset += (next - *ii).length_squared();
                    *gi = next;
                    *pi = *xi;
                }
                Sums { residual: residual as f64, step: step as f64, offset: offset as f64 }
            })
            .collect();
        sums.iter().fold(Sums::default(), |a, b| Sums {
            residual: a.residual + b.residual,
            step: a.step + b.step,
            offset: a.offset + b.offset,
        })
    }
}

/// Whether `m` (entries sorted by row and column) has the pattern of `rows`.
fn same_pattern(m: &[(u32, u32, f32)], rows: &VertexRows) -> bool {
    m.len() == rows.columns.len()
        && m.par_iter().zip(&rows.columns).all(|(e, &j)| e.1 == j)
        && (0..rows.offsets.len() - 1).into_par_iter().all(|i| {
            let (a, b) = (rows.offsets[i] as usize, rows.offsets[i + 1] as usize);
            m[a..b].iter().all(|e| e.0 as usize == i)
        })
}

/// `Pᵀ(I − M)P` on the first level, symmetrised, both triangles; with
/// `held`, `P` without the held vertices' rows (an aggregate of held
/// vertices only gets an empty row: its correction is 0).
fn first_level(aggregate: &[u32], count: usize, m: &VertexRows, held: Option<&[bool]>) -> Csr {
    let mut entries: Vec<(u32, u32, f64)> = Vec::with_capacity(aggregate.len() + 2 * m.columns.len());
    first_level_entries(aggregate, m, held, |_, a, b, value| entries.push((a, b, value)));
    Csr::from_entries(count, entries)
}

/// Calls `f(index, row, column, value)` for each entry of [`first_level`]'s
/// matrix before duplicates are summed, in the order they are summed in:
/// `index` is the entry's place in the sequence with nothing held (one
/// diagonal entry per vertex, then two per entry of `M`), so that a held set
/// gives a subsequence of the same indices.
fn first_level_entries(aggregate: &[u32], m: &VertexRows, held: Option<&[bool]>, mut f: impl FnMut(usize, u32, u32, f64)) {
    let n = aggregate.len();
    let free = |v: usize| held.is_none_or(|h| !h[v]);
    for (v, &a) in aggregate.iter().enumerate() {
        if free(v) {
            f(v, a, a, 1.0);
        }
    }
    for i in (0..n).filter(|&i| free(i)) {
        for k in m.offsets[i] as usize..m.offsets[i + 1] as usize {
            let j = m.columns[k] as usize;
            if !free(j) {
                continue;
            }
            let (a, b, value) = (aggregate[i], aggregate[j], -0.5 * m.values[k] as f64);
            f(n + 2 * k, a, b, value);
            f(n + 2 * k + 1, b, a, value);
        }
    }
}

/// The pattern of the first level with nothing held, and the slot (index
/// into `columns`) each entry [`first_level_entries`] generates lands in.
/// A held set only leaves entries out, so its matrix's entries fall in a
/// subset of these slots, and summing each slot's entries in generation
/// order gives what the stable sort of [`Csr::from_entries`] gives, to the
/// bit, without sorting: the problems with held vertices are assembled
/// whenever a contact's held set is new, several times a step (at Converge
/// on the 100k flesh bench that sort was most of the step, issue 29).
struct FirstLevelPattern {
    offsets: Vec<u32>,
    columns: Vec<u32>,
    slots: Vec<u32>,
    /// The generated entries of each slot, in generation order (ascending
    /// index): `by_slot[by_slot_offsets[s]..by_slot_offsets[s + 1]]`.
    by_slot_offsets: Vec<u32>,
    by_slot: Vec<u32>,
    /// The row vertex of each entry of `M`.
    entry_rows: Vec<u32>,
    /// The slot of `(b, a)` for the slot of `(a, b)` (the pattern is symmetric).
    transposed: Vec<u32>,
}

impl FirstLevelPattern {
    /// For `free`, the first level of `aggregate` and `m` with nothing held.
    fn new(aggregate: &[u32], m: &VertexRows, free: &Csr) -> Self {
        let mut slots = vec![0u32; aggregate.len() + 2 * m.columns.len()];
        first_level_entries(aggregate, m, None, |index, a, b, _| {
            let (start, end) = (free.offsets[a as usize] as usize, free.offsets[a as usize + 1] as usize);
            let at = free.columns[start..end].binary_search(&b).expect("every generated entry has a slot");
            slots[index] = (start + at) as u32;
        });
        // `first_level_entries` generates in ascending index, and grouping
        // (a counting sort) keeps each slot's entries in that order.
        let (by_slot_offsets, by_slot) = group_members(&slots, free.columns.len());
        let mut entry_rows = vec![0u32; m.columns.len()];
        for i in 0..aggregate.len() {
            entry_rows[m.offsets[i] as usize..m.offsets[i + 1] as usize].fill(i as u32);
        }
        let transposed = (0..free.len())
            .flat_map(|a| free.row(a).map(move |(b, _)| (a, b)))
            .map(|(a, b)| {
                let (start, end) = (free.offsets[b] as usize, free.offsets[b + 1] as usize);
                (start + free.columns[start..end].binary_search(&(a as u32)).expect("a symmetric pattern")) as u32
            })
            .collect();
        FirstLevelPattern { offsets: free.offsets.clone(), columns: free.columns.clone(), slots, by_slot_offsets, by_slot, entry_rows, transposed }
    }

    /// [`first_level`]'s sums by slot, with `held` fixed (`None`: nothing held).
    fn sums(&self, aggregate: &[u32], m: &VertexRows, held: Option<&[bool]>) -> SlotSums {
        let mut sums = SlotSums::new(self.columns.len());
        first_level_entries(aggregate, m, held, |index, _, _, value| sums.add(self.slots[index] as usize, value));
        sums
    }

    /// [`Self::sums`] with the vertices `vertices` (`held` per vertex) fixed,
    /// from `free`, the sums with nothing held: a slot no entry of a held
    /// vertex falls in keeps all its entries, so its sum is `free`'s, to the
    /// bit; only the slots of the held vertices' aggregates' rows and their
    /// transposes are summed again, each over its surviving entries in
    /// generation order, as [`Self::sums`] does. A contact's held set is a
    /// small part of the skin, so this sums a small part of the entries.
    fn held_sums(&self, free: &SlotSums, aggregate: &[u32], m: &VertexRows, held: &[bool], vertices: &[u32]) -> SlotSums {
        let n = aggregate.len();
        let mut sums = SlotSums { sums: free.sums.clone(), used: free.used.clone() };
        let mut row_done = vec![false; self.offsets.len() - 1];
        let sum_again = |slot: usize, sums: &mut SlotSums| {
            let (mut sum, mut used) = (SlotSums::start(), false);
            for &index in &self.by_slot[self.by_slot_offsets[slot] as usize..self.by_slot_offsets[slot + 1] as usize] {
                let index = index as usize;
                let (i, j, value) = if index < n {
                    (index, index, 1.0)
                } else {
                    let k = (index - n) / 2;
                    (self.entry_rows[k] as usize, m.columns[k] as usize, -0.5 * m.values[k] as f64)
                };
                if !held[i] && !held[j] {
                    sum += value;
                    used = true;
                }
            }
            sums.sums[slot] = sum;
            sums.used[slot] = used;
        };
        for &v in vertices {
            let a = aggregate[v as usize] as usize;
            if std::mem::replace(&mut row_done[a], true) {
                continue;
            }
            for slot in self.offsets[a] as usize..self.offsets[a + 1] as usize {
                sum_again(slot, &mut sums);
                let across = self.transposed[slot] as usize;
                if across != slot {
                    sum_again(across, &mut sums);
                }
            }
        }
        sums
    }
}

/// A matrix on a level's pattern with nothing held, slot by slot: each
/// slot's sum of its entries in the order they were generated, and whether
/// it got one (a problem with held vertices leaves some out).
struct SlotSums {
    sums: Vec<f64>,
    used: Vec<bool>,
}

impl SlotSums {
    fn new(slots: usize) -> Self {
        SlotSums { sums: vec![Self::start(); slots], used: vec![false; slots] }
    }

    /// The value `Iterator::sum` starts from, so that each slot's sum is
    /// the same fold as `Csr::from_entries`'.
    fn start() -> f64 {
        std::iter::empty::<f64>().sum()
    }

    fn add(&mut self, slot: usize, value: f64) {
        self.sums[slot] += value;
        self.used[slot] = true;
    }

    /// The matrix of the used slots of the pattern `offsets`, `columns`,
    /// as [`Csr::from_entries`] makes it.
    fn matrix(&self, offsets: &[u32], columns: &[u32]) -> Csr {
        let n = offsets.len() - 1;
        let mut compact = vec![0u32; n + 1];
        let (mut kept_columns, mut values) = (Vec::new(), Vec::new());
        let mut inverse_diagonal = vec![0.0f32; n];
        let mut diagonal = vec![0.0f32; n];
        for i in 0..n {
            for slot in offsets[i] as usize..offsets[i + 1] as usize {
                if !self.used[slot] {
                    continue;
                }
                let (j, sum) = (columns[slot], self.sums[slot]);
                if j as usize == i {
                    diagonal[i] = sum as f32;
                    inverse_diagonal[i] = if sum > 0.0 { (1.0 / sum) as f32 } else { 0.0 };
                }
                kept_columns.push(j);
                values.push(sum as f32);
            }
            compact[i + 1] = kept_columns.len() as u32;
        }
        Csr { offsets: compact, columns: kept_columns, values, diagonal, inverse_diagonal }
    }
}

/// A level below the first of the free problem: its pattern and, for each
/// slot of the level above, the slot [`Csr::restricted`] sums it into.
struct CoarserPattern {
    offsets: Vec<u32>,
    columns: Vec<u32>,
    from_above: Vec<u32>,
}

/// The free problem's patterns on every level, first to coarsest, so that
/// a problem with held vertices, or new values of the same `M`, is
/// assembled level by level by slot instead of by sorting. A held
/// problem's level uses a subset of the free level's slots, and
/// [`Csr::restricted`] generates its entries in slot order, so summing
/// each coarser slot's entries in that order is what its stable sort
/// gives, to the bit (at Converge the coarser levels' sorts were what was
/// left of a held assembly, issue 29).
struct HierarchyPattern {
    first: FirstLevelPattern,
    coarser: Vec<CoarserPattern>,
}

impl HierarchyPattern {
    /// For the free problem's `matrices` (first to coarsest, as
    /// [`Hierarchy::chain`] makes them from `aggregate` and `m`) and the
    /// aggregations `downs` between them.
    fn new(aggregate: &[u32], m: &VertexRows, matrices: &[Csr], downs: &[Vec<u32>]) -> Self {
        let first = FirstLevelPattern::new(aggregate, m, &matrices[0]);
        let coarser = matrices
            .windows(2)
            .zip(downs)
            .map(|(pair, down)| {
                let (above, below) = (&pair[0], &pair[1]);
                let mut from_above = Vec::with_capacity(above.columns.len());
                for i in 0..above.len() {
                    let a = down[i] as usize;
                    let (start, end) = (below.offsets[a] as usize, below.offsets[a + 1] as usize);
                    for (j, _) in above.row(i) {
                        let at = below.columns[start..end].binary_search(&down[j]).expect("every restricted entry has a slot");
                        from_above.push((start + at) as u32);
                    }
                }
                CoarserPattern { offsets: below.offsets.clone(), columns: below.columns.clone(), from_above }
            })
            .collect();
        HierarchyPattern { first, coarser }
    }

    /// The matrices of every level, first to coarsest, with `held` fixed
    /// (`None`: nothing held): [`first_level`] and then [`Csr::restricted`]
    /// level by level, to the bit.
    fn chain(&self, aggregate: &[u32], m: &VertexRows, held: Option<&[bool]>) -> Vec<Csr> {
        self.chain_from(self.first.sums(aggregate, m, held))
    }

    /// [`Self::chain`] from the first level's sums.
    fn chain_from(&self, mut sums: SlotSums) -> Vec<Csr> {
        let mut matrices = vec![sums.matrix(&self.first.offsets, &self.first.columns)];
        for level in &self.coarser {
            let mut next = SlotSums::new(level.columns.len());
            for (slot, &to) in level.from_above.iter().enumerate() {
                if sums.used[slot] {
                    // `restricted` sums the level's f32 values.
                    next.add(to as usize, sums.sums[slot] as f32 as f64);
                }
            }
            matrices.push(next.matrix(&level.offsets, &level.columns));
            sums = next;
        }
        matrices
    }
}

/// How an `M` was generated: new weights on the same constraints usually
/// generate the same sequence of (row, column), and then the sorts that
/// assembled the coarse levels are known in advance ([`Coarse::revalued`]).
struct Sequence {
    /// Each generated entry's (row, column), in generation order.
    pairs: Vec<(u32, u32)>,
    /// The generated entries in (row, column) order, stably: `order[k]` is
    /// the generated index of `M`'s `k`-th entry.
    order: Vec<u32>,
    /// The slot of `ω Pᵀ M` (`Coarse::columns`) that `M`'s `k`-th entry is summed into.
    q_slots: Vec<u32>,
}

impl Sequence {
    /// Whether `generated` has this sequence of (row, column).
    fn is_of(&self, generated: &[(u32, u32, f32)]) -> bool {
        self.pairs.len() == generated.len() && self.pairs.par_iter().zip(generated).all(|(p, g)| *p == (g.0, g.1))
    }
}

impl Hierarchy {
    /// The matrices below `first`, first to coarsest, each the one above
    /// restricted, with the aggregations between them: by further rounds of
    /// aggregation until the coarsest is small enough to factorise, or by
    /// the aggregations `downs` of another hierarchy (the same levels for a
    /// modified first matrix).
    fn chain(first: Csr, downs: Option<&[&[u32]]>) -> (Vec<Csr>, Vec<Vec<u32>>) {
        let mut matrices = vec![first];
        let mut taken: Vec<Vec<u32>> = Vec::new();
        loop {
            let matrix = matrices.last().expect("the first level");
            let (down, next) = match downs {
                Some(downs) => match downs.get(taken.len()) {
                    Some(down) => (down.to_vec(), down.iter().max().map_or(0, |&a| a as usize + 1)),
                    None => break,
                },
                None => {
                    if taken.len() + 1 >= MAX_ROUNDS || matrix.len() <= MAX_AGGREGATES {
                        break;
                    }
                    let (down, next) = aggregate_once(matrix.len(), &matrix.edges());
                    if next * 2 > matrix.len() {
                        break;
                    }
                    (down, next)
                }
            };
            let coarser = matrix.restricted(&down, next);
            matrices.push(coarser);
            taken.push(down);
        }
        (matrices, taken)
    }

    /// The cycle of `matrices` (first to coarsest) with the aggregations
    /// `downs` between them, the coarsest factorised on the first of `known`
    /// analyses that fits its pattern ([`Coarsest::new`]); `None` if the
    /// coarsest level is not positive definite.
    fn from_chain<'a>(mut matrices: Vec<Csr>, downs: Vec<Vec<u32>>, known: impl IntoIterator<Item = &'a Arc<Analysis>>) -> Option<Self> {
        let matrix = matrices.pop().expect("the first level");
        let levels = matrices
            .into_iter()
            .zip(downs)
            .map(|(matrix, down)| {
                let len = matrix.len();
                Level { matrix, down, rhs: vec![Vec3::ZERO; len], error: vec![Vec3::ZERO; len], scratch: vec![Vec3::ZERO; len] }
            })
            .collect();
        // A node without a free vertex below it has an empty row: 1 on its
        // diagonal makes its correction 0 (its right-hand side is 0).
        let lower: Vec<(u32, u32, f64)> = (0..matrix.len())
            .flat_map(|i| {
                let empty = matrix.diagonal[i] == 0.0;
                let identity = empty.then_some((i as u32, i as u32, 1.0));
                matrix.row(i).filter(move |&(j, _)| j <= i).map(move |(j, v)| (j as u32, i as u32, v as f64)).chain(identity)
            })
            .collect();
        let coarsest = Coarsest::new(matrix.len(), lower, known)?;
        let last = coarsest.len();
        Some(Hierarchy { levels, coarsest, coarsest_rhs: vec![Vec3::ZERO; last], coarsest_error: vec![Vec3::ZERO; last] })
    }

    /// The first level's right-hand side, for [`Hierarchy::solve`].
    fn first_rhs(&mut self) -> &mut [Vec3] {
        match self.levels.first_mut() {
            Some(level) => &mut level.rhs,
            None => &mut self.coarsest_rhs,
        }
    }

    /// One V-cycle from the first level's right-hand side; its error.
    fn solve(&mut self) -> &[Vec3] {
        if self.levels.is_empty() {
            self.coarsest.solve(&self.coarsest_rhs, &mut self.coarsest_error);
            &self.coarsest_error
        } else {
            self.cycle(0);
            &self.levels[0].error
        }
    }

    /// One cycle on level `l`, from its `rhs` into its `error`: the
    /// correction from the next level for the whole right-hand side, then
    /// [`SWEEPS`] backward Gauss–Seidel sweeps.
    fn cycle(&mut self, l: usize) {
        let (upper, lower) = self.levels.split_at_mut(l + 1);
        let level = &mut upper[l];
        let next_rhs = match lower.first_mut() {
            Some(next) => &mut next.rhs,
            None => &mut self.coarsest_rhs,
        };
        next_rhs.fill(Vec3::ZERO);
        for (&a, r) in level.down.iter().zip(&level.rhs) {
            next_rhs[a as usize] += *r;
        }
        if lower.is_empty() {
            self.coarsest.solve(&self.coarsest_rhs, &mut self.coarsest_error);
        } else {
            self.cycle(l + 1);
        }
        let (upper, lower) = self.levels.split_at_mut(l + 1);
        let level = &mut upper[l];
        let next_error = lower.first().map_or(&self.coarsest_error, |next| &next.error);
        for (e, &a) in level.error.iter_mut().zip(&level.down) {
            *e = next_error[a as usize] * OVERCORRECTION;
        }
        for sweep in 0..SWEEPS {
            level.matrix.sweep(&level.rhs, &mut level.error, &mut level.scratch, sweep % 2 == 1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use super::super::Rows;

    fn xorshift(mut seed: u32) -> impl FnMut() -> u32 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed
        }
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// A `side × side` grid: each vertex's 4-neighbours, and coupling rows
    /// sharing 1 among them, each share scaled by `random(0.8, 1.2)`.
    fn grid_coupling(side: u32, random: &mut impl FnMut(f32, f32) -> f32) -> (Rows, Vec<Vec<u32>>) {
        let mut coupling = Rows::new();
        let mut neighbours_of = Vec::new();
        for v in 0..side * side {
            let (x, y) = (v % side, v / side);
            let mut neighbours = Vec::new();
            if x > 0 { neighbours.push(v - 1); }
            if x + 1 < side { neighbours.push(v + 1); }
            if y > 0 { neighbours.push(v - side); }
            if y + 1 < side { neighbours.push(v + side); }
            let share = 1.0 / neighbours.len() as f32;
            coupling.push(neighbours.iter().map(|&j| (j, share * random(0.8, 1.2))).collect::<Vec<_>>());
            neighbours_of.push(neighbours);
        }
        (coupling, neighbours_of)
    }

    fn assert_same(sorted: &Csr, by_slot: &Csr, what: &str) {
        assert_eq!(sorted.offsets, by_slot.offsets, "{what}");
        assert_eq!(sorted.columns, by_slot.columns, "{what}");
        assert_eq!(bits(&sorted.values), bits(&by_slot.values), "{what}");
        assert_eq!(bits(&sorted.diagonal), bits(&by_slot.diagonal), "{what}");
        assert_eq!(bits(&sorted.inverse_diagonal), bits(&by_slot.inverse_diagonal), "{what}");
    }

    /// The assembly by slot must be the sorted assembly to the bit on every
    /// level, for any held set, since the solver's output depends on every
    /// bit of it.
    #[test]
    fn held_levels_by_slot_are_the_sorted_ones_bit_for_bit() {
        let n = 300;
        // A ring-like coupling with uneven values (so that sums of several
        // entries round differently in another order) and duplicates of
        // one aggregate pair from many vertices.
        let mut next = xorshift(12345);
        let mut entries = Vec::new();
        for i in 0..n as u32 {
            let mut columns: Vec<u32> = (0..5).map(|_| next() % n as u32).filter(|&j| j != i).collect();
            columns.sort_unstable();
            columns.dedup();
            for j in columns {
                entries.push((i, j, (next() % 1000) as f32 / 997.0 + 1e-3));
            }
        }
        let m = VertexRows::from_sorted(n, &entries);
        let aggregate: Vec<u32> = (0..n as u32).map(|v| (v * 7919 % n as u32) / 7).collect();
        let count = *aggregate.iter().max().unwrap() as usize + 1;
        // Two coarser levels by the same aggregation as the solver's.
        let free = first_level(&aggregate, count, &m, None);
        let (down1, count1) = aggregate_once(free.len(), &free.edges());
        let second = free.restricted(&down1, count1);
        let (down2, _) = aggregate_once(second.len(), &second.edges());
        let downs: Vec<&[u32]> = vec![&down1, &down2];
        let (matrices, taken) = Hierarchy::chain(free, Some(&downs));
        assert_eq!(matrices.len(), 3, "two levels below the first");
        let pattern = HierarchyPattern::new(&aggregate, &m, &matrices, &taken);
        for (l, (sorted, by_slot)) in matrices.iter().zip(pattern.chain(&aggregate, &m, None)).enumerate() {
            assert_same(sorted, &by_slot, &format!("nothing held, level {l}"));
        }
        for round in 0..20 {
            // From nothing held to most vertices held, whole aggregates included.
            let held: Vec<bool> = (0..n).map(|_| round > 0 && (next() % 20) < round).collect();
            let (sorted, _) = Hierarchy::chain(first_level(&aggregate, count, &m, Some(&held)), Some(&downs));
            let by_slot = pattern.chain(&aggregate, &m, Some(&held));
            let vertices: Vec<u32> = (0..n as u32).filter(|&v| held[v as usize]).collect();
            let again = pattern.chain_from(pattern.first.held_sums(&pattern.first.sums(&aggregate, &m, None), &aggregate, &m, &held, &vertices));
            assert_eq!(sorted.len(), by_slot.len());
            assert_eq!(sorted.len(), again.len());
            for (l, ((sorted, by_slot), again)) in sorted.iter().zip(&by_slot).zip(&again).enumerate() {
                assert_same(sorted, by_slot, &format!("round {round}, level {l}"));
                assert_same(sorted, again, &format!("round {round}, level {l}, from the free sums"));
            }
        }
    }

    /// New weights on the same constraints (`with_values`, by slot) must
    /// give what a fresh build gives, to the bit; and a changed sequence
    /// (a row whose weight became 0 generates nothing) falls back to the sort.
    #[test]
    fn new_values_by_slot_are_a_fresh_build_bit_for_bit() {
        let side = 24u32;
        let n = (side * side) as usize;
        let mut next = xorshift(777);
        let mut random = move |low: f32, high: f32| low + (high - low) * (next() % 10_000) as f32 / 10_000.0;
        let rows = Rows::identity(&(0..n as u32).collect::<Vec<_>>());
        let (coupling, _) = grid_coupling(side, &mut random);
        let weights: Vec<f32> = (0..n).map(|_| random(0.5, 1.5)).collect();
        let block = |weights| RowBlock { rows: &rows, weights, offset: 0 };
        let inverse: Vec<f32> = (0..n).map(|_| random(0.2, 0.5)).collect();
        let coarse = Coarse::build(n, &[block(&weights)], &[Some(&coupling)], &inverse).unwrap().expect("a coarse level");
        let mut zeroed = weights.clone();
        zeroed[17] = 0.0;
        for (case, weights) in [("same sequence", &weights), ("a row left out", &zeroed)] {
            let inverse: Vec<f32> = (0..n).map(|_| random(0.2, 0.5)).collect();
            let mut kept = coarse.with_values(n, &[block(weights)], &[Some(&coupling)], &inverse).unwrap().expect("a coarse level");
            let mut fresh = Coarse::build(n, &[block(weights)], &[Some(&coupling)], &inverse).unwrap().expect("a coarse level");
            assert_eq!(Arc::ptr_eq(&kept.sequence, &coarse.sequence), case == "same sequence", "{case}: by slot only for the same sequence");
            assert_eq!(kept.aggregate, fresh.aggregate, "{case}");
            assert_eq!((&kept.offsets, &kept.columns), (&fresh.offsets, &fresh.columns), "{case}");
            assert_eq!(bits(&kept.values), bits(&fresh.values), "{case}: ω Pᵀ M");
            assert_eq!((&kept.m.offsets, &kept.m.columns), (&fresh.m.offsets, &fresh.m.columns), "{case}");
            assert_eq!(bits(&kept.m.values), bits(&fresh.m.values), "{case}: M");
            assert_eq!(kept.free.levels.len(), fresh.free.levels.len(), "{case}");
            for (a, b) in kept.free.levels.iter().zip(&fresh.free.levels) {
                assert_same(&b.matrix, &a.matrix, case);
            }
            // The coarsest factors, through a solve.
            let rhs: Vec<Vec3> = (0..kept.free.first_rhs().len()).map(|a| Vec3::new(a as f32, 1.0, -(a as f32).sqrt())).collect();
            kept.free.first_rhs().copy_from_slice(&rhs);
            fresh.free.first_rhs().copy_from_slice(&rhs);
            let (a, b) = (kept.free.solve().to_vec(), fresh.free.solve().to_vec());
            let flat = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array()).map(f32::to_bits).collect::<Vec<_>>();
            assert_eq!(flat(&a), flat(&b), "{case}: the cycle's solve");
            if case == "same sequence" {
                assert!(Arc::ptr_eq(kept.free.coarsest.analysis(), coarse.free.coarsest.analysis()), "new values of the same pattern keep its analysis");
            }
        }
    }

    /// A held problem whose coarsest pattern is one already analysed (the
    /// free problem's, or a cached held set's) is factorised on that
    /// analysis, and must solve as one analysed afresh, to the bit; another
    /// pattern gets its own analysis.
    #[test]
    fn held_coarsest_on_a_known_analysis_is_a_fresh_one_bit_for_bit() {
        let side = 24u32;
        let n = (side * side) as usize;
        let mut next = xorshift(4242);
        let mut random = move |low: f32, high: f32| low + (high - low) * (next() % 10_000) as f32 / 10_000.0;
        let rows = Rows::identity(&(0..n as u32).collect::<Vec<_>>());
        let (coupling, neighbours_of) = grid_coupling(side, &mut random);
        let weights: Vec<f32> = (0..n).map(|_| random(0.5, 1.5)).collect();
        let inverse: Vec<f32> = (0..n).map(|_| random(0.2, 0.5)).collect();
        let block = RowBlock { rows: &rows, weights: &weights, offset: 0 };
        let mut coarse = Coarse::build(n, &[block], &[Some(&coupling)], &inverse).unwrap().expect("a coarse level");
        // A vertex whose neighbours all share its aggregate: holding it
        // leaves every link between aggregates, so the pattern stays.
        let aggregate = coarse.aggregate.clone();
        let interior = |v: usize| aggregate[v] != aggregate[0] && neighbours_of[v].iter().all(|&j| aggregate[j as usize] == aggregate[v]);
        let inside = (0..n).find(|&v| interior(v)).expect("an aggregate with a vertex inside it");
        // Every vertex of one aggregate: its node's row empties, so the pattern changes.
        let whole: Vec<u32> = (0..n as u32).filter(|&v| aggregate[v as usize] == aggregate[0]).collect();
        let mut whole_and_inside = whole.clone();
        whole_and_inside.push(inside as u32);
        whole_and_inside.sort_unstable();
        let free_analysis = Arc::clone(coarse.free.coarsest.analysis());
        let mut whole_analysis = None;
        for (case, held) in [("one inside vertex", vec![inside as u32]), ("a whole aggregate", whole), ("the same and one inside vertex", whole_and_inside)] {
            let mut mask = vec![false; n];
            for &v in &held {
                mask[v as usize] = true;
            }
            coarse.prepare_held(&held, &mask);
            let matrices = coarse.pattern.chain(&coarse.aggregate, &coarse.m, Some(&mask));
            let downs = coarse.free.levels.iter().map(|l| l.down.clone()).collect();
            let mut fresh = Hierarchy::from_chain(matrices, downs, []).expect("positive definite");
            let kept = coarse.held[0].hierarchy.as_mut().expect("positive definite");
            let analysis = Arc::clone(kept.coarsest.analysis());
            match case {
                "one inside vertex" => assert!(Arc::ptr_eq(&analysis, &free_analysis), "{case}: the free problem's analysis"),
                "a whole aggregate" => {
                    assert!(!Arc::ptr_eq(&analysis, &free_analysis), "{case}: an analysis of its own");
                    whole_analysis = Some(analysis);
                }
                _ => assert!(Arc::ptr_eq(&analysis, whole_analysis.as_ref().unwrap()), "{case}: the cached held set's analysis"),
            }
            let rhs: Vec<Vec3> = (0..kept.first_rhs().len()).map(|a| Vec3::new(a as f32, 1.0, -(a as f32).sqrt())).collect();
            kept.first_rhs().copy_from_slice(&rhs);
            fresh.first_rhs().copy_from_slice(&rhs);
            let (a, b) = (kept.solve().to_vec(), fresh.solve().to_vec());
            let flat = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array()).map(f32::to_bits).collect::<Vec<_>>();
            assert_eq!(flat(&a), flat(&b), "{case}: the cycle's solve");
        }
        assert_eq!(coarse.held_assemblies(), 3);
    }
}
