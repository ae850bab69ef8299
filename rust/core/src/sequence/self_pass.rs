//! The skin's contact with itself in the frame stepper: the same two passes
//! as the colliders' (seed 000, Algorithm 2), together with them, but with
//! the second one run once, after the solve, instead of after every iteration.
//!
//! * **First pass**: after the colliders' sweep, self-collision along each
//!   vertex's path from the last output to the substep's start of the solve
//!   (the warm start: the last output carried by the input's motion); where
//!   it changed paths, the colliders once more. Skin squeezed between a
//!   sweeping collider and itself is left to the colliders and counted as
//!   `self_pinched` (a tangle of the next frame, never a NaN).
//! * **In the solve**: the contacts where the first pass ended are held
//!   after every iteration ([`HeldContacts`]: work proportional to them),
//!   so that the solve forms a crease or a bulge around them instead of
//!   pulling the skin back through an input that passes through itself.
//!   Between the two passes the iterates may pass through themselves: only
//!   the output, and the path to it, must not.
//! * **Closing pass**: from where the first pass ended (free of both the
//!   colliders and itself) to the solve's output, self-collision's rounds;
//!   where they moved skin, the colliders' pass again; then the joint
//!   fail-safe: every vertex whose path still crosses other skin, or whose
//!   step a collider now meets, goes back to where the first pass left it,
//!   until none is left. The output satisfies both.
//!
//! The intersections of each frame's output are counted (the report's
//! `self_intersections`) and kept as the tangles of the next frame: what
//! the input brought in intersecting is exempt until it comes apart.

use glam::Vec3;

use super::options::{SelfOptions, StepReport};
use super::Sequence;
use crate::collide::{Candidates, Clearance, Collider, ColliderSet, HeldContacts, ResolveParams, SelfCollision, SelfSettings, Skin, Tangles};
use crate::{Error, Result};

/// What self-collision carries through one step.
pub(super) struct SelfPass {
    settings: SelfSettings,
    takes_part: Option<Vec<bool>>,
    tangles: Tangles,
    /// The contacts where the current substep's first pass ended, held in its solve.
    held: HeldContacts,
    /// Where the current substep's first pass ended: the closing pass starts there.
    first_end: Option<Vec<Vec3>>,
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
    pub(super) fn begin_self(&mut self, options: Option<&SelfOptions<'_>>, start: &[Vec3]) -> Result<Option<SelfPass>> {
        let Some(options) = options else { return Ok(None) };
        options.settings.validate()?;
        if self.skin.triangles().is_empty() {
            return Err(Error::invalid("self-collision needs a deformer bound to a mesh (its triangles)"));
        }
        if self.self_collision.is_none() {
            self.self_collision = Some(SelfCollision::new(&self.skin, &self.rest)?);
        }
        let collision = self.self_collision.as_mut().expect("just made");
        collision.prepare(&options.settings)?;
        let takes_part = collision.takes_part(options.weights)?;
        let kept = self.self_tangles.take();
        let kept = kept.filter(|k| k.rings == options.settings.rings && k.takes_part == takes_part);
        let tangles = match kept {
            Some(k) => k.tangles,
            None => Tangles::at(collision, start, &options.settings, takes_part.as_deref())?.0,
        };
        Ok(Some(SelfPass { settings: options.settings, takes_part, tangles, held: HeldContacts::default(), first_end: None }))
    }

    /// Counts the output's intersections into the report and keeps them as
    /// the next frame's tangles.
    pub(super) fn finish_self(&mut self, pass: SelfPass, output: &[Vec3], report: &mut StepReport) -> Result<()> {
        let collision = self.self_collision.as_ref().expect("begun");
        // With no tangle at the start and nothing left pinched, every pass kept
        // the skin free of intersections: nothing to look for.
        let clean = pass.tangles.vertex_count() == 0 && report.self_pinched.is_empty();
        let (tangles, crossing) =
            if clean { (Tangles::default(), Vec::new()) } else { Tangles::at(collision, output, &pass.settings, pass.takes_part.as_deref())? };
        report.self_intersections = crossing.len();
        report.self_tangled = pass.tangles.vertex_count();
        report.self_pinched.sort_unstable();
        report.self_pinched.dedup();
        self.self_tangles = Some(KeptTangles { rings: pass.settings.rings, tangles, takes_part: pass.takes_part });
        Ok(())
    }
}


/// The first pass's self-collision, after the colliders' (see the module
/// documentation).
pub(super) fn first_pass(
    collision: &SelfCollision,
    pass: &mut SelfPass,
    x_n: &[Vec3],
    x: &mut [Vec3],
    colliders: &[&Collider],
    skin: &Skin,
    report: &mut StepReport,
) -> Result<()> {
    let part = pass.takes_part.as_deref();
    let mut candidates = None;
    let stats = collision.resolve_path(&mut candidates, x_n, x, &pass.settings, &pass.tangles, part)?;
    report.self_contacts += stats.contacts;
    report.self_held += stats.held.len();
    report.self_candidates += candidates.as_ref().map_or(0, Candidates::len);
    if !colliders.is_empty() && (stats.contacts > 0 || !stats.held.is_empty()) {
        let again = ColliderSet::new(colliders.iter().copied()).resolve_path(x_n, x, skin, &ResolveParams::first_pass())?;
        report.pinched.extend_from_slice(&again.pinched);
        if !again.moved.is_empty() {
            report.self_pinched.extend(collision.crossings(x_n, x, &pass.settings, &pass.tangles, part)?);
        }
    }
    pass.held = match &candidates {
        Some(c) => collision.held_contacts(c, x, &pass.settings, &pass.tangles, part)?,
        _ => HeldContacts::default(),
    };
    report.self_held_contacts += pass.held.len();
    pass.first_end = Some(x.to_vec());
    Ok(())
}

impl SelfPass {
    /// Holds the first pass's contacts in `after`, an iterate of the solve
    /// (see [`crate::collide::HeldContacts`]).
    pub(super) fn hold(&self, collision: &SelfCollision, after: &mut [Vec3]) -> Result<()> {
        match &self.first_end {
            Some(reference) => collision.hold(&self.held, reference, after, &self.settings, &self.tangles, self.takes_part.as_deref()).map(|_| ()),
            None => Ok(()),
        }
    }
}

/// The closing pass: self-collision from where the first pass ended (free of
/// both the colliders and itself) to the solve's output `x`, then the
/// colliders where it moved skin, then the joint fail-safe: every vertex
/// whose path still crosses other skin, or whose step a collider now meets,
/// goes back to where the first pass left it, until none is left.
pub(super) fn closing_pass(
    collision: &SelfCollision,
    pass: &mut SelfPass,
    x: &mut [Vec3],
    colliders: &[&Collider],
    skin: &Skin,
    clearance: Option<&Clearance>,
    report: &mut StepReport,
) -> Result<()> {
    let before = pass.first_end.as_deref().expect("the first pass ran");
    let (settings, tangles, part) = (&pass.settings, &pass.tangles, pass.takes_part.as_deref());
    let mut candidates = None;
    let stats = collision.resolve_path(&mut candidates, before, x, settings, tangles, part)?;
    report.self_contacts += stats.contacts;
    report.self_held += stats.held.len();
    report.self_candidates += candidates.as_ref().map_or(0, Candidates::len);
    if colliders.is_empty() || (stats.contacts == 0 && stats.held.is_empty()) {
        return Ok(());
    }
    let set = ColliderSet::new(colliders.iter().copied());
    let params = ResolveParams::in_loop();
    let again = set.resolve_path_with(before, x, skin, &params, clearance)?;
    report.in_loop_contacts += again.vertex_contacts + again.edge_contacts + again.collider_vertex_contacts;
    report.held += again.held.len();
    if again.moved.is_empty() {
        return Ok(());
    }
    // The joint fail-safe: back to `before` (free of both) until nothing crosses.
    let mut last: Vec<u32> = Vec::new();
    loop {
        let mut bad = collision.crossings(before, x, settings, tangles, part)?;
        bad.extend(set.violations(before, x, skin, &last, &params));
        bad.retain(|&v| x[v as usize] != before[v as usize]);
        bad.sort_unstable();
        bad.dedup();
        if bad.is_empty() {
            return Ok(());
        }
        for &v in &bad {
            x[v as usize] = before[v as usize];
        }
        report.self_held += bad.len();
        last = bad;
    }
}
