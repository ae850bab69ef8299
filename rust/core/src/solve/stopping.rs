//! When an accelerated solve may stop before its iteration count.
//!
//! Issue 28 measures a solve by its convergence error, `RMS |x_k − x_∞|`
//! over `RMS |x_∞ − input|`. A solve does not know `x_∞`, but a linearly
//! converging iteration with contraction `ρ` bounds the error left after a
//! step `s_k = x_{k+1} − x_k` by `ρ / (1 − ρ) · |s_k|`. The rule estimates `ρ`
//! from the ratio of the last two steps, never below [`MIN_RATIO`] (the
//! accelerated iteration's ratio on the benchmark tube is about 0.5, and a
//! ratio read from two noisy steps can be far smaller than the iteration's),
//! and stops once that bound is at most the tolerance times the iterate's
//! RMS offset from the input, or than the tolerance times a floor where the
//! offset is smaller (an input at rest has no offset to be relative to; the
//! deformer's floor is a thousandth of the mesh's size). A step that grew
//! (the extrapolation restarting) never stops it. A solve whose start is already its solution (a still
//! frame warm-started from its own result) stops after its first step.
//!
//! On small meshes the count is a limit in work rather than in iterations
//! ([`limit`]): an iteration of a few hundred vertices costs microseconds, and
//! there the multilevel correction has too few aggregates to carry the smooth
//! error (the demo's 206-vertex limb at closeness 0.01 is 14.9 % from
//! converged after 12 iterations, 5.7 % after 50, 2.0 % where the rule stops
//! it at 83), so a mesh below [`WORK_VERTICES`] may run as many iterations as
//! cost the same as the count on that many vertices, at most
//! [`MAX_WORK_FACTOR`] times the count. There the error that is left decays
//! slowly (about 2.4 % an iteration on the 206-vertex limb) while the steps
//! are still dominated by faster modes, so the last two steps underestimate
//! it: on warm bake frames of that limb the rule stopped at 3–5 iterations
//! with 17.6 % left. So the rule spends the work on certainty as well: it
//! asks for a step smaller by the same factor (the tolerance divided by it).
//!
//! The rule is for the accelerated solver only: plain local/global
//! iterations contract by about `1 − closeness` per iteration, where the
//! estimate `ρ / (1 − ρ)` is 20–100 steps and a ratio read from two of them
//! is not reliable.

/// The smallest contraction the rule assumes (see the module documentation).
const MIN_RATIO: f64 = 0.5;

/// Meshes below this many vertices count their iteration limit in work (see
/// the module documentation).
pub const WORK_VERTICES: usize = 4096;

/// At most this many times the iteration count, however small the mesh.
pub const MAX_WORK_FACTOR: usize = 32;

/// The iteration limit of a solve with a stopping rule of `iterations` on
/// `vertices` vertices: the count, or on a mesh below [`WORK_VERTICES`] the
/// count times `WORK_VERTICES / vertices` (rounded down, at most
/// [`MAX_WORK_FACTOR`]): the same work as the count on that many vertices.
pub fn limit(iterations: usize, vertices: usize) -> usize {
    iterations.saturating_mul(work_factor(vertices))
}

/// How many times the count a mesh of `vertices` may run (see [`limit`]).
pub(super) fn work_factor(vertices: usize) -> usize {
    (WORK_VERTICES / vertices.max(1)).clamp(1, MAX_WORK_FACTOR)
}

/// When a solve may stop: its estimated error at most `relative` times the
/// RMS offset of the iterate from the input, or times `floor` where that is
/// smaller (same units as the positions).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerance {
    pub relative: f32,
    pub floor: f32,
}

/// The stopping rule of one solve.
#[derive(Debug, Clone)]
pub(super) struct Rule {
    tolerance: f64,
    /// The smallest offset the tolerance is relative to (RMS).
    floor: f64,
    /// The last step's squared norm (none before the first).
    last_step: Option<f64>,
}

impl Rule {
    /// The rule of a solve on `vertices` vertices: on a mesh below
    /// [`WORK_VERTICES`] the step it stops at is smaller by the
    /// [`work_factor`] (see the module documentation).
    pub(super) fn new(tolerance: Tolerance, vertices: usize) -> Self {
        let tolerance_of_mesh = tolerance.relative as f64 / work_factor(vertices) as f64;
        Rule { tolerance: tolerance_of_mesh, floor: tolerance.floor as f64, last_step: None }
    }

    /// Whether the solve may stop after a step that left the iterate
    /// `offset` from the input, both RMS over the vertices.
    pub(super) fn converged(&mut self, step: f64, offset: f64) -> bool {
        let last = self.last_step.replace(step);
        if step == 0.0 {
            return true;
        }
        let Some(last) = last else { return false };
        if step >= last {
            return false;
        }
        let ratio = (step / last).max(MIN_RATIO);
        let bound = ratio / (1.0 - ratio) * step;
        bound <= self.tolerance * offset.max(self.floor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_geometric_sequence_stops_once_its_tail_is_within_the_tolerance() {
        // Steps 1, 0.5, 0.25, …: the error left after a step is the sum of
        // the steps after it, which equals the step (ratio 0.5). Offset 10,
        // tolerance 0.01: it may stop once a step is at most 0.1, 0.0625.
        let mut rule = Rule::new(Tolerance { relative: 0.01, floor: 0.0 }, WORK_VERTICES);
        let stopped = (0..20).position(|k| rule.converged(0.5f64.powi(k), 10.0));
        assert_eq!(stopped, Some(4));
    }

    #[test]
    fn a_step_that_grew_or_the_first_step_never_stops_it() {
        let mut rule = Rule::new(Tolerance { relative: 0.5, floor: 0.0 }, WORK_VERTICES);
        assert!(!rule.converged(1e-6, 1.0), "the first step");
        assert!(!rule.converged(1e-3, 1.0), "a step that grew");
        assert!(rule.converged(1e-7, 1.0));
    }

    #[test]
    fn an_input_at_rest_is_measured_against_the_floor() {
        let mut rule = Rule::new(Tolerance { relative: 0.01, floor: 1.0 }, WORK_VERTICES);
        assert!(!rule.converged(1e-3, 0.0));
        assert!(rule.converged(1e-3 * 0.5, 0.0), "0.0005 ≤ 0.01 of the floor");
    }

    #[test]
    fn small_meshes_count_their_limit_in_work() {
        assert_eq!(limit(12, 100_000), 12);
        assert_eq!(limit(12, WORK_VERTICES), 12);
        assert_eq!(limit(12, WORK_VERTICES - 1), 12);
        assert_eq!(limit(12, WORK_VERTICES / 2), 24);
        assert_eq!(limit(12, 206), 12 * 19);
        assert_eq!(limit(12, 3), 12 * MAX_WORK_FACTOR);
        assert_eq!(limit(12, 0), 12 * MAX_WORK_FACTOR);
        assert_eq!(limit(0, 206), 0);
    }

    #[test]
    fn a_solve_that_does_not_move_stops_at_once() {
        let mut rule = Rule::new(Tolerance { relative: 1e-6, floor: 0.0 }, WORK_VERTICES);
        assert!(rule.converged(0.0, 0.0));
    }
}
