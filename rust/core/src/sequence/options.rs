//! What a step is asked to do, and what it reports.

use super::dynamics::Dynamics;
use crate::collide::{ContactStats, SelfSettings};
use crate::pyramid::Closeness;
use crate::strain::MaxStretch;

/// When strain limits are enforced relative to the contacts (seed 002 §2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StrainMode {
    /// In the same projection loop as the contacts, after every iteration,
    /// until both hold: no penetration and no edge over its limit.
    #[default]
    Unified,
    /// Once after the solve and its collision passes, unaware of the
    /// colliders: edges hold, but shortening them can pull skin back into a
    /// collider. Kept to show the difference.
    Post,
}

impl StrainMode {
    pub fn name(self) -> &'static str {
        match self {
            StrainMode::Unified => "unified",
            StrainMode::Post => "post",
        }
    }
}

/// Strain limits of a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StrainOptions<'a> {
    pub max_stretch: MaxStretch<'a>,
    pub mode: StrainMode,
}

/// Self-collision of a step: its settings, and where it applies.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SelfOptions<'a> {
    pub settings: SelfSettings,
    /// Per vertex: a triangle with a corner weighted above 0 takes part, and
    /// a pair is tested when both its triangles do (None: everywhere).
    pub weights: Option<&'a [f32]>,
}

/// Everything one [`super::Sequence::step`] is asked to do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOptions<'a> {
    /// Solver iterations per substep.
    pub iterations: usize,
    pub closeness: Closeness<'a>,
    /// Substeps per frame (1..=[`MAX_SUBSTEPS`]): input and colliders are
    /// interpolated linearly from the last frame's.
    pub substeps: usize,
    pub dynamics: Option<Dynamics>,
    pub strain: Option<StrainOptions<'a>>,
    /// The skin's contact with itself ([`super::self_pass`]).
    pub self_collision: Option<SelfOptions<'a>>,
}

impl Default for StepOptions<'_> {
    fn default() -> Self {
        StepOptions { iterations: 10, closeness: Closeness::Default, substeps: 1, dynamics: None, strain: None, self_collision: None }
    }
}

impl<'a> StepOptions<'a> {
    /// `iterations` iterations with `closeness`, everything else off.
    pub fn new(iterations: usize, closeness: Closeness<'a>) -> Self {
        StepOptions { iterations, closeness, ..Default::default() }
    }
}

/// What one [`super::Sequence::step`] did about contacts, dynamics and strain.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StepReport {
    /// The first pass (last output → this frame's input, colliders sweeping),
    /// summed over substeps.
    pub first_pass: ContactStats,
    /// Contacts resolved by the in-loop passes, over all iterations.
    pub in_loop_contacts: usize,
    /// Vertices any pass of this frame left pinched (ascending).
    pub pinched: Vec<u32>,
    /// Largest correction one in-loop pass applied to one vertex.
    pub max_in_loop_correction: f32,
    /// Kinetic energy at the end of the step (0 without dynamics).
    pub kinetic_energy: f64,
    /// Largest `length / rest length` over the strain-limited edges at the
    /// end of the step (0 without strain limits).
    pub worst_stretch: f32,
    /// Contacts that stopped compliant collider vertices at the skin.
    pub compliant_contacts: usize,
    /// Skin vertices giving way to compliant colliders (most in one substep).
    pub compliant_skin_vertices: usize,
    /// Largest distance of a compliant collider vertex from its animated
    /// position at the end of the step: how far the colliders receded.
    pub max_recession: f32,
    /// Times a pass put a vertex it could not clear of colliders standing
    /// still back where the pass started (over all passes and iterations):
    /// contacts that held instead of pinching.
    pub held: usize,
    /// Self-contacts projected by the first and in-loop passes.
    pub self_contacts: usize,
    /// Times the self-collision fail-safe put a vertex back where its pass
    /// started (over all passes): paths the rounds could not clear.
    pub self_held: usize,
    /// Vertices left crossing other skin where a sweeping collider had the
    /// last word (ascending; they are tangles of the next frame).
    pub self_pinched: Vec<u32>,
    /// Pairs of the skin's triangles intersecting in the output, neighbours
    /// not counted: those the input brought (tangles still coming apart) and
    /// those left by pinched vertices.
    pub self_intersections: usize,
    /// Vertices exempt at the start of the frame: their triangles
    /// intersected there.
    pub self_tangled: usize,
    /// Where self-collision's time went in this step (for benchmarks).
    pub self_work: SelfWork,
    /// Clearances measured for the in-loop passes: one per substep with
    /// colliders, and again where a compliant collider left its envelope.
    pub clearance_measurements: usize,
    /// Skin vertices the in-loop collider passes tested against the
    /// colliders, over all passes: those the clearance did not prove apart.
    /// It follows the region near the colliders, not the skin's size.
    pub in_loop_tested: usize,
    /// In-loop recessions of compliant colliders (one per collider and
    /// iteration that ran one, over all substeps): every third iteration's,
    /// counted back from the last, which always recedes.
    pub in_loop_recessions: usize,
    /// Skin vertices whose boxes were made again for compliant colliders to
    /// recede from, after the solver's iterations: those that moved since.
    pub in_loop_skin_refits: usize,
    /// Where the contact work's time went in this step (for benchmarks).
    pub contact_work: ContactWork,
}

/// Where one step's collider and strain time went: wall-clock milliseconds
/// per phase, summed over substeps and iterations (0 for phases that did not
/// run). Timings, so not the same from run to run: for benchmarks and
/// traces, never for decisions (the strain pass's counts are exact).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContactWork {
    /// The skin's target rows that give way to compliant colliders.
    pub compliant_targets_ms: f64,
    /// Compliant colliders receding before the first pass.
    pub first_recession_ms: f64,
    /// The first pass (last output towards the input, colliders sweeping).
    pub first_pass_ms: f64,
    /// The in-loop passes against the colliders, with their clearances.
    pub in_loop_pass_ms: f64,
    /// The unified strain passes after them.
    pub strain_ms: f64,
    /// The unified strain passes' rounds (strain projection, then contact
    /// resolution) and, within them, cycles of the multilevel projection: a
    /// count, the same in every run, for comparing strain solvers.
    pub strain_rounds: usize,
    pub strain_cycles: usize,
    /// Compliant colliders' in-loop recessions: where each vertex heads.
    pub recession_heading_ms: f64,
    /// Compliant colliders' in-loop recessions: the contact pass that stops
    /// them at the skin (with the skin's boxes made again where it moved).
    pub recession_contacts_ms: f64,
}

/// Where one step's self-collision time went: wall-clock milliseconds per
/// phase and how much the candidate search did. Timings, so not the same
/// from run to run: for benchmarks and traces, never for decisions.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SelfWork {
    /// Readying the step: settings, and the tangles of the first frame.
    pub begin_ms: f64,
    /// The first passes: their gathering, rounds and fail-safe.
    pub first_pass_ms: f64,
    /// The in-loop passes' rounds (with the gatherings they needed).
    pub in_loop_rounds_ms: f64,
    /// The in-loop passes' joint fail-safe (with the colliders' check).
    pub in_loop_fail_safe_ms: f64,
    /// Counting the output's intersections and the next frame's tangles.
    pub tangles_ms: f64,
    /// Candidate gatherings over the whole skin, over the step's passes.
    pub gathers: usize,
    /// Of those, the in-loop passes' (the rest are the first passes').
    pub in_loop_gathers: usize,
    /// Candidate gatherings only around vertices that left their margins
    /// (or that the first pass's fail-safe put back).
    pub gathers_around: usize,
    /// The most candidate pairs one pass held.
    pub most_candidates: usize,
    /// Within the phases above: the first passes' gatherings over the whole
    /// skin, the in-loop passes' ones, the gatherings around a few
    /// vertices (of both), the rounds' pair tests and projections (of
    /// both), and the fail-safes' checks of the skin (of both).
    pub first_gather_ms: f64,
    pub in_loop_gather_ms: f64,
    pub around_gather_ms: f64,
    pub rounds_ms: f64,
    pub fail_safe_checks_ms: f64,
    /// Candidate pairs the rounds and fail-safe checks went over (each its
    /// whole list, over the step), and of those the pairs tested by CCD.
    pub pairs_scanned: usize,
    pub pairs_tested: usize,
}

/// Adds a substep's first-pass figures to the frame's.
pub(super) fn accumulate(total: &mut ContactStats, part: &ContactStats) {
    total.vertex_contacts += part.vertex_contacts;
    total.edge_contacts += part.edge_contacts;
    total.collider_vertex_contacts += part.collider_vertex_contacts;
    total.plane_lifts += part.plane_lifts;
    total.tested += part.tested;
    total.rounds += part.rounds;
    total.max_correction = total.max_correction.max(part.max_correction);
    total.moved.extend_from_slice(&part.moved);
    total.moved.sort_unstable();
    total.moved.dedup();
    total.pinched.extend_from_slice(&part.pinched);
    total.pinched.sort_unstable();
    total.pinched.dedup();
    total.held.extend_from_slice(&part.held);
    total.held.sort_unstable();
    total.held.dedup();
}
