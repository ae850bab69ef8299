//! Small geometry of one contact: when a path enters a box, and which side
//! of an open collider the skin belongs on.

use glam::DVec3;

use super::{ColliderMotion, ColliderSet, ResolveParams};
use crate::collide::friction::{friction, Hold, Slide};
use crate::collide::geometry::unit;
use crate::collide::planes::resting_reference;

impl<'a> ColliderSet<'a> {
    /// How an edge–edge or collider-corner contact of collider `c` moves the
    /// skin's contact point: out along the unit `n` by `depth`, less what
    /// friction holds of its slip relative to the collider since contact
    /// (the law of [`friction`], as for a vertex on a triangle; on a still
    /// collider measured from where the point rests, see
    /// [`resting_reference`]), and how that leaves it. Pairs are
    /// `[skin point, collider point]` at contact, at the start and at the
    /// end of the step.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn shared_contact_change(
        &self,
        c: usize,
        params: &ResolveParams,
        n: DVec3,
        depth: f64,
        [pt, rt]: [DVec3; 2],
        [p0, r0]: [DVec3; 2],
        [p1, r1]: [DVec3; 2],
    ) -> (DVec3, Hold) {
        let settings = self.colliders[c].settings();
        let push = depth * n;
        if !params.friction || (settings.static_friction <= 0.0 && settings.kinetic_friction <= 0.0) {
            return (push, Hold::Sliding(Slide { normal: n.as_vec3(), friction: 0.0 }));
        }
        let contact = match params.motion {
            ColliderMotion::AtCurrent => {
                let sep = settings.thickness as f64;
                resting_reference((p0 - r0).dot(n) - sep, self.slack(sep), p0, pt)
            }
            ColliderMotion::Swept => pt,
        };
        let (change, hold) = friction((p1 + push - contact) - (r1 - rt), n, depth, settings.static_friction as f64, settings.kinetic_friction as f64);
        (push - change, hold)
    }
}

/// Side (+1/−1 along the triangle normal) an open collider's contact is
/// resolved to: where the vertex was just before contact, else at the start,
/// else opposite to the relative motion, else the normal's side.
#[allow(clippy::too_many_arguments)]
pub(super) fn open_side(
    s: DVec3,
    e: DVec3,
    xt: DVec3,
    qt: DVec3,
    q0: DVec3,
    q1: DVec3,
    nt: Option<DVec3>,
    n0: Option<DVec3>,
    n1: DVec3,
    sep: f64,
) -> f64 {
    let at_contact = nt.map_or(0.0, |n| (xt - qt).dot(n) * n.dot(n1).signum());
    let at_start = n0.map_or(0.0, |n| (s - q0).dot(n) * n.dot(n1).signum());
    open_side_generic(at_contact, at_start, ((e - s) - (q1 - q0)).dot(n1), sep)
}

pub(super) fn open_side_generic(at_contact: f64, at_start: f64, relative_motion: f64, sep: f64) -> f64 {
    let tiny = 1e-12;
    if at_contact.abs() > (0.25 * sep).max(tiny) {
        at_contact.signum()
    } else if at_start.abs() > tiny {
        at_start.signum()
    } else if relative_motion.abs() > tiny {
        -relative_motion.signum()
    } else {
        1.0
    }
}

/// The normal along which a contact is resolved, given the normal the
/// contact's own geometry suggests (`n1`, if any). Against a closed collider,
/// `n1` turned to the outside unless it is nearly perpendicular to it, else
/// the outside itself (`outward`, from the adjacent faces); against an open
/// one, `n1` (or the direction between the points at the end) turned to the
/// side the skin came from ([`open_side_generic`]). Pairs are
/// `[skin point, collider point]` at contact (`t`), at the start and at the
/// end.
#[allow(clippy::too_many_arguments)]
pub(super) fn contact_normal(
    closed: bool,
    outward: impl FnOnce() -> Option<DVec3>,
    n1: Option<DVec3>,
    [pt, rt]: [DVec3; 2],
    [p0, r0]: [DVec3; 2],
    [p1, r1]: [DVec3; 2],
    sep: f64,
) -> Option<DVec3> {
    if closed {
        let out = outward()?;
        Some(match n1 {
            Some(n) if n.dot(out).abs() > 0.2 => n * n.dot(out).signum(),
            _ => out,
        })
    } else {
        let n1 = n1.or_else(|| unit(p1 - r1))?;
        let side = open_side_generic((pt - rt).dot(n1), (p0 - r0).dot(n1), ((p1 - p0) - (r1 - r0)).dot(n1), sep);
        Some(side * n1)
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::collide::bvh::Bounds;
    use proptest::prelude::*;

    fn point() -> impl Strategy<Value = DVec3> {
        (-2.0f64..2.0, -2.0f64..2.0, -2.0f64..2.0).prop_map(|(x, y, z)| DVec3::new(x, y, z))
    }

    proptest! {
        /// No point of the path before its entry time lies in the (grown)
        /// box, and a path said to miss it has no point in it at all.
        #[test]
        fn a_path_is_never_in_a_box_before_it_enters_it(s in point(), e in point(), a in point(), b in point(), axis_aligned in any::<bool>()) {
            let e = if axis_aligned { DVec3::new(s.x, s.y, e.z) } else { e };
            let bounds = Bounds::of_points(&[a.as_vec3(), b.as_vec3()]);
            let grow = 0.01;
            let (lo, hi) = (bounds.min.as_dvec3() - grow, bounds.max.as_dvec3() + grow);
            let inside = |p: DVec3| p.cmpge(lo).all() && p.cmple(hi).all();
            let entry = bounds.entry_time(s, e, grow);
            for k in 0..=400 {
                let t = k as f64 / 400.0;
                if inside(s.lerp(e, t)) {
                    prop_assert!(entry.is_some_and(|entry| entry <= t + 1e-12), "in the box at {t}, entry {entry:?}");
                }
            }
        }
    }

    #[test]
    fn entry_times_of_simple_paths() {
        let unit = Bounds { min: Vec3::ZERO, max: Vec3::ONE };
        let at = |s: [f64; 3], e: [f64; 3]| unit.entry_time(DVec3::from(s), DVec3::from(e), 0.0);
        assert_eq!(at([-1.0, 0.5, 0.5], [3.0, 0.5, 0.5]), Some(0.25));
        assert_eq!(at([0.5, 0.5, 0.5], [3.0, 0.5, 0.5]), Some(0.0), "starting inside");
        assert_eq!(at([-1.0, 2.0, 0.5], [3.0, 2.0, 0.5]), None, "passing beside");
        assert_eq!(at([-3.0, 0.5, 0.5], [-2.0, 0.5, 0.5]), None, "stopping short");
    }
}

