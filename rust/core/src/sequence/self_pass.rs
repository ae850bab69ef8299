//! The skin's contact with itself in the frame stepper: the same two passes
//! as the colliders' (seed 000, Algorithm 2), together with them.
//!
//! * **First pass**: after the colliders' sweep, self-collision along each
//!   vertex's path from the last output; where it changed paths, the
//!   colliders once more. Without colliders or dynamics the path ends at the
//!   warm start (the last output carried by the input's motion), and the
//!   candidates' margins cover how far the last warm solve took the skin. Skin squeezed between a sweeping collider and
//!   itself is left to the colliders and counted as `self_pinched` (a
//!   tangle of the next frame, never a NaN).
//! * **In-loop passes**: after the colliders, strain limits and compliant
//!   colliders of an iteration, self-collision's rounds; where they moved
//!   skin, the (still) colliders' pass again; then the joint fail-safe: every
//!   vertex whose path still crosses other skin, or whose step a collider
//!   now meets, goes back to where the iteration started, which was free of
//!   both, with every vertex most of whose ring goes back, until none is
//!   left. The output satisfies both.
//!
//! The intersections of each frame's output are counted (the report's
//! `self_intersections`) and kept as the tangles of the next frame: what
//! the input brought in intersecting is exempt until it comes apart.

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use super::options::{SelfOptions, StepReport};
use super::Sequence;
use crate::collide::{Candidates, Clearance, Collider, ColliderSet, Held, HeldBorder, ResolveParams, SelfCollision, SelfSettings, SelfStats, Skin, Tangles};
use crate::mesh::MeshInput;
use crate::{Error, Result};

/// What self-collision carries through one step.
pub(super) struct SelfPass {
    settings: SelfSettings,
    takes_part: Option<Vec<bool>>,
    tangles: Tangles,
    /// The candidates of the current substep, for its first and in-loop passes.
    candidates: Option<Candidates>,
    /// How far the last step's solves took each vertex from where their
    /// first passes left it (see [`Sequence`]'s `self_moves`).
    last_moves: Option<Vec<f32>>,
    /// The same for this step, while every substep so far started warm.
    moves: Option<Vec<f32>>,
    /// Where the current substep's first pass left the skin, if it started warm.
    first_end: Option<Vec<Vec3>>,
    /// How long readying the step took (for the report's [`super::SelfWork`]).
    begin_ms: f64,
}

/// The tangles of the last output, with what they were found under.
#[derive(Debug, Clone)]
pub(super) struct KeptTangles {
    rings: u32,
    takes_part: Option<Vec<bool>>,
    tangles: Tangles,
}

impl Sequence {
    /// Readies self-collision for a step from `start` (bound on the first
    /// step that asks for it), or None without it.
    pub(super) fn begin_self(&mut self, options: Option<&SelfOptions<'_>>, start: &[Vec3], last_moves: Option<Vec<f32>>) -> Result<Option<SelfPass>> {
        let Some(options) = options else { return Ok(None) };
        let began = Instant::now();
        options.settings.validate()?;
        if self.skin.triangles().is_empty() {
            return Err(Error::invalid("self-collision needs a deformer bound to a mesh (its triangles)"));
        }
        if self.self_collision.is_none() {
            let (corner_verts, polygon_sizes) = (&self.polygons.0, &self.polygons.1);
            self.self_collision = Some(SelfCollision::new(MeshInput { positions: &self.rest, corner_verts, polygon_sizes })?);
        }
        let collision = self.self_collision.as_mut().expect("just made");
        collision.prepare(&options.settings)?;
        let takes_part = collision.takes_part(options.weights)?;
        let kept = self.self_tangles.take().filter(|k| k.rings == options.settings.rings && k.takes_part == takes_part);
        let tangles = match kept {
            Some(k) => k.tangles,
            None => Tangles::at(collision, start, &options.settings, takes_part.as_deref())?.0,
        };
        let begin_ms = milliseconds(began);
        let moves = Some(vec![0.0; start.len()]);
        Ok(Some(SelfPass { settings: options.settings, takes_part, tangles, candidates: None, last_moves, moves, first_end: None, begin_ms }))
    }

    /// Counts the output's intersections into the report and keeps them as
    /// the next frame's tangles.
    pub(super) fn finish_self(&mut self, pass: SelfPass, output: &[Vec3], report: &mut StepReport) -> Result<()> {
        let began = Instant::now();
        let collision = self.self_collision.as_ref().expect("begun");
        // Every pass kept each pair apart by at least its separation, except
        // pairs with both sides in a tangle (exempt) and pinched paths: only
        // around those can the output intersect or touch. With neither,
        // nothing to look for.
        let clean = pass.tangles.vertex_count() == 0 && report.self_pinched.is_empty();
        let (tangles, crossing) = if clean {
            (Tangles::default(), Vec::new())
        } else {
            let mut around = pass.tangles.vertex_flags().to_vec();
            around.resize(output.len(), false);
            for &v in &report.self_pinched {
                around[v as usize] = true;
            }
            Tangles::around(collision, output, &pass.settings, pass.takes_part.as_deref(), &around)?
        };
        report.self_intersections = crossing.len();
        report.self_tangled = pass.tangles.vertex_count();
        report.self_pinched.sort_unstable();
        report.self_pinched.dedup();
        self.self_tangles = Some(KeptTangles { rings: pass.settings.rings, tangles, takes_part: pass.takes_part });
        self.self_moves = pass.moves;
        report.self_work.begin_ms += pass.begin_ms;
        report.self_work.tangles_ms += milliseconds(began);
        Ok(())
    }
}

impl SelfPass {
    /// Whether a substep with self-collision may start warm: only where the
    /// solve ends where a cold one would, with Converge (`converges`: it
    /// solves to its tolerance; a fixed count of plain iterations ends
    /// nearer the contacts the warmer it starts, and Blender's 150° tube
    /// then spiked above its input, 0.185 ring edges against 0.149), and
    /// with no rings left out (pairs in a ring left out are kept apart by
    /// nothing but the solve's pull towards the input, which a cold start
    /// begins at: warm, the same tube with one ring left out ended frames
    /// 10–12 with 15–23 intersecting pairs; issue 30, seventeenth round).
    pub(super) fn starts_warm(&self, converges: bool) -> bool {
        converges && self.settings.rings == 0
    }

    /// Notes how far the solve has taken each vertex from where a warm
    /// first pass left it, at `positions` (after an iteration).
    fn track(&mut self, positions: &[Vec3]) {
        if let (Some(first_end), Some(moves)) = (self.first_end.as_deref(), self.moves.as_mut()) {
            moves.par_iter_mut().zip(first_end).zip(positions).with_min_len(4096).for_each(|((m, a), b)| *m = m.max((*b - *a).length()));
        }
    }
}

fn milliseconds(since: Instant) -> f64 {
    1000.0 * since.elapsed().as_secs_f64()
}

/// Adds a pass's gatherings, candidate count and work to the report's
/// figures; `first`: whether it is the first pass.
fn count_work(report: &mut StepReport, stats: &SelfStats, first: bool, candidates: Option<&Candidates>) {
    let work = &mut report.self_work;
    work.gathers += stats.gathers;
    work.gathers_around += stats.gathers_around;
    work.most_candidates = work.most_candidates.max(candidates.map_or(0, Candidates::len));
    if first {
        work.first_gather_ms += stats.whole_gather_ms;
    } else {
        work.in_loop_gathers += stats.gathers;
        work.in_loop_gather_ms += stats.whole_gather_ms;
    }
    work.around_gather_ms += stats.around_gather_ms;
    work.rounds_ms += stats.rounds_ms;
    work.fail_safe_checks_ms += stats.fail_safe_ms;
    work.pairs_scanned += stats.pairs_scanned;
    work.pairs_tested += stats.pairs_tested;
}


/// The first pass's self-collision, after the colliders' (see the module
/// documentation).
#[allow(clippy::too_many_arguments)]
pub(super) fn first_pass(
    collision: &SelfCollision,
    pass: &mut SelfPass,
    x_n: &[Vec3],
    x: &mut [Vec3],
    colliders: &[&Collider],
    skin: &Skin,
    warm: bool,
    converges: bool,
    report: &mut StepReport,
) -> Result<()> {
    let began = Instant::now();
    let part = pass.takes_part.as_deref();
    // From a warm start, margins for the solve to come, from how far the
    // last warm solve moved the skin: its iterations then stay within this
    // list, with no whole gathering of their own. From a cold one, the
    // least margins (each vertex's own corrections widen its margin as the
    // rounds make them, `resolve_path`): a cold solve pulls the skin back
    // from the contacts to the input, and margins from that move paired up
    // the character's closing fold by the million: 9.8M candidates where
    // the least margins list 76k (issue 30, eighth round).
    let margins = match (warm, pass.last_moves.as_deref()) {
        (true, Some(moves)) => collision.warm_margins(&pass.settings, moves)?,
        _ => vec![0.0; x.len()],
    };
    let gathering = Instant::now();
    pass.candidates = Some(collision.candidates(x_n, x, &margins, &pass.settings, &pass.tangles, part)?);
    let gathered_ms = milliseconds(gathering);
    // A held patch's border sloped where the solve is a fixed count of plain
    // iterations, which may end before they smooth a step away
    // (`collide::self_contact::ramp`); with Converge they do, and the
    // solve's path is left as it was (a slope there led Blender's tube
    // elsewhere, into a lock at frame 12; issue 30, twenty-second round (b)).
    let border = if converges { HeldBorder::Step } else { HeldBorder::Sloped };
    let mut stats = collision.resolve_path(&mut pass.candidates, x_n, x, &pass.settings, &pass.tangles, part, border)?;
    stats.gathers += 1;
    stats.whole_gather_ms += gathered_ms;
    count_work(report, &stats, true, pass.candidates.as_ref());
    report.self_work.first_pass_ms += milliseconds(began);
    report.self_contacts += stats.contacts;
    report.self_held += stats.held.len();
    // Only a warm solve's moves say how far the next warm one goes.
    pass.first_end = warm.then(|| x.to_vec());
    if !warm {
        pass.moves = None;
    }
    if colliders.is_empty() || (stats.contacts == 0 && stats.held.is_empty()) {
        return Ok(());
    }
    let again = ColliderSet::new(colliders.iter().copied()).resolve_path(x_n, x, skin, &ResolveParams::first_pass())?;
    report.pinched.extend_from_slice(&again.pinched);
    if !again.moved.is_empty() {
        report.self_pinched.extend(collision.crossings(x_n, x, &pass.settings, &pass.tangles, part)?);
    }
    Ok(())
}

/// An in-loop pass's self-collision, after the colliders, strain limits and
/// compliant colliders of the iteration (see the module documentation).
#[allow(clippy::too_many_arguments)]
pub(super) fn in_loop(
    collision: &SelfCollision,
    pass: &mut SelfPass,
    before: &[Vec3],
    after: &mut [Vec3],
    colliders: &[&Collider],
    skin: &Skin,
    clearance: Option<&Clearance>,
    report: &mut StepReport,
) -> Result<()> {
    let began = Instant::now();
    // The iteration's own move, before the contacts take any of it back,
    // is what the candidates must cover.
    pass.track(after);
    let (settings, tangles, part) = (&pass.settings, &pass.tangles, pass.takes_part.as_deref());
    let stats = collision.resolve_in_loop(&mut pass.candidates, before, after, settings, tangles, part)?;
    report.self_contacts += stats.contacts;
    count_work(report, &stats, false, pass.candidates.as_ref());
    let set = ColliderSet::new(colliders.iter().copied());
    let params = ResolveParams::in_loop();
    if !colliders.is_empty() && stats.contacts > 0 {
        let again = set.resolve_path_with(before, after, skin, &params, clearance, None)?;
        report.in_loop_contacts += again.vertex_contacts + again.edge_contacts + again.collider_vertex_contacts;
        report.held += again.held.len();
    }
    report.self_work.in_loop_rounds_ms += milliseconds(began);
    // The joint fail-safe: back to `before` (free of both) until nothing crosses.
    let began = Instant::now();
    let mut touching: Option<Vec<bool>> = None;
    let mut last: Vec<u32> = Vec::new();
    let mut checks = SelfStats::default();
    let mut holding = Held::none(before.len());
    loop {
        let mut bad = collision.in_loop_crossings(&mut pass.candidates, before, after, touching.as_deref(), settings, tangles, part, &mut checks)?;
        bad.extend(set.violations(before, after, skin, &last, &params));
        bad.retain(|&v| after[v as usize] != before[v as usize]);
        bad.sort_unstable();
        bad.dedup();
        if bad.is_empty() {
            count_work(report, &checks, false, pass.candidates.as_ref());
            report.self_work.in_loop_fail_safe_ms += milliseconds(began);
            pass.track(after);
            return Ok(());
        }
        // With the vertices whose rings those mostly hold: a held patch moves
        // as a patch (`collide::self_contact::held`).
        let batch = collision.put_back(&mut holding, &bad, |v| after[v as usize] != before[v as usize]);
        let mut flags = vec![false; before.len()];
        for &v in &batch {
            after[v as usize] = before[v as usize];
            flags[v as usize] = true;
        }
        report.self_held += batch.len();
        touching = Some(flags);
        last = batch;
    }
}
