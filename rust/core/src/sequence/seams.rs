//! The sequence's public face, in the user's vertices.
//!
//! Meshes from glTF, FBX and USD importers are split wherever a UV or a sharp
//! normal changes: seams whose two sides lie exactly on top of each other.
//! [`Sequence::bind`] welds them ([`Weld`]): the deformer, the collision skin,
//! strain limits and dynamics all see one vertex per seam point, so a seam
//! cannot open and its vertices get full one-rings. Every method here takes and
//! returns the mesh's own vertices: inputs and painted weights are gathered
//! onto the welded vertices (the mean; the tightest strain limit), results are
//! scattered back, so every member of a seam gets the same position. On a mesh
//! without split seams the weld is the identity and nothing is copied.

use glam::Vec3;

use super::options::{SelfOptions, StepOptions, StepReport, StrainOptions};
use super::Sequence;
use crate::collide::Collider;
use crate::mesh::{validate_positions, Weld};
use crate::pyramid::{validate_closeness, Closeness, PinReason};
use crate::solve::IterationHook;
use crate::strain::{validate_max_stretch, MaxStretch};
use crate::{Error, Result};

impl Sequence {
    /// Number of the mesh's vertices (before welding).
    pub fn vertex_count(&self) -> usize {
        self.weld.vertex_count()
    }

    /// Number of vertices the solver sees: split seams welded.
    pub fn welded_vertex_count(&self) -> usize {
        self.weld.welded_count()
    }

    /// The map between the mesh's vertices and the welded ones.
    pub fn weld(&self) -> &Weld {
        &self.weld
    }

    /// Solves the next frame of a sequence against `colliders` (already
    /// [`Collider::update`]-d to this frame) and remembers the result as the
    /// start of the next one. The first call, and the first after
    /// [`Self::reset`], starts from `input` itself, which should then be free
    /// of collisions. Compliant colliders are solved too: their `current`
    /// positions are the result (where they receded), their animated ones
    /// the goals.
    pub fn step(
        &mut self,
        input: &[Vec3],
        colliders: &mut [&mut Collider],
        options: &StepOptions<'_>,
    ) -> Result<(Vec<Vec3>, StepReport)> {
        if self.weld.is_identity() {
            return self.step_welded(input, colliders, options);
        }
        self.check_len("input", input.len())?;
        validate_positions("input", input)?;
        let mut closeness_buffer = Vec::new();
        let mut stretch_buffer = Vec::new();
        let mut self_weights = Vec::new();
        let welded_options = StepOptions {
            self_collision: match options.self_collision {
                Some(own) => Some(SelfOptions { weights: self.gather_self_weights(own.weights, &mut self_weights)?, ..own }),
                None => None,
            },
            closeness: self.gather_closeness(options.closeness, &mut closeness_buffer)?,
            strain: match options.strain {
                Some(strain) => Some(StrainOptions {
                    max_stretch: self.gather_max_stretch(strain.max_stretch, &mut stretch_buffer)?,
                    mode: strain.mode,
                }),
                None => None,
            },
            ..*options
        };
        let (welded, mut report) = self.step_welded(&self.weld.gather(input), colliders, &welded_options)?;
        report.pinched = self.weld.expand(&report.pinched);
        report.first_pass.pinched = self.weld.expand(&report.first_pass.pinched);
        report.first_pass.moved = self.weld.expand(&report.first_pass.moved);
        report.self_pinched = self.weld.expand(&report.self_pinched);
        Ok((self.scatter(&welded), report))
    }

    /// Solves one frame from `input`, without history, collisions or
    /// dynamics ([`crate::pyramid::PyramidDeformer::solve`]); leaves the
    /// sequence's state alone.
    pub fn solve(&mut self, input: &[Vec3], iterations: usize, closeness: Closeness<'_>) -> Result<Vec<Vec3>> {
        let mut out = input.to_vec();
        self.solve_into(input, &mut out, iterations, closeness, None)?;
        Ok(out)
    }

    /// [`Self::solve`] into `positions`, which hold the start (usually the
    /// input), with an optional hook after every iteration (in welded
    /// vertices).
    pub fn solve_into(
        &mut self,
        input: &[Vec3],
        positions: &mut [Vec3],
        iterations: usize,
        closeness: Closeness<'_>,
        hook: Option<&mut dyn IterationHook>,
    ) -> Result<()> {
        if self.weld.is_identity() {
            return self.deformer.solve_into(input, positions, iterations, closeness, hook);
        }
        self.check_len("input", input.len())?;
        self.check_len("positions", positions.len())?;
        validate_positions("input", input)?;
        validate_positions("positions", positions)?;
        let mut buffer = Vec::new();
        let closeness = self.gather_closeness(closeness, &mut buffer)?;
        let welded_input = self.weld.gather(input);
        let mut welded = self.weld.gather(positions);
        self.deformer.solve_into(&welded_input, &mut welded, iterations, closeness, hook)?;
        self.weld.scatter(&welded, positions);
        Ok(())
    }

    /// Makes `positions` the last output, as if a step had produced them:
    /// a bake resuming after frames already cached starts from the last of
    /// them (at rest, and without substep interpolation from the input
    /// before it). They must be free of collisions for the next step's
    /// guarantee.
    pub fn set_history(&mut self, positions: &[Vec3]) -> Result<()> {
        self.check_len("history", positions.len())?;
        validate_positions("history", positions)?;
        self.history = Some(if self.weld.is_identity() { positions.to_vec() } else { self.weld.gather(positions) });
        self.velocity = None;
        self.last_input = None;
        self.self_tangles = None;
        Ok(())
    }

    /// The last output of [`Self::step`], if any.
    pub fn history(&self) -> Option<Vec<Vec3>> {
        self.history.as_deref().map(|h| self.scatter(h))
    }

    /// Velocities at the end of the last dynamic step, if any.
    pub fn velocity(&self) -> Option<Vec<Vec3>> {
        self.velocity.as_deref().map(|v| self.scatter(v))
    }

    /// Vertices that follow the input (no pyramid row and no ring fit), with
    /// the reason, ascending. Every member of a welded seam point is listed.
    pub fn pinned(&self) -> Vec<(u32, PinReason)> {
        self.unweld_reasons(self.deformer.pinned())
    }

    /// Vertices without a pyramid row that deform with their neighbourhood
    /// through a ring fit ([`crate::pyramid::PyramidDeformer::ring_fitted`]),
    /// with the reason they have no pyramid row, ascending. Every member of a
    /// welded seam point is listed.
    pub fn ring_fitted(&self) -> Vec<(u32, PinReason)> {
        self.unweld_reasons(self.deformer.ring_fitted())
    }

    /// Welded vertices with a reason, as the mesh's own vertices.
    fn unweld_reasons(&self, welded: &[(u32, PinReason)]) -> Vec<(u32, PinReason)> {
        if self.weld.is_identity() {
            return welded.to_vec();
        }
        let mut out: Vec<(u32, PinReason)> = welded
            .iter()
            .flat_map(|&(w, reason)| self.weld.members(w as usize).iter().map(move |&v| (v, reason)))
            .collect();
        out.sort_unstable_by_key(|&(v, _)| v);
        out
    }

    /// [`Self::pinned`] without the reasons.
    pub fn pinned_vertices(&self) -> Vec<u32> {
        self.pinned().into_iter().map(|(v, _)| v).collect()
    }

    /// Mean pyramid residual of `positions` ([`crate::pyramid::PyramidDeformer::residual`]).
    pub fn residual(&self, positions: &[Vec3]) -> Result<f32> {
        if self.weld.is_identity() {
            return self.deformer.residual(positions);
        }
        self.check_len("positions", positions.len())?;
        validate_positions("positions", positions)?;
        self.deformer.residual(&self.weld.gather(positions))
    }

    fn check_len(&self, what: &str, len: usize) -> Result<()> {
        let n = self.vertex_count();
        if len != n {
            return Err(Error::invalid(format!("{what}: {len} vertices given, the deformer has {n}")));
        }
        Ok(())
    }

    fn scatter(&self, welded: &[Vec3]) -> Vec<Vec3> {
        if self.weld.is_identity() {
            return welded.to_vec();
        }
        let mut out = vec![Vec3::ZERO; self.vertex_count()];
        self.weld.scatter(welded, &mut out);
        out
    }

    /// Per-vertex closeness checked against the mesh, then the mean over each
    /// welded vertex's members.
    fn gather_closeness<'b>(&self, closeness: Closeness<'_>, buffer: &'b mut Vec<f32>) -> Result<Closeness<'b>> {
        Ok(match closeness {
            Closeness::Default => Closeness::Default,
            Closeness::Uniform(c) => Closeness::Uniform(c),
            Closeness::PerVertex(weights) => {
                validate_closeness(weights, self.vertex_count())?;
                *buffer = self.weld.gather_scalars(weights);
                Closeness::PerVertex(buffer)
            }
        })
    }

    /// Self-collision weights checked against the mesh, then the largest
    /// over each welded vertex's members: a seam takes part if a side does.
    fn gather_self_weights<'b>(&self, weights: Option<&[f32]>, buffer: &'b mut Vec<f32>) -> Result<Option<&'b [f32]>> {
        let Some(weights) = weights else { return Ok(None) };
        self.check_len("self-collision weights", weights.len())?;
        if let Some(v) = weights.iter().position(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::invalid(format!("self-collision weight of vertex {v} is {}; it must be finite and ≥ 0", weights[v])));
        }
        *buffer = (0..self.weld.welded_count())
            .map(|w| self.weld.members(w).iter().map(|&v| weights[v as usize]).fold(0.0, f32::max))
            .collect();
        Ok(Some(buffer))
    }

    /// Per-vertex ε checked against the mesh, then the smallest over each
    /// welded vertex's members: a seam is held as tightly as its tightest side.
    fn gather_max_stretch<'b>(&self, stretch: MaxStretch<'_>, buffer: &'b mut Vec<f32>) -> Result<MaxStretch<'b>> {
        Ok(match stretch {
            MaxStretch::Uniform(eps) => MaxStretch::Uniform(eps),
            MaxStretch::PerVertex(eps) => {
                validate_max_stretch(stretch, self.vertex_count())?;
                *buffer = (0..self.weld.welded_count())
                    .map(|w| self.weld.members(w).iter().map(|&v| eps[v as usize]).fold(f32::INFINITY, f32::min))
                    .collect();
                MaxStretch::PerVertex(buffer)
            }
        })
    }
}
