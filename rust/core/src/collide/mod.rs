//! Collisions of the skin against kinematic colliders.
//!
//! Modules, one job each:
//! * [`ccd`]: conservative continuous collision detection (vertex–triangle,
//!   edge–edge) by interval root finding with a rigorous f64 error bound.
//! * [`bvh`]: a BVH (`obvhs`) over boxes, refitted each frame and rebuilt when
//!   refitting has degraded it (SAH cost ratio).
//! * [`collider`]: a triangle mesh moving from last frame to this frame, with
//!   thickness, friction and a BVH over its swept triangles.

pub mod bvh;
pub mod ccd;
pub mod collider;

pub use bvh::{BoxTree, Bounds, UpdateReport};
pub use ccd::{CcdHit, CcdParams};
pub use collider::{Collider, ColliderSettings};

#[cfg(test)]
mod tests;
