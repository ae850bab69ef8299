//! Pyramid coordinates (Sheffer & Kraevoy 2004) as projective constraints
//! (seed 000 §2).
//!
//! * [`encoding`]: the stored coordinates ([`Encoding`]) and pin reasons.
//! * [`encode`]: at bind time, each vertex is described relative to its
//!   ordered one-ring (an open ring, at a boundary, closed by a virtual
//!   neighbour): mean-value weights of its projection on the ring's
//!   plane, and a normal offset (a plain height, or per-neighbour edge
//!   elevation tangents in scale-safe mode). Vertices that cannot be encoded
//!   are pinned and listed with the reason.
//! * [`project`]: Algorithm 1 of the seed, the target of one vertex given the
//!   current positions of its neighbours.
//! * [`ring_fit`]: the rows of vertices the encoding cannot describe but
//!   whose edge neighbours can carry them (non-manifold, bow-ties, folded or
//!   flat rings, poles): their rest offset from the neighbours' mean, moved
//!   by the neighbours' best-fit rotation (and scale).
//! * [`constraint`]: the two formulations as [`crate::solve::Constraint`]s.
//! * [`deformer`]: bind (topology, encoding, the prefactored solver), solve,
//!   residual.
//!
//! Frame-to-frame solving against colliders (history, dynamics, strain
//! limits, compliant colliders) is [`crate::sequence`]'s: it owns a
//! [`PyramidDeformer`] and the state of one bake. This module knows nothing
//! of collisions.
//!
//! The design and the measurements behind the default formulation are in
//! `docs/design/pyramid-solver.md`.

pub mod constraint;
pub mod deformer;
pub mod encode;
pub mod encoding;
pub mod kernel;
mod lanes;
pub mod project;
pub mod ring_fit;

pub use constraint::{PyramidLaplacian, PyramidTargets};
pub use ring_fit::RingFit;
pub use deformer::{
    mean_residual, Closeness, DeformerOptions, Formulation, PyramidDeformer, ACCELERATED_ITERATIONS, CONVERGE_TOLERANCE,
    DEFAULT_CLOSENESS, DEFAULT_CONVERGE,
    MAX_ITERATIONS, MIN_CLOSENESS, validate_closeness,
};
pub use encode::{encode, Encoding, PinReason, MAX_REST_ELEVATION, MAX_VALENCE};

#[cfg(test)]
mod open_ring_tests;
#[cfg(test)]
mod tests;
