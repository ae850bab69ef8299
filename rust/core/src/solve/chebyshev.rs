//! Chebyshev semi-iterative acceleration of the corrected iteration (Wang
//! 2015, "A Chebyshev semi-iterative approach for accelerating projective and
//! position-based dynamics").
//!
//! An iteration that converges linearly with spectral radius `ρ` converges
//! faster when each iterate is extrapolated along the last step:
//! `x_{k+1} = x_{k−1} + ω_{k+1} (G(x_k) − x_{k−1})`, with the weights of the
//! Chebyshev polynomials `ω₁ = 1`, `ω₂ = 2 / (2 − ρ²)`,
//! `ω_{k+1} = 4 / (4 − ρ² ω_k)`. It costs one more vector (the iterate
//! before) and a few flops per vertex, fused into the correction's last pass
//! ([`super::coarse::Coarse::correct`]).
//!
//! [`RHO`] is the radius of the multilevel-corrected iteration, measured, not
//! estimated per solve: the error of the 100k benchmark tube falls by about
//! 0.64 per corrected iteration at closeness 0.01. [`RHO`] and [`DELAY`] were
//! chosen on the MakeHuman character in its hard pose, welded quads (the OBJ)
//! and triangulated with split seams (a glTF round trip), closeness 0.05,
//! worst convergence error over the pose's frames after 6 iterations (issue
//! 28): ρ 0.6 / 0.7 / 0.8 give 6.1 / 4.1 / 2.8 % on the triangles and 2.7 /
//! 1.8 / 3.2 % on the quads.
//! Extrapolating from the second iteration on gives 4.1 % where starting
//! with the third gives 4.9 %.
//!
//! The first iteration is not extrapolated ([`DELAY`]): a cold solve's
//! first step is far from the linear regime the weights assume. An iteration
//! whose hook moved vertices (contacts holding them) restarts the sequence:
//! the extrapolation of a held vertex would push it off its hold.
//!
//! The iteration is not linear, and where it is far from it the
//! extrapolation can overshoot into another fixed point: on the convergence
//! benchmark's MakeHuman body bent about the hips (the hands hanging at hip
//! height sheared hard) the extrapolated iteration settled 9.5 % away from the
//! plain one's fixed point. So the solver restarts the sequence whenever the
//! residual `|G(x) − x|` grows from one iteration to the next (the classic
//! safeguard); with it both reach the same point (0.0 %) and the hard-posed
//! character, where the residual falls every iteration, keeps the figures
//! above.
//!
//! The weights assume the iteration's modes are real (in `[−ρ, ρ]`). Rows
//! that carry a vertex from another vertex's position (a ring fit's sliver
//! anchored to its neighbour, [`crate::pyramid::ring_fit`]) break that: on a
//! triangle fan's rim each vertex is carried from the next, a chain whose
//! linear model is a shift, with modes spread over a disc. Extrapolated, a
//! mode on the rims of a 1,000-segment fan cap grew ~12 % an iteration, and
//! the residual guard's restarts did not stop it (it grew between them). The
//! solver leaves such vertices out of the extrapolation
//! ([`super::Solver::set_unextrapolated`]); they still get the correction.

/// Spectral radius the weights are built for (see the module documentation).
pub(super) const RHO: f32 = 0.7;

/// Iterations before the extrapolation starts.
const DELAY: usize = 1;

/// The weight sequence of one solve.
#[derive(Debug, Clone)]
pub(super) struct Chebyshev {
    /// Iterations since the start or the last restart.
    step: usize,
    omega: f32,
}

impl Chebyshev {
    pub(super) fn new() -> Self {
        Chebyshev { step: 0, omega: 1.0 }
    }

    /// Starts the sequence again: the next weights are 1 for [`DELAY`] iterations.
    pub(super) fn restart(&mut self) {
        *self = Chebyshev::new();
    }

    /// The extrapolation weight of this iteration (1: none); advances the sequence.
    pub(super) fn next_weight(&mut self) -> f32 {
        let step = self.step;
        self.step += 1;
        let rho2 = RHO * RHO;
        self.omega = match step {
            s if s < DELAY => 1.0,
            s if s == DELAY => 2.0 / (2.0 - rho2),
            _ => 4.0 / (4.0 - rho2 * self.omega),
        };
        self.omega
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_start_at_one_and_approach_the_optimal_relaxation() {
        let mut sequence = Chebyshev::new();
        let weights: Vec<f32> = (0..40).map(|_| sequence.next_weight()).collect();
        assert_eq!(&weights[..DELAY], &[1.0; DELAY]);
        assert!((weights[DELAY] - 2.0 / (2.0 - RHO * RHO)).abs() < 1e-6);
        // The limit is the optimal over-relaxation 2 / (1 + sqrt(1 − ρ²)), approached from above.
        let limit = 2.0 / (1.0 + (1.0 - RHO * RHO).sqrt());
        assert!(weights.windows(2).skip(DELAY).all(|w| w[1] <= w[0] + 1e-6 && w[1] >= limit - 1e-6));
        assert!((weights[39] - limit).abs() < 1e-4, "{} vs {limit}", weights[39]);
        sequence.restart();
        assert_eq!(sequence.next_weight(), 1.0);
    }
}
