//! Collisions of the skin against kinematic colliders.
//!
//! Modules, one job each:
//! * [`ccd`]: conservative continuous collision detection (vertex–triangle,
//!   edge–edge) by interval root finding with a rigorous f64 error bound.
//! * [`bvh`]: a BVH (`obvhs`) over boxes, refitted each frame and rebuilt when
//!   refitting has degraded it (SAH cost ratio).
//! * [`clearance`]: per-vertex distance bounds from the colliders, measured
//!   once per frame, that let the in-loop passes skip the skin far from them.
//! * [`envelope`]: where a collider that moves between passes (a compliant
//!   one, receding) stays, so that a clearance can hold while it moves.
//! * [`collider`]: a triangle mesh moving from last frame to this frame, with
//!   thickness, friction and a BVH over its swept triangles.
//! * [`friction`]: position-based friction of one contact, and whether it
//!   left the vertex stuck or sliding.
//! * [`geometry`]: f64 helpers (normals, distances, crossing tests).
//! * [`inside`]: whether a point is inside a closed collider (ray parity),
//!   for the solver.
//! * [`planes`]: supporting planes of the still colliders around the skin in
//!   contact, measured with the clearance, that prove resting contacts apart
//!   and lift the vertices the solver pulls back in, without a lookup.
//! * [`proximity`]: cheap exact-distance proofs that a pair stays apart,
//!   which spare resting contacts the interval CCD.
//! * `slab`: proofs that a skin element stays apart from a whole patch of
//!   collider triangles at once, the patch's corners gathered once.
//! * [`response`]: [`ColliderSet::resolve_path`], the building block of both
//!   collision passes (projection, friction, pinched vertices); its module doc
//!   shows the intended use in seed 000's Algorithm 2.
//! * [`skin`]: the skin's vertices, edges and triangles as the passes test
//!   them.
//! * [`self_contact`]: the skin against itself, in the same two passes.
//! * [`audit`]: penetration audit (vertices inside closed colliders, edges
//!   crossing in both directions), independent of the solver;
//!   [`audit_self`] its count of the skin's self-intersections.

pub mod audit;
pub mod audit_self;
pub mod bvh;
pub mod ccd;
pub mod clearance;
pub mod collider;
pub mod envelope;
pub mod friction;
pub mod geometry;
pub mod inside;
pub mod planes;
pub mod proximity;
pub mod response;
pub mod self_contact;
pub mod skin;
mod slab;

pub use audit::{audit, AuditParams, AuditReport};
pub use audit_self::self_intersections;
pub use bvh::{BoxTree, Bounds, UpdateReport};
pub use ccd::{CcdHit, CcdParams};
pub use clearance::{Clearance, Unproven};
pub use collider::{Collider, ColliderSettings, Compliance, SurfacePoint};
pub use envelope::Envelope;
pub use friction::{Anchor, Anchors, Cone, Hold, Slide};
pub use inside::is_inside;
pub use response::{ColliderMotion, ColliderSet, ContactStats, ResolveParams};
pub use self_contact::{Candidates, Held, HeldBorder, SelfCollision, SelfSettings, SelfStats, Tangles};
pub use skin::Skin;

#[cfg(test)]
mod tests;
