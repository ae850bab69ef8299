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

use glam::DVec3;

use super::geometry::{point_triangle_distance_squared, segment_segment_distance_squared, unit};

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

    let motion = (0..3).map(|k| (dp - (tri1[k] - tri0[k])).length()).fold(0.0, f64::max);
    let distance = |t: f64| {
        let at = |a: DVec3, b: DVec3| a + t * (b - a);
        point_triangle_distance_squared(at(p0, p1), at(tri0[0], tri1[0]), at(tri0[1], tri1[1]), at(tri0[2], tri1[2]))
            .sqrt()
    };
    apart_over(&distance, motion, clearance, 0.0, 1.0, 0)
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
