//! The iteration loop: local step, global step, hooks.

use std::sync::Arc;

use faer::sparse::linalg::cholesky::SymbolicCholesky;
use glam::Vec3;
use rayon::prelude::*;

use super::chebyshev::Chebyshev;
use super::coarse::Coarse;
use super::contacts::{MovedVertices, Sliding};
use super::constraint::{Constraint, Context};
use super::stopping::{self, Tolerance};
use super::system::{RowBlock, System, SystemKind};
use crate::mesh::validate_positions;
use crate::{Error, Result};

/// Handle of a constraint inside its [`Solver`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConstraintId(usize);

/// Where an iteration stands in its solve, as [`IterationHook::after_iteration`]
/// is told: a hook whose work only counts at the end of a solve (strain
/// limits' full rounds) does it where the solve ends, whatever ends it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Iteration {
    /// 0 for the first.
    pub index: usize,
    /// How many iterations follow this one where the solver knows: where
    /// the count (or limit) ends the solve, and after its stopping rule is
    /// met (then the hook's [`IterationHook::closing_iterations`] follow).
    /// `None` while the stopping rule may still end the solve.
    pub remaining: Option<usize>,
}

impl Iteration {
    /// Whether the solve ends after this iteration: nothing after the hook
    /// moves the iterate.
    pub fn is_last(&self) -> bool {
        self.remaining == Some(0)
    }
}

/// Runs after every iteration with the positions before and after it; may move
/// vertices of `after`. This is where the second collision pass (seed 000,
/// Algorithm 2) plugs in: detect and resolve along the path `before → after`.
pub trait IterationHook {
    fn after_iteration(
        &mut self,
        iteration: Iteration,
        before: &[Vec3],
        after: &mut [Vec3],
    ) -> Result<()>;

    /// Of the vertices the last call moved, those it left free to slide
    /// along a surface (contacts with kinetic friction or none). The
    /// accelerated solver's next correction moves them along that surface;
    /// the other moved vertices it keeps where the hook put them. Default:
    /// none slides.
    fn sliding(&self) -> &[Sliding] {
        &[]
    }

    /// Iterations the solve runs after its stopping rule is met (within its
    /// limit), each told how many follow it ([`Iteration::remaining`]): for
    /// a hook whose work counts only in a solve's last iterations, so that
    /// it is not measured by the rule (that work is undone by the iteration
    /// after it, and the rule would not see the steps shrink). Default: 0,
    /// the solve stops where its rule is met.
    fn closing_iterations(&self) -> usize {
        0
    }
}

/// A hook that reports the vertices it leaves sliding
/// ([`IterationHook::sliding`]): the closure fills the list it is given,
/// empty at every call.
pub struct SlidingHook<F> {
    hook: F,
    sliding: Vec<Sliding>,
    closing: usize,
}

impl<F> SlidingHook<F>
where
    F: FnMut(Iteration, &[Vec3], &mut [Vec3], &mut Vec<Sliding>) -> Result<()>,
{
    pub fn new(hook: F) -> Self {
        SlidingHook { hook, sliding: Vec::new(), closing: 0 }
    }

    /// The hook with [`IterationHook::closing_iterations`] answering `closing`.
    pub fn closing(self, closing: usize) -> Self {
        SlidingHook { closing, ..self }
    }
}

impl<F> IterationHook for SlidingHook<F>
where
    F: FnMut(Iteration, &[Vec3], &mut [Vec3], &mut Vec<Sliding>) -> Result<()>,
{
    fn after_iteration(&mut self, iteration: Iteration, before: &[Vec3], after: &mut [Vec3]) -> Result<()> {
        self.sliding.clear();
        (self.hook)(iteration, before, after, &mut self.sliding)
    }

    fn sliding(&self) -> &[Sliding] {
        &self.sliding
    }

    fn closing_iterations(&self) -> usize {
        self.closing
    }
}

/// A plain closure is told the iteration's index only.
impl<F> IterationHook for F
where
    F: FnMut(usize, &[Vec3], &mut [Vec3]) -> Result<()>,
{
    fn after_iteration(
        &mut self,
        iteration: Iteration,
        before: &[Vec3],
        after: &mut [Vec3],
    ) -> Result<()> {
        self(iteration.index, before, after)
    }
}

struct Entry {
    constraint: Box<dyn Constraint>,
    weights: Vec<f32>,
}

/// A projective solver over a fixed vertex count and a set of constraints.
///
/// The global matrix is built lazily on the first solve after constraints or
/// weights change, so a deformer that solves frame after frame with the same
/// settings factorises exactly once.
pub struct Solver {
    vertex_count: usize,
    entries: Vec<Entry>,
    system: Option<System>,
    /// Symbolic Cholesky analysis, kept across weight changes (it only
    /// depends on the rows) and dropped when a constraint is added.
    symbolic: Option<Arc<SymbolicCholesky<usize>>>,
    variable_projections: Vec<Vec3>,
    constant_projections: Vec<Vec3>,
    rhs_constant: Vec<Vec3>,
    work: Vec<Vec3>,
    /// Whether to build and run the coarse correction, and the built level
    /// (rebuilt with the system).
    coarse_enabled: bool,
    coarse: Option<Coarse>,
    /// How many times the coarse levels were aggregated afresh.
    aggregations: usize,
    /// An accelerated iteration's positions before the hook ran, and the
    /// vertices the hook then moved.
    before_hook: Vec<Vec3>,
    hook_moved: MovedVertices,
    /// Vertices the Chebyshev extrapolation leaves out (empty: none); see
    /// [`Solver::set_unextrapolated`].
    unextrapolated: Vec<bool>,
    /// The corrected iteration's iterate before the current one, for its
    /// Chebyshev extrapolation (see [`super::chebyshev`]).
    previous: Vec<Vec3>,
    /// Stop an accelerated solve once its estimated error is below this
    /// fraction of the displacement (see [`Solver::set_tolerance`]).
    tolerance: Option<Tolerance>,
    /// Iterations the last solve ran.
    last_iterations: usize,
}

impl Solver {
    pub fn new(vertex_count: usize) -> Self {
        Solver {
            vertex_count,
            entries: Vec::new(),
            system: None,
            symbolic: None,
            variable_projections: Vec::new(),
            constant_projections: Vec::new(),
            rhs_constant: Vec::new(),
            work: Vec::new(),
            coarse_enabled: false,
            coarse: None,
            aggregations: 0,
            before_hook: Vec::new(),
            hook_moved: MovedVertices::default(),
            unextrapolated: Vec::new(),
            previous: Vec::new(),
            tolerance: None,
            last_iterations: 0,
        }
    }

    /// Lets an accelerated solve stop before its iteration count once the
    /// error it has left, estimated from its last steps, is within the
    /// tolerance (`None`: always run the count). See [`stopping`]. Plain
    /// iterations converge too slowly for the estimate to hold: those solves
    /// run their count. With a tolerance the count is a limit, and on meshes
    /// below [`stopping::WORK_VERTICES`] vertices a limit in work (see
    /// [`stopping::limit`]). With a hook the rule measures the iterate the hook
    /// left, so a solve stops where the hook's guarantees hold (contacts
    /// resolved after every iteration).
    pub fn set_tolerance(&mut self, tolerance: Option<Tolerance>) -> Result<()> {
        if let Some(t) = tolerance {
            if !(t.relative.is_finite() && t.relative > 0.0 && t.floor.is_finite() && t.floor >= 0.0) {
                return Err(Error::invalid(format!(
                    "tolerance is {} (floor {}); it must be a positive number",
                    t.relative, t.floor
                )));
            }
        }
        self.tolerance = tolerance;
        Ok(())
    }

    /// The stopping tolerance (see [`Solver::set_tolerance`]).
    pub fn tolerance(&self) -> Option<Tolerance> {
        self.tolerance
    }

    /// How many coarse problems with held vertices the accelerated solver
    /// assembled and factorised since it was last prepared (a measure of the
    /// work contacts cost it; 0 without the coarse correction).
    pub fn held_assemblies(&self) -> usize {
        self.coarse.as_ref().map_or(0, Coarse::held_assemblies)
    }

    /// How many times the coarse levels were aggregated afresh (on the
    /// first build and whenever the varying constraints changed; new weights
    /// of a constant one keep the aggregation, see [`Solver::set_weights`]).
    pub fn coarse_aggregations(&self) -> usize {
        self.aggregations
    }

    /// Iterations the last solve ran (its count; with a tolerance fewer, or
    /// on a small mesh up to [`stopping::limit`]).
    pub fn last_iterations(&self) -> usize {
        self.last_iterations
    }

    /// Turns the coarse-level correction on or off (see [`super::coarse`]);
    /// it only runs with a diagonal global matrix and a constraint that
    /// reports its [`super::Constraint::coupling`].
    pub fn set_coarse_correction(&mut self, on: bool) {
        if on != self.coarse_enabled {
            self.coarse_enabled = on;
            self.coarse = None;
            if let Some(system) = self.system.take() {
                self.symbolic = system.symbolic().or(self.symbolic.take());
            }
        }
    }

    /// Marks the vertices whose rows the accelerated solver's Chebyshev
    /// extrapolation and coarse correction must leave out (`mask[v]`; an
    /// empty mask: none): rows that carry a vertex from another vertex's
    /// position (a ring fit's sliver anchored to its neighbour). A chain of
    /// such rows is a shift: its iteration's modes are not the real ones the
    /// weights are built for (see [`super::chebyshev`]), and extrapolated or
    /// corrected they grow. They keep the plain step, which carries their
    /// anchor's correction to them.
    pub fn set_unextrapolated(&mut self, mask: &[bool]) -> Result<()> {
        if !mask.is_empty() && mask.len() != self.vertex_count {
            return Err(Error::invalid(format!(
                "unextrapolated vertices: a mask of {} given, the solver has {} vertices",
                mask.len(),
                self.vertex_count
            )));
        }
        self.unextrapolated = if mask.iter().any(|&m| m) { mask.to_vec() } else { Vec::new() };
        Ok(())
    }

    /// Whether the coarse-level correction is on.
    pub fn coarse_correction(&self) -> bool {
        self.coarse_enabled
    }

    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }

    /// Adds a constraint with one non-negative weight per row.
    pub fn add(
        &mut self,
        constraint: Box<dyn Constraint>,
        weights: Vec<f32>,
    ) -> Result<ConstraintId> {
        constraint
            .rows()
            .validate(constraint.name(), self.vertex_count)?;
        check_weights(constraint.as_ref(), &weights)?;
        self.entries.push(Entry {
            constraint,
            weights,
        });
        self.system = None;
        self.symbolic = None;
        self.coarse = None;
        Ok(ConstraintId(self.entries.len() - 1))
    }

    /// Replaces a constraint's row weights; the next solve refactorises
    /// numerically (the symbolic analysis is kept). A constant constraint's
    /// weights change only the diagonal: the coarse levels keep their
    /// aggregations and are built again numerically ([`Coarse::with_values`]).
    pub fn set_weights(&mut self, id: ConstraintId, weights: &[f32]) -> Result<()> {
        let entry = self.entry(id)?;
        check_weights(entry.constraint.as_ref(), weights)?;
        if entry.weights != weights {
            if !entry.constraint.is_constant() {
                self.coarse = None;
            }
            self.entries[id.0].weights = weights.to_vec();
            if let Some(system) = self.system.take() {
                self.symbolic = system.symbolic().or(self.symbolic.take());
            }
        }
        Ok(())
    }

    pub fn weights(&self, id: ConstraintId) -> Result<&[f32]> {
        Ok(&self.entry(id)?.weights)
    }

    pub fn constraint(&self, id: ConstraintId) -> Result<&dyn Constraint> {
        Ok(self.entry(id)?.constraint.as_ref())
    }

    /// Sets the targets of a [`super::Targets`] constraint (constant within
    /// a solve: call it before [`Solver::solve`]).
    pub fn set_targets(&mut self, id: ConstraintId, targets: &[Vec3]) -> Result<()> {
        self.entry(id)?;
        let name = self.entries[id.0].constraint.name().to_string();
        match self.entries[id.0].constraint.replace_targets(targets) {
            Some(result) => result,
            None => Err(Error::invalid(format!("constraint {name} has no settable targets"))),
        }
    }

    fn entry(&self, id: ConstraintId) -> Result<&Entry> {
        self.entries.get(id.0).ok_or_else(|| {
            Error::invalid(format!(
                "constraint {} does not belong to this solver",
                id.0
            ))
        })
    }

    /// Builds (and factorises) the global system if needed; returns its kind.
    pub fn prepare(&mut self) -> Result<SystemKind> {
        if self.system.is_none() {
            // Built for the variable constraints as they are (see `set_weights`).
            let kept = self.coarse.take();
            let (variable, constant) = self.blocks();
            let system = System::build(
                self.vertex_count,
                &variable,
                &constant,
                self.symbolic.clone(),
            )?;
            let variable_rows: usize = variable.iter().map(|b| b.rows.len()).sum();
            let constant_rows: usize = constant.iter().map(|b| b.rows.len()).sum();
            self.coarse = match (self.coarse_enabled, system.diagonal_inverse()) {
                (true, Some(inverse)) => {
                    let couplings: Vec<_> = self
                        .entries
                        .iter()
                        .filter(|e| !e.constraint.is_constant())
                        .map(|e| e.constraint.coupling())
                        .collect();
                    match &kept {
                        Some(kept) => kept.with_values(self.vertex_count, &variable, &couplings, inverse)?,
                        None => Coarse::build(self.vertex_count, &variable, &couplings, inverse)?,
                    }
                }
                _ => None,
            };
            if self.coarse.is_some() && kept.is_none() {
                self.aggregations += 1;
            }
            self.symbolic = system.symbolic();
            self.system = Some(system);
            self.variable_projections = vec![Vec3::ZERO; variable_rows];
            self.constant_projections = vec![Vec3::ZERO; constant_rows];
            self.rhs_constant = vec![Vec3::ZERO; self.vertex_count];
            self.work = vec![Vec3::ZERO; self.vertex_count];
        }
        Ok(self
            .system
            .as_ref()
            .map(System::kind)
            .unwrap_or(SystemKind::Diagonal))
    }

    /// Entries of the Cholesky factor (0 for a diagonal system); builds the system if needed.
    pub fn factor_nnz(&mut self) -> Result<usize> {
        self.prepare()?;
        Ok(self.system.as_ref().map(System::factor_nnz).unwrap_or(0))
    }

    fn blocks(&self) -> (Vec<RowBlock<'_>>, Vec<RowBlock<'_>>) {
        let (mut variable, mut constant) = (Vec::new(), Vec::new());
        let (mut variable_rows, mut constant_rows) = (0, 0);
        for entry in &self.entries {
            let rows = entry.constraint.rows();
            let (list, offset) = if entry.constraint.is_constant() {
                (&mut constant, &mut constant_rows)
            } else {
                (&mut variable, &mut variable_rows)
            };
            list.push(RowBlock {
                rows,
                weights: &entry.weights,
                offset: *offset,
            });
            *offset += rows.len();
        }
        (variable, constant)
    }

    /// Runs `iterations` local/global iterations starting from `positions`
    /// and leaves the result there. `input` is what constant constraints
    /// (closeness) pull towards.
    pub fn solve(
        &mut self,
        input: &[Vec3],
        positions: &mut [Vec3],
        iterations: usize,
        mut hook: Option<&mut dyn IterationHook>,
    ) -> Result<()> {
        for (what, array) in [("input", input), ("start positions", &*positions)] {
            if array.len() != self.vertex_count {
                return Err(Error::invalid(format!(
                    "{what}: {} vertices given, the solver has {}",
                    array.len(),
                    self.vertex_count
                )));
            }
            validate_positions(what, array)?;
        }
        self.prepare()?;
        for entry in &mut self.entries {
            entry.constraint.begin_solve(input)?;
        }
        let system = self.system.as_mut().expect("prepared above");

        // Constant projections once per solve.
        {
            let context = Context { positions, input };
            let mut offset = 0;
            for entry in self.entries.iter().filter(|e| e.constraint.is_constant()) {
                let rows = entry.constraint.rows().len();
                entry.constraint.project(
                    &context,
                    &mut self.constant_projections[offset..offset + rows],
                );
                offset += rows;
            }
            system.constant_rhs(&self.constant_projections, &mut self.rhs_constant);
        }

        // The varying constraints with the index of their first row.
        let mut variable: Vec<(&dyn Constraint, usize)> = Vec::new();
        let mut start = 0;
        for entry in self.entries.iter().filter(|e| !e.constraint.is_constant()) {
            variable.push((entry.constraint.as_ref(), start));
            start += entry.constraint.rows().len();
        }

        let accelerated = self.coarse.is_some();
        let mut chebyshev = Chebyshev::new();
        let mut last_residual = f64::INFINITY;
        if self.coarse.is_some() {
            self.previous.resize(self.vertex_count, Vec3::ZERO);
        }
        self.hook_moved.clear();
        let mut stop = match (self.tolerance, &self.coarse) {
            (Some(tolerance), Some(_)) => Some(stopping::Rule::new(tolerance, self.vertex_count)),
            _ => None,
        };
        // With a stopping rule the count is a limit, counted in work on small meshes.
        let limit = match stop {
            Some(_) => stopping::limit(iterations, self.vertex_count),
            None => iterations,
        };
        self.last_iterations = limit;
        // Once the rule is met, the hook's closing iterations follow (within
        // the limit): `end` is then the last iteration's index.
        let closing = hook.as_deref().map_or(0, |h| h.closing_iterations());
        let mut end: Option<usize> = None;
        // Ping-pong between the caller's buffer and our own, copying at most once.
        let mut in_work = false;
        for index in 0..limit {
            let remaining = match (end, &stop) {
                (Some(end), _) => Some(end - index),
                (None, None) => Some(limit - 1 - index),
                // The rule may still end the solve, unless the limit would
                // end the closing iterations after it anyway.
                (None, Some(_)) => (index + closing >= limit - 1).then(|| limit - 1 - index),
            };
            let iteration = Iteration { index, remaining };
            let (current, next): (&[Vec3], &mut [Vec3]) = if in_work {
                (&self.work, &mut *positions)
            } else {
                (&*positions, &mut self.work)
            };
            let context = Context { positions: current, input };
            // Squared norms of this iteration's step and of the iterate's
            // offset from the input, for the stopping rule.
            let mut step_norms: Option<(f64, f64)> = None;
            if !system.solve_fused(&self.rhs_constant, &variable, &context, next) {
                for &(constraint, start) in &variable {
                    let rows = constraint.rows().len();
                    constraint.project(&context, &mut self.variable_projections[start..start + rows]);
                }
                system.solve(&self.rhs_constant, &self.variable_projections, next);
            }
            // Acceleration extrapolates the map `G`; a hook that moved
            // positions changed the map (contacts hold vertices against
            // it). Chebyshev's extrapolation across that would move the fixed
            // point: such iterations restart its sequence. The coarse
            // correction fixes the vertices the hook moved (Dirichlet rows
            // of its coarse problem), so that it moves the rest as they stay
            // and still vanishes where the hook holds them (see `contacts`
            // for what was measured beyond that).
            if let Some(coarse) = self.coarse.as_mut() {
                if self.hook_moved.any() {
                    chebyshev.restart();
                }
                let weight = chebyshev.next_weight();
                let unextrapolated = (!self.unextrapolated.is_empty()).then_some(&self.unextrapolated[..]);
                let sums = coarse.correct(current, next, &self.hook_moved, &mut self.previous, (weight, unextrapolated), input);
                // A residual that grew: the extrapolation overshot where the
                // iteration is far from linear (see `chebyshev`); start again.
                if sums.residual > last_residual {
                    chebyshev.restart();
                }
                last_residual = sums.residual;
                step_norms = Some((sums.step, sums.offset));
            }
            let mut contacts_changed = false;
            if let Some(hook) = hook.as_deref_mut() {
                if accelerated {
                    self.before_hook.clear();
                    self.before_hook.extend_from_slice(next);
                }
                hook.after_iteration(iteration, current, next)?;
                if accelerated {
                    self.hook_moved.update(&self.before_hook, next, hook.sliding());
                    contacts_changed = self.hook_moved.changed();
                }
                // The hook moved the iterate: measure where it left it.
                if stop.is_some() {
                    step_norms = Some(step_norms_of(current, next, input));
                }
            }
            in_work = !in_work;
            if iteration.is_last() {
                self.last_iterations = index + 1;
                break;
            }
            if let (Some(rule), Some((step, offset)), None) = (stop.as_mut(), step_norms, end) {
                let rms = |sum: f64| (sum / self.vertex_count as f64).sqrt();
                // Never while contacts still appear or let go: the steps
                // measure a map that is still changing.
                if rule.converged(rms(step), rms(offset)) && !contacts_changed {
                    if closing == 0 {
                        self.last_iterations = index + 1;
                        break;
                    }
                    end = Some((index + closing).min(limit - 1));
                }
            }
        }
        if in_work {
            positions.copy_from_slice(&self.work);
        }
        if !crate::mesh::all_finite(bytemuck::cast_slice(positions)) {
            let v = positions.iter().position(|p| !p.is_finite()).unwrap_or(0);
            return Err(Error::Numerical(format!(
                "the solve produced a non-finite position at vertex {v}"
            )));
        }
        for entry in &mut self.entries {
            entry.constraint.end_solve(positions)?;
        }
        Ok(())
    }
}

/// `(Σ |after − before|², Σ |after − input|²)`, summed by fixed blocks in order.
fn step_norms_of(before: &[Vec3], after: &[Vec3], input: &[Vec3]) -> (f64, f64) {
    const BLOCK: usize = 4096;
    let sums: Vec<(f64, f64)> = after
        .par_chunks(BLOCK)
        .zip(before.par_chunks(BLOCK))
        .zip(input.par_chunks(BLOCK))
        .map(|((after, before), input)| {
            let (mut step, mut offset) = (0.0f32, 0.0f32);
            for ((a, b), i) in after.iter().zip(before).zip(input) {
                step += (*a - *b).length_squared();
                offset += (*a - *i).length_squared();
            }
            (step as f64, offset as f64)
        })
        .collect();
    sums.iter().fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1))
}

fn check_weights(constraint: &dyn Constraint, weights: &[f32]) -> Result<()> {
    let rows = constraint.rows().len();
    if weights.len() != rows {
        return Err(Error::invalid(format!(
            "constraint {}: {} weights given for {rows} rows",
            constraint.name(),
            weights.len()
        )));
    }
    if let Some(r) = weights.iter().position(|w| !(w.is_finite() && *w >= 0.0)) {
        return Err(Error::invalid(format!(
            "constraint {}: weight of row {r} is {}, weights must be finite and non-negative",
            constraint.name(),
            weights[r]
        )));
    }
    Ok(())
}
