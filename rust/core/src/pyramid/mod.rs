//! Pyramid coordinates (Sheffer & Kraevoy 2004) as projective constraints
//! (seed 000 §2).
//!
//! * [`encode`]: at bind time, each vertex is described relative to its
//!   ordered one-ring (an open ring, at a boundary, closed by a virtual
//!   neighbour): mean-value weights of its projection on the ring's
//!   plane, and a normal offset (a plain height, or per-neighbour edge
//!   elevation tangents in scale-safe mode). Vertices that cannot be encoded
//!   are pinned and listed with the reason.
//! * [`project`]: Algorithm 1 of the seed, the target of one vertex given the
//!   current positions of its neighbours.
//! * [`constraint`]: the two formulations as [`crate::solve::Constraint`]s.
//! * [`deformer`]: bind + solve + residual, what the bindings call.
//! * [`step`]: frame-to-frame solving with the two collision passes,
//!   substeps, dynamics ([`dynamics`]), strain limits and compliant
//!   colliders ([`compliance`]).
//!
//! The design and the measurements behind the default formulation are in
//! `docs/design/pyramid-solver.md`.

pub mod compliance;
pub mod constraint;
pub mod deformer;
pub mod dynamics;
pub mod encode;
pub mod kernel;
pub mod project;
pub mod step;

pub use constraint::{PyramidLaplacian, PyramidTargets};
pub use deformer::{
    mean_residual, Closeness, DeformerOptions, Formulation, PyramidDeformer, DEFAULT_CLOSENESS,
    MAX_ITERATIONS, MIN_CLOSENESS,
};
pub use encode::{encode, Encoding, PinReason, MAX_VALENCE};
pub use dynamics::{Dynamics, MAX_SUBSTEPS, STIFFNESS_DENSITY};
pub use step::{StepOptions, StepReport, StrainMode, StrainOptions};

#[cfg(test)]
mod open_ring_tests;
#[cfg(test)]
mod tests;

#[cfg(test)]
mod step_tests;
