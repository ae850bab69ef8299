//! The skin's contact with itself: folds at elbows, knees and armpits that
//! crease or bulge instead of passing through.
//!
//! Self-collision runs in the same two passes as the colliders (seed 000,
//! Algorithm 2), between pairs of skin elements that are not neighbours:
//! vertex–triangle and edge–edge, both sides moving, with conservative CCD
//! ([`crate::collide::ccd`], [`crate::collide::proximity`]), a thickness,
//! friction, and a projection shared between the two sides. A pass whose
//! rounds cannot clear every contact puts the vertices involved back where
//! it started, which was free of intersections: the output of a step is
//! free of new self-intersections whenever its history was.
//!
//! What keeps it cheap is that skin rarely comes near itself: a patch tree
//! built at bind, whose nodes carry normal cones over the motion, drops
//! every patch that provably cannot touch itself and every pair of patches
//! whose boxes stay apart; the in-loop passes of a frame reuse one
//! gathering while the vertices stay near where it was made.
//!
//! Files, each one job, bottom-up: [`settings`] (what a pass is asked and
//! reports), `exclusion` (which pairs are neighbours), `tree` (the patch
//! tree, which patches are disks), `bounds` (boxes, normal cones and the
//! contour criterion per node over a motion), `separation` (a plane between
//! patches meeting at a corner or a ring apart), `hinge` and `star` (the
//! near pairs that are never contacts, whatever the tree: one hinge apart,
//! two polygons apart round a vertex), `gather` (the candidate
//! pairs), `pair_index` (where each vertex's pairs are in the candidates'
//! list, kept through the gatherings around a few vertices), `contact` (one pair's CCD and projection with friction),
//! `collision` ([`SelfCollision`]: the bind, the separations at rest, the
//! intersections of a state), `fit` (at which time along the
//! gathered paths the in-loop positions fit them, kept from round to
//! round), `held` (which vertices the fail-safe puts
//! back: a held patch moves as a patch), `ramp` (how far the skin round
//! a held patch goes without Converge: a slope, not a step), `resolve` (the passes, the
//! fail-safe, [`Tangles`]).

mod bounds;
mod collision;
mod contact;
mod exclusion;
mod fit;
mod gather;
mod held;
mod ramp;
mod hinge;
mod pair_index;
mod resolve;
mod separation;
mod star;
pub mod settings;
mod tree;

pub use collision::SelfCollision;
pub use held::Held;
pub use ramp::HeldBorder;
pub use resolve::{Candidates, Tangles, SELF_ROUNDS};
pub use settings::{SelfSettings, SelfStats, MAX_RINGS};

#[cfg(test)]
mod tests;
