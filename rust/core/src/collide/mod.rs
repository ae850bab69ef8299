//! Collisions of the skin against kinematic colliders.
//!
//! Modules, one job each:
//! * [`ccd`]: conservative continuous collision detection (vertex–triangle,
//!   edge–edge) by interval root finding with a rigorous f64 error bound.
//! * [`bvh`]: a BVH (`obvhs`) over boxes, refitted each frame and rebuilt when
//!   refitting has degraded it (SAH cost ratio).

pub mod ccd;

#[cfg(test)]
mod tests;
