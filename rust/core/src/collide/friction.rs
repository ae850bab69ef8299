//! Position-based friction of one contact (Bender, Müller, Macklin 2015),
//! and whether it left the vertex stuck or sliding.
//!
//! Shared by the contacts with a collider triangle ([`super::response`]) and
//! the lifts along a supporting plane ([`super::planes`]): the tangential slip
//! since contact is removed entirely while it is within the static cone
//! (`|slip⊥| < μs·depth`), otherwise reduced by `μk·depth`.
//!
//! The accelerated solver reads the outcome ([`Hold`]): a stuck vertex is
//! fixed where it is for its next iteration, a sliding one is constrained
//! only along its contact normal, so the solver's coarse correction may move
//! a sliding contact patch along the collider (issue 28).

use glam::{DVec3, Vec3};

/// How a contact's projection left its vertex.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Hold {
    /// Static friction held it where its slip started.
    Stuck,
    /// Free to slide along the surface.
    Sliding(Slide),
}

/// A vertex sliding along a surface: pushed out along `normal` (unit), its
/// slip reduced by kinetic `friction` times the depth of the push (0: none).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Slide {
    pub normal: Vec3,
    pub friction: f32,
}

/// The change friction makes to a projected end whose tangential `slip`
/// (relative to the collider, since contact) comes with a projection of
/// `depth` along the unit `normal`, and how that leaves the vertex. Without
/// friction coefficients the vertex slides freely.
pub(crate) fn friction(slip: DVec3, normal: DVec3, depth: f64, static_friction: f64, kinetic_friction: f64) -> (DVec3, Hold) {
    let tangential = slip - slip.dot(normal) * normal;
    let len = tangential.length();
    let sliding = |friction: f64| Hold::Sliding(Slide { normal: normal.as_vec3(), friction: friction as f32 });
    if static_friction <= 0.0 && kinetic_friction <= 0.0 {
        return (DVec3::ZERO, sliding(0.0));
    }
    if len < static_friction * depth {
        (tangential, Hold::Stuck)
    } else if len > 0.0 {
        (tangential * (kinetic_friction * depth / len).min(1.0), sliding(kinetic_friction))
    } else {
        (DVec3::ZERO, sliding(kinetic_friction))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_slip_within_the_static_cone_sticks_and_beyond_it_slides_less_by_kinetic_friction() {
        let n = DVec3::Z;
        // Slip 0.1 along x (and some along the normal, which friction ignores), depth 0.2.
        let slip = DVec3::new(0.1, 0.0, 0.3);
        let (change, hold) = friction(slip, n, 0.2, 1.0, 0.8);
        assert_eq!((change, hold), (DVec3::new(0.1, 0.0, 0.0), Hold::Stuck), "0.1 < 1.0 · 0.2");
        let (change, hold) = friction(slip, n, 0.2, 0.4, 0.25);
        assert!((change - DVec3::new(0.05, 0.0, 0.0)).length() < 1e-12, "reduced by 0.25 · 0.2: {change}");
        assert_eq!(hold, Hold::Sliding(Slide { normal: Vec3::Z, friction: 0.25 }));
        let (change, hold) = friction(slip, n, 0.2, 0.0, 0.0);
        assert_eq!((change, hold), (DVec3::ZERO, Hold::Sliding(Slide { normal: Vec3::Z, friction: 0.0 })), "frictionless");
    }
}
