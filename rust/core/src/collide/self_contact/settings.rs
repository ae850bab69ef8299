//! What a self-collision pass is asked to do, and what it reports.

use crate::{Error, Result};

/// Most rings a user may exclude around a vertex: beyond a few rings the
/// exclusion hides real folds (and the lists grow with the square).
pub const MAX_RINGS: u32 = 4;

/// Settings of the skin's contact with itself.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SelfSettings {
    /// Distance kept between skin that folds onto itself (scene units). Pairs
    /// of elements already closer at rest keep their rest distance instead:
    /// they are the rest shape, not a contact.
    pub thickness: f32,
    /// Static and kinetic friction between the two sides of a contact.
    pub static_friction: f32,
    pub kinetic_friction: f32,
    /// Neighbours left out: elements sharing a vertex are never tested
    /// (0, the default); `k` also leaves out elements within `k` edges of
    /// each other. More than 0 hides folds sharper than that.
    pub rings: u32,
}

impl Default for SelfSettings {
    fn default() -> Self {
        SelfSettings { thickness: 0.001, static_friction: 0.2, kinetic_friction: 0.15, rings: 0 }
    }
}

impl SelfSettings {
    pub fn validate(&self) -> Result<()> {
        let check = |name: &str, value: f32| -> Result<()> {
            if !(value.is_finite() && value >= 0.0) {
                return Err(Error::invalid(format!("self-collision {name} is {value}; it must be finite and ≥ 0")));
            }
            Ok(())
        };
        check("thickness", self.thickness)?;
        check("static friction", self.static_friction)?;
        check("kinetic friction", self.kinetic_friction)?;
        if self.rings > MAX_RINGS {
            return Err(Error::invalid(format!("self-collision rings is {}; at most {MAX_RINGS} are allowed", self.rings)));
        }
        Ok(())
    }
}

/// What one self-collision pass did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SelfStats {
    /// Contacts projected (over all rounds).
    pub contacts: usize,
    /// Vertices the fail-safe put back at the start of the pass: the rounds
    /// could not clear their paths, and the start was free of intersections.
    pub held: Vec<u32>,
    /// Vertices whose paths still cross other skin (only where another
    /// guarantee had the last word: a collider sweeping in the first pass).
    pub pinched: Vec<u32>,
    /// Rounds of detection and projection run.
    pub rounds: usize,
    /// Times the candidate pairs were gathered again (a vertex left the
    /// bounds they were gathered for).
    pub gathers: usize,
    /// Times they were gathered again only around the vertices that left
    /// their bounds (the rest of the list kept).
    pub gathers_around: usize,
    /// Largest correction of one vertex.
    pub max_correction: f32,
    /// Where the pass's time went, wall-clock milliseconds (for traces and
    /// benchmarks, never for decisions): gatherings over the whole skin,
    /// gatherings around a few vertices, the rounds' pair tests and
    /// projections, the fail-safe's checks (their gatherings included).
    pub whole_gather_ms: f64,
    pub around_gather_ms: f64,
    pub rounds_ms: f64,
    pub fail_safe_ms: f64,
    /// Pairs the rounds and fail-safe checks went over (each its whole
    /// list), and of those the pairs tested by CCD: touching a vertex that
    /// moved and not proven apart without it.
    pub pairs_scanned: usize,
    pub pairs_tested: usize,
}

#[cfg(test)]
impl SelfStats {
    pub(crate) fn add(&mut self, other: &SelfStats) {
        self.contacts += other.contacts;
        self.held.extend_from_slice(&other.held);
        self.held.sort_unstable();
        self.held.dedup();
        self.pinched.extend_from_slice(&other.pinched);
        self.pinched.sort_unstable();
        self.pinched.dedup();
        self.rounds += other.rounds;
        self.gathers += other.gathers;
        self.gathers_around += other.gathers_around;
        self.max_correction = self.max_correction.max(other.max_correction);
        self.whole_gather_ms += other.whole_gather_ms;
        self.around_gather_ms += other.around_gather_ms;
        self.rounds_ms += other.rounds_ms;
        self.fail_safe_ms += other.fail_safe_ms;
        self.pairs_scanned += other.pairs_scanned;
        self.pairs_tested += other.pairs_tested;
    }
}
