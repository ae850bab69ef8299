//! The self-collision passes: rounds of detection and projection over the
//! candidate pairs, gathered again whenever a vertex leaves the bounds they
//! were gathered for, and the fail-safe that ends every pass free of new
//! intersections.
//!
//! One list of candidates ([`Candidates`]) serves all the passes of a
//! substep: it covers every vertex's straight path from a start to a
//! reference (the first pass: the last output to the target; the in-loop
//! passes: an iteration's start to its end), give or take a
//! per-vertex margin, and is kept up to date as vertices leave their
//! margins.
//!
//! * **First pass** ([`SelfCollision::resolve_path`]): from the last output
//!   towards the frame's target.
//! * **In-loop passes** ([`SelfCollision::resolve_in_loop`]): after every
//!   solver iteration, from where it started to where it ended. A pair is
//!   skipped outright while its two sides have strayed from the target less,
//!   together, than its distance there less the separation.
//! * A vertex leaving its margin gathers the candidates again. Where a few
//!   did, only *around* them ([`Pass::gather_around`]): each gets a new
//!   path and margin, the pairs with it as a corner are listed again and
//!   every other pair is kept (whether a pair can come within its reach
//!   depends on its own corners' paths and margins alone). Where many did,
//!   the whole skin.
//!   - The first pass starts from the least margin ([`SelfCollision::margin_floor`]):
//!     a vertex its rounds correct is gathered around again with a margin
//!     as large as its correction so far. A margin taken from the last
//!     frame instead (twice how far its solve moved the skin) paired up a
//!     closing fold by the million (issue 30, eighth round): a cold solve
//!     starts at the input and pulls the skin back from its contacts. A
//!     warm solve (from the last output carried by the input's motion)
//!     moves the skin little, and its first pass takes margins from how far
//!     the last warm solve did ([`SelfCollision::warm_margins`]), so that
//!     its iterations stay within the first pass's list (issue 30,
//!     seventeenth round).
//!   - An in-loop whole gathering follows the iteration's own paths, `before
//!     → after`, with margins for the iterations to come (eight times the
//!     iteration's move, at most four separations); later iterations are
//!     matched against those paths at whichever time fits them
//!     ([`Candidates::fitted`]). The margins shrink as the solve converges,
//!     so where many vertices left, a whole gathering narrows the list
//!     again; the few that leave are gathered around, each as a ball about
//!     where the iteration started.
//! * **Fail-safe**: when the rounds end with contacts left, the vertices of
//!   every pair whose paths still cross are put back where the pass started
//!   (free of intersections), with every vertex that would otherwise leave
//!   most of its ring behind ([`Held`]), and the pairs around them checked
//!   again, until none crosses: with every vertex at its start nothing can
//!   cross. They are counted as `held`, like vertices pinched between
//!   colliders.
//!
//! Pairs both of whose sides lie in a [`Tangles`] region (intersecting, or
//! touching, at the start of the frame) are exempt: they may move through
//! each other, so that an intersection the input already had can come apart.

use std::collections::BTreeMap;
use std::time::Instant;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::bounds::{Motion, NodeBounds};
use super::collision::{distance, SelfCollision};
use super::contact::{correction, first_contact, ContactParams};
use super::fit::{PathFits, Paths};
use super::gather::{ElementPair, Focus};
use super::held::Held;
use super::pair_index::{compact, PairIndex};
use super::ramp::{self, HeldBorder};
use super::settings::{SelfSettings, SelfStats};
use crate::mesh::validate_positions;
use crate::{Error, Result};

/// Rounds of detection and projection before the fail-safe.
pub const SELF_ROUNDS: usize = 8;

/// At most this share of the vertices (1/n) leaving their margins in the
/// first pass are gathered around; more, the whole skin. Its margins only
/// grow, so the pairs it keeps were listed for margins as tight as any
/// new gathering would give: a whole gathering costs the same and keeps
/// nothing, worth it only where most of the skin moved.
const AROUND_FIRST_PASS: usize = 4;

/// The same for the in-loop passes. A kept pair keeps the margins it was
/// listed for, which the converging solve's later iterations no longer
/// need: where hundreds of vertices left, a whole gathering around the
/// iteration's start narrows the list (measured on the MakeHuman
/// character: around-gatherings for those kept lists of 5–6M pairs where a
/// whole one lists 0.1–0.5M, issue 30, eighth round).
const AROUND_IN_LOOP: usize = 64;

/// An in-loop whole gathering's margin for the iterations after the one
/// that made it: this many times that iteration's move...
const IN_LOOP_MARGIN_MOVES: f32 = 8.0;

/// ...but at most this many times the vertex's separation (which is at most
/// a quarter of its shortest edge). The solve's iterations converge slowly:
/// four times an iteration's move as the margin made the straight frames of
/// the MakeHuman character gather the whole skin 5–12 times a frame, eight
/// times 2–5. But a margin pairs a vertex up with every element within it:
/// where the last frame's fail-safe held skin back, the first iteration
/// moves it up to 59 mm, and uncapped margins listed 1.4–5.8M pairs for the
/// whole frame. Capped, such a vertex leaves its margin sooner and is
/// gathered around (issue 30, ninth round).
const IN_LOOP_MARGIN_SEPARATIONS: f32 = 4.0;

/// A warm-started first pass's margin: this many times how far the last
/// frame's solve took the vertex ([`SelfCollision::warm_margins`]). On the
/// MakeHuman character's replay, with twice, the first iteration of the
/// frame after the first warm one still left thousands of vertices beyond
/// their margins (an in-loop gathering over the whole skin); with four
/// times, no frame after it did, and frames 1–6 cost 12.53G instructions
/// against twice's 13.04G (issue 30, seventeenth round).
const WARM_MARGIN_MOVES: f32 = 4.0;

/// The vertices of the triangles that intersected (or touched) at the start
/// of a frame.
#[derive(Debug, Clone, Default)]
pub struct Tangles {
    vertices: Vec<bool>,
    count: usize,
}

impl Tangles {
    /// The tangles of a frame starting at `positions`: the corners of the
    /// triangles (of either split of a quad) that intersect there, or touch
    /// (closer than a tenth of the thickness, where a contact has no side to
    /// be put back on). Returns them with the intersecting polygon pairs
    /// ([`SelfCollision::intersections`]).
    pub fn at(collision: &SelfCollision, positions: &[Vec3], settings: &SelfSettings, takes_part: Option<&[bool]>) -> Result<(Self, Vec<[u32; 2]>)> {
        Self::found(collision, positions, settings, takes_part, None)
    }

    /// [`Self::at`], looking only at the triangles with a corner among
    /// `vertices` (flags per vertex): at the end of a frame, the last
    /// tangles and the pinched vertices. Everywhere else the passes kept
    /// every pair apart by at least its separation (only pairs with both
    /// sides in a tangle were exempt, only pinched paths left crossing), so
    /// nothing there intersects or touches.
    pub fn around(collision: &SelfCollision, positions: &[Vec3], settings: &SelfSettings, takes_part: Option<&[bool]>, vertices: &[bool]) -> Result<(Self, Vec<[u32; 2]>)> {
        if vertices.len() != collision.vertex_count {
            return Err(Error::invalid(format!("self-collision tangles: {} vertex flags given for {} vertices", vertices.len(), collision.vertex_count)));
        }
        Self::found(collision, positions, settings, takes_part, Some(&collision.focus_around(vertices)))
    }

    fn found(collision: &SelfCollision, positions: &[Vec3], settings: &SelfSettings, takes_part: Option<&[bool]>, focus: Option<&Focus>) -> Result<(Self, Vec<[u32; 2]>)> {
        let touching = 0.1 * settings.thickness + 2.5 * collision.rounding;
        let meeting = collision.meeting(positions, takes_part, touching, focus)?;
        let pairs: Vec<[u32; 2]> = meeting.iter().map(|&(pair, _)| pair).collect();
        let crossing: Vec<[u32; 2]> = meeting.iter().filter(|&&(_, crossing)| crossing).map(|&(pair, _)| pair).collect();
        Ok((Tangles::new(collision, &pairs), collision.polygon_pairs(&crossing)))
    }

    /// The tangles of the triangle pairs `pairs` (tree positions).
    fn new(collision: &SelfCollision, pairs: &[[u32; 2]]) -> Self {
        if pairs.is_empty() {
            return Tangles::default();
        }
        let mut vertices = vec![false; collision.vertex_count];
        for pair in pairs {
            for &t in pair {
                for v in collision.tree.triangles[t as usize] {
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

    /// Per vertex, whether it is in a tangle (empty without tangles).
    pub fn vertex_flags(&self) -> &[bool] {
        &self.vertices
    }

    fn holds(&self, corners: &[u32]) -> bool {
        !self.vertices.is_empty() && corners.iter().all(|&v| self.vertices[v as usize])
    }
}

/// The candidate pairs of a stretch of motion (see the module
/// documentation), shared by the passes of a substep: all with the same
/// settings, tangles and weights, under which the pairs it keeps were
/// listed and its tree bounds fitted.
#[derive(Debug, Clone)]
pub struct Candidates {
    /// Where the straight paths start, and where they end: the state the
    /// passes stay near.
    start: Vec<Vec3>,
    reference: Vec<Vec3>,
    /// How far from the paths (and from `reference`) each vertex may stray.
    margin: Vec<f32>,
    pairs: Vec<ElementPair>,
    /// Each pair's distance at `reference`.
    distance: Vec<f32>,
    /// Each pair's separation ([`SelfCollision::pair_separation`], the
    /// least of its corners'), kept with it: the proofs that a pair stays
    /// apart (`apart`) ask for it every round, and were a seventh of the
    /// MakeHuman character's fold frame 11 working it out from the four
    /// corners each time (issue 30, twenty-third round).
    separation: Vec<f32>,
    /// Per vertex, how far it may stray from `reference` while every pair
    /// of it listed here is still proven apart ([`Self::proves_apart`]):
    /// the active set of the in-loop passes is the pairs of vertices that
    /// strayed farther ([`Self::open`]), so that a round or a check looks
    /// at those alone instead of testing every pair's clearance (the
    /// proofs over the whole list were about a sixth of the character's
    /// straight frames, issue 30, eleventh round).
    clearance: Vec<f64>,
    /// The patch tree's bounds over these paths and margins, refitted where
    /// a gathering around a few vertices changes theirs: only the leaves
    /// holding them and the nodes above are fitted again, where fitting the
    /// whole tree for each such gathering made up about a tenth of the
    /// character's straight frames (issue 30, tenth round).
    bounds: NodeBounds,
    /// The in-loop rounds' distances at the start of their iteration, kept
    /// in step with the list, for the fail-safe's check of the same
    /// iteration ([`SelfCollision::in_loop_crossings`]).
    at_start: AtStart,
    /// The fits of the last positions the in-loop passes asked about
    /// ([`Self::fitted`]), kept to be worked out again only where those
    /// positions or the paths changed.
    fits: PathFits,
    /// Where the pairs of each vertex are in the list, made at the first
    /// gathering around a few vertices ([`Self::drop_pairs_of`]) and kept
    /// in step with the list from then on.
    index: Option<PairIndex>,
}

impl Candidates {
    /// How many pairs were gathered.
    pub fn len(&self) -> usize {
        self.pairs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }

    /// Per vertex, whether one of `positions` is beyond its margin of the
    /// reference; and how many are.
    fn strayed(&self, positions: &[&[Vec3]]) -> (Vec<bool>, usize) {
        let flags: Vec<bool> = (0..self.reference.len())
            .into_par_iter()
            .with_min_len(4096)
            .map(|v| positions.iter().any(|x| (x[v] - self.reference[v]).length() > self.margin[v]))
            .collect();
        let count = flags.iter().filter(|&&f| f).count();
        (flags, count)
    }

    /// Each vertex's start, reference and margin, and the pairs listed for
    /// them (for the tests: a whole gathering of these lists the same pairs).
    #[cfg(test)]
    pub(super) fn parts(&self) -> (&[Vec3], &[Vec3], &[f32], &[ElementPair]) {
        (&self.start, &self.reference, &self.margin, &self.pairs)
    }

    /// The vertices of `x` beyond their margins of the gathered paths at the
    /// one time (for every vertex) that leaves out the fewest, and how many
    /// ([`PathFits::best`]).
    fn best_fit(&mut self, x: &[Vec3]) -> (Vec<bool>, usize) {
        let paths = Paths { start: &self.start, reference: &self.reference, margin: &self.margin };
        self.fits.best(&paths, x)
    }

    /// Per vertex, whether the in-loop motion `before → after` leaves what
    /// the candidates cover, and how many vertices do: `before` is matched
    /// with the gathered paths at one time `t₀`, `after` at one time `t₁`,
    /// each the one that leaves out the fewest ([`Self::best_fit`]).
    ///
    /// Why any such pair of times keeps the guarantee: the gathering listed
    /// every pair that can come within its reach while each vertex `v` stays
    /// within its margin `m_v` of its path `p_v(t)`, `t` one time for all
    /// vertices. Map the motion's `u ∈ [0, 1]` to `t(u) = t₀ + u·(t₁ − t₀)`,
    /// the same for every vertex: the offset `x_v(u) − p_v(t(u))` is linear
    /// in `u`, so never longer than at `u = 0` or `u = 1`, within `m_v` for
    /// every vertex not flagged. A flagged vertex is gathered around as a
    /// ball about `before` holding `after` ([`Pass::ensure`]), which no time
    /// enters, so the mix stays covered.
    fn fitted(&mut self, before: &[Vec3], after: &[Vec3]) -> (Vec<bool>, usize) {
        let (mut left, count) = self.best_fit(before);
        let (out, more) = self.best_fit(after);
        if more == 0 {
            return (left, count);
        }
        if count == 0 {
            return (out, more);
        }
        left.iter_mut().zip(&out).for_each(|(l, o)| *l |= o);
        let count = left.iter().filter(|&&l| l).count();
        (left, count)
    }

    /// Whether every vertex of `positions` is within its margin of the reference.
    fn holds(&self, positions: &[&[Vec3]]) -> bool {
        (0..self.reference.len()).into_par_iter().with_min_len(4096).all(|v| {
            let r = self.reference[v];
            positions.iter().all(|x| (x[v] - r).length() <= self.margin[v])
        })
    }

    /// Per vertex, whether it strayed from the reference (in `before` or
    /// `after`) as far as its clearance: only pairs with such a corner can
    /// fail [`Self::proves_apart`].
    ///
    /// Why: a vertex's clearance is at most half the room of each of its
    /// pairs, `(distance − threshold) / 2`, less `ε·distance` (`ε` the f32
    /// epsilon). If no corner of pair `k` is open, each side strayed less
    /// than half the room, together less than the room less `2ε·distance`;
    /// `proves_apart` computes `distance − strayed(a) − strayed(b)` in f32,
    /// two roundings of at most `ε/2·distance` each (both differences lie
    /// between 0 and the distance), so it finds more than the threshold and
    /// proves the pair apart. The decisions are the same as testing every
    /// pair; only the pairs of open vertices are looked at.
    fn open(&self, strays: &Strays) -> Vec<bool> {
        strays.from_reference.par_iter().zip(&self.clearance).with_min_len(4096).map(|(&strayed, &clearance)| strayed as f64 >= clearance).collect()
    }

    /// How far each vertex strayed over `before → after`, from the
    /// reference and from `before`, once for all the pairs that ask.
    fn strays(&self, before: &[Vec3], after: &[Vec3]) -> Strays {
        let (from_reference, from_before) = (0..self.reference.len()).into_par_iter().with_min_len(4096).map(|v| self.stray(v, before, after)).unzip();
        Strays { from_reference, from_before }
    }

    /// How far vertex `v` strayed over `before → after`, from the reference
    /// and from `before` ([`Strays`]).
    fn stray(&self, v: usize, before: &[Vec3], after: &[Vec3]) -> (f32, f32) {
        let r = self.reference[v];
        ((before[v] - r).length().max((after[v] - r).length()), (after[v] - before[v]).length())
    }

    /// [`Self::strays`] again after only the vertices flagged in `changed`
    /// moved or got another reference: the others' are what they were.
    fn restray(&self, strays: &mut Strays, before: &[Vec3], after: &[Vec3], changed: &[bool]) {
        for v in (0..changed.len()).filter(|&v| changed[v]) {
            (strays.from_reference[v], strays.from_before[v]) = self.stray(v, before, after);
        }
    }

    /// Drops the pairs with a corner among `vertices` (`flags` the same,
    /// per vertex), keeping the others (with their distances and
    /// separations) in their order; returns how many are kept. In place: a
    /// gathering around a few vertices drops a few pairs of a list of up to
    /// millions, which copying made a pass over the whole list in new
    /// memory for each such gathering (issue 30, twenty-third round); and
    /// found by the list's [`PairIndex`], made at the first such gathering,
    /// not by a pass testing every pair. The rounds' distances at `before`
    /// ([`AtStart::kept_with`]) are compacted alike.
    fn drop_pairs_of(&mut self, vertices: &[u32], flags: &[bool]) -> usize {
        let index = match &mut self.index {
            Some(index) if !index.stale() => index,
            _ => self.index.insert(PairIndex::new(&self.pairs, self.start.len())),
        };
        let dropped = index.drop_pairs_of(vertices, flags);
        if let Some(values) = self.at_start.kept_with(self.pairs.len()) {
            compact(values, &dropped);
        }
        compact(&mut self.pairs, &dropped);
        compact(&mut self.distance, &dropped);
        compact(&mut self.separation, &dropped);
        self.pairs.len()
    }

    /// Lowers the clearances of the corners of pairs `from..` to what those
    /// pairs allow ([`Self::open`]).
    fn tighten(&mut self, from: usize, pass: &Pass<'_>) {
        for k in from..self.pairs.len() {
            let threshold = self.threshold(k, pass);
            let d = self.distance[k] as f64;
            let half_room = 0.5 * (d - threshold) - f32::EPSILON as f64 * d.abs();
            for &v in &self.pairs[k].corners {
                let c = &mut self.clearance[v as usize];
                *c = c.min(half_room);
            }
        }
    }

    /// For the tests, over the motion `before → after`: how many pairs lie
    /// outside the active set (no corner [`Self::open`]), how many of those
    /// [`Self::proves_apart`] does not prove apart (none, if the active set
    /// holds every pair that needs a test), and how many inside it it does
    /// not prove apart.
    #[cfg(test)]
    pub(super) fn active_set_counts(&self, collision: &SelfCollision, settings: &SelfSettings, before: &[Vec3], after: &[Vec3]) -> (usize, usize, usize) {
        let tangles = Tangles::default();
        let pass = collision.pass(settings, &tangles, None).expect("prepared");
        let strays = self.strays(before, after);
        let asks = Asks::new(&self.open(&strays), None);
        let (mut outside, mut missed, mut unproven) = (0, 0, 0);
        for k in 0..self.pairs.len() {
            let proven = self.proves_apart(k, &strays, &pass);
            if asks.about(&self.pairs[k]) {
                unproven += usize::from(!proven);
            } else {
                outside += 1;
                missed += usize::from(!proven);
            }
        }
        (outside, missed, unproven)
    }

    /// For the tests, over the motion `before → after`: how many pairs the
    /// first in-loop round leaves out ([`AtStart::chosen`]), how many of
    /// those its CCD test would find in contact (none, if leaving them out
    /// changes no decision), and how many it tests.
    #[cfg(test)]
    pub(super) fn round_choice_counts(&self, collision: &SelfCollision, settings: &SelfSettings, before: &[Vec3], after: &[Vec3]) -> (usize, usize, usize) {
        let tangles = Tangles::default();
        let pass = collision.pass(settings, &tangles, None).expect("prepared");
        let strays = self.strays(before, after);
        let chosen = AtStart::default().chosen(self, before, &strays, &self.open(&strays), None, &pass);
        let mut tested = vec![false; self.pairs.len()];
        chosen.iter().for_each(|&k| tested[k] = true);
        let left_out: Vec<usize> = (0..self.pairs.len()).filter(|&k| !tested[k]).collect();
        let in_contact = left_out
            .iter()
            .filter(|&&k| first_contact(&self.pairs[k], before, after, collision.pair_separation(&self.pairs[k]), pass.params.tolerance).is_some())
            .count();
        (left_out.len(), in_contact, chosen.len())
    }

    /// The pairs the fail-safe's check over `before → after` tests: those
    /// with a corner among `touching` (or all; the check's later rounds look
    /// only round what the one before put back, and proving the others
    /// apart first was work thrown away) and a corner among the open
    /// vertices ([`Self::open`]) that neither
    /// the reference's proof nor the rounds' from `before` ([`AtStart`],
    /// where this check's `before` is theirs) puts apart. Both prove a pair
    /// stays farther apart than its separation, so farther than the
    /// crossing the check looks for.
    fn unsettled(&self, before: &[Vec3], after: &[Vec3], touching: Option<&[bool]>, pass: &Pass<'_>) -> Vec<ElementPair> {
        let strays = self.strays(before, after);
        let asks = Asks::new(&self.open(&strays), touching);
        let at_start = self.at_start.at(before);
        let settled = |k: usize| {
            self.proves_apart(k, &strays, pass) || at_start.and_then(|d| d.get(k)).is_some_and(|&d| apart(&self.pairs[k], d, &strays.from_before, self.threshold(k, pass)))
        };
        (0..self.pairs.len()).into_par_iter().with_min_len(256).filter(|&k| asks.about(&self.pairs[k]) && !settled(k)).map(|k| self.pairs[k]).collect()
    }

    /// For the tests, over the motion `before → after`, after a first
    /// in-loop round from `before` ([`AtStart::chosen`]): how many listed
    /// pairs the fail-safe's check leaves out ([`Self::unsettled`]), how
    /// many of those come within their separation by the rounds' CCD test
    /// (none, if leaving them out changes no decision: the check's test,
    /// with no separation, finds a subset), and how many more it would
    /// test without the round's proof from `before`.
    #[cfg(test)]
    pub(super) fn check_choice_counts(&mut self, collision: &SelfCollision, settings: &SelfSettings, before: &[Vec3], after: &[Vec3]) -> (usize, usize, usize) {
        let tangles = Tangles::default();
        let pass = collision.pass(settings, &tangles, None).expect("prepared");
        let strays = self.strays(before, after);
        let mut at_start = AtStart::default();
        at_start.begin(before);
        at_start.chosen(self, before, &strays, &self.open(&strays), None, &pass);
        self.at_start = AtStart::default();
        let by_reference = self.unsettled(before, after, None, &pass).len();
        self.at_start = at_start;
        let tested = self.unsettled(before, after, None, &pass);
        let left_out: Vec<&ElementPair> = self.pairs.iter().filter(|pair| !tested.contains(pair)).collect();
        let in_contact = left_out.iter().filter(|pair| first_contact(pair, before, after, collision.pair_separation(pair), pass.params.tolerance).is_some()).count();
        (left_out.len(), in_contact, by_reference - tested.len())
    }

    /// Whether pair `k` provably stays farther apart than its separation
    /// over the motion of `strays`: its sides have strayed from the
    /// reference by less, together, than its distance there less the
    /// separation.
    fn proves_apart(&self, k: usize, strays: &Strays, pass: &Pass<'_>) -> bool {
        apart(&self.pairs[k], self.distance[k], &strays.from_reference, self.threshold(k, pass))
    }

    /// The distance pair `k` is proven apart beyond: its separation, the
    /// CCD's tolerance and room for the f32 arithmetic ([`Self::open`]).
    fn threshold(&self, k: usize, pass: &Pass<'_>) -> f64 {
        self.separation[k] as f64 + pass.params.tolerance + pass.collision.rounding as f64
    }
}

/// Per vertex, how far it strayed over an in-loop motion `before → after`
/// ([`Candidates::strays`]).
struct Strays {
    /// From the candidates' reference, in `before` or `after`.
    from_reference: Vec<f32>,
    /// From `before` (how far from it the path goes).
    from_before: Vec<f32>,
}

/// Whether `pair`, `distance` apart at some positions, provably stays
/// farther apart than its separation while each vertex strays at most
/// `strayed` from those: its sides strayed less, together, than that
/// distance less the separation (the `threshold` has room for the f32
/// arithmetic, [`Candidates::threshold`]).
///
/// The sides' corners are read at fixed places, not folded over
/// [`ElementPair::sides`]' slices: the rounds and checks ask the
/// reference's proof of every open pair, 20.5M times on the MakeHuman
/// character's frames 1–11, at 85 instructions a time with the slices'
/// loops, 70 without (issue 30, twenty-fourth round). The same maxima in
/// the same order, so the same room.
fn apart(pair: &ElementPair, distance: f32, strayed: &[f32], threshold: f64) -> bool {
    let [s0, s1, s2, s3] = at_corners(&pair.corners, strayed);
    let (a, b) = if pair.edge_edge { (0.0f32.max(s0).max(s1), 0.0f32.max(s2).max(s3)) } else { (0.0f32.max(s0), 0.0f32.max(s1).max(s2).max(s3)) };
    let room = distance - a - b;
    room as f64 > threshold
}

/// `values` at the four `corners`, written out: as `corners.map(…)` the
/// rounds' per-pair tests (`apart`, [`Asks::about`], millions of times a
/// fold frame) went through an out-of-line `array::try_map` in some builds
/// and not in others, 125M instructions of the MakeHuman character's frame
/// 8 moving with unrelated changes to the crate (issue 30, twenty-sixth
/// round).
#[inline(always)]
fn at_corners<T: Copy>(corners: &[u32; 4], values: &[T]) -> [T; 4] {
    [values[corners[0] as usize], values[corners[1] as usize], values[corners[2] as usize], values[corners[3] as usize]]
}

/// The listed pairs' distances at the start of an in-loop pass (`before`),
/// computed for the pairs a round would test: a second proof that a pair
/// stays apart, from where the iteration started rather than from the
/// candidates' reference ([`Candidates::proves_apart`]).
///
/// Why it pays: the reference is where the skin was when the list was
/// gathered, iterations ago on a fold frame, and the skin held by its
/// contacts creeps from it at every iteration; so there nearly every pair of
/// a vertex the rounds move was left unproven and tested, about 800 pairs
/// a moved vertex on the 19k tube's frame 8, again at each of the 8 rounds.
/// From `before`, a side strays only by the iteration's move and the
/// rounds' corrections, and only the pairs near at `before` are tested.
///
/// Why it is sound: the distance of two elements changes by at most how
/// far each side's farthest corner moves, and a vertex's path `before →
/// after` stays within `|after − before|` of `before`; the test is the
/// reference proof's, with `before` as the reference, and the same room for
/// the f32 arithmetic (`SelfCollision::rounding` in the threshold).
///
/// Kept with the list ([`Candidates`]), so that the fail-safe's check of
/// the same iteration settles pairs by it too
/// ([`SelfCollision::in_loop_crossings`]).
#[derive(Debug, Clone, Default)]
struct AtStart {
    /// Where the iteration started.
    before: Vec<Vec3>,
    /// Per listed pair, its distance at `before`; NaN where not computed
    /// (never proves anything).
    distance: Vec<f32>,
}

impl AtStart {
    /// Starts over at `before`, with no distance known.
    fn begin(&mut self, before: &[Vec3]) {
        self.before.clear();
        self.before.extend_from_slice(before);
        self.distance.clear();
    }

    /// The distances at `before`, if these were taken there (NaN, or none
    /// past the end, where not computed).
    fn at(&self, before: &[Vec3]) -> Option<&[f32]> {
        (self.before.as_slice() == before).then_some(self.distance.as_slice())
    }

    /// The distances to compact along with the list a gathering around a
    /// few vertices keeps ([`Candidates::drop_pairs_of`]): a kept pair is the
    /// same pair at the same `before`, so its distance there still holds
    /// (the new pairs, appended, get theirs when a round asks). None where
    /// they are not one per pair of the `listed` (no round has asked since
    /// the list was made or pairs were appended): then forgotten.
    fn kept_with(&mut self, listed: usize) -> Option<&mut Vec<f32>> {
        if self.distance.len() == listed {
            Some(&mut self.distance)
        } else {
            self.distance.clear();
            None
        }
    }

    /// The pairs of `c` a round over `before → after` tests, ascending:
    /// those with a corner among `moved` (or all) and among the `open`
    /// vertices, that neither proof puts apart. A pair's distance at
    /// `before` is computed the first time the reference's proof fails
    /// for it; from then on that is its proof (the closer one as the
    /// rounds go on).
    #[allow(clippy::too_many_arguments)]
    fn chosen(&mut self, c: &Candidates, before: &[Vec3], strays: &Strays, open: &[bool], moved: Option<&[bool]>, pass: &Pass<'_>) -> Vec<usize> {
        self.distance.resize(c.pairs.len(), f32::NAN);
        let asks = Asks::new(open, moved);
        let (tolerance, rounding) = (pass.params.tolerance, pass.collision.rounding as f64);
        self.distance
            .par_iter_mut()
            .zip(&c.pairs)
            .zip(&c.distance)
            .zip(&c.separation)
            .enumerate()
            .with_min_len(1024)
            .filter_map(|(k, (((d, pair), &at_reference), &separation))| {
                if !asks.about(pair) {
                    return None;
                }
                // `Candidates::threshold`'s sum, in its order.
                let threshold = separation as f64 + tolerance + rounding;
                if d.is_nan() {
                    if apart(pair, at_reference, &strays.from_reference, threshold) {
                        return None;
                    }
                    *d = distance(pair, before);
                }
                (!apart(pair, *d, &strays.from_before, threshold)).then_some(k)
            })
            .collect()
    }
}

/// Per vertex, whether a round asks about its pairs, as one byte: bit 0
/// that it moved (every vertex, where the round looks at every pair), bit 1
/// that it is open ([`Candidates::open`]). A pair is asked about where some
/// corner moved and some corner is open: the or of its four corners' bytes
/// has both bits, four loads where the two tests apart read up to eight
/// flags with a branch for each.
struct Asks(Vec<u8>);

impl Asks {
    fn new(open: &[bool], moved: Option<&[bool]>) -> Self {
        Asks(match moved {
            Some(moved) => open.iter().zip(moved).map(|(&o, &m)| u8::from(m) | (u8::from(o) << 1)).collect(),
            None => open.iter().map(|&o| 1 | (u8::from(o) << 1)).collect(),
        })
    }

    /// Inlined: asked of every listed pair at every round, where the call
    /// was about a fifth of its 25 instructions (issue 30, twenty-fifth
    /// round (b)).
    #[inline]
    fn about(&self, pair: &ElementPair) -> bool {
        let [a, b, c, d] = at_corners(&pair.corners, &self.0);
        a | b | c | d == 3
    }
}

/// What [`Pass::ensure`] had to do for the candidates to hold.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Gathered {
    Nothing,
    /// Only around some vertices (flags per vertex): only pairs with a
    /// corner among them were listed again.
    Around(Vec<bool>),
    /// The whole skin.
    Whole,
}

impl SelfStats {
    /// Counts a gathering that took `ms`.
    fn count(&mut self, gathered: &Gathered, ms: f64) {
        match gathered {
            Gathered::Nothing => {}
            Gathered::Around(_) => {
                self.gathers_around += 1;
                self.around_gather_ms += ms;
            }
            Gathered::Whole => {
                self.gathers += 1;
                self.whole_gather_ms += ms;
            }
        }
    }
}

/// Runs `f`, returning what it returned and how long it took (wall-clock ms).
fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let began = Instant::now();
    let out = f();
    (out, 1000.0 * began.elapsed().as_secs_f64())
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

    /// The least margin a vertex gets: room for the f32 bounds. Margins
    /// widen the normal cones and the contour's angles, so that a margin of a
    /// few percent of an edge everywhere would leave nothing to cull: a
    /// vertex gets one where the solve moves it (where skin folds, which is
    /// examined pair by pair anyway), and almost none elsewhere.
    pub fn margin_floor(&self, _settings: &SelfSettings) -> f32 {
        8.0 * self.rounding
    }

    /// The first pass's margins for a solve that starts warm (from the last
    /// output carried by the input's motion): [`WARM_MARGIN_MOVES`] times how
    /// far the last frame's solve took each vertex from where its first pass
    /// left it (`last_moves`: its iterations' own moves, before the contacts
    /// took any back, and where the passes left it), at most [`IN_LOOP_MARGIN_SEPARATIONS`] times
    /// its separation, at least [`Self::margin_floor`]. A warm solve moves
    /// the skin about as far as the last one did, so its iterations stay
    /// within these and the first in-loop pass needs no whole gathering.
    pub fn warm_margins(&self, settings: &SelfSettings, last_moves: &[f32]) -> Result<Vec<f32>> {
        if last_moves.len() != self.vertex_count || last_moves.iter().any(|m| !(m.is_finite() && *m >= 0.0)) {
            return Err(Error::invalid(format!("self-collision moves: {} given for {} vertices, each finite and ≥ 0", last_moves.len(), self.vertex_count)));
        }
        let floor = self.margin_floor(settings);
        Ok(last_moves.par_iter().zip(self.separations()).map(|(&m, &s)| (WARM_MARGIN_MOVES * m).min(IN_LOOP_MARGIN_SEPARATIONS * s).max(floor)).collect())
    }

    /// Gathers the candidates of the straight paths `start → end`, each
    /// vertex free to stray `margin` from its path (at least
    /// [`Self::margin_floor`]).
    #[allow(clippy::too_many_arguments)]
    pub fn candidates(
        &self,
        start: &[Vec3],
        end: &[Vec3],
        margin: &[f32],
        settings: &SelfSettings,
        tangles: &Tangles,
        takes_part: Option<&[bool]>,
    ) -> Result<Candidates> {
        self.check("start positions", start)?;
        self.check("end positions", end)?;
        if margin.len() != self.vertex_count || margin.iter().any(|m| !(m.is_finite() && *m >= 0.0)) {
            return Err(Error::invalid(format!("self-collision margins: {} given for {} vertices, each finite and ≥ 0", margin.len(), self.vertex_count)));
        }
        let floor = self.margin_floor(settings);
        let margin: Vec<f32> = margin.par_iter().map(|m| m.max(floor)).collect();
        Ok(self.pass(settings, tangles, takes_part)?.candidates(start, end, margin))
    }

    /// Makes the motion `start → end` free of new self-intersections by
    /// changing `end` (first pass). `start` must be free of them, apart from
    /// the `tangles`. `candidates` are those of this motion (gathered here if
    /// None, and again where a correction strays beyond them).
    #[allow(clippy::too_many_arguments)]
    pub fn resolve_path(
        &self,
        candidates: &mut Option<Candidates>,
        start: &[Vec3],
        end: &mut [Vec3],
        settings: &SelfSettings,
        tangles: &Tangles,
        takes_part: Option<&[bool]>,
        border: HeldBorder,
    ) -> Result<SelfStats> {
        self.check("start positions", start)?;
        self.check("end positions", end)?;
        let pass = self.pass(settings, tangles, takes_part)?;
        let requested = end.to_vec();
        let mut stats = SelfStats::default();
        let fits = |c: &Candidates, end: &[Vec3]| c.start.as_slice() == start && c.holds(&[end]);
        if !candidates.as_ref().is_some_and(|c| fits(c, end)) {
            let margin = candidates.take().map_or_else(|| vec![self.margin_floor(settings); self.vertex_count], |c| c.margin);
            let (gathered, ms) = timed(|| pass.candidates(start, end, margin));
            *candidates = Some(gathered);
            stats.count(&Gathered::Whole, ms);
        }
        let mut moved: Option<Vec<bool>> = None;
        let mut converged = false;
        for _ in 0..SELF_ROUNDS {
            stats.rounds += 1;
            let current = candidates.as_ref().expect("gathered");
            debug_assert!(current.start.as_slice() == start, "the candidates are of this path");
            let chosen = touching(&current.pairs, moved.as_deref());
            let (contacts, changes) = pass.round(&current.pairs, start, end, &chosen, &mut stats);
            stats.contacts += contacts;
            if changes.is_empty() {
                converged = true;
                break;
            }
            let mut flags = vec![false; self.vertex_count];
            for (v, p) in changes {
                end[v as usize] = p;
                flags[v as usize] = true;
            }
            // Vertices corrected beyond their margins get one as large as
            // their correction so far (the rounds' next corrections are
            // mostly smaller), around the corrected end.
            let c = candidates.as_mut().expect("gathered");
            let (left, count) = c.strayed(&[end]);
            if count == 0 {
                moved = Some(flags);
                continue;
            }
            let margin: Vec<f32> = (0..end.len()).map(|v| if left[v] { c.margin[v].max((end[v] - c.reference[v]).length()) } else { c.margin[v] }).collect();
            if count <= end.len() / AROUND_FIRST_PASS {
                let ((), ms) = timed(|| pass.gather_around(c, &left, start, end, &margin));
                stats.count(&Gathered::Around(Vec::new()), ms);
                // The pairs listed again have a corner among `left`: the
                // next round looks at them, as at every pair of a moved vertex.
                flags.iter_mut().zip(&left).for_each(|(f, l)| *f |= l);
                moved = Some(flags);
            } else {
                let (gathered, ms) = timed(|| pass.candidates(start, end, margin));
                *candidates = Some(gathered);
                stats.count(&Gathered::Whole, ms);
                moved = None;
            }
        }
        if !converged {
            stats.held = pass.hold_back_path(candidates.as_ref(), start, end, border, &mut stats);
        }
        stats.max_correction = max_correction(&requested, end);
        Ok(stats)
    }

    /// The vertices of pairs whose paths `start → end` may cross (no
    /// separation), gathered afresh; those that did not move are left out.
    pub fn crossings(&self, start: &[Vec3], end: &[Vec3], settings: &SelfSettings, tangles: &Tangles, takes_part: Option<&[bool]>) -> Result<Vec<u32>> {
        self.check("start positions", start)?;
        self.check("end positions", end)?;
        let pass = self.pass(settings, tangles, takes_part)?;
        let zero = vec![0.0; self.vertex_count];
        let pairs = pass.gather(&Motion { start, end, margin: &zero }, None);
        Ok(pass.crossing_corners(&pairs, start, end, None).0)
    }

    /// For the tests: the first pass's fail-safe alone over `start → end`
    /// (no tangles, no weights), from `candidates` where they hold (else
    /// gathering, as in [`Self::resolve_path`]), with the held patches'
    /// `border`; `end` is changed as there.
    /// Returns its stats: what it held and how it gathered.
    #[cfg(test)]
    pub(super) fn hold_back_path_alone(&self, candidates: Option<&Candidates>, start: &[Vec3], end: &mut [Vec3], settings: &SelfSettings, border: HeldBorder) -> SelfStats {
        let tangles = Tangles::default();
        let pass = self.pass(settings, &tangles, None).expect("prepared");
        let mut stats = SelfStats::default();
        stats.held = pass.hold_back_path(candidates, start, end, border, &mut stats);
        stats
    }

    /// Makes the in-loop motion `before → after` free of new
    /// self-intersections by changing `after`, with `candidates` (gathered
    /// again if a vertex strayed beyond them). Runs the
    /// rounds only: the caller ends with [`Self::hold_back_in_loop`] (alone,
    /// or together with the colliders' check).
    #[allow(clippy::too_many_arguments)]
    pub fn resolve_in_loop(
        &self,
        candidates: &mut Option<Candidates>,
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
        let (gathered, ms) = timed(|| pass.ensure(candidates, before, after));
        stats.count(&gathered, ms);
        candidates.as_mut().expect("ensured").at_start.begin(before);
        let mut moved: Option<Vec<bool>> = None;
        // How far each vertex strayed, kept from round to round where only
        // the vertices a round moved (or gathered around) change theirs.
        let mut strays: Option<Strays> = None;
        for _ in 0..SELF_ROUNDS {
            stats.rounds += 1;
            let current = candidates.as_mut().expect("ensured");
            let strays = match (strays.as_mut(), moved.as_deref()) {
                (Some(kept), Some(changed)) => {
                    current.restray(kept, before, after, changed);
                    kept
                }
                _ => strays.insert(current.strays(before, after)),
            };
            let open = current.open(strays);
            let mut at_start = std::mem::take(&mut current.at_start);
            let chosen = at_start.chosen(current, before, strays, &open, moved.as_deref(), &pass);
            current.at_start = at_start;
            let (contacts, changes) = pass.round(&current.pairs, before, after, &chosen, &mut stats);
            stats.contacts += contacts;
            if changes.is_empty() {
                break;
            }
            let mut flags = vec![false; self.vertex_count];
            for (v, p) in changes {
                after[v as usize] = p;
                flags[v as usize] = true;
            }
            let (gathered, ms) = timed(|| pass.ensure(candidates, before, after));
            stats.count(&gathered, ms);
            if gathered == Gathered::Whole {
                // Its pairs are listed anew (in another order).
                candidates.as_mut().expect("ensured").at_start.begin(before);
            }
            moved = match gathered {
                Gathered::Nothing => Some(flags),
                // Only the pairs with a corner among those gathered around
                // are new; every other pair is the one the rounds so far
                // looked at, with the same corners' positions unless a
                // corner was just moved (flagged): the next round looks at
                // both, the rest would find what it found before (nothing
                // to correct), as in the first pass's rounds.
                Gathered::Around(left) => {
                    flags.iter_mut().zip(&left).for_each(|(f, l)| *f |= l);
                    Some(flags)
                }
                Gathered::Whole => None,
            };
        }
        stats.max_correction = max_correction(&requested, after);
        Ok(stats)
    }

    /// The fail-safe's check in the in-loop passes: the vertices (of pairs
    /// touching `touching`, or all) of pairs whose paths `before → after`
    /// may cross. Its work is added to `stats`.
    #[allow(clippy::too_many_arguments)]
    pub fn in_loop_crossings(
        &self,
        candidates: &mut Option<Candidates>,
        before: &[Vec3],
        after: &[Vec3],
        touching: Option<&[bool]>,
        settings: &SelfSettings,
        tangles: &Tangles,
        takes_part: Option<&[bool]>,
        stats: &mut SelfStats,
    ) -> Result<Vec<u32>> {
        let pass = self.pass(settings, tangles, takes_part)?;
        let (gathered, ms) = timed(|| pass.ensure(candidates, before, after));
        stats.count(&gathered, ms);
        let began = Instant::now();
        let current = candidates.as_ref().expect("ensured");
        let open = current.unsettled(before, after, touching, &pass);
        let (bad, tested) = pass.crossing_corners(&open, before, after, touching);
        stats.pairs_scanned += current.pairs.len();
        stats.pairs_tested += tested;
        stats.fail_safe_ms += 1000.0 * began.elapsed().as_secs_f64();
        Ok(bad)
    }

    /// What a fail-safe puts back now, `held` what it put back before: the
    /// `crossing` corners and every vertex that `moved` more than half of
    /// whose ring is held with them ([`Held`]), ascending.
    pub fn put_back(&self, held: &mut Held, crossing: &[u32], moved: impl Fn(u32) -> bool) -> Vec<u32> {
        held.batch(&self.rings, crossing, moved)
    }

    /// [`Self::in_loop_crossings`] until none is left, putting each crossing
    /// pair's vertices back at `before`, with the vertices whose rings they
    /// mostly hold ([`Held`]): the in-loop fail-safe without colliders.
    /// Returns the vertices put back.
    #[allow(clippy::too_many_arguments)]
    pub fn hold_back_in_loop(
        &self,
        candidates: &mut Option<Candidates>,
        before: &[Vec3],
        after: &mut [Vec3],
        settings: &SelfSettings,
        tangles: &Tangles,
        takes_part: Option<&[bool]>,
    ) -> Result<Vec<u32>> {
        let mut held = Vec::new();
        let mut holding = Held::none(self.vertex_count);
        let mut touching: Option<Vec<bool>> = None;
        let mut work = SelfStats::default();
        loop {
            let bad = self.in_loop_crossings(candidates, before, after, touching.as_deref(), settings, tangles, takes_part, &mut work)?;
            if bad.is_empty() {
                break;
            }
            let batch = self.put_back(&mut holding, &bad, |v| after[v as usize] != before[v as usize]);
            let mut flags = vec![false; self.vertex_count];
            for &v in &batch {
                after[v as usize] = before[v as usize];
                flags[v as usize] = true;
            }
            held.extend_from_slice(&batch);
            touching = Some(flags);
        }
        held.sort_unstable();
        held.dedup();
        Ok(held)
    }
}

impl Pass<'_> {
    fn accept(&self) -> impl Fn(&[u32], &[u32]) -> bool + Sync + '_ {
        move |a: &[u32], b: &[u32]| !self.collision.excluded(a, b) && (!self.tangles.holds(a) || !self.tangles.holds(b))
    }

    fn gather(&self, motion: &Motion<'_>, focus: Option<&Focus>) -> Vec<ElementPair> {
        self.gather_with(None, motion, focus)
    }

    /// [`Self::gather`] with the tree's bounds over `motion`, if already made.
    fn gather_with(&self, bounds: Option<&NodeBounds>, motion: &Motion<'_>, focus: Option<&Focus>) -> Vec<ElementPair> {
        let accept = self.accept();
        self.collision.gather(motion, self.settings.thickness, true, self.takes_part, &accept, focus, bounds)
    }

    /// Each pair's separation, as [`Candidates`] keeps it.
    fn pair_separations(&self, pairs: &[ElementPair]) -> Vec<f32> {
        pairs.par_iter().with_min_len(4096).map(|pair| self.collision.pair_separation(pair) as f32).collect()
    }

    /// The candidates of `start → end` with these margins; pairs that
    /// cannot come within their separation near the end are dropped.
    fn candidates(&self, start: &[Vec3], end: &[Vec3], margin: Vec<f32>) -> Candidates {
        let motion = Motion { start, end, margin: &margin };
        let bounds = self.collision.bounds(&motion, self.takes_part);
        let pairs = self.gather_with(Some(&bounds), &motion, None);
        let distance: Vec<f32> = pairs.par_iter().map(|pair| distance(pair, end)).collect();
        let separation = self.pair_separations(&pairs);
        let mut c = Candidates {
            start: start.to_vec(),
            reference: end.to_vec(),
            margin,
            pairs,
            distance,
            separation,
            bounds,
            clearance: vec![f64::INFINITY; start.len()],
            at_start: AtStart::default(),
            fits: PathFits::default(),
            index: None,
        };
        c.tighten(0, self);
        c
    }

    /// Gathers the in-loop candidates again if the motion `before → after`
    /// leaves them ([`Candidates::fitted`]): around the vertices that left,
    /// if they are few, else the whole skin along the iteration's paths.
    /// Returns what it did.
    ///
    /// Not the last candidates' margins in either: those of the first pass
    /// grow with its corrections, and where a fold closes (its rounds and
    /// fail-safe moving skin far) carrying them into every in-loop gathering
    /// paired up millions of elements of the fold (issue 30, seventh round).
    fn ensure(&self, candidates: &mut Option<Candidates>, before: &[Vec3], after: &[Vec3]) -> Gathered {
        let fit = candidates.as_mut().map(|c| c.fitted(before, after));
        if fit.as_ref().is_some_and(|(_, count)| *count == 0) {
            return Gathered::Nothing;
        }
        let floor = self.collision.margin_floor(self.settings);
        let moved = |v: usize| (after[v] - before[v]).length();
        if let (Some(c), Some((left, count))) = (candidates.as_mut(), fit) {
            if count <= before.len() / AROUND_IN_LOOP {
                // Each a ball about `before` holding `after` and the next
                // iterations' moves, which shrink as the solve converges.
                let ball: Vec<f32> = (0..before.len()).into_par_iter().with_min_len(4096).map(|v| (4.0 * moved(v)).max(floor)).collect();
                self.gather_around(c, &left, before, before, &ball);
                return Gathered::Around(left);
            }
        }
        // Along the iteration's own paths, not a ball about `before` holding
        // `after`: skin the solve carries along together (a limb) keeps its
        // relative boxes however far it moves, where balls as wide as the
        // move pair it up with everything within that move (the character's
        // closing fold: 5.5M pairs listed where the paths list 1.0M, issue
        // 30, ninth round). The margins are for the iterations to come.
        let separation = self.collision.separations();
        let margin: Vec<f32> = (0..before.len())
            .into_par_iter()
            .with_min_len(4096)
            .map(|v| (IN_LOOP_MARGIN_MOVES * moved(v)).min(IN_LOOP_MARGIN_SEPARATIONS * separation[v]).max(floor))
            .collect();
        *candidates = Some(self.candidates(before, after, margin));
        Gathered::Whole
    }

    /// Gathers again only around the vertices `left` (flags per vertex):
    /// each gets the path `start → end` and the `margin` given for it, the
    /// pairs with one of them as a corner are listed again under those, and
    /// every other pair is kept.
    ///
    /// The list stays what a whole gathering would need: whether two
    /// elements can come within their reach depends only on their own
    /// corners' paths and margins. A pair with no corner among `left` has
    /// the corners' paths and margins of the gathering that listed it (or
    /// proved it out of reach), so keeping it, or keeping it out, is right
    /// still; every pair with a corner among `left` has a triangle around
    /// one of them (the triangle owning that corner or edge, or the
    /// vertex–triangle pair's triangle), which the focus looks at.
    fn gather_around(&self, c: &mut Candidates, left: &[bool], start: &[Vec3], end: &[Vec3], margin: &[f32]) {
        let vertices: Vec<u32> = (0..left.len() as u32).filter(|&v| left[v as usize]).collect();
        for &v in &vertices {
            let v = v as usize;
            c.start[v] = start[v];
            c.reference[v] = end[v];
            c.margin[v] = margin[v];
            // Its reference moved: its pairs are all listed again below.
            c.clearance[v] = f64::INFINITY;
        }
        c.fits.repathed(&vertices);
        let touches = |pair: &ElementPair| pair.corners.iter().any(|&v| left[v as usize]);
        let kept = c.drop_pairs_of(&vertices, left);
        let focus = self.collision.focus_around(left);
        // Only the vertices `left` changed path or margin: the bounds of the
        // leaves without one of them as a corner, and of the nodes above
        // only such leaves, are what a fresh fit gives.
        let motion = Motion { start: &c.start, end: &c.reference, margin: &c.margin };
        self.collision.refit_bounds(&mut c.bounds, &motion, self.takes_part, left);
        let found: Vec<ElementPair> = self.gather_with(Some(&c.bounds), &motion, Some(&focus)).into_iter().filter(|p| touches(p)).collect();
        let reference = &c.reference;
        let found_distance: Vec<f32> = found.par_iter().map(|pair| distance(pair, reference)).collect();
        if let Some(index) = &mut c.index {
            index.append(&found);
        }
        c.pairs.extend(found);
        c.distance.extend(found_distance);
        c.separation.extend(self.pair_separations(&c.pairs[kept..]));
        // The kept pairs' corners keep their clearances (a pair dropped can
        // only have lowered them: still a lower bound of what is left), the
        // new pairs lower theirs.
        c.tighten(kept, self);
    }

    /// One round: the corrections of the `chosen` pairs (ascending indices
    /// into `pairs`), averaged per vertex. Its work is added to `stats`.
    fn round(&self, pairs: &[ElementPair], start: &[Vec3], end: &[Vec3], chosen: &[usize], stats: &mut SelfStats) -> (usize, Vec<(u32, Vec3)>) {
        let began = Instant::now();
        // Collected in order: the corrections are summed in the order of
        // the list, whatever the threads.
        let found: Vec<(usize, [DVec3; 4])> = chosen
            .par_iter()
            .with_min_len(256)
            .filter_map(|&k| {
                let pair = &pairs[k];
                let separation = self.collision.pair_separation(pair);
                let hit = first_contact(pair, start, end, separation, self.params.tolerance)?;
                correction(pair, start, end, &hit, separation, &self.params).map(|c| (k, c))
            })
            .collect();
        stats.pairs_scanned += pairs.len();
        stats.pairs_tested += chosen.len();
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
        stats.rounds_ms += 1000.0 * began.elapsed().as_secs_f64();
        (found.len(), changes)
    }

    /// The corners (of pairs touching `touching`, or all) of `pairs` whose
    /// paths may cross, leaving out pairs none of whose corners moved; and
    /// how many pairs were tested.
    fn crossing_corners(&self, pairs: &[ElementPair], start: &[Vec3], end: &[Vec3], touching: Option<&[bool]>) -> (Vec<u32>, usize) {
        let moved = |v: u32| start[v as usize] != end[v as usize];
        let tested: Vec<&ElementPair> = pairs
            .par_iter()
            .with_min_len(256)
            .filter(|pair| touching.is_none_or(|t| pair.corners.iter().any(|&v| t[v as usize])))
            .filter(|pair| pair.corners.iter().any(|&v| moved(v)))
            .collect();
        let mut bad: Vec<u32> = tested
            .par_iter()
            .with_min_len(256)
            .filter(|pair| first_contact(pair, start, end, 0.0, self.params.tolerance).is_some())
            .flat_map_iter(|pair| pair.corners.into_iter().filter(|&v| moved(v)))
            .collect();
        bad.sort_unstable();
        bad.dedup();
        (bad, tested.len())
    }

    /// The first pass's fail-safe: puts the corners of crossing pairs back at
    /// `start`, with the vertices whose rings they mostly hold ([`Held`]),
    /// until none crosses. Returns the vertices put back.
    ///
    /// Only the first check looks at the whole skin; each later one at the
    /// pairs with a corner among the vertices just put back. A pair with
    /// none has the same path as at the check before, which found it clear
    /// (or put a corner of it back, which put it in this batch).
    ///
    /// A check takes its pairs from the rounds' `candidates` where every
    /// vertex's `end` is within its margin of its reference (and the
    /// candidates start at `start`), else it gathers them (the whole skin,
    /// or around the batch) with no margin, as before. Why the list holds
    /// every pair whose paths `start → end` can cross: it lists every pair
    /// that can come within its reach (the thickness, more than the 0 of a
    /// crossing) while each vertex `v` stays within its margin `m_v` of its
    /// gathered path `p_v(t) = start_v + t·(reference_v − start_v)`, `t` one
    /// time for all vertices ([`Candidates::fitted`]'s argument, the same
    /// gathering). The check's path is `x_v(t) = start_v + t·(end_v −
    /// start_v)`: its offset `x_v(t) − p_v(t) = t·(end_v − reference_v)` is
    /// never longer than `|end_v − reference_v| ≤ m_v`. After the rounds
    /// this holds for every vertex (each round gathers again, around or
    /// whole, where a correction left its margin), so the first check needs
    /// no gathering; a vertex put back at `start` may leave its margin, and
    /// the later checks then gather around the batch as before.
    fn hold_back_path(&self, candidates: Option<&Candidates>, start: &[Vec3], end: &mut [Vec3], border: HeldBorder, stats: &mut SelfStats) -> Vec<u32> {
        let zero = vec![0.0; start.len()];
        let mut held = Vec::new();
        let mut holding = Held::none(start.len());
        let mut batch: Option<Vec<bool>> = None;
        let mut requested: Option<Vec<Vec3>> = None;
        loop {
            let listed = candidates.filter(|c| c.start.as_slice() == start && c.holds(&[end]));
            let gathered;
            let pairs: &[ElementPair] = match listed {
                Some(c) => &c.pairs,
                None => {
                    let ((focus, pairs), ms) = timed(|| {
                        let focus = batch.as_deref().map(|b| self.collision.focus_around(b));
                        let pairs = self.gather(&Motion { start, end, margin: &zero }, focus.as_ref());
                        (focus, pairs)
                    });
                    stats.count(&if focus.is_some() { Gathered::Around(Vec::new()) } else { Gathered::Whole }, ms);
                    gathered = pairs;
                    &gathered
                }
            };
            let began = Instant::now();
            let (bad, tested) = self.crossing_corners(pairs, start, end, batch.as_deref());
            stats.pairs_scanned += pairs.len();
            stats.pairs_tested += tested;
            stats.fail_safe_ms += 1000.0 * began.elapsed().as_secs_f64();
            if bad.is_empty() {
                break;
            }
            // Where the rounds left the skin, for a sloped border (kept once needed).
            let requested: &Vec<Vec3> = requested.get_or_insert_with(|| if border == HeldBorder::Sloped { end.to_vec() } else { Vec::new() });
            let put_back = self.collision.put_back(&mut holding, &bad, |v| start[v as usize] != end[v as usize]);
            let mut flags = vec![false; start.len()];
            for &v in &put_back {
                end[v as usize] = start[v as usize];
                flags[v as usize] = true;
            }
            // The skin round the patch goes part of its way (`ramp`).
            if border == HeldBorder::Sloped {
                for (v, share) in ramp::shares(&self.collision.rings, holding.flags(), start, requested) {
                    let p = start[v as usize] + share * (requested[v as usize] - start[v as usize]);
                    if end[v as usize] != p {
                        end[v as usize] = p;
                        flags[v as usize] = true;
                    }
                }
            }
            batch = Some(flags);
            held.extend(put_back);
        }
        held.sort_unstable();
        held.dedup();
        held
    }
}

/// The indices of the `pairs` with a corner among `moved` (or all), ascending.
fn touching(pairs: &[ElementPair], moved: Option<&[bool]>) -> Vec<usize> {
    (0..pairs.len()).into_par_iter().with_min_len(1024).filter(|&k| moved.is_none_or(|m| pairs[k].corners.iter().any(|&v| m[v as usize]))).collect()
}

fn max_correction(requested: &[Vec3], end: &[Vec3]) -> f32 {
    requested.par_iter().zip(end).map(|(a, b)| (*a - *b).length()).reduce(|| 0.0, f32::max)
}
