//! The strain pass of a step (seed 002 §2): edge shortening against the
//! contacts ([`StrainMode::Unified`]) or after them ([`StrainMode::Post`]).

use glam::Vec3;

use crate::collide::{Clearance, Collider, ColliderSet, ResolveParams, Skin};
use crate::strain::{EdgeLimits, Hierarchy};
use crate::Result;

#[allow(unused_imports)] // named by the docs
use super::options::StrainMode;

/// Gauss–Seidel sweeps of the strain projection per round of the unified
/// loop, at most: the sweeps stop once every edge holds, and after the first
/// they visit only the edges around what moved ([`EdgeLimits::project_above`]).
/// Against the contact planes the sweeps converge slowly: on issue 29's
/// dragged sheet (a 1.1 limit), 8 left an edge at 1.1116, 16 keep every edge
/// within 1.1017 and 64 within 1.1007, but 64 cost
/// the 100k-vertex flesh benchmark twice as much (2.8 s against 1.4 s a
/// frame, worst edge 1.16 against 1.24: it does not converge there either).
pub(super) const STRAIN_SWEEPS: usize = 16;
/// Rounds of (strain sweeps, contact resolution) in the last iteration of the
/// unified loop, until both hold; the [`STRAIN_EARLY_ITERATIONS`] before it
/// run [`STRAIN_ROUNDS_EARLY`]: the next iteration's solve moves the skin anyway,
/// and every round costs a whole contact pass (16 rounds in every iteration
/// took 18 s per frame on the 100k-vertex benchmark scene).
pub(super) const STRAIN_ROUNDS: usize = 16;
pub(super) const STRAIN_ROUNDS_EARLY: usize = 2;
/// The iterations just before the last that run strain rounds; those before
/// them run none (issue 29). Each solve iteration pulls the skin back over
/// its limits (on the 100k-vertex flesh benchmark's frame 8, to 1.5–1.75 ×
/// the limit after rounds had left it at 1.26–1.44), so early rounds only
/// shape where the last iteration starts, and only the last ones before it
/// still do that. Measured there (frames 1–8): rounds in all 9 early
/// iterations, 22 of frame 8's rounds, 132 in all; in the last 2, 8 and 48,
/// worst edge ≤ 1.1098 either way (promise 1.111). Fewer do not hold:
/// none left the skin a friction-1 sphere drags going 0.031 of the drag
/// (`a_held_sheet_dragged_by_a_rough_sphere_slides_within_its_strain_limit`
/// allows 0.03: the frictionless rounds are what lets it slide); one round
/// in each early iteration, 1.160 on the benchmark; one in each of the last
/// two, 1.122.
pub(super) const STRAIN_EARLY_ITERATIONS: usize = 2;
/// The last iteration's rounds open with cycles of the multilevel
/// projection ([`Hierarchy`]) and over-relaxed sweeps, at most this many a
/// round. Issue 29's 100k-vertex flesh benchmark (a sphere tenting a sheet
/// at closeness 0.1: the solve stretches the cap on the sphere 2.3–2.5×,
/// and the material it needs is drawn from a band some 50 edges wide, every
/// edge of it at its limit) ends its frames at 1.106–1.108 × the rest length
/// (limit 1.1, promise 1.111) with 4 cycles in every round; with one cycle
/// of rigid blocks in the first round only, as before, at 1.24; with 2
/// cycles, 1.112–1.113; with 8 cycles and no over-relaxation, 1.106–1.108
/// for more time.
pub(super) const MULTILEVEL_CYCLES: usize = 4;
/// Sweeps per level of a multilevel cycle.
pub(super) const MULTILEVEL_SWEEPS: usize = 4;
/// Over-relaxation of the sweeps after a multilevel cycle
/// ([`EdgeLimits::project_relaxed`]): on the flesh benchmark 1.6 took the
/// worst edge from 1.110–1.112 to 1.106–1.108 at 4 cycles for the same CPU
/// time; 1.8 at 2 cycles diverged (1.27).
pub(super) const OVER_RELAXATION: f32 = 1.6;
/// Relative excess over an edge's limit that counts as holding in the post
/// pass.
pub(super) const STRAIN_TOLERANCE: f32 = 1e-3;
/// Relative excess over an edge's limit at which the unified pass stops:
/// what strain limits promise is every edge within 1 % of its limit
/// (`(1 + ε)·1.01` its rest length), and the pass stops once every edge is
/// within 0.9 % (a margin for lengths measured from other arithmetic, e.g.
/// a cache's float32 positions). Where the pass cannot get there in its
/// rounds it runs them all, as before.
///
/// Its tail converges slowly (issue 29's 100k-vertex flesh benchmark: the
/// worst edge, at the top of the tent over the sphere with both ends on
/// their contact planes, shrinks ~1 % of its excess a round), so the
/// rounds after the promise holds were most of the pass: running on to
/// 0.1 % took rounds 10–16 of 16 on frames 6–8 to reach 1.0058–1.0075,
/// ~40 % of the strain pass for a bound nobody is promised.
pub(super) const HOLDS: f32 = 9e-3;
/// The reach of the clearance the last iteration's rounds measure for their
/// contact resolutions once those test far more than the contact region, in
/// radii of the in-loop passes' clearance. The rounds' multilevel cycles
/// move a band of skin some 50 edges wide, much farther than an in-loop pass
/// moves it: against the in-loop clearance, measured before the frame's
/// first in-loop pass, vertices that moved beyond its radius are tested
/// again, far from any collider. On issue 29's 100k-vertex flesh benchmark
/// the rounds after the first tested 19,000–41,000 vertices each in frames
/// 6–8, against 7,000–11,000 in the first (the contact region), and about
/// 9,000 with a clearance of 4 radii. Frames 6–8 took 19.81 G instructions
/// with 2 radii, 20.15 G with 4 and 20.07 G with 8 (21.35 G without): a
/// wider reach proves more but costs more to measure, the tree searched
/// farther around more of the skin.
pub(super) const ROUNDS_CLEARANCE_REACH: f32 = 2.0;
/// The wider clearance is measured once a round's resolution tested more
/// than this many times what the pass's first round tested: the measurement
/// costs about what testing 40,000 vertices does on the benchmark (a whole
/// skin's bounds and the tree searched within the wider radius), so it is
/// not paid for passes whose rounds stay on the contact region (a frame's
/// first rounds, or all three features together, where the rounds are one
/// or two and test what the first did).
pub(super) const WIDER_CLEARANCE_AFTER: usize = 2;
/// Sweeps of the post-collision strain pass (one long projection, as many
/// sweeps as the unified loop had before its contact planes).
pub(super) const POST_STRAIN_SWEEPS: usize = 128;

/// What one unified strain pass did.
pub(super) struct StrainPass {
    /// The vertices the last contact resolution left pinched.
    pub pinched: Vec<u32>,
    /// Rounds of (shortening, contact resolution) run.
    pub rounds: usize,
    /// Cycles of the multilevel projection run, over all rounds.
    pub cycles: usize,
}

/// Unified strain limiting (seed 002 §2): edge shortening and contact
/// resolution alternate until both hold or the rounds run out. Returns the
/// vertices the last contact resolution left pinched, and the work done. With `levels`, every
/// round's shortening runs cycles of the multilevel projection, which draws
/// material from far away, each followed by over-relaxed sweeps, all of
/// them keeping the contacts on their planes.
///
/// Friction is capped by the limits (issue 29). The contact resolution of a
/// round resolves the strain projection's moves **without friction**: where
/// an edge beyond its limit pulls a vertex in contact, the vertex is pushed
/// back out along the contact normal only and keeps the tangential part, so
/// it slides along the collider towards where the limit wants it instead of
/// being held by static friction. Friction still acts in the solve's own
/// contact passes, so it drags the skin wherever the limits are not at stake.
/// And every vertex a round's resolution pushed out gets that push as a
/// plane (`n·x ≥ n·x_resolved`, `n` the push's direction): the next rounds'
/// sweeps keep it on or above the plane ([`EdgeLimits::project_above`]), so
/// they move contact vertices along the collider rather than into it and the
/// resolution that follows has (nearly) nothing left to undo. Without the
/// planes the two projections undo each other on skin wrapped around a
/// collider and the rounds end before the limits hold.
///
/// Measured on issue 29's dragged sheet with 64 sweeps a round (friction-1
/// sphere, ε = 0.1; the worst edge over the drag, and how far the skin the
/// sphere pressed goes with it against the sphere's 0.6): both, 1.1007 and
/// 0.009 at the end (1.1017 and 0.009 with the 16 sweeps kept);
/// planes with friction kept here, 1.1010 and 0.022; no planes, 1.1148;
/// neither (only the 64 sweeps), 1.1214; before all this (8 sweeps), 1.25.
#[allow(clippy::too_many_arguments)]
pub(super) fn limit_strain_with_contacts(
    limits: &EdgeLimits,
    levels: Option<&Hierarchy>,
    colliders: &[&mut Collider],
    x: &mut [Vec3],
    skin: &Skin,
    inverse_mass: &[f32],
    rounds: usize,
    clearance: Option<&Clearance>,
) -> Result<StrainPass> {
    let refs: Vec<&Collider> = colliders.iter().map(|c| &**c).collect();
    let set = ColliderSet::new(refs);
    let params = ResolveParams { friction: false, ..ResolveParams::in_loop() };
    let mut pass = StrainPass { pinched: Vec::new(), rounds: 0, cycles: 0 };
    // Per vertex, the plane of its last push out of a collider (zero normal: none).
    let mut above: Vec<(Vec3, f32)> = Vec::new();
    // With the levels, a clearance of a wider reach around where a round
    // starts, measured once the rounds test far more than the first did (see
    // `ROUNDS_CLEARANCE_REACH`); the colliders stand still through the pass,
    // so it holds for the rounds after.
    let mut wider: Option<Clearance> = None;
    let (mut first_tested, mut last_tested) = (None, 0);
    for _ in 0..rounds {
        if limits.worst_ratio(x) <= 1.0 + HOLDS {
            break;
        }
        pass.rounds += 1;
        let mut shortened = x.to_vec();
        match levels {
            // Cycles of the levels and over-relaxed sweeps, until the limits
            // hold or the cycles run out; the planes keep contacts sliding.
            Some(levels) => {
                for _ in 0..MULTILEVEL_CYCLES {
                    pass.cycles += 1;
                    levels.project(&mut shortened, inverse_mass, &above, MULTILEVEL_SWEEPS);
                    limits.project_relaxed(&mut shortened, inverse_mass, &above, STRAIN_SWEEPS, HOLDS, OVER_RELAXATION);
                    if limits.worst_ratio(&shortened) <= 1.0 + HOLDS {
                        break;
                    }
                }
            }
            None => {
                limits.project_above(&mut shortened, inverse_mass, &above, STRAIN_SWEEPS, HOLDS);
            }
        }
        if !set.colliders().is_empty() {
            let projected = shortened.clone();
            let spread = first_tested.is_some_and(|first: usize| last_tested > WIDER_CLEARANCE_AFTER * first.max(1));
            if let (Some(_), Some(first), None, true) = (levels, clearance, &wider, spread) {
                wider = Some(Clearance::new(set.colliders(), skin, x, ROUNDS_CLEARANCE_REACH * first.radius())?);
            }
            let stats = set.resolve_path_within(x, &mut shortened, skin, &params, clearance, wider.as_ref())?;
            first_tested.get_or_insert(stats.tested);
            last_tested = stats.tested;
            if !stats.moved.is_empty() && above.is_empty() {
                above = vec![(Vec3::ZERO, 0.0); x.len()];
            }
            for &i in &stats.moved {
                let i = i as usize;
                let push = shortened[i] - projected[i];
                let length = push.length();
                if length > 0.0 {
                    let n = push / length;
                    above[i] = (n, n.dot(shortened[i]));
                }
            }
            pass.pinched = stats.pinched;
        }
        x.copy_from_slice(&shortened);
    }
    Ok(pass)
}
