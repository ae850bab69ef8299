//! The first pass's contacts, held inside the solve.
//!
//! Where the rig's input folds through itself, every solver iteration pulls
//! the skin back towards it, through the contacts the first pass found. Left
//! to the closing pass, that is the whole fold to correct again, with CCD,
//! rounds and a fail-safe that puts the skin back where the first pass left
//! it (a stuck patch instead of a crease). Instead, each contact of the first
//! pass's end becomes a small fixed constraint of the solve: after every
//! iteration its two sides are projected back to the separation along the
//! contact normal they had there (the side each was on, which was free of
//! intersections), with the same friction as the passes. The solver then
//! redistributes the skin around them: a crease or a bulge. The work is
//! proportional to the contacts, not to the fold; nothing here is a
//! guarantee (the closing pass is).

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::contact::{correction, first_contact};
use super::gather::ElementPair;
use super::collision::SelfCollision;
use super::resolve::{averaged, Candidates, Pass, Tangles};
use super::settings::SelfSettings;
use crate::Result;
use crate::collide::ccd::CcdHit;

/// Jacobi sweeps of the held contacts after each iteration.
const SWEEPS: usize = 2;

/// The pairs in contact where the first pass ended, each with where on its
/// two elements the contact is.
#[derive(Debug, Clone, Default)]
pub struct HeldContacts {
    pairs: Vec<ElementPair>,
    hits: Vec<CcdHit>,
}

impl HeldContacts {
    /// How many contacts are held.
    pub fn len(&self) -> usize {
        self.pairs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }
}

impl SelfCollision {
    /// The contacts among `candidates` at `x` (where a first pass ended), to
    /// hold in the solve that follows.
    pub fn held_contacts(&self, candidates: &Candidates, x: &[Vec3], settings: &SelfSettings, tangles: &Tangles, takes_part: Option<&[bool]>) -> Result<HeldContacts> {
        self.check("positions where the first pass ended", x)?;
        Ok(self.pass(settings, tangles, takes_part)?.held_contacts(candidates, x))
    }

    /// Projects `held` (found at `reference`) apart in `after`; returns how
    /// many vertices moved.
    pub fn hold(&self, held: &HeldContacts, reference: &[Vec3], after: &mut [Vec3], settings: &SelfSettings, tangles: &Tangles, takes_part: Option<&[bool]>) -> Result<usize> {
        if held.is_empty() {
            return Ok(0);
        }
        self.check("positions where the first pass ended", reference)?;
        self.check("positions after the iteration", after)?;
        Ok(self.pass(settings, tangles, takes_part)?.hold(held, reference, after))
    }
}

impl Pass<'_> {
    /// The pairs of `candidates` that are in contact at `x` (within their
    /// separation and twice the projection's slack).
    pub(super) fn held_contacts(&self, candidates: &Candidates, x: &[Vec3]) -> HeldContacts {
        let found: Vec<(ElementPair, CcdHit)> = candidates
            .pairs()
            .par_iter()
            .with_min_len(256)
            .filter_map(|pair| {
                let reach = self.collision.pair_separation(pair) + 2.0 * self.params.slack;
                let hit = first_contact(pair, x, x, reach, self.params.tolerance)?;
                Some((*pair, CcdHit { toi: 0.0, ..hit }))
            })
            .collect();
        let (pairs, hits) = found.into_iter().unzip();
        HeldContacts { pairs, hits }
    }

    /// Projects the held contacts of `reference` (where they were found) apart
    /// in `after`. Returns how many vertices moved.
    pub(super) fn hold(&self, held: &HeldContacts, reference: &[Vec3], after: &mut [Vec3]) -> usize {
        let mut moved = 0;
        for _ in 0..SWEEPS {
            let found: Vec<(usize, [DVec3; 4])> = (0..held.pairs.len())
                .into_par_iter()
                .with_min_len(256)
                .filter_map(|k| {
                    let pair = &held.pairs[k];
                    let separation = self.collision.pair_separation(pair);
                    correction(pair, reference, after, &held.hits[k], separation, &self.params).map(|c| (k, c))
                })
                .collect();
            if found.is_empty() {
                break;
            }
            let changes = averaged(&held.pairs, &found, after);
            moved = moved.max(changes.len());
            for (v, p) in changes {
                after[v as usize] = p;
            }
        }
        moved
    }
}
