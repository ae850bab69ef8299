//! A projective solver in the style of ShapeOp (Bouaziz et al. 2012, 2014).
//!
//! A constraint is two things: fixed rows of a selection matrix `A_c` (which
//! vertices it looks at, with which coefficients) and a projection `p_c(x)`
//! (where those rows would like to be, computed from the current positions).
//! The solver minimises `Σ_c Σ_r w_r ‖A_r x − p_r‖²` by alternating
//!
//! * a **local step**: every constraint projects, in parallel, and
//! * a **global step**: `(Σ w AᵀA) x = Σ w Aᵀ p`, whose matrix only depends on
//!   the rows and the weights, so it is factorised once and every iteration is
//!   a back-substitution per coordinate.
//!
//! The solver never knows which constraint it runs. Pyramid coordinates,
//! closeness, and later strain limits (rows `e_a − e_b` per edge), dynamics
//! (an inertia constraint whose identity rows carry `m/h²` and project to the
//! predicted position) and collision passes (an [`IterationHook`]) all plug in
//! through [`Constraint`] and [`IterationHook`] without touching this module.
//!
//! Results do not depend on the number of threads: every parallel loop writes
//! disjoint outputs and every sum runs in a fixed order.

mod chebyshev;
mod closeness;
mod coarse;
mod coarsest;
mod contacts;
mod constraint;
mod solver;
mod stopping;
mod system;
mod targets;

pub use closeness::Closeness;
pub use constraint::{Constraint, Context, DiagonalChunk, Rows};
pub use contacts::Sliding;
pub use solver::{ConstraintId, Iteration, IterationHook, Solver, SlidingHook};
pub use stopping::{limit as iteration_limit, Tolerance, MAX_WORK_FACTOR, WORK_VERTICES};
pub use system::SystemKind;
pub use targets::Targets;

#[cfg(test)]
mod tests;

