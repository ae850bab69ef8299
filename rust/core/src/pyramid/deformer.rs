//! Pyramid Deform as one object: bind once, solve every frame.
//!
//! Energy per vertex `i`, with closeness `c_i ∈ [0, 1]`:
//! `(1 − c_i)·‖pyramid row_i‖² + c_i·‖x_i − input_i‖²`. So `c = 1` follows the
//! input exactly and `c = 0` keeps only the local shape; with per-vertex
//! targets the fixed point is literally `x_i = (1 − c_i)·target_i + c_i·input_i`.
//! Vertices the encoding cannot describe (see [`PinReason`]) have no pyramid
//! row. Bound from a mesh, those with at least two edge neighbours get a ring
//! fit row instead ([`super::ring_fit`]), weighted `1 − c_i` like a pyramid
//! row: they deform with their neighbourhood. The others (isolated, a single
//! neighbour; or every one of them on a deformer built from a bare encoding)
//! are pinned: `c = 1`, they follow the input, and their neighbours
//! reconstruct around them.

use std::sync::Arc;

use glam::Vec3;
use rayon::prelude::*;

use super::constraint::{PyramidLaplacian, PyramidTargets};
use super::encode::{encode, Encoding, PinReason};
use super::project::residual;
use super::ring_fit::{RingFit, RingFitVertices};
use crate::mesh::{validate_positions, MeshInput, Topology};
use crate::solve::{self, ConstraintId, IterationHook, Solver, SystemKind, Tolerance};
use crate::{Error, Result};

/// Closeness used when the caller gives none. Low enough that the local shape
/// wins against candy-wrapper collapse, high enough that the result stays
/// anchored to the rig (see docs/design/pyramid-solver.md).
pub const DEFAULT_CLOSENESS: f32 = 0.05;

/// Closeness weights are raised to at least this, so that the linearised
/// global matrix (whose pyramid rows sum to zero) stays positive definite on
/// a closed mesh with zero closeness. It biases the linearised solution by
/// about `MIN_CLOSENESS / λ_min(AᵀA)` times the displacement, and λ_min of a
/// squared Laplacian is small on long meshes: 1e-6 measurably moved the fixed
/// point (2e-3 of the diagonal on a 10-ring cylinder), 1e-8 does not.
pub const MIN_CLOSENESS: f32 = 1e-8;

/// Closeness weight of pinned vertices. In the linearised formulation their
/// neighbours' rows reach them, so a weight of 1 would let those rows drag
/// them off the input; a large weight makes "follow the input" hard in both
/// formulations (the diagonal formulation normalises it away).
pub const PINNED_CLOSENESS: f32 = 1e4;

/// Whether the add-on's bakes use the accelerated solver
/// ([`PyramidDeformer::set_accelerated`] with [`CONVERGE_TOLERANCE`], at most
/// [`ACCELERATED_ITERATIONS`], warm bake frames) unless the user turns
/// Converge off (issue 28: the iteration count is an accuracy knob, not a
/// look). On since every frame of the rough slide is within 5 % of
/// converged (`sequence::contact_convergence_tests`: an anchored vertex
/// pulled into the slack above its contact stays anchored, which ended a
/// four-iteration cycle). The core's and the wheel's deformers stay plain
/// until asked: their callers choose the iteration count.
pub const DEFAULT_CONVERGE: bool = true;

/// The add-on's Converge iteration limit: the accelerated solver
/// ([`PyramidDeformer::set_accelerated`]) with [`CONVERGE_TOLERANCE`] stops
/// before it once converged (issue 28, MakeHuman character in its hard pose
/// and the 100k tube: 5–8 iterations from the input, 2–6 from the last
/// frame's result). Without a tolerance six iterations are within 5 % of the
/// converged solve at closeness 0.05 and 0.01 on meshes of a few thousand
/// vertices and more (five leave the triangulated character 6.2 % away, six
/// 4.1 %); a 1,570-vertex limb at closeness 0.01 is 5.2 % away at six, a
/// 206-vertex one 16 %.
pub const ACCELERATED_ITERATIONS: usize = 12;

/// The offset (RMS) below which [`PyramidDeformer::set_tolerance`] measures
/// the error against this fraction of the mean rest edge length instead.
const STOPPING_FLOOR: f32 = 0.1;

/// The stopping tolerance of the add-on's Converge
/// ([`PyramidDeformer::set_tolerance`]): a solve stops once its estimated
/// convergence error is at most 2 % of the displacement. On the MakeHuman
/// character in its hard pose the frames then end 1.0–2.8 % from the
/// converged solve (issue 28 asks for at most 5 %).
pub const CONVERGE_TOLERANCE: f32 = 0.02;

/// Most iterations one solve accepts; more is certainly a mistake.
pub const MAX_ITERATIONS: usize = 100_000;

/// Which form of the pyramid constraint the solver runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Formulation {
    /// Per-vertex target row `e_i → m + s n` (seed 000): diagonal global step.
    #[default]
    VertexTargets,
    /// Linearised mean-value Laplacian row `x_i − Σ w_j x_j → s n`: prefactored
    /// sparse Cholesky global step.
    Laplacian,
}

impl Formulation {
    pub fn name(self) -> &'static str {
        match self {
            Formulation::VertexTargets => "targets",
            Formulation::Laplacian => "laplacian",
        }
    }
}

/// Bind-time settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeformerOptions {
    /// Store edge elevation angles instead of plain heights: the offset then
    /// scales with the neighbours (uniform scale is reproduced exactly).
    pub scale_safe: bool,
    pub formulation: Formulation,
}

impl Default for DeformerOptions {
    fn default() -> Self {
        DeformerOptions {
            scale_safe: true,
            formulation: Formulation::default(),
        }
    }
}

/// Closeness of one solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Closeness<'a> {
    /// [`DEFAULT_CLOSENESS`] everywhere.
    Default,
    /// The same weight everywhere, in `[0, 1]`.
    Uniform(f32),
    /// One weight per vertex, each in `[0, 1]` (a painted vertex group).
    PerVertex(&'a [f32]),
}

/// A bound mesh, ready to solve frames.
pub struct PyramidDeformer {
    encoding: Arc<Encoding>,
    formulation: Formulation,
    pinned_mask: Vec<bool>,
    /// Vertices carried from a nearly coincident neighbour by their ring fit:
    /// closeness would pull the pair of a sliver apart by `c` times the
    /// shape correction, so they have none (just [`MIN_CLOSENESS`]).
    anchored_mask: Vec<bool>,
    /// Vertices that follow the input, with the reason, ascending.
    pinned: Vec<(u32, PinReason)>,
    /// Vertices without a pyramid row held by a ring fit, with the reason
    /// they have none, ascending.
    ring_fitted: Vec<(u32, PinReason)>,
    solver: Solver,
    pyramid: ConstraintId,
    /// The ring fit rows, only when some vertex has one: a second varying
    /// constraint costs the fused step its single-kernel path.
    ring_fit: Option<ConstraintId>,
    closeness: ConstraintId,
    /// The closeness the solver's weights were last set from, so that a
    /// frame with the same closeness as the last one skips rebuilding and
    /// checking two weight arrays (a measurable part of a 10-iteration solve).
    applied: Option<Applied>,
    /// Per-vertex closeness as last applied to the solver (clamped; pinned
    /// vertices at [`PINNED_CLOSENESS`]): the stepper's inertia weights and
    /// strain-limit inverse masses follow it.
    closeness_weights: Vec<f32>,
}

/// What [`PyramidDeformer::set_closeness`] last applied.
#[derive(Debug, Clone, PartialEq)]
enum Applied {
    Uniform(u32),
    PerVertex(Vec<f32>),
}

impl PyramidDeformer {
    /// Builds the topology and the encoding of a mesh at rest.
    pub fn bind(mesh: MeshInput<'_>, options: DeformerOptions) -> Result<Self> {
        let topology = Topology::build(mesh)?;
        let encoding = Arc::new(encode(&topology, mesh.positions, options.scale_safe)?);
        let split = RingFitVertices::split(&topology, encoding.pinned());
        let ring_fit = if split.fitted.is_empty() {
            None
        } else {
            let vertices: Vec<u32> = split.fitted.iter().map(|&(v, _)| v).collect();
            Some(RingFit::new(&topology, mesh.positions, &vertices, options.scale_safe))
        };
        Self::build(encoding, options.formulation, split, ring_fit)
    }

    /// A deformer over an existing encoding (shared, e.g. to compare
    /// formulations). Without the topology there is no ring fit: every
    /// vertex the encoding pins follows the input.
    pub fn from_encoding(encoding: Arc<Encoding>, formulation: Formulation) -> Result<Self> {
        let split = RingFitVertices { fitted: Vec::new(), pinned: encoding.pinned().to_vec() };
        Self::build(encoding, formulation, split, None)
    }

    fn build(
        encoding: Arc<Encoding>,
        formulation: Formulation,
        split: RingFitVertices,
        ring_fit: Option<RingFit>,
    ) -> Result<Self> {
        let n = encoding.vertex_count();
        let mut pinned_mask = vec![false; n];
        for &(v, _) in &split.pinned {
            pinned_mask[v as usize] = true;
        }
        let mut anchored_mask = vec![false; n];
        if let Some(fit) = &ring_fit {
            for v in fit.anchored() {
                anchored_mask[v as usize] = true;
            }
        }
        let mut solver = Solver::new(n);
        let pyramid_rows = encoding.len();
        let constraint: Box<dyn solve::Constraint> = match formulation {
            Formulation::VertexTargets => Box::new(PyramidTargets::new(encoding.clone())),
            Formulation::Laplacian => Box::new(PyramidLaplacian::new(encoding.clone())),
        };
        let pyramid = solver.add(constraint, vec![1.0; pyramid_rows])?;
        let ring_fit = match ring_fit {
            Some(fit) => {
                let rows = fit.vertices().len();
                Some(solver.add(Box::new(fit), vec![1.0; rows])?)
            }
            None => None,
        };
        let closeness = solver.add(Box::new(solve::Closeness::all(n)), vec![1.0; n])?;
        // A sliver's vertex is carried from its anchor; on a triangle fan's
        // rim each is anchored to the next, a chain the length of the rim.
        solver.set_unextrapolated(&anchored_mask)?;
        let mut deformer = PyramidDeformer {
            encoding,
            formulation,
            pinned_mask,
            anchored_mask,
            pinned: split.pinned,
            ring_fitted: split.fitted,
            solver,
            pyramid,
            ring_fit,
            closeness,
            applied: None,
            closeness_weights: Vec::new(),
        };
        deformer.set_closeness(Closeness::Default)?;
        Ok(deformer)
    }

    pub fn vertex_count(&self) -> usize {
        self.encoding.vertex_count()
    }

    pub fn encoding(&self) -> &Arc<Encoding> {
        &self.encoding
    }

    pub fn formulation(&self) -> Formulation {
        self.formulation
    }

    /// Vertices that follow the input (no pyramid row and no ring fit), ascending.
    pub fn pinned_vertices(&self) -> Vec<u32> {
        self.pinned.iter().map(|&(v, _)| v).collect()
    }

    /// Pinned vertices with the reason the encoding gave.
    pub fn pinned(&self) -> &[(u32, PinReason)] {
        &self.pinned
    }

    /// Vertices without a pyramid row that deform with their neighbourhood
    /// through a ring fit, with the reason they have no pyramid row, ascending.
    pub fn ring_fitted(&self) -> &[(u32, PinReason)] {
        &self.ring_fitted
    }

    /// Factorises the global system now (otherwise the first solve does).
    pub fn prepare(&mut self) -> Result<SystemKind> {
        self.solver.prepare()
    }

    /// Entries of the global Cholesky factor (0 for the diagonal formulation).
    pub fn factor_nnz(&mut self) -> Result<usize> {
        self.solver.factor_nnz()
    }

    /// Sets the closeness weights; refactorises lazily only if they changed.
    pub fn set_closeness(&mut self, closeness: Closeness<'_>) -> Result<()> {
        let n = self.vertex_count();
        let unchanged = match (&self.applied, closeness) {
            (Some(Applied::Uniform(bits)), Closeness::Default) => *bits == DEFAULT_CLOSENESS.to_bits(),
            (Some(Applied::Uniform(bits)), Closeness::Uniform(c)) => *bits == c.to_bits(),
            (Some(Applied::PerVertex(last)), Closeness::PerVertex(weights)) => {
                last.len() == weights.len()
                    && last.iter().zip(weights).all(|(a, b)| a.to_bits() == b.to_bits())
            }
            _ => false,
        };
        if unchanged {
            return Ok(());
        }
        self.applied = None;
        let mut per_vertex = match closeness {
            Closeness::Default => vec![DEFAULT_CLOSENESS; n],
            Closeness::Uniform(c) => {
                if !(0.0..=1.0).contains(&c) {
                    return Err(Error::invalid(format!(
                        "closeness is {c}; it must be between 0 and 1"
                    )));
                }
                vec![c; n]
            }
            Closeness::PerVertex(weights) => {
                validate_closeness(weights, n)?;
                weights.to_vec()
            }
        };
        for ((c, &pinned), &anchored) in per_vertex.iter_mut().zip(&self.pinned_mask).zip(&self.anchored_mask) {
            *c = if pinned {
                PINNED_CLOSENESS
            } else if anchored {
                MIN_CLOSENESS
            } else {
                c.max(MIN_CLOSENESS)
            };
        }
        let pyramid: Vec<f32> = self
            .encoding
            .vertices()
            .iter()
            .map(|&v| 1.0 - per_vertex[v as usize].min(1.0))
            .collect();
        self.solver.set_weights(self.pyramid, &pyramid)?;
        if let Some(id) = self.ring_fit {
            let fit: Vec<f32> = self
                .ring_fitted
                .iter()
                .map(|&(v, _)| 1.0 - per_vertex[v as usize].min(1.0))
                .collect();
            self.solver.set_weights(id, &fit)?;
        }
        self.solver.set_weights(self.closeness, &per_vertex)?;
        self.closeness_weights = per_vertex;
        self.applied = Some(match closeness {
            Closeness::Default => Applied::Uniform(DEFAULT_CLOSENESS.to_bits()),
            Closeness::Uniform(c) => Applied::Uniform(c.to_bits()),
            Closeness::PerVertex(weights) => Applied::PerVertex(weights.to_vec()),
        });
        Ok(())
    }

    /// The accelerated solver (the multilevel correction of `solve::coarse`:
    /// [`ACCELERATED_ITERATIONS`] deliver the converged solve within 5 %) or
    /// plain local/global iterations (the default: at 10 iterations they
    /// cost half as much, which the bake's budget needs, and get 40–60 % of
    /// the way at closeness 0.05).
    pub fn set_accelerated(&mut self, on: bool) {
        self.set_coarse_correction(on);
    }

    /// Whether [`Self::set_accelerated`] is on.
    pub fn accelerated(&self) -> bool {
        self.solver.coarse_correction()
    }

    /// Lets an accelerated solve stop before its iteration count once its
    /// estimated convergence error is at most `tolerance` (a fraction of the
    /// displacement, e.g. 0.02; `None`: always run the count). Offsets below
    /// a tenth of the mean rest edge length count as that much, so a frame
    /// at rest stops too. See `solve::stopping`.
    pub fn set_tolerance(&mut self, tolerance: Option<f32>) -> Result<()> {
        let floor = STOPPING_FLOOR * self.encoding.mean_edge_length();
        self.solver.set_tolerance(tolerance.map(|relative| Tolerance { relative, floor }))
    }

    /// The tolerance of [`Self::set_tolerance`].
    pub fn tolerance(&self) -> Option<f32> {
        self.solver.tolerance().map(|t| t.relative)
    }

    /// Iterations the last solve ran: its count, or fewer with a tolerance.
    pub fn last_iterations(&self) -> usize {
        self.solver.last_iterations()
    }

    /// Turns the solver's coarse-level correction on or off (see
    /// `solve::coarse`; only the per-vertex-target formulation has one).
    pub fn set_coarse_correction(&mut self, on: bool) {
        self.solver.set_coarse_correction(on);
    }

    /// Solves one frame starting from `input` and returns the result.
    pub fn solve(
        &mut self,
        input: &[Vec3],
        iterations: usize,
        closeness: Closeness<'_>,
    ) -> Result<Vec<Vec3>> {
        let mut out = input.to_vec();
        self.solve_into(input, &mut out, iterations, closeness, None)?;
        Ok(out)
    }

    /// Solves one frame from the start positions already in `positions`
    /// (usually the input), with an optional hook after every iteration.
    pub fn solve_into(
        &mut self,
        input: &[Vec3],
        positions: &mut [Vec3],
        iterations: usize,
        closeness: Closeness<'_>,
        hook: Option<&mut dyn IterationHook>,
    ) -> Result<()> {
        if iterations > MAX_ITERATIONS {
            return Err(Error::invalid(format!(
                "iterations is {iterations}; at most {MAX_ITERATIONS} are allowed"
            )));
        }
        self.set_closeness(closeness)?;
        self.solver.solve(input, positions, iterations, hook)
    }

    /// Per-vertex closeness as last applied (clamped to
    /// [[`MIN_CLOSENESS`], 1]; pinned vertices at [`PINNED_CLOSENESS`]).
    pub fn closeness_weights(&self) -> &[f32] {
        &self.closeness_weights
    }

    /// The solver, for terms a caller adds around the pyramid and closeness
    /// rows (the stepper's inertia and contact targets) and for solves with
    /// an [`IterationHook`]. The pyramid and closeness weights stay the
    /// deformer's: set them through [`Self::set_closeness`].
    pub fn solver_mut(&mut self) -> &mut Solver {
        &mut self.solver
    }

    /// Mean pyramid residual `|x_v − target_v|` over the encoded vertices,
    /// relative to the mean rest edge length (0 when nothing is encoded).
    pub fn residual(&self, positions: &[Vec3]) -> Result<f32> {
        mean_residual(&self.encoding, positions)
    }
}

/// Checks per-vertex closeness weights: one per vertex, each in `[0, 1]`.
pub fn validate_closeness(weights: &[f32], vertex_count: usize) -> Result<()> {
    if weights.len() != vertex_count {
        return Err(Error::invalid(format!(
            "closeness has {} weights but the mesh has {vertex_count} vertices",
            weights.len()
        )));
    }
    if let Some(v) = weights.iter().position(|c| !(0.0..=1.0).contains(c)) {
        return Err(Error::invalid(format!(
            "closeness of vertex {v} is {}; it must be between 0 and 1",
            weights[v]
        )));
    }
    Ok(())
}

/// [`PyramidDeformer::residual`] for an encoding.
pub fn mean_residual(encoding: &Encoding, positions: &[Vec3]) -> Result<f32> {
    if positions.len() != encoding.vertex_count() {
        return Err(Error::invalid(format!(
            "positions: {} vertices given, the mesh has {}",
            positions.len(),
            encoding.vertex_count()
        )));
    }
    validate_positions("positions", positions)?;
    let count = encoding.len();
    if count == 0 || encoding.mean_edge_length() <= 0.0 {
        return Ok(0.0);
    }
    // Fixed chunks summed in order: the same figure on any thread count.
    const CHUNK: usize = 4096;
    let partial: Vec<f64> = (0..count.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            (c * CHUNK..((c + 1) * CHUNK).min(count))
                .map(|e| residual(encoding, e, positions) as f64)
                .sum()
        })
        .collect();
    let mean = partial.iter().sum::<f64>() / count as f64;
    Ok((mean / encoding.mean_edge_length() as f64) as f32)
}

