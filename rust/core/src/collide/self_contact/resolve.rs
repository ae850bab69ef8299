//! The self-collision passes: rounds of detection and projection over the
//! candidate pairs, gathered again whenever a vertex leaves the bounds they
//! were gathered for, and the fail-safe that ends every pass free of new
//! intersections.
//!
//! * **First pass** ([`SelfCollision::resolve_path`]): from the last output
//!   towards the frame's target. Candidates are gathered for the straight
//!   paths, with a margin per vertex for the corrections to come.
//! * **In-loop passes** ([`SelfCollision::resolve_in_loop`]): after every
//!   solver iteration, from where it started to where it ended. The
//!   candidates are gathered once around a reference state (the positions
//!   before the pass that gathered them), each vertex with a margin of twice
//!   that pass's move; later passes reuse them while every vertex stays
//!   within its margin, and skip a pair outright while its two sides have
//!   moved less, together, than its distance at the reference less the
//!   separation. A vertex that strays gathers them again.
//! * **Fail-safe**: when the rounds end with contacts left, the vertices of
//!   every pair whose paths still cross are put back where the pass started
//!   (free of intersections), and the pairs around them checked again, until
//!   none crosses: with every vertex at its start nothing can cross. They are
//!   counted as `held`, like vertices pinched between colliders.
//!
//! Pairs both of whose sides lie in a [`Tangles`] region (intersecting at
//! the start of the frame) are exempt: they may move through each other, so
//! that an intersection the input already had can come apart.

use std::collections::BTreeMap;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::bounds::Motion;
use super::collision::{distance, SelfCollision};
use super::contact::{correction, first_contact, ContactParams};
use super::gather::ElementPair;
use super::settings::{SelfSettings, SelfStats};
use crate::mesh::validate_positions;
use crate::{Error, Result};

/// Rounds of detection and projection before the fail-safe.
pub const SELF_ROUNDS: usize = 8;

/// The vertices of the triangles that intersected at the start of a frame.
#[derive(Debug, Clone, Default)]
pub struct Tangles {
    vertices: Vec<bool>,
    count: usize,
}

impl Tangles {
    /// The tangles of a frame starting at `positions`: the corners of the
    /// triangles that intersect there, or touch (closer than a tenth of the
    /// thickness, where a contact has no side to be put back on). Returns
    /// them with the intersecting pairs ([`SelfCollision::intersections`]).
    pub fn at(collision: &SelfCollision, positions: &[Vec3], settings: &SelfSettings, takes_part: Option<&[bool]>) -> Result<(Self, Vec<[u32; 2]>)> {
        let touching = 0.1 * settings.thickness + 2.5 * collision.rounding;
        let meeting = collision.meeting(positions, takes_part, touching)?;
        let pairs: Vec<[u32; 2]> = meeting.iter().map(|&(pair, _)| pair).collect();
        let crossing = meeting.iter().filter(|&&(_, crossing)| crossing).map(|&(pair, _)| pair).collect();
        Ok((Tangles::new(collision, &pairs), crossing))
    }

    /// The tangles of the triangle pairs `pairs` (the skin's indices).
    pub fn new(collision: &SelfCollision, pairs: &[[u32; 2]]) -> Self {
        if pairs.is_empty() {
            return Tangles::default();
        }
        let mut vertices = vec![false; collision.vertex_count];
        for pair in pairs {
            for &t in pair {
                for v in collision.tree.triangles[collision.tree.position[t as usize] as usize] {
                    vertices[v as usize] = true;
                }
            }
        }
        let count = vertices.iter().filter(|&&t| t).count();
        Tangles { vertices, count }
    }

    /// How many vertices are in a tangle.
    pub fn vertex_count(&self) -> usize {
        self.count
    }

    /// Whether vertex `v` is in a tangle.
    pub fn contains(&self, v: u32) -> bool {
        self.vertices.get(v as usize).copied().unwrap_or(false)
    }

    fn holds(&self, corners: &[u32]) -> bool {
        !self.vertices.is_empty() && corners.iter().all(|&v| self.vertices[v as usize])
    }
}

/// The candidates the in-loop passes of a frame share (see the module
/// documentation). Start each frame (each substep) with `None`.
#[derive(Debug, Clone)]
pub struct InLoop {
    reference: Vec<Vec3>,
    margin: Vec<f32>,
    pairs: Vec<ElementPair>,
    /// Each pair's distance at the reference.
    distance: Vec<f32>,
}

/// What one pass works with.
struct Pass<'a> {
    collision: &'a SelfCollision,
    settings: &'a SelfSettings,
    tangles: &'a Tangles,
    takes_part: Option<&'a [bool]>,
    params: ContactParams,
}

impl SelfCollision {
    fn pass<'a>(&'a self, settings: &'a SelfSettings, tangles: &'a Tangles, takes_part: Option<&'a [bool]>) -> Result<Pass<'a>> {
        let prepared = self.separations().len() == self.vertex_count;
        if !prepared {
            return Err(Error::invalid("self-collision is not prepared for these settings (call prepare first)"));
        }
        if takes_part.is_some_and(|t| t.len() != self.tree.triangles.len()) {
            return Err(Error::invalid("self-collision: the triangles taking part are of another skin"));
        }
        let scale = self.rounding as f64 / 4e-6;
        let slack = 0.1 * settings.thickness as f64 + 1e-5 * scale;
        let params = ContactParams {
            slack,
            tolerance: (1e-6 * scale).max(0.25 * slack),
            static_friction: settings.static_friction as f64,
            kinetic_friction: settings.kinetic_friction as f64,
        };
        Ok(Pass { collision: self, settings, tangles, takes_part, params })
    }

    fn check(&self, what: &str, positions: &[Vec3]) -> Result<()> {
        if positions.len() != self.vertex_count {
            return Err(Error::invalid(format!("{what}: {} positions given for a skin of {} vertices", positions.len(), self.vertex_count)));
        }
        validate_positions(what, positions)
    }

    /// Makes the motion `start → end` free of new self-intersections by
    /// changing `end` (first pass). `start` must be free of them, apart from
    /// the `tangles`.
    pub fn resolve_path(&self, start: &[Vec3], end: &mut [Vec3], settings: &SelfSettings, tangles: &Tangles, takes_part: Option<&[bool]>) -> Result<SelfStats> {
        self.check("start positions", start)?;
        self.check("end positions", end)?;
        let pass = self.pass(settings, tangles, takes_part)?;
        let requested = end.to_vec();
        let mut stats = SelfStats::default();
        let margin_of = |end: &[Vec3]| -> Vec<f32> {
            start.par_iter().zip(end).map(|(s, e)| settings.thickness + 0.25 * (*e - *s).length()).collect()
        };
        let mut gathered = end.to_vec();
        let mut margin = margin_of(&gathered);
        let mut pairs = pass.gather(&Motion { start, end: &gathered, margin: &margin }, true);
        stats.gathers += 1;
        let mut moved: Option<Vec<bool>> = None;
        let mut converged = false;
        for _ in 0..SELF_ROUNDS {
            stats.rounds += 1;
            let (contacts, changes) = pass.round(&pairs, start, end, moved.as_deref(), |_, _| false);
            stats.contacts += contacts;
            if changes.is_empty() {
                converged = true;
                break;
            }
            let mut flags = vec![false; self.vertex_count];
            let mut strayed = false;
            for (v, p) in changes {
                end[v as usize] = p;
                flags[v as usize] = true;
                strayed |= (p - gathered[v as usize]).length() > margin[v as usize];
            }
            moved = Some(flags);
            if strayed {
                gathered.copy_from_slice(end);
                margin = margin_of(&gathered);
                pairs = pass.gather(&Motion { start, end: &gathered, margin: &margin }, true);
                stats.gathers += 1;
                moved = None;
            }
        }
        if !converged {
            stats.held = pass.hold_back_path(start, end, &mut stats.gathers);
        }
        stats.max_correction = max_correction(&requested, end);
        Ok(stats)
    }

    /// The vertices of pairs whose paths `start → end` may cross (no
    /// separation), gathered afresh; those at their start on every corner
    /// are left out (they did not move).
    pub fn crossings(&self, start: &[Vec3], end: &[Vec3], settings: &SelfSettings, tangles: &Tangles, takes_part: Option<&[bool]>) -> Result<Vec<u32>> {
        self.check("start positions", start)?;
        self.check("end positions", end)?;
        let pass = self.pass(settings, tangles, takes_part)?;
        let zero = vec![0.0; self.vertex_count];
        let pairs = pass.gather(&Motion { start, end, margin: &zero }, true);
        Ok(pass.crossing_corners(&pairs, start, end, None))
    }

    /// Makes the in-loop motion `before → after` free of new
    /// self-intersections by changing `after`, with the candidates of
    /// `state` (see the module documentation). Runs the rounds only: the
    /// caller ends with [`Self::hold_back_in_loop`] (alone, or together with
    /// the colliders' check).
    pub fn resolve_in_loop(
        &self,
        state: &mut Option<InLoop>,
        before: &[Vec3],
        after: &mut [Vec3],
        settings: &SelfSettings,
        tangles: &Tangles,
        takes_part: Option<&[bool]>,
    ) -> Result<SelfStats> {
        self.check("positions before the iteration", before)?;
        self.check("positions after the iteration", after)?;
        let pass = self.pass(settings, tangles, takes_part)?;
        let requested = after.to_vec();
        let mut stats = SelfStats::default();
        stats.gathers += pass.ensure(state, before, after) as usize;
        let mut moved: Option<Vec<bool>> = None;
        for _ in 0..SELF_ROUNDS {
            stats.rounds += 1;
            let current = state.as_ref().expect("ensured");
            let skip = |k: usize, pair: &ElementPair| current.proves_apart(k, pair, before, after, &pass);
            let (contacts, changes) = pass.round(&current.pairs, before, after, moved.as_deref(), skip);
            stats.contacts += contacts;
            if changes.is_empty() {
                break;
            }
            let mut flags = vec![false; self.vertex_count];
            for (v, p) in changes {
                after[v as usize] = p;
                flags[v as usize] = true;
            }
            moved = Some(flags);
            if pass.ensure(state, before, after) {
                stats.gathers += 1;
                moved = None;
            }
        }
        stats.max_correction = max_correction(&requested, after);
        Ok(stats)
    }

    /// The fail-safe of the in-loop passes: the vertices (among those
    /// `touching` flags, or all) of pairs whose paths `before → after` may
    /// cross. With `state`'s candidates (gathered again if a vertex strayed).
    pub fn in_loop_crossings(
        &self,
        state: &mut Option<InLoop>,
        before: &[Vec3],
        after: &[Vec3],
        touching: Option<&[bool]>,
        settings: &SelfSettings,
        tangles: &Tangles,
        takes_part: Option<&[bool]>,
    ) -> Result<Vec<u32>> {
        let pass = self.pass(settings, tangles, takes_part)?;
        pass.ensure(state, before, after);
        let current = state.as_ref().expect("ensured");
        let candidates: Vec<ElementPair> = current
            .pairs
            .iter()
            .enumerate()
            .filter(|&(k, pair)| !current.proves_apart(k, pair, before, after, &pass))
            .map(|(_, pair)| *pair)
            .collect();
        Ok(pass.crossing_corners(&candidates, before, after, touching))
    }

    /// [`Self::in_loop_crossings`] until none is left, putting each
    /// crossing pair's vertices back at `before`: the in-loop fail-safe
    /// without colliders. Returns the vertices put back.
    #[allow(clippy::too_many_arguments)]
    pub fn hold_back_in_loop(
        &self,
        state: &mut Option<InLoop>,
        before: &[Vec3],
        after: &mut [Vec3],
        settings: &SelfSettings,
        tangles: &Tangles,
        takes_part: Option<&[bool]>,
    ) -> Result<Vec<u32>> {
        let mut held = Vec::new();
        let mut touching: Option<Vec<bool>> = None;
        loop {
            let bad = self.in_loop_crossings(state, before, after, touching.as_deref(), settings, tangles, takes_part)?;
            if bad.is_empty() {
                break;
            }
            let mut flags = vec![false; self.vertex_count];
            for &v in &bad {
                after[v as usize] = before[v as usize];
                flags[v as usize] = true;
            }
            held.extend_from_slice(&bad);
            touching = Some(flags);
        }
        held.sort_unstable();
        held.dedup();
        Ok(held)
    }
}

impl InLoop {
    /// Whether pair `k` provably stays farther apart than its separation:
    /// its sides have strayed from the reference by less, together, than its
    /// distance there less the separation.
    fn proves_apart(&self, k: usize, pair: &ElementPair, before: &[Vec3], after: &[Vec3], pass: &Pass<'_>) -> bool {
        let strayed = |corners: &[u32]| {
            corners.iter().fold(0.0f32, |m, &v| {
                let r = self.reference[v as usize];
                m.max((before[v as usize] - r).length()).max((after[v as usize] - r).length())
            })
        };
        let (a, b) = pair.sides();
        let room = self.distance[k] - strayed(a) - strayed(b);
        room as f64 > pass.collision.pair_separation(pair) + pass.params.tolerance + pass.collision.rounding as f64
    }
}

impl Pass<'_> {
    fn accept(&self) -> impl Fn(&[u32], &[u32]) -> bool + Sync + '_ {
        move |a: &[u32], b: &[u32]| !self.collision.excluded(a, b) && !(self.tangles.holds(a) && self.tangles.holds(b))
    }

    fn gather(&self, motion: &Motion<'_>, cull: bool) -> Vec<ElementPair> {
        let accept = self.accept();
        self.collision.gather(motion, self.settings.thickness, cull, self.takes_part, &accept)
    }

    /// Gathers the in-loop candidates again if there are none or a vertex
    /// strayed beyond its margin; returns whether it did.
    fn ensure(&self, state: &mut Option<InLoop>, before: &[Vec3], after: &[Vec3]) -> bool {
        let stale = match state {
            None => true,
            Some(s) => (0..before.len()).into_par_iter().with_min_len(4096).any(|v| {
                let r = s.reference[v];
                (before[v] - r).length().max((after[v] - r).length()) > s.margin[v]
            }),
        };
        if !stale {
            return false;
        }
        let thickness = self.settings.thickness;
        let floor = 0.5 * thickness + 8.0 * self.collision.rounding;
        let margin: Vec<f32> = before.par_iter().zip(after).map(|(b, a)| 2.0 * (*a - *b).length() + floor).collect();
        let pairs = self.gather(&Motion { start: before, end: before, margin: &margin }, true);
        // Pairs that cannot come within their separation while both stay within their margins go.
        let kept: Vec<(ElementPair, f32)> = pairs
            .into_par_iter()
            .filter_map(|pair| {
                let d = distance(&pair, before);
                let (a, b) = pair.sides();
                let reach = |corners: &[u32]| corners.iter().map(|&v| margin[v as usize]).fold(0.0f32, f32::max);
                (d <= thickness + reach(a) + reach(b) + self.collision.rounding).then_some((pair, d))
            })
            .collect();
        let (pairs, distance) = kept.into_iter().unzip();
        *state = Some(InLoop { reference: before.to_vec(), margin, pairs, distance });
        true
    }

    /// One round: the corrections of every pair `active` (touching a moved
    /// vertex, or all) and not proven apart by `skip`, averaged per vertex.
    fn round(
        &self,
        pairs: &[ElementPair],
        start: &[Vec3],
        end: &[Vec3],
        moved: Option<&[bool]>,
        skip: impl Fn(usize, &ElementPair) -> bool + Sync,
    ) -> (usize, Vec<(u32, Vec3)>) {
        let found: Vec<(usize, [DVec3; 4])> = pairs
            .par_iter()
            .enumerate()
            .with_min_len(256)
            .filter(|(_, pair)| moved.is_none_or(|m| pair.corners.iter().any(|&v| m[v as usize])))
            .filter(|&(k, pair)| !skip(k, pair))
            .filter_map(|(k, pair)| {
                let separation = self.collision.pair_separation(pair);
                let hit = first_contact(pair, start, end, separation, self.params.tolerance)?;
                correction(pair, start, end, &hit, separation, &self.params).map(|c| (k, c))
            })
            .collect();
        let mut sum: BTreeMap<u32, (DVec3, u32)> = BTreeMap::new();
        for (k, deltas) in &found {
            for (&v, delta) in pairs[*k].corners.iter().zip(deltas) {
                let slot = sum.entry(v).or_insert((DVec3::ZERO, 0));
                slot.0 += *delta;
                slot.1 += 1;
            }
        }
        let changes = sum
            .into_iter()
            .filter_map(|(v, (delta, count))| {
                let p = (end[v as usize].as_dvec3() + delta / count as f64).as_vec3();
                p.is_finite().then_some((v, p))
            })
            .collect();
        (found.len(), changes)
    }

    /// The corners (those `touching`, or all) of `pairs` whose paths may
    /// cross, leaving out pairs none of whose corners moved.
    fn crossing_corners(&self, pairs: &[ElementPair], start: &[Vec3], end: &[Vec3], touching: Option<&[bool]>) -> Vec<u32> {
        let moved = |v: u32| start[v as usize] != end[v as usize];
        let mut bad: Vec<u32> = pairs
            .par_iter()
            .with_min_len(256)
            .filter(|pair| touching.is_none_or(|t| pair.corners.iter().any(|&v| t[v as usize])))
            .filter(|pair| pair.corners.iter().any(|&v| moved(v)))
            .filter(|pair| first_contact(pair, start, end, 0.0, self.params.tolerance).is_some())
            .flat_map_iter(|pair| pair.corners.into_iter().filter(|&v| moved(v)))
            .collect();
        bad.sort_unstable();
        bad.dedup();
        bad
    }

    /// The first pass's fail-safe: puts the corners of crossing pairs back at
    /// `start` until none crosses. Returns the vertices put back.
    fn hold_back_path(&self, start: &[Vec3], end: &mut [Vec3], gathers: &mut usize) -> Vec<u32> {
        let zero = vec![0.0; start.len()];
        let mut held = Vec::new();
        loop {
            let pairs = self.gather(&Motion { start, end, margin: &zero }, true);
            *gathers += 1;
            let bad = self.crossing_corners(&pairs, start, end, None);
            if bad.is_empty() {
                break;
            }
            for &v in &bad {
                end[v as usize] = start[v as usize];
            }
            held.extend(bad);
        }
        held.sort_unstable();
        held.dedup();
        held
    }
}

fn max_correction(requested: &[Vec3], end: &[Vec3]) -> f32 {
    requested.par_iter().zip(end).map(|(a, b)| (*a - *b).length()).reduce(|| 0.0, f32::max)
}
