//! Cheap proofs of separation that spare most pairs the interval CCD.
//!
//! Resting contact is the common case: after a projection a skin vertex sits
//! just outside the thickness of a collider triangle, and every later step
//! moves it a little along the surface. The conservative interval search in
//! [`super::ccd`] has to shrink its boxes below the slack left by the
//! projection before it can prove such a pair apart, hundreds of boxes per
//! pair. Two cheaper certificates prove most of them apart in a few dozen
//! flops; a `false` answer proves nothing, it only means "ask the CCD".
//!
//! 1. **A separating plane.** Move into the frame of one primitive's first
//!    corner, so that it translates not at all; its remaining corners move by
//!    at most `r` (zero for rigidly translating or still colliders, the common
//!    case). Every point of the other primitive is an affine combination of
//!    its corners, and each corner moves linearly in time, so its signed
//!    distance to a fixed plane is bilinear and takes its extremes at the
//!    corners at the start and the end of the step. If all of them lie beyond
//!    `separation + r` on the same side of a plane containing the first
//!    primitive, the pair stays apart. Planes tried: the triangle's own plane,
//!    and the plane through the vertex (or the edge) facing the other
//!    primitive.
//! 2. **Sampled distance with a motion bound.** The distance vector
//!    `F(t, u, v)` of a pair changes with `t` by a convex combination of the
//!    relative corner motions, so `|F(t', u, v)| ≥ dist(t) − |t' − t|·m` with
//!    `m` the largest relative corner motion and `dist(t)` the exact minimum
//!    distance of the primitives frozen at `t`. A few bisections of the step
//!    prove pairs that stay well apart while moving fast.
//!
//! 3. **A slab between a skin element and a whole neighbourhood of the
//!    collider** ([`separated_along`]): the same bilinearity, with the plane
//!    replaced by a direction. If, along a unit direction `n`, every corner of
//!    the skin element stays beyond every corner of the collider's nearby
//!    triangles by more than `separation` (in a frame that translates with
//!    the collider), no point of the one comes within `separation` of a point
//!    of the other: one test for all the pairs of a resting contact, where 1
//!    and 2 take one test per pair.
//!
//! The same bound finds first contacts: **conservative advancement**
//! (Mirtich 1996) steps time forward by `(dist(t) − separation) / m`, a step
//! in which no contact can occur, until the gap is within the tolerance (a
//! contact, reported with the closest points' parameters) or the step ends
//! (none). Where it would need too many steps (a grazing pass) it stops and
//! reports its time as an unconverged contact, which is early, never late:
//! the caller's projection then finds nothing to correct if there is none.

use glam::DVec3;

use super::ccd::CcdHit;
use super::geometry::{closest_on_segments, closest_on_triangle, point_triangle_distance_squared, segment_segment_distance_squared, unit};

/// [`separated_along`] against a collider standing still, whose points
/// (`collider`, each measured once) are no larger in magnitude than
/// `collider_scale`: the element's corners (`element`, at both ends of the
/// step) on one side of a slab of direction `n`, the collider's on the
/// other, farther apart than `separation`. With the bound on the collider's
/// magnitude given, each of its points costs one dot product, where a
/// whole patch is measured at once (`response::star`).
pub fn separated_along_still(n: DVec3, element: &[DVec3], collider: impl Iterator<Item = DVec3>, collider_scale: f64, separation: f64) -> bool {
    let mut scale = collider_scale;
    let mut own = (f64::INFINITY, f64::NEG_INFINITY);
    for &p in element {
        let h = n.dot(p);
        own = (own.0.min(h), own.1.max(h));
        scale = scale.max(p.abs().max_element());
    }
    let mut other = (f64::INFINITY, f64::NEG_INFINITY);
    for p in collider {
        let h = n.dot(p);
        other = (other.0.min(h), other.1.max(h));
    }
    // NaN heights fail both comparisons: nothing proven.
    let clearance = separation + RELATIVE_MARGIN * scale;
    own.0 - other.1 > clearance || other.0 - own.1 > clearance
}

/// Halvings of the step before the sampled test gives up: at most 2⁸ − 1
/// distance evaluations (a few µs), usually one, still far cheaper than the
/// interval search it spares. A contact sliding over a curved collider needs
/// the deep end: its clearance is the projection slack, its motion far more.
const MAX_DEPTH: u32 = 7;

/// Relative rounding allowance of the distance computations: far above the
/// few ulps they lose, far below the CCD tolerance (1e-6 of the scene scale).
const RELATIVE_MARGIN: f64 = 1e-9;

/// True when vertex `p` and triangle `tri`, moving linearly from their
/// `…0` to their `…1` positions, provably stay farther apart than
/// `separation` over the whole step.
pub fn vertex_triangle_apart(p0: DVec3, tri0: [DVec3; 3], p1: DVec3, tri1: [DVec3; 3], separation: f64) -> bool {
    if vertex_triangle_apart_by_plane(p0, tri0, p1, tri1, separation) {
        return true;
    }
    let scale = max_abs(&[p0, p1, tri0[0], tri0[1], tri0[2], tri1[0], tri1[1], tri1[2]]);
    let clearance = separation + RELATIVE_MARGIN * scale;
    let dp = p1 - p0;
    let motion = (0..3).map(|k| (dp - (tri1[k] - tri0[k])).length()).fold(0.0, f64::max);
    let distance = |t: f64| {
        let at = |a: DVec3, b: DVec3| a + t * (b - a);
        point_triangle_distance_squared(at(p0, p1), at(tri0[0], tri1[0]), at(tri0[1], tri1[1]), at(tri0[2], tri1[2]))
            .sqrt()
    };
    apart_over(&distance, motion, clearance, 0.0, 1.0, 0)
}

/// The plane certificates of [`vertex_triangle_apart`] alone (the
/// triangle's plane, the plane through the vertex facing the triangle),
/// without the sampled distances: for a still or translating triangle,
/// whose exact first contact has a closed form that costs less than sampling.
pub fn vertex_triangle_apart_by_plane(p0: DVec3, tri0: [DVec3; 3], p1: DVec3, tri1: [DVec3; 3], separation: f64) -> bool {
    let scale = max_abs(&[p0, p1, tri0[0], tri0[1], tri0[2], tri1[0], tri1[1], tri1[2]]);
    let clearance = separation + RELATIVE_MARGIN * scale;

    // The triangle's plane, in the frame of its first corner.
    let shift = tri1[0] - tri0[0];
    let residual = (1..3).map(|k| (tri1[k] - tri0[k] - shift).length()).fold(0.0, f64::max);
    if let Some(n) = unit((tri0[1] - tri0[0]).cross(tri0[2] - tri0[0])) {
        if one_side(n, tri0[0], &[p0, p1 - shift], clearance + residual) {
            return true;
        }
    }
    // The plane through the vertex facing the triangle, in the vertex's frame.
    let dp = p1 - p0;
    let centroid = (tri0[0] + tri0[1] + tri0[2]) / 3.0;
    if let Some(n) = unit(centroid - p0) {
        let corners = [tri0[0], tri0[1], tri0[2], tri1[0] - dp, tri1[1] - dp, tri1[2] - dp];
        if one_side(n, p0, &corners, clearance) {
            return true;
        }
    }
    false
}

/// True when every point of a skin primitive whose corners move from
/// `start` to `end` stays beyond `separation` on one side of the plane of
/// triangle `tri` (moving from `tri0` to `tri1`), which proves the primitive
/// apart from the triangle *and its edges* at once: one test where the three
/// edge–edge filters would take three.
pub fn beyond_triangle_plane(tri0: [DVec3; 3], tri1: [DVec3; 3], start: &[DVec3], end: &[DVec3], separation: f64) -> bool {
    let Some(n) = unit((tri0[1] - tri0[0]).cross(tri0[2] - tri0[0])) else { return false };
    let shift = tri1[0] - tri0[0];
    let residual = (1..3).map(|k| (tri1[k] - tri0[k] - shift).length()).fold(0.0, f64::max);
    let mut points = [DVec3::ZERO; 8];
    let count = start.len() + end.len();
    if count > points.len() {
        return false;
    }
    for (slot, p) in points.iter_mut().zip(start.iter().copied().chain(end.iter().map(|&p| p - shift))) {
        *slot = p;
    }
    let scale = max_abs(&points[..count]).max(max_abs(&tri0)).max(max_abs(&tri1));
    one_side(n, tri0[0], &points[..count], separation + RELATIVE_MARGIN * scale + residual)
}

/// True when, along the unit direction `n`, every corner of a skin element
/// (`skin_start` → `skin_end`) stays farther than `separation` from every
/// collider point (`collider` yields each point's start and end), all on one
/// side, over the whole step: then every point of the element is farther than
/// `separation` from every point of the collider primitives those points span.
///
/// Heights are measured in a frame that moves by `t·shift` (any vector; the
/// collider's translation makes the test sharp for a translating collider,
/// zero for a still one). In it each corner's height is linear in time, and a
/// point of a primitive is a convex combination of the primitive's corners at
/// the same time, so the corners' heights at the two ends of the step bound
/// every point's height at every time; the distance of two points is at least
/// the difference of their heights.
pub fn separated_along(n: DVec3, shift: DVec3, skin_start: &[DVec3], skin_end: &[DVec3], collider: impl Iterator<Item = (DVec3, DVec3)>, separation: f64) -> bool {
    let mut scale = shift.abs().max_element();
    let mut skin = (f64::INFINITY, f64::NEG_INFINITY);
    let add = |range: &mut (f64, f64), scale: &mut f64, p: DVec3| {
        let h = n.dot(p);
        *range = (range.0.min(h), range.1.max(h));
        *scale = scale.max(p.abs().max_element());
    };
    for &p in skin_start {
        add(&mut skin, &mut scale, p);
    }
    for &p in skin_end {
        add(&mut skin, &mut scale, p - shift);
    }
    let mut other = (f64::INFINITY, f64::NEG_INFINITY);
    for (p0, p1) in collider {
        add(&mut other, &mut scale, p0);
        add(&mut other, &mut scale, p1 - shift);
    }
    // NaN heights fail both comparisons: nothing proven.
    let clearance = separation + RELATIVE_MARGIN * scale;
    skin.0 - other.1 > clearance || other.0 - skin.1 > clearance
}

/// True when edges `a` and `b`, each end moving linearly from the `…0` to the
/// `…1` positions, provably stay farther apart than `separation` over the step.
pub fn edge_edge_apart(a0: [DVec3; 2], b0: [DVec3; 2], a1: [DVec3; 2], b1: [DVec3; 2], separation: f64) -> bool {
    let scale = max_abs(&[a0[0], a0[1], b0[0], b0[1], a1[0], a1[1], b1[0], b1[1]]);
    let clearance = separation + RELATIVE_MARGIN * scale;

    // Planes containing edge `b`, in the frame of its first end, facing the
    // middle of `a` at the start and at the end of the step.
    let shift = b1[0] - b0[0];
    let residual = (b1[1] - b0[1] - shift).length();
    let corners = [a0[0], a0[1], a1[0] - shift, a1[1] - shift];
    let axis = b0[1] - b0[0];
    for middle in [0.5 * (corners[0] + corners[1]), 0.5 * (corners[2] + corners[3])] {
        let towards = middle - b0[0];
        let along = axis.length_squared();
        let perpendicular = if along > 0.0 { towards - axis * (towards.dot(axis) / along) } else { towards };
        if let Some(n) = unit(perpendicular) {
            if one_side(n, b0[0], &corners, clearance + residual) {
                return true;
            }
        }
    }

    let mut motion: f64 = 0.0;
    for i in 0..2 {
        for j in 0..2 {
            motion = motion.max(((a1[i] - a0[i]) - (b1[j] - b0[j])).length());
        }
    }
    let distance = |t: f64| {
        let at = |x: DVec3, y: DVec3| x + t * (y - x);
        segment_segment_distance_squared(at(a0[0], a1[0]), at(a0[1], a1[1]), at(b0[0], b1[0]), at(b0[1], b1[1])).sqrt()
    };
    apart_over(&distance, motion, clearance, 0.0, 1.0, 0)
}

/// Steps of conservative advancement before it settles for an early,
/// unconverged contact time.
const MAX_ADVANCES: usize = 64;

/// First time vertex `p` comes within `separation + tolerance` of triangle
/// `tri` (both moving linearly over the step, up to `t_max`), by conservative
/// advancement: never later than the true first contact within `separation`.
/// `u`, `v` of the hit are the barycentric weights of the triangle's second
/// and third corners at the closest point.
pub fn vertex_triangle_advance(
    p0: DVec3,
    tri0: [DVec3; 3],
    p1: DVec3,
    tri1: [DVec3; 3],
    separation: f64,
    tolerance: f64,
    t_max: f64,
) -> Option<CcdHit> {
    let dp = p1 - p0;
    let motion = (0..3).map(|k| (dp - (tri1[k] - tri0[k])).length()).fold(0.0, f64::max);
    let closest = |t: f64| {
        let at = |a: DVec3, b: DVec3| a + t * (b - a);
        let (p, a, b, c) = (at(p0, p1), at(tri0[0], tri1[0]), at(tri0[1], tri1[1]), at(tri0[2], tri1[2]));
        let (u, v) = closest_on_triangle(p, a, b, c);
        ((p - (a + u * (b - a) + v * (c - a))).length(), u, v)
    };
    advance(closest, motion, separation, tolerance, t_max)
}

/// First time edges `a` and `b` (ends moving linearly over the step) come
/// within `separation + tolerance`, by conservative advancement; `u` is the
/// closest point's position along `a`, `v` along `b`.
pub fn edge_edge_advance(
    a0: [DVec3; 2],
    b0: [DVec3; 2],
    a1: [DVec3; 2],
    b1: [DVec3; 2],
    separation: f64,
    tolerance: f64,
    t_max: f64,
) -> Option<CcdHit> {
    let mut motion: f64 = 0.0;
    for i in 0..2 {
        for j in 0..2 {
            motion = motion.max(((a1[i] - a0[i]) - (b1[j] - b0[j])).length());
        }
    }
    let closest = |t: f64| {
        let at = |x: DVec3, y: DVec3| x + t * (y - x);
        let (s, r, d2) = closest_on_segments(at(a0[0], a1[0]), at(a0[1], a1[1]), at(b0[0], b1[0]), at(b0[1], b1[1]));
        (d2.sqrt(), s, r)
    };
    advance(closest, motion, separation, tolerance, t_max)
}

fn advance(
    closest: impl Fn(f64) -> (f64, f64, f64),
    motion: f64,
    separation: f64,
    tolerance: f64,
    t_max: f64,
) -> Option<CcdHit> {
    let t_max = if t_max > 0.0 && t_max <= 1.0 { t_max } else { 1.0 };
    let mut t = 0.0;
    for _ in 0..MAX_ADVANCES {
        let (gap, u, v) = closest(t);
        if !gap.is_finite() {
            return Some(CcdHit { toi: t, u: 0.0, v: 0.0, converged: false });
        }
        if gap <= separation + tolerance {
            return Some(CcdHit { toi: t, u, v, converged: true });
        }
        if motion <= 0.0 {
            return None;
        }
        // The safe step is (gap − separation) / motion; stopping short of
        // it by the tolerance's worth keeps rounding on the safe side and
        // lets a true contact be met within the tolerance.
        t += (gap - separation - 0.5 * tolerance) / motion;
        if t > t_max {
            return None;
        }
    }
    let (_, u, v) = closest(t);
    Some(CcdHit { toi: t, u, v, converged: false })
}

/// Whether every point lies farther than `clearance` from the plane through
/// `origin` with unit normal `n`, all on the same side.
fn one_side(n: DVec3, origin: DVec3, points: &[DVec3], clearance: f64) -> bool {
    let heights = points.iter().map(|&p| n.dot(p - origin));
    let (low, high) = heights.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), h| (lo.min(h), hi.max(h)));
    low > clearance || high < -clearance
}

fn apart_over(distance: &impl Fn(f64) -> f64, motion: f64, clearance: f64, t0: f64, t1: f64, depth: u32) -> bool {
    let mid = 0.5 * (t0 + t1);
    let d = distance(mid);
    if !(d > clearance) {
        // Too close at a real instant (or NaN): only the CCD can say more.
        return false;
    }
    if d - motion * 0.5 * (t1 - t0) > clearance {
        return true;
    }
    depth < MAX_DEPTH
        && apart_over(distance, motion, clearance, t0, mid, depth + 1)
        && apart_over(distance, motion, clearance, mid, t1, depth + 1)
}

fn max_abs(points: &[DVec3]) -> f64 {
    points.iter().map(|p| p.abs().max_element()).fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn d(x: f64, y: f64, z: f64) -> DVec3 {
        DVec3::new(x, y, z)
    }

    fn tri() -> [DVec3; 3] {
        [d(0.0, 0.0, 0.0), d(1.0, 0.0, 0.0), d(0.0, 1.0, 0.0)]
    }

    #[test]
    fn sliding_just_outside_the_thickness_is_apart() {
        let (p0, p1) = (d(0.2, 0.2, 0.0105), d(0.4, 0.3, 0.0105));
        assert!(vertex_triangle_apart(p0, tri(), p1, tri(), 0.01));
        assert!(!vertex_triangle_apart(p0, tri(), d(0.4, 0.3, 0.0095), tri(), 0.01));
    }

    #[test]
    fn passing_through_is_never_apart() {
        assert!(!vertex_triangle_apart(d(0.2, 0.2, 1.0), tri(), d(0.2, 0.2, -1.0), tri(), 0.0));
        let a0 = [d(0.5, -1.0, 1.0), d(0.5, 1.0, 1.0)];
        let a1 = [d(0.5, -1.0, -1.0), d(0.5, 1.0, -1.0)];
        let b = [d(-1.0, 0.0, 0.0), d(1.0, 0.0, 0.0)];
        assert!(!edge_edge_apart(a0, b, a1, b, 0.0));
    }

    fn point() -> impl Strategy<Value = DVec3> {
        (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64).prop_map(|(x, y, z)| d(x, y, z))
    }

    /// The densely sampled minimum distance over the step, a lower estimate
    /// of nothing but an exact value at each sample: if the filter says
    /// "apart", every sample must be farther than the separation.
    fn sampled_min(distance: impl Fn(f64) -> f64) -> f64 {
        (0..=2000).map(|k| distance(k as f64 / 2000.0)).fold(f64::INFINITY, f64::min)
    }

    /// Cases in which [`a_slab_is_never_wrong`] had something to check.
    static SLABS_PROVEN: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

    #[test]
    fn the_slab_property_test_proves_cases() {
        a_slab_is_never_wrong();
        assert!(SLABS_PROVEN.load(std::sync::atomic::Ordering::Relaxed) > 200, "too few separated cases to check");
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

        #[test]
        fn vertex_triangle_apart_is_never_wrong(p0 in point(), p1 in point(), a0 in point(), b0 in point(),
                                                 c0 in point(), shift in point(), sep in 0.0..0.3f64) {
            let tri0 = [a0, b0, c0];
            let tri1 = [a0 + shift, b0 + 0.5 * shift, c0];
            if vertex_triangle_apart(p0, tri0, p1, tri1, sep) {
                let min = sampled_min(|t| {
                    let at = |x: DVec3, y: DVec3| x + t * (y - x);
                    point_triangle_distance_squared(at(p0, p1), at(tri0[0], tri1[0]), at(tri0[1], tri1[1]), at(tri0[2], tri1[2])).sqrt()
                });
                prop_assert!(min > sep, "filter said apart but the distance reaches {min} <= {sep}");
            }
        }

        #[test]
        fn a_slab_is_never_wrong(p0 in point(), p1 in point(), q0 in point(), a0 in point(), b0 in point(), c0 in point(),
                                 motion in point(), wobble in point(), dir in point(), lift in 0.0..2.5f64, sep in 0.0..0.3f64) {
            // A skin edge, lifted along `dir` so that about half the cases
            // are separated, against a moving collider triangle; the frame
            // translates with the triangle's first corner.
            let (p0, p1, q0) = (p0 * 0.5 + lift * dir, p1 * 0.5 + lift * dir, q0 * 0.5 + lift * dir);
            let q1 = q0 + 0.3 * motion;
            let tri0 = [a0, b0, c0];
            let tri1 = [a0 + 0.2 * motion, b0 + 0.2 * motion + 0.05 * wobble, c0 + 0.2 * motion];
            let shift = tri1[0] - tri0[0];
            for n in [unit(dir), unit(q0 - a0), unit((b0 - a0).cross(c0 - a0))].into_iter().flatten() {
                let pairs = (0..3).map(|k| (tri0[k], tri1[k]));
                if separated_along(n, shift, &[p0, q0], &[p1, q1], pairs, sep) {
                    // Sampled over time and along the segment (a few hundred
                    // thousand distances per case would make the test slow).
                    let mut min = f64::INFINITY;
                    for i in 0..=200 {
                        let t = i as f64 / 200.0;
                        let at = |x: DVec3, y: DVec3| x + t * (y - x);
                        let (a, b, c) = (at(tri0[0], tri1[0]), at(tri0[1], tri1[1]), at(tri0[2], tri1[2]));
                        let (p, q) = (at(p0, p1), at(q0, q1));
                        for k in 0..=20 {
                            min = min.min(point_triangle_distance_squared(p + k as f64 / 20.0 * (q - p), a, b, c).sqrt());
                        }
                    }
                    prop_assert!(min > sep, "slab said apart but the distance reaches {min} <= {sep}");
                    SLABS_PROVEN.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
            }
        }

        #[test]
        fn translating_triangle_apart_is_never_wrong(p0 in point(), p1 in point(), a0 in point(), b0 in point(),
                                                     c0 in point(), shift in point(), sep in 0.0..0.3f64) {
            let tri0 = [a0, b0, c0];
            let tri1 = tri0.map(|x| x + 0.2 * shift);
            let near = p0 * 0.1 + a0 * 0.9;
            for (s, e) in [(p0, p1), (near, near + 0.05 * (p1 - p0))] {
                if vertex_triangle_apart(s, tri0, e, tri1, sep) {
                    let min = sampled_min(|t| {
                        let at = |x: DVec3, y: DVec3| x + t * (y - x);
                        point_triangle_distance_squared(at(s, e), at(tri0[0], tri1[0]), at(tri0[1], tri1[1]), at(tri0[2], tri1[2])).sqrt()
                    });
                    prop_assert!(min > sep, "filter said apart but the distance reaches {min} <= {sep}");
                }
            }
        }

        #[test]
        fn edge_edge_apart_is_never_wrong(a in point(), b in point(), c in point(), e in point(),
                                          da in point(), db in point(), sep in 0.0..0.3f64) {
            let (a0, b0) = ([a, b], [c, e]);
            let (a1, b1) = ([a + da, b + 0.3 * da], [c + db, e]);
            if edge_edge_apart(a0, b0, a1, b1, sep) {
                let min = sampled_min(|t| {
                    let at = |x: DVec3, y: DVec3| x + t * (y - x);
                    segment_segment_distance_squared(at(a0[0], a1[0]), at(a0[1], a1[1]), at(b0[0], b1[0]), at(b0[1], b1[1])).sqrt()
                });
                prop_assert!(min > sep, "filter said apart but the distance reaches {min} <= {sep}");
            }
        }

        /// Conservative advancement is never later than the first sampled
        /// contact, and what it reports as converged is a contact.
        #[test]
        fn advancement_is_never_late(p0 in point(), p1 in point(), a in point(), b in point(), c in point(),
                                     shift in point(), e in point(), sep in 0.0..0.2f64) {
            let tri0 = [a, b, c];
            let tri1 = [a + shift, b + 0.5 * shift, c - 0.2 * shift];
            let tol = 1e-4;
            let found = vertex_triangle_advance(p0, tri0, p1, tri1, sep, tol, 1.0);
            let gap = |t: f64| {
                let at = |x: DVec3, y: DVec3| x + t * (y - x);
                point_triangle_distance_squared(at(p0, p1), at(tri0[0], tri1[0]), at(tri0[1], tri1[1]), at(tri0[2], tri1[2])).sqrt()
            };
            if let Some(first) = (0..=2000).map(|k| k as f64 / 2000.0).find(|&t| gap(t) < sep) {
                let hit = found.expect("advancement missed a sampled contact");
                prop_assert!(hit.toi <= first + 1e-9);
            }
            if let Some(hit) = found.filter(|h| h.converged) {
                prop_assert!(gap(hit.toi) <= sep + tol + 1e-9);
            }
            let (a0, b0, a1, b1) = ([p0, p1], [a, b], [p0 + shift, e], [a, b - shift]);
            let found = edge_edge_advance(a0, b0, a1, b1, sep, tol, 1.0);
            let gap = |t: f64| {
                let at = |x: DVec3, y: DVec3| x + t * (y - x);
                segment_segment_distance_squared(at(a0[0], a1[0]), at(a0[1], a1[1]), at(b0[0], b1[0]), at(b0[1], b1[1])).sqrt()
            };
            if let Some(first) = (0..=2000).map(|k| k as f64 / 2000.0).find(|&t| gap(t) < sep) {
                let hit = found.expect("advancement missed a sampled edge contact");
                prop_assert!(hit.toi <= first + 1e-9);
            }
        }

        #[test]
        fn segment_distance_is_not_above_any_sampled_pair(a in point(), b in point(), c in point(), e in point()) {
            let exact = segment_segment_distance_squared(a, b, c, e).sqrt();
            let mut sampled = f64::INFINITY;
            for i in 0..=60 {
                for j in 0..=60 {
                    let (s, t) = (i as f64 / 60.0, j as f64 / 60.0);
                    sampled = sampled.min((a + s * (b - a) - (c + t * (e - c))).length());
                }
            }
            prop_assert!(exact <= sampled + 1e-12);
            // ... and close to it: the grid is within half a cell of the optimum.
            prop_assert!(sampled - exact <= ((b - a).length() + (e - c).length()) / 60.0 + 1e-12);
        }
    }
}
