//! Position-based friction of one contact (Bender, Müller, Macklin 2015),
//! whether it left the vertex stuck or sliding, and where a stuck vertex is
//! anchored.
//!
//! One law for every contact kind: the contacts with a collider triangle
//! ([`super::response`]), the lifts along a supporting plane
//! ([`super::planes`]), and the edge–edge and collider-corner pushes: the
//! tangential slip since contact is removed entirely while it is within the
//! static cone (`|slip⊥| < μs·depth`), otherwise reduced by `μk·depth`.
//!
//! A vertex the law leaves stuck on a collider standing still is
//! **anchored** ([`Anchor`]): while the pull of the following iterations
//! stays inside the static cone it is held at the point where it stuck,
//! lifted out along that contact's normal only as far as a contact asks,
//! whichever triangle or plane touches it then. An edge or corner of the
//! collider pushing it lets it go for the rest of the pass: the push is
//! applied with its own friction, and the vertex is anchored again where it
//! ends (held at the old anchor, a pushed vertex could stay inside). On a faceted
//! collider the nearest facet changes as the solve moves a vertex, and each
//! facet's normal moves it a little along the surface: without the anchor a
//! held vertex creeps (issue 28).
//!
//! The accelerated solver reads the outcome ([`Hold`]): a stuck vertex is
//! fixed where it is for its next iteration, a sliding one is constrained
//! only along its contact normal, so the solver's coarse correction may move
//! a sliding contact patch along the collider (issue 28).

use std::collections::HashMap;

use glam::{DVec3, Vec3};

/// How a contact's projection left its vertex.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Hold {
    /// Static friction held it where its slip started, inside this cone.
    Stuck(Cone),
    /// Free to slide along the surface.
    Sliding(Slide),
}

impl Hold {
    /// The unit normal of the contact.
    pub fn normal(&self) -> Vec3 {
        match self {
            Hold::Stuck(cone) => cone.normal,
            Hold::Sliding(slide) => slide.normal,
        }
    }
}

/// The static cone of a contact that holds a vertex: its unit `normal` and
/// the collider's friction coefficients.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cone {
    pub normal: Vec3,
    pub static_friction: f32,
    pub kinetic_friction: f32,
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
        let cone = Cone { normal: normal.as_vec3(), static_friction: static_friction as f32, kinetic_friction: kinetic_friction as f32 };
        (tangential, Hold::Stuck(cone))
    } else if len > 0.0 {
        (tangential * (kinetic_friction * depth / len).min(1.0), sliding(kinetic_friction))
    } else {
        (DVec3::ZERO, sliding(kinetic_friction))
    }
}

/// Where static friction holds a vertex on a collider standing still: the
/// clear position it stuck at, and the cone of the contact that held it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Anchor {
    pub point: Vec3,
    pub cone: Cone,
}

impl Anchor {
    /// Whether a vertex pulled to `pulled` stays stuck: the pull's part
    /// along the surface, from the anchor, within the static cone of how
    /// far it goes into the surface below the anchor (the law of
    /// [`friction`], measured from the anchor along the anchor's normal).
    pub(crate) fn holds(&self, pulled: Vec3) -> bool {
        let n = self.cone.normal.as_dvec3();
        let (point, pulled) = (self.point.as_dvec3(), pulled.as_dvec3());
        let depth = (point - pulled).dot(n);
        let cone = self.cone;
        depth > 0.0 && matches!(friction(pulled - point, n, depth, cone.static_friction as f64, cone.kinetic_friction as f64).1, Hold::Stuck(_))
    }

    /// A held vertex's end, given where a contact along the unit `normal`
    /// would put it: at the anchor, lifted along the anchor's normal only as
    /// far as that contact's level asks (none if the anchor is above it;
    /// a contact at a steep angle to the anchor's normal is lifted at most
    /// five times its own lift, and the next round checks again).
    pub(crate) fn lift(&self, projected: Vec3, normal: Vec3) -> Vec3 {
        let n = self.cone.normal;
        let below = (projected - self.point).dot(normal);
        self.point + (below.max(0.0) / n.dot(normal).max(0.2)) * n
    }
}

/// The anchors of a skin's stuck vertices, kept from one in-loop pass to
/// the next while the colliders stand still (one substep's solve).
#[derive(Debug, Clone, Default)]
pub struct Anchors {
    by_vertex: HashMap<u32, Anchor>,
}

impl Anchors {
    pub fn new() -> Self {
        Anchors::default()
    }

    pub fn get(&self, vertex: u32) -> Option<&Anchor> {
        self.by_vertex.get(&vertex)
    }

    /// Every anchor with its vertex, in no particular order.
    pub(crate) fn iter(&self) -> impl Iterator<Item = (u32, Anchor)> + '_ {
        self.by_vertex.iter().map(|(&i, &anchor)| (i, anchor))
    }

    pub fn len(&self) -> usize {
        self.by_vertex.len()
    }

    pub fn is_empty(&self) -> bool {
        self.by_vertex.is_empty()
    }

    /// Lets go of the vertices `let_go` names, for the passes that follow:
    /// each is then treated as a vertex newly in contact, stuck or sliding by
    /// the law of [`friction`] from wherever it is when the next pass starts.
    /// How strain limits cap static friction (issue 29): a vertex whose
    /// anchor holds an edge of the skin past its limit is let go before the
    /// strain rounds slide it, so the next pass holds it where the limit
    /// left it rather than putting it back. Returns how many were let go.
    pub fn release(&mut self, let_go: impl Fn(u32) -> bool) -> usize {
        let before = self.by_vertex.len();
        self.by_vertex.retain(|&v, _| !let_go(v));
        before - self.by_vertex.len()
    }

    /// Replaces every anchor by `anchors` (a pass decides them all anew).
    pub(crate) fn replace(&mut self, anchors: HashMap<u32, Anchor>) {
        self.by_vertex = anchors;
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
        assert_eq!((change, hold), (DVec3::new(0.1, 0.0, 0.0), Hold::Stuck(Cone { normal: Vec3::Z, static_friction: 1.0, kinetic_friction: 0.8 })), "0.1 < 1.0 · 0.2");
        let (change, hold) = friction(slip, n, 0.2, 0.4, 0.25);
        assert!((change - DVec3::new(0.05, 0.0, 0.0)).length() < 1e-12, "reduced by 0.25 · 0.2: {change}");
        assert_eq!(hold, Hold::Sliding(Slide { normal: Vec3::Z, friction: 0.25 }));
        let (change, hold) = friction(slip, n, 0.2, 0.0, 0.0);
        assert_eq!((change, hold), (DVec3::ZERO, Hold::Sliding(Slide { normal: Vec3::Z, friction: 0.0 })), "frictionless");
    }

    #[test]
    fn released_vertices_lose_their_anchors_and_the_others_keep_them() {
        let cone = Cone { normal: Vec3::Z, static_friction: 1.0, kinetic_friction: 0.8 };
        let mut anchors = Anchors::new();
        anchors.replace((0..4).map(|v| (v, Anchor { point: Vec3::new(v as f32, 0.0, 0.0), cone })).collect());
        assert_eq!(anchors.release(|v| v % 2 == 1), 2);
        assert_eq!(anchors.len(), 2);
        assert!(anchors.get(1).is_none() && anchors.get(3).is_none());
        assert_eq!(anchors.get(2).map(|a| a.point), Some(Vec3::new(2.0, 0.0, 0.0)));
    }
}
