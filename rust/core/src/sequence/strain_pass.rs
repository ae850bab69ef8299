//! The strain pass of a step (seed 002 §2): edge shortening against the
//! contacts ([`StrainMode::Unified`]) or after them ([`StrainMode::Post`]).

use glam::Vec3;

use crate::collide::{Clearance, Collider, ColliderSet, ResolveParams, Skin};
use crate::strain::EdgeLimits;
use crate::Result;

#[allow(unused_imports)] // named by the docs
use super::options::StrainMode;

/// Gauss–Seidel sweeps of the strain projection per round of the unified loop.
pub(super) const STRAIN_SWEEPS: usize = 8;
/// Rounds of (strain sweeps, contact resolution) in the last iteration of the
/// unified loop, until both hold; earlier iterations run
/// [`STRAIN_ROUNDS_EARLY`]: the next iteration's solve moves the skin anyway,
/// and every round costs a whole contact pass (16 rounds in every iteration
/// took 18 s per frame on the 100k-vertex benchmark scene).
pub(super) const STRAIN_ROUNDS: usize = 16;
pub(super) const STRAIN_ROUNDS_EARLY: usize = 2;
/// Relative excess over an edge's limit that counts as holding.
pub(super) const STRAIN_TOLERANCE: f32 = 1e-3;
/// Sweeps of the post-collision strain pass.
pub(super) const POST_STRAIN_SWEEPS: usize = STRAIN_SWEEPS * STRAIN_ROUNDS;

/// Unified strain limiting (seed 002 §2): edge shortening and contact
/// resolution alternate until both hold or the rounds run out. Returns the
/// vertices the last contact resolution left pinched.
pub(super) fn limit_strain_with_contacts(
    limits: &EdgeLimits,
    colliders: &[&mut Collider],
    x: &mut [Vec3],
    skin: &Skin,
    inverse_mass: &[f32],
    rounds: usize,
    clearance: Option<&Clearance>,
) -> Result<Vec<u32>> {
    let refs: Vec<&Collider> = colliders.iter().map(|c| &**c).collect();
    let set = ColliderSet::new(refs);
    let mut pinched = Vec::new();
    for _ in 0..rounds {
        if limits.worst_ratio(x) <= 1.0 + STRAIN_TOLERANCE {
            break;
        }
        let mut shortened = x.to_vec();
        limits.project(&mut shortened, inverse_mass, STRAIN_SWEEPS, STRAIN_TOLERANCE);
        if !set.colliders().is_empty() {
            pinched = set.resolve_path_with(x, &mut shortened, skin, &ResolveParams::in_loop(), clearance)?.pinched;
        }
        x.copy_from_slice(&shortened);
    }
    Ok(pinched)
}
