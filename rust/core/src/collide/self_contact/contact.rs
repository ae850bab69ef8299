//! One self-contact: the earliest time a candidate pair comes within its
//! separation (conservative CCD, both sides moving), and the projection of
//! the pair's end positions apart, shared between its two sides.
//!
//! The projection is the minimum-norm change (position-based dynamics) of
//! the four corners under the constraint that the contact points end at
//! least the separation apart along the contact normal: with unit inverse
//! masses and gradient weights `g` (the vertex 1 and the triangle's
//! barycentric weights negated, or each edge's `(1 − s, s)` with opposite
//! signs), corner `i` moves by `g_i · λ · n` with `λ = depth / Σ g_k²`.
//! Friction (Bender, Müller and Macklin 2015) removes the two sides'
//! relative slip since the contact, `Δx⊥`, entirely when `|Δx⊥| < μs·depth`
//! (static) and by `μk·depth` otherwise (kinetic), shared the same way.
//!
//! The normal is the direction between the two contact points at the time
//! of contact, where they are about the separation apart (the side each
//! came from); where they touch (no separation, or a graze the tolerance
//! reported early) it is the triangle's normal (the edges' common normal),
//! turned to the side the vertex was on at the start, which was free of
//! intersections.

use glam::{DVec3, Vec3};

use super::gather::ElementPair;
use crate::collide::ccd::{self, CcdHit, CcdParams};
use crate::collide::geometry::{triangle_normal, unit};
use crate::collide::proximity;

/// How one pass treats its contacts.
#[derive(Debug, Clone, Copy)]
pub(super) struct ContactParams {
    /// Added beyond the separation when projecting (rounding, and the
    /// margin that lets the next pass prove a resting pair apart cheaply).
    pub slack: f64,
    /// CCD tolerance (position units).
    pub tolerance: f64,
    pub static_friction: f64,
    pub kinetic_friction: f64,
}

fn d(v: Vec3) -> DVec3 {
    v.as_dvec3()
}

/// The pair's corners at the start and the end of the step. Written out,
/// not `corners.map(…)`, which some builds left an out-of-line
/// `array::try_map` call (issue 30, twenty-sixth round).
#[inline]
fn ends(pair: &ElementPair, start: &[Vec3], end: &[Vec3]) -> ([DVec3; 4], [DVec3; 4]) {
    let [a, b, c, e] = [pair.corners[0] as usize, pair.corners[1] as usize, pair.corners[2] as usize, pair.corners[3] as usize];
    ([d(start[a]), d(start[b]), d(start[c]), d(start[e])], [d(end[a]), d(end[b]), d(end[c]), d(end[e])])
}

/// The earliest contact of `pair` within `separation` over `start → end`.
pub(super) fn first_contact(pair: &ElementPair, start: &[Vec3], end: &[Vec3], separation: f64, tolerance: f64) -> Option<CcdHit> {
    let ([a0, b0, c0, e0], [a1, b1, c1, e1]) = ends(pair, start, end);
    let params = CcdParams { min_separation: separation, tolerance, max_iterations: 400, t_max: 1.0 };
    if pair.edge_edge {
        if proximity::edge_edge_apart([a0, b0], [c0, e0], [a1, b1], [c1, e1], separation) {
            return None;
        }
        match proximity::edge_edge_advance([a0, b0], [c0, e0], [a1, b1], [c1, e1], separation, tolerance, 1.0) {
            Some(hit) if !hit.converged => ccd::edge_edge(a0, b0, c0, e0, a1, b1, c1, e1, &params),
            other => other,
        }
    } else {
        if proximity::vertex_triangle_apart(a0, [b0, c0, e0], a1, [b1, c1, e1], separation) {
            return None;
        }
        proximity::vertex_triangle_advance(a0, [b0, c0, e0], a1, [b1, c1, e1], separation, tolerance, 1.0)
            .filter(|hit| hit.converged)
            .or_else(|| ccd::vertex_triangle(a0, b0, c0, e0, a1, b1, c1, e1, &params))
    }
}

/// The changes of the pair's four end positions that put its contact
/// `separation + slack` apart, with friction; None when the ends already
/// keep the separation.
pub(super) fn correction(pair: &ElementPair, start: &[Vec3], end: &[Vec3], hit: &CcdHit, separation: f64, params: &ContactParams) -> Option<[DVec3; 4]> {
    let (s, e) = ends(pair, start, end);
    let t = hit.toi;
    let at = |k: usize| s[k] + t * (e[k] - s[k]);
    // Gradient weights: the first side's point minus the second side's.
    let g: [f64; 4] = if pair.edge_edge {
        [1.0 - hit.u, hit.u, -(1.0 - hit.v), -hit.v]
    } else {
        [1.0, -(1.0 - hit.u - hit.v), -hit.u, -hit.v]
    };
    let point = |x: [DVec3; 4]| -> DVec3 { (0..4).map(|k| g[k] * x[k]).sum() };
    let gap_t = point([at(0), at(1), at(2), at(3)]);
    let (gap_0, gap_1) = (point(s), point(e));
    let n = match unit(gap_t) {
        Some(n) if gap_t.length() > 0.25 * separation && separation > 0.0 => n,
        _ => {
            let geometric = if pair.edge_edge { unit((e[1] - e[0]).cross(e[3] - e[2])) } else { triangle_normal(e[1], e[2], e[3]) };
            let n = geometric.or_else(|| unit(gap_1)).or_else(|| unit(gap_0))?;
            // The side at the start (free of intersections), else against the relative motion.
            let side = if gap_0.dot(n).abs() > 1e-12 * (1.0 + gap_0.length()) {
                gap_0.dot(n).signum()
            } else if (gap_1 - gap_0).dot(n) != 0.0 {
                -(gap_1 - gap_0).dot(n).signum()
            } else {
                1.0
            };
            side * n
        }
    };
    let distance = gap_1.dot(n);
    if distance >= separation {
        return None;
    }
    let depth = separation + params.slack - distance;
    let norm: f64 = g.iter().map(|w| w * w).sum();
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // a NaN norm must give no correction
    if !(norm > 1e-12) {
        return None;
    }
    let mut delta = g.map(|w| w * depth / norm * n);
    if params.static_friction > 0.0 || params.kinetic_friction > 0.0 {
        // The relative slip since the contact, tangential to the normal.
        let slip = (gap_1 + depth * n) - gap_t;
        let tangential = slip - slip.dot(n) * n;
        let len = tangential.length();
        if len > 0.0 {
            let removed = if len < params.static_friction * depth { tangential } else { tangential * (params.kinetic_friction * depth / len).min(1.0) };
            for k in 0..4 {
                delta[k] -= g[k] / norm * removed;
            }
        }
    }
    delta.iter().all(|x| x.is_finite()).then_some(delta)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f32, y: f32, z: f32) -> Vec3 {
        Vec3::new(x, y, z)
    }

    const PARAMS: ContactParams = ContactParams { slack: 1e-4, tolerance: 1e-7, static_friction: 0.0, kinetic_friction: 0.0 };

    #[test]
    fn a_vertex_falling_through_a_triangle_is_stopped_both_sides_sharing() {
        let pair = ElementPair { edge_edge: false, corners: [0, 1, 2, 3] };
        let start = [v(0.2, 0.2, 0.5), v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0)];
        let mut end = start;
        end[0].z = -0.5;
        let hit = first_contact(&pair, &start, &end, 0.01, 1e-7).expect("it falls through");
        let delta = correction(&pair, &start, &end, &hit, 0.01, &PARAMS).expect("it needs a correction");
        let fixed: Vec<Vec3> = (0..4).map(|k| end[k] + delta[k].as_vec3()).collect();
        // The vertex is back above the triangle by the separation.
        let plane_z = fixed[1].z + 0.2 * (fixed[2].z - fixed[1].z) + 0.2 * (fixed[3].z - fixed[1].z);
        assert!(fixed[0].z - plane_z >= 0.01 - 1e-6, "{fixed:?}");
        // Both sides moved: the vertex up, the triangle down.
        assert!(delta[0].z > 0.0 && delta[1].z < 0.0 && delta[2].z < 0.0 && delta[3].z < 0.0);
        // The momentum-like sum of the weighted changes is zero (shared, not imposed).
        let total: DVec3 = delta.iter().copied().sum();
        assert!(total.length() < 1e-9 * (1.0 + delta[0].length()) || total.z.abs() < delta[0].z, "{total:?}");
        // Nothing to do when it stays above.
        let mut above = start;
        above[0].z = 0.3;
        assert!(first_contact(&pair, &start, &above, 0.01, 1e-7).is_none());
    }

    #[test]
    fn crossing_edges_are_pushed_apart_to_the_sides_they_came_from() {
        let pair = ElementPair { edge_edge: true, corners: [0, 1, 2, 3] };
        let start = [v(-1.0, 0.0, 0.1), v(1.0, 0.0, 0.1), v(0.0, -1.0, -0.1), v(0.0, 1.0, -0.1)];
        let end = [v(-1.0, 0.0, -0.1), v(1.0, 0.0, -0.1), v(0.0, -1.0, 0.1), v(0.0, 1.0, 0.1)];
        let hit = first_contact(&pair, &start, &end, 0.02, 1e-7).expect("they cross");
        let delta = correction(&pair, &start, &end, &hit, 0.02, &PARAMS).expect("correction");
        let fixed: Vec<Vec3> = (0..4).map(|k| end[k] + delta[k].as_vec3()).collect();
        let (za, zb) = (0.5 * (fixed[0].z + fixed[1].z), 0.5 * (fixed[2].z + fixed[3].z));
        assert!(za - zb >= 0.02 - 1e-6, "edge a must stay above edge b: {za} {zb}");
    }

    #[test]
    fn static_friction_stops_the_slip_kinetic_slows_it() {
        let pair = ElementPair { edge_edge: false, corners: [0, 1, 2, 3] };
        let start = [v(0.2, 0.2, 0.011), v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0)];
        let end = [v(0.3, 0.2, -0.05), v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0)];
        let hit = first_contact(&pair, &start, &end, 0.01, 1e-7).expect("contact");
        // The vertex's offset along x from the triangle's contact point, at the end.
        let slip = |mu: f64| {
            let params = ContactParams { static_friction: mu, kinetic_friction: mu, ..PARAMS };
            let delta = correction(&pair, &start, &end, &hit, 0.01, &params).unwrap();
            let x: Vec<DVec3> = (0..4).map(|k| end[k].as_dvec3() + delta[k]).collect();
            let q = x[1] + hit.u * (x[2] - x[1]) + hit.v * (x[3] - x[1]);
            x[0].x - q.x
        };
        let free = slip(0.0);
        let held = slip(10.0);
        assert!(free > 0.05, "without friction it slides: {free}");
        assert!(held.abs() < 0.05 * free, "with static friction it holds: {held} against {free}");
        let slowed = slip(0.5);
        assert!(slowed > held.abs() && slowed < free, "kinetic friction slows it: {slowed}");
    }
}
