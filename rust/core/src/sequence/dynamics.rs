//! Dynamics: projective dynamics on top of the pyramid solve (seed 000 §4,
//! after Bouaziz et al. 2014).
//!
//! Each substep of length `h` minimises
//! `Σ_i (1 − c_i)·ρ/(K·h²)·‖x_i − y_i‖² + (the static energy)`, with the
//! prediction `y = x_n + h·v_n + h²·g`: an inertia term, identity rows that
//! are constant within a solve ([`crate::solve::Targets`]), so the global
//! step stays the same diagonal average. `K` ([`STIFFNESS_DENSITY`]) is the
//! stiffness the static weights stand for, which makes `mass` a density in
//! the same units. The closeness `c_i` is the goal strength: the inertia
//! weight carries `1 − c_i` like the pyramid weight, so `c = 1` follows the
//! animation exactly and low closeness jiggles. A vertex displaced from its
//! goal oscillates at about `√(c·K / ((1 − c)·ρ))` rad/s.
//!
//! Backward Euler dissipates energy, so with still input the kinetic energy
//! never grows; `damping` removes a further fraction of the velocity per
//! second.

use glam::Vec3;

use crate::{Error, Result};

/// Stiffness density of the static energy (pyramid and closeness weights of
/// 1 stand for this many N/m per m²). Sets the time scale of the dynamics
/// together with `mass`: closeness 0.1 and mass 1 give about 1.7 Hz.
pub const STIFFNESS_DENSITY: f32 = 1000.0;

/// Most substeps one step accepts.
pub const MAX_SUBSTEPS: usize = 64;

/// Dynamics settings of a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dynamics {
    /// Duration of one frame in seconds (1 / the scene's frame rate).
    pub frame_time: f32,
    /// Surface density (kg/m²); vertex masses are density × vertex area.
    pub mass: f32,
    /// Fraction of the velocity removed per second, as a rate (1/s):
    /// velocities are multiplied by `exp(−damping·h)` every substep.
    pub damping: f32,
    /// Acceleration in world space (m/s²); zero by default.
    pub gravity: Vec3,
}

impl Default for Dynamics {
    fn default() -> Self {
        Dynamics { frame_time: 1.0 / 24.0, mass: 1.0, damping: 1.0, gravity: Vec3::ZERO }
    }
}

impl Dynamics {
    pub fn validate(&self) -> Result<()> {
        if !(self.frame_time.is_finite() && self.frame_time > 0.0) {
            return Err(Error::invalid(format!("frame time is {}; it must be positive (1 / frame rate)", self.frame_time)));
        }
        if !(self.mass.is_finite() && self.mass > 0.0) {
            return Err(Error::invalid(format!("mass is {}; it must be positive", self.mass)));
        }
        if !(self.damping.is_finite() && self.damping >= 0.0) {
            return Err(Error::invalid(format!("damping is {}; it must be finite and ≥ 0", self.damping)));
        }
        if !self.gravity.is_finite() {
            return Err(Error::invalid("gravity must be finite".to_string()));
        }
        Ok(())
    }

    /// Inertia weight of a vertex of closeness weight 1 for substep `h`.
    pub fn inertia_scale(&self, h: f32) -> f32 {
        self.mass / (STIFFNESS_DENSITY * h * h)
    }
}

/// Kinetic energy `½ Σ m_i ‖v_i‖²` with `m_i = density · area_i`.
pub fn kinetic_energy(velocity: &[Vec3], area: &[f32], density: f32) -> f64 {
    velocity.iter().zip(area).map(|(v, &a)| 0.5 * (density * a) as f64 * v.length_squared() as f64).sum()
}
