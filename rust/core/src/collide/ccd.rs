//! Conservative continuous collision detection: vertex–triangle and edge–edge.
//!
//! The method follows Tight-Inclusion (Wang et al. 2021): the distance vector
//! between the two primitives is a *multilinear* function of the time `t` and
//! the two surface parameters `u`, `v`,
//!
//! * vertex–triangle: `F(t,u,v) = p(t) − a(t) − u·(b(t) − a(t)) − v·(c(t) − a(t))`
//! * edge–edge:       `F(t,u,v) = a0(t) + u·(a1(t) − a0(t)) − b0(t) − v·(b1(t) − b0(t))`
//!
//! with every point moving linearly over `t ∈ [0, 1]`. Because `F` has no
//! `t²`, `u²` or `u·v` terms, its exact image over a box `[t]×[u]×[v]` lies in
//! the bounding box of its values at the 8 corners. We evaluate the corners in
//! f64 and widen the result by a rigorous bound on the rounding error (see
//! [`rounding_bound`]), so a box whose widened image stays farther than the
//! minimum separation from the origin provably holds no contact and is
//! discarded. Boxes are bisected along the parameter that changes `F` most and
//! processed in order of their earliest time, so the first box that becomes
//! smaller than the tolerance gives a time of impact that is never later than
//! the true one. The result is conservative: **no false negatives**; a
//! reported contact can be false only when the true minimal distance over the
//! step is within `min_separation + tolerance + rounding` of contact.
//!
//! Degenerate configurations (parallel or coplanar edges, polynomials that are
//! identically zero, zero-area triangles) need no special handling: they are
//! just boxes whose image keeps touching the origin.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use glam::DVec3;

/// Settings of one CCD query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CcdParams {
    /// Contact is reported when the primitives come closer than this
    /// (Euclidean distance, same units as the positions). The thickness.
    pub min_separation: f64,
    /// Boxes whose image is narrower than this (in position units) end the
    /// search. Smaller is tighter and slower; 1e-6 of the scene scale is typical.
    pub tolerance: f64,
    /// Upper bound on the number of boxes examined. When it is reached the
    /// earliest remaining box is reported (still conservative).
    pub max_iterations: usize,
    /// End of the time interval examined, `0 < t_max ≤ 1`.
    pub t_max: f64,
}

impl Default for CcdParams {
    fn default() -> Self {
        CcdParams { min_separation: 0.0, tolerance: 1e-6, max_iterations: 100_000, t_max: 1.0 }
    }
}

/// A (possible) contact found by CCD.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CcdHit {
    /// Time of impact in `[0, t_max]`, never later than the true first contact.
    pub toi: f64,
    /// First surface parameter at the contact: barycentric weight of the
    /// triangle's second corner (vertex–triangle) or the position along the
    /// first edge (edge–edge). In `[0, 1]`.
    pub u: f64,
    /// Second surface parameter: weight of the triangle's third corner, or the
    /// position along the second edge. In `[0, 1]`; for triangles `u + v ≤ 1`.
    pub v: f64,
    /// False when the iteration limit ended the search (the time is then a
    /// safe lower bound but the contact is less certain).
    pub converged: bool,
}

/// Which multilinear function is searched.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    VertexTriangle,
    EdgeEdge,
}

/// The 8 points of a query: 4 at t=0, 4 at t=1.
struct Query {
    kind: Kind,
    p0: [DVec3; 4],
    p1: [DVec3; 4],
    /// Bound on the absolute rounding error of one computed component of `F`.
    err: f64,
}

/// Rigorous bound on the rounding error of one component of `F` evaluated as
/// in [`Query::eval`], for coordinates of magnitude at most `max_abs`, with
/// `t`, `u`, `v` exact in `[0, 1]` (they are dyadic bisection points).
///
/// Term by term (ε = f64::EPSILON/2 per rounding, bounds in units of ε·M):
/// a lerp `x0 + t·(x1 − x0)` is off by ≤ 7; a difference of two lerps times a
/// weight in [0,1] by ≤ 18; the three subtractions that assemble `F` add ≤ 12
/// more; in total ≤ 63 ε·M. We use 128 ε·M (twice that) plus the smallest
/// normal number, so underflow cannot defeat it.
pub fn rounding_bound(max_abs: f64) -> f64 {
    128.0 * f64::EPSILON * max_abs + f64::MIN_POSITIVE
}

impl Query {
    fn new(kind: Kind, p0: [DVec3; 4], p1: [DVec3; 4]) -> Self {
        let max_abs = p0.iter().chain(p1.iter()).map(|p| p.abs().max_element()).fold(0.0, f64::max);
        Query { kind, p0, p1, err: rounding_bound(max_abs) }
    }

    fn at(&self, t: f64) -> [DVec3; 4] {
        let mut out = [DVec3::ZERO; 4];
        for k in 0..4 {
            out[k] = self.p0[k] + t * (self.p1[k] - self.p0[k]);
        }
        out
    }

    #[inline]
    fn eval(&self, q: &[DVec3; 4], u: f64, v: f64) -> DVec3 {
        match self.kind {
            // p − a − u(b − a) − v(c − a)
            Kind::VertexTriangle => (q[0] - q[1]) - u * (q[2] - q[1]) - v * (q[3] - q[1]),
            // a0 + u(a1 − a0) − b0 − v(b1 − b0)
            Kind::EdgeEdge => (q[0] + u * (q[1] - q[0])) - q[2] - v * (q[3] - q[2]),
        }
    }
}

/// A parameter box `[t0,t1]×[u0,u1]×[v0,v1]` waiting in the queue.
#[derive(Clone, Copy)]
struct Cell {
    lo: [f64; 3],
    hi: [f64; 3],
    depth: u32,
}

impl PartialEq for Cell {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Cell {}
impl PartialOrd for Cell {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Cell {
    /// Max-heap order: earliest time first, then the deepest (smallest) box.
    fn cmp(&self, other: &Self) -> Ordering {
        other.lo[0].total_cmp(&self.lo[0]).then(self.depth.cmp(&other.depth))
    }
}

/// Smallest width a parameter interval is split to (keeps bisection points
/// exact dyadic numbers).
const MIN_WIDTH: f64 = 1.0 / (1u64 << 48) as f64;

/// Outcome of examining one box.
enum Verdict {
    /// Provably no contact inside.
    Empty,
    /// Image narrower than the tolerance: report.
    Converged,
    /// The corner `(t_lo, u, v)` is provably within the separation: contact
    /// at exactly `t_lo`.
    Touching(f64, f64),
    /// Split along this parameter (0 = t, 1 = u, 2 = v).
    Split(usize),
}

fn examine(query: &Query, cell: &Cell, params: &CcdParams) -> Verdict {
    let ts = [query.at(cell.lo[0]), query.at(cell.hi[0])];
    // values[it][iu][iv]
    let mut values = [[[DVec3::ZERO; 2]; 2]; 2];
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for it in 0..2 {
        for iu in 0..2 {
            for iv in 0..2 {
                let u = if iu == 0 { cell.lo[1] } else { cell.hi[1] };
                let v = if iv == 0 { cell.lo[2] } else { cell.hi[2] };
                let f = query.eval(&ts[it], u, v);
                values[it][iu][iv] = f;
                lo = lo.min(f);
                hi = hi.max(f);
            }
        }
    }
    if !(lo.is_finite() && hi.is_finite()) {
        // Overflow or NaN input: cannot exclude anything; treat as contact.
        return Verdict::Converged;
    }
    let err = DVec3::splat(query.err);
    let wlo = lo - err;
    let whi = hi + err;
    // Euclidean distance from the origin to the widened image box.
    let gap = DVec3::ZERO.max(wlo).max(-whi);
    let ms = params.min_separation;
    // A component beyond `ms` is exact; the sum of squares carries a relative
    // rounding error below 8 ε, which the factor covers.
    if gap.max_element() > ms || gap.length_squared() > ms * ms * (1.0 + 1e-12) {
        return Verdict::Empty;
    }
    // A corner at the box's earliest time that is provably in contact: every
    // earlier time has been excluded (boxes are taken in time order), so the
    // first contact is exactly t_lo.
    let reach = ms - 3f64.sqrt() * query.err;
    if reach > 0.0 {
        for iu in 0..2 {
            for iv in 0..2 {
                if values[0][iu][iv].length_squared() <= reach * reach {
                    let u = if iu == 0 { cell.lo[1] } else { cell.hi[1] };
                    let v = if iv == 0 { cell.lo[2] } else { cell.hi[2] };
                    if query.kind == Kind::EdgeEdge || u + v <= 1.0 {
                        return Verdict::Touching(u, v);
                    }
                }
            }
        }
    }
    if (hi - lo).max_element() <= params.tolerance {
        return Verdict::Converged;
    }
    // How much F changes along each parameter over this box.
    let mut change = [0.0f64; 3];
    for a in 0..2 {
        for b in 0..2 {
            change[0] = change[0].max((values[1][a][b] - values[0][a][b]).abs().max_element());
            change[1] = change[1].max((values[a][1][b] - values[a][0][b]).abs().max_element());
            change[2] = change[2].max((values[a][b][1] - values[a][b][0]).abs().max_element());
        }
    }
    let mut best = None;
    for d in 0..3 {
        if cell.hi[d] - cell.lo[d] > MIN_WIDTH && best.is_none_or(|b: usize| change[d] > change[b]) {
            best = Some(d);
        }
    }
    match best {
        Some(d) => Verdict::Split(d),
        None => Verdict::Converged,
    }
}

fn solve(query: Query, params: &CcdParams) -> Option<CcdHit> {
    let t_max = if params.t_max > 0.0 && params.t_max <= 1.0 { params.t_max } else { 1.0 };
    let mut heap = BinaryHeap::new();
    heap.push(Cell { lo: [0.0; 3], hi: [t_max, 1.0, 1.0], depth: 0 });
    let mut iterations = 0usize;
    while let Some(cell) = heap.pop() {
        iterations += 1;
        if query.kind == Kind::VertexTriangle && cell.lo[1] + cell.lo[2] > 1.0 {
            continue; // entirely outside the triangle (u + v > 1)
        }
        let hit = |converged| {
            let mut u = 0.5 * (cell.lo[1] + cell.hi[1]);
            let mut v = 0.5 * (cell.lo[2] + cell.hi[2]);
            if query.kind == Kind::VertexTriangle && u + v > 1.0 {
                let s = u + v;
                u /= s;
                v /= s;
            }
            Some(CcdHit { toi: cell.lo[0], u, v, converged })
        };
        if iterations > params.max_iterations {
            return hit(false);
        }
        match examine(&query, &cell, params) {
            Verdict::Empty => {}
            Verdict::Converged => return hit(true),
            Verdict::Touching(u, v) => return Some(CcdHit { toi: cell.lo[0], u, v, converged: true }),
            Verdict::Split(d) => {
                let mid = 0.5 * (cell.lo[d] + cell.hi[d]);
                let mut a = cell;
                let mut b = cell;
                a.hi[d] = mid;
                b.lo[d] = mid;
                a.depth += 1;
                b.depth += 1;
                heap.push(a);
                heap.push(b);
            }
        }
    }
    None
}

/// Earliest time at which vertex `p` comes within `min_separation` of
/// triangle `(a, b, c)`, all moving linearly from their `*0` to `*1` positions.
/// `u`, `v` of the hit are the barycentric weights of `b` and `c`.
#[allow(clippy::too_many_arguments)]
pub fn vertex_triangle(
    p0: DVec3,
    a0: DVec3,
    b0: DVec3,
    c0: DVec3,
    p1: DVec3,
    a1: DVec3,
    b1: DVec3,
    c1: DVec3,
    params: &CcdParams,
) -> Option<CcdHit> {
    solve(Query::new(Kind::VertexTriangle, [p0, a0, b0, c0], [p1, a1, b1, c1]), params)
}

/// Earliest time at which edge `(a0, a1)` comes within `min_separation` of
/// edge `(b0, b1)`; `ea*` and `eb*` are the endpoints at t=0, `ea*_1`,
/// `eb*_1` at t=1. `u` of the hit is the position along edge a, `v` along b.
#[allow(clippy::too_many_arguments)]
pub fn edge_edge(
    ea0_t0: DVec3,
    ea1_t0: DVec3,
    eb0_t0: DVec3,
    eb1_t0: DVec3,
    ea0_t1: DVec3,
    ea1_t1: DVec3,
    eb0_t1: DVec3,
    eb1_t1: DVec3,
    params: &CcdParams,
) -> Option<CcdHit> {
    solve(Query::new(Kind::EdgeEdge, [ea0_t0, ea1_t0, eb0_t0, eb1_t0], [ea0_t1, ea1_t1, eb0_t1, eb1_t1]), params)
}

/// Earliest time at which vertex `p`, moving linearly from `p0` to `p1`,
/// comes within `min_separation` of triangle `tri0` while the triangle
/// translates rigidly by `shift` over the step: the common case of a still
/// collider (the in-loop pass) or one that only translates.
///
/// In the triangle's frame the vertex moves along a segment, and the set of
/// points within the separation of the triangle is bounded by the two faces
/// of a slab over the triangle, three cylinders around its edges and three
/// spheres at its corners. The first entry is the earliest root among those
/// pieces, found in closed form: a handful of flops instead of an interval
/// search. `min_separation` should already include the caller's tolerance
/// (the response adds the CCD tolerance and the triangle's deviation from a
/// rigid translation): a graze is then missed only where the true distance
/// stays above the separation by that tolerance, less rounding.
pub fn vertex_triangle_translating(
    p0: DVec3,
    p1: DVec3,
    tri0: [DVec3; 3],
    shift: DVec3,
    min_separation: f64,
    t_max: f64,
) -> Option<CcdHit> {
    use super::geometry::closest_on_triangle;

    let [a, b, c] = tri0;
    let q0 = p0;
    let dir = (p1 - shift) - p0;
    let sep = min_separation;
    let hit_at = |t: f64| {
        let q = q0 + t * dir;
        let (u, v) = closest_on_triangle(q, a, b, c);
        Some(CcdHit { toi: t, u, v, converged: true })
    };
    let start_gap = super::geometry::point_triangle_distance_squared(q0, a, b, c);
    if !start_gap.is_finite() || !dir.is_finite() {
        return hit_at(0.0).map(|h| CcdHit { converged: false, ..h });
    }
    if start_gap <= sep * sep {
        return hit_at(0.0);
    }
    let t_max = if t_max > 0.0 && t_max <= 1.0 { t_max } else { 1.0 };
    let mut first = f64::INFINITY;
    let mut consider = |t: f64| {
        if (0.0..=t_max).contains(&t) && t < first {
            first = t;
        }
    };
    let slack = 1e-9;

    // The slab faces over the triangle.
    let normal = (b - a).cross(c - a);
    let area2 = normal.length();
    if area2 > 0.0 && area2.is_finite() {
        let n = normal / area2;
        let (h0, dh) = (n.dot(q0 - a), n.dot(dir));
        if dh != 0.0 {
            for face in [sep, -sep] {
                let t = (face - h0) / dh;
                if (0.0..=t_max).contains(&t) {
                    // Inside the triangle's prism: barycentric coordinates of
                    // the point projected onto the plane, with a little slack.
                    let q = q0 + t * dir - (h0 + t * dh) * n;
                    let (ab, ac, aq) = (b - a, c - a, q - a);
                    let w_c = ab.cross(aq).dot(n) / area2;
                    let w_b = aq.cross(ac).dot(n) / area2;
                    if w_b >= -slack && w_c >= -slack && w_b + w_c <= 1.0 + slack {
                        consider(t);
                    }
                }
            }
        }
    }
    // Cylinders around the edges, within the edge's length.
    for (e0, e1) in [(a, b), (b, c), (c, a)] {
        let axis = e1 - e0;
        let len2 = axis.length_squared();
        if len2 <= 0.0 {
            continue;
        }
        let m = q0 - e0;
        let m_perp = m - axis * (m.dot(axis) / len2);
        let d_perp = dir - axis * (dir.dot(axis) / len2);
        for t in smallest_roots(d_perp.length_squared(), 2.0 * m_perp.dot(d_perp), m_perp.length_squared() - sep * sep) {
            let s = (m + t * dir).dot(axis) / len2;
            if (-slack..=1.0 + slack).contains(&s) {
                consider(t);
            }
        }
    }
    // Spheres at the corners.
    for corner in [a, b, c] {
        let m = q0 - corner;
        for t in smallest_roots(dir.length_squared(), 2.0 * m.dot(dir), m.length_squared() - sep * sep) {
            consider(t);
        }
    }
    first.is_finite().then(|| hit_at(first)).flatten()
}

/// The real roots of `a t² + b t + c` (ascending), where `c > 0` (the start
/// is outside): entry and exit times of a quadric, or NaN for none.
fn smallest_roots(a: f64, b: f64, c: f64) -> [f64; 2] {
    let none = [f64::NAN; 2];
    if a <= 0.0 {
        return none; // no motion relative to this piece
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return none;
    }
    // Stable form: no cancellation between -b and the root.
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    let (r0, r1) = if q != 0.0 { (q / a, c / q) } else { (0.0, 0.0) };
    [r0.min(r1), r0.max(r1)]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn d(x: f64, y: f64, z: f64) -> DVec3 {
        DVec3::new(x, y, z)
    }

    #[test]
    fn vertex_falling_through_triangle_hits_at_plane_time() {
        let (a, b, c) = (d(0.0, 0.0, 0.0), d(1.0, 0.0, 0.0), d(0.0, 1.0, 0.0));
        let p0 = d(0.25, 0.25, 1.0);
        let p1 = d(0.25, 0.25, -3.0);
        let hit = vertex_triangle(p0, a, b, c, p1, a, b, c, &CcdParams::default()).expect("contact");
        assert!(hit.toi <= 0.25 && hit.toi > 0.25 - 1e-5, "toi {}", hit.toi);
        assert!((hit.u - 0.25).abs() < 1e-3 && (hit.v - 0.25).abs() < 1e-3, "{hit:?}");
        // With a separation of 0.5 the contact comes when z = 0.5, t = 0.125.
        let params = CcdParams { min_separation: 0.5, ..Default::default() };
        let hit = vertex_triangle(p0, a, b, c, p1, a, b, c, &params).expect("contact");
        assert!(hit.toi <= 0.125 && hit.toi > 0.125 - 1e-5, "toi {}", hit.toi);
    }

    #[test]
    fn vertex_passing_beside_triangle_misses() {
        let (a, b, c) = (d(0.0, 0.0, 0.0), d(1.0, 0.0, 0.0), d(0.0, 1.0, 0.0));
        let p0 = d(0.8, 0.8, 1.0);
        let p1 = d(0.8, 0.8, -1.0);
        assert_eq!(vertex_triangle(p0, a, b, c, p1, a, b, c, &CcdParams::default()), None);
        // ... but a separation larger than its distance to the hypotenuse catches it.
        let gap = (0.6f64 / 2f64.sqrt()) + 1e-3; // distance from (0.8,0.8) to x+y=1
        let params = CcdParams { min_separation: gap, ..Default::default() };
        assert!(vertex_triangle(p0, a, b, c, p1, a, b, c, &params).is_some());
        let params = CcdParams { min_separation: gap - 2e-3, ..Default::default() };
        assert_eq!(vertex_triangle(p0, a, b, c, p1, a, b, c, &params), None);
    }

    #[test]
    fn moving_triangle_sweeps_over_resting_vertex() {
        let p = d(0.2, 0.2, 0.0);
        let (a0, b0, c0) = (d(0.0, 0.0, 1.0), d(1.0, 0.0, 1.0), d(0.0, 1.0, 1.0));
        let down = d(0.0, 0.0, -2.0);
        let hit = vertex_triangle(p, a0, b0, c0, p, a0 + down, b0 + down, c0 + down, &CcdParams::default())
            .expect("contact");
        assert!(hit.toi <= 0.5 && hit.toi > 0.5 - 1e-5, "toi {}", hit.toi);
    }

    #[test]
    fn crossing_edges_hit_and_parallel_edges_miss() {
        let ea0 = d(-1.0, 0.0, 1.0);
        let ea1 = d(1.0, 0.0, 1.0);
        let eb0 = d(0.0, -1.0, 0.0);
        let eb1 = d(0.0, 1.0, 0.0);
        let down = d(0.0, 0.0, -2.0);
        let hit = edge_edge(ea0, ea1, eb0, eb1, ea0 + down, ea1 + down, eb0, eb1, &CcdParams::default())
            .expect("contact");
        assert!(hit.toi <= 0.5 && hit.toi > 0.5 - 1e-5, "toi {}", hit.toi);
        assert!((hit.u - 0.5).abs() < 1e-3 && (hit.v - 0.5).abs() < 1e-3);
        // Parallel, offset sideways: never meet.
        let side = d(0.0, 0.0, 0.0);
        let (fa0, fa1) = (d(-1.0, 0.5, 1.0), d(1.0, 0.5, 1.0));
        let (fb0, fb1) = (d(-1.0, -0.5, 1.0), d(1.0, -0.5, 1.0));
        assert_eq!(edge_edge(fa0, fa1, fb0, fb1, fa0 + side, fa1 + side, fb0, fb1, &CcdParams::default()), None);
    }

    #[test]
    fn identically_zero_coplanar_overlap_is_a_contact() {
        // Two overlapping collinear edges that do not move: F ≡ 0 on a segment.
        let (a0, a1) = (d(0.0, 0.0, 0.0), d(1.0, 0.0, 0.0));
        let (b0, b1) = (d(0.5, 0.0, 0.0), d(2.0, 0.0, 0.0));
        let hit = edge_edge(a0, a1, b0, b1, a0, a1, b0, b1, &CcdParams::default()).expect("contact");
        assert_eq!(hit.toi, 0.0);
    }

    #[test]
    fn iteration_limit_still_reports_a_safe_time() {
        let (a, b, c) = (d(0.0, 0.0, 0.0), d(1.0, 0.0, 0.0), d(0.0, 1.0, 0.0));
        let params = CcdParams { max_iterations: 3, ..Default::default() };
        let hit = vertex_triangle(d(0.25, 0.25, 1.0), a, b, c, d(0.25, 0.25, -1.0), a, b, c, &params)
            .expect("contact");
        assert!(!hit.converged);
        assert!(hit.toi <= 0.5);
    }

    mod translating {
        use super::super::*;
        use crate::collide::geometry::point_triangle_distance_squared;
        use proptest::prelude::*;

        fn point() -> impl Strategy<Value = DVec3> {
            (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64).prop_map(|(x, y, z)| DVec3::new(x, y, z))
        }

        fn gap(p0: DVec3, p1: DVec3, tri: [DVec3; 3], shift: DVec3, t: f64) -> f64 {
            let q = p0 + t * (p1 - p0);
            let [a, b, c] = tri.map(|x| x + t * shift);
            point_triangle_distance_squared(q, a, b, c).sqrt()
        }

        #[test]
        fn sliding_along_the_face_then_dipping() {
            let tri = [DVec3::ZERO, DVec3::X, DVec3::Y];
            let slide = vertex_triangle_translating(DVec3::new(0.2, 0.2, 0.02), DVec3::new(0.5, 0.3, 0.02), tri, DVec3::ZERO, 0.01, 1.0);
            assert!(slide.is_none());
            let dip = vertex_triangle_translating(DVec3::new(0.2, 0.2, 0.02), DVec3::new(0.2, 0.2, -0.02), tri, DVec3::ZERO, 0.01, 1.0)
                .expect("contact");
            assert!((dip.toi - 0.25).abs() < 1e-12, "{dip:?}");
            assert!((dip.u - 0.2).abs() < 1e-12 && (dip.v - 0.2).abs() < 1e-12);
            // The triangle rising into a still vertex: contact when it is 0.01 below.
            let rise = vertex_triangle_translating(DVec3::new(0.2, 0.2, 0.5), DVec3::new(0.2, 0.2, 0.5), tri, DVec3::new(0.0, 0.0, 1.0), 0.01, 1.0)
                .expect("contact");
            assert!((rise.toi - 0.49).abs() < 1e-12, "{rise:?}");
        }

        proptest! {
            #![proptest_config(ProptestConfig { cases: 1000, ..ProptestConfig::default() })]

            /// Agrees with the interval search and with dense sampling: never
            /// later than the first sampled contact, never reporting a time
            /// before which the vertex was already clear of it by far.
            #[test]
            fn matches_sampling_and_the_interval_search(p0 in point(), p1 in point(), a in point(), b in point(),
                                                        c in point(), shift in point(), sep in 0.0..0.2f64) {
                let tri = [a, b, c];
                let shift = 0.5 * shift;
                let found = vertex_triangle_translating(p0, p1, tri, shift, sep, 1.0);
                let samples: Vec<f64> = (0..=4000).map(|k| gap(p0, p1, tri, shift, k as f64 / 4000.0)).collect();
                let first_sampled = samples.iter().position(|&g| g < sep).map(|k| k as f64 / 4000.0);
                if let Some(t) = first_sampled {
                    let hit = found.expect("sampling found a contact the closed form missed");
                    prop_assert!(hit.toi <= t + 1e-9, "closed form {} later than sampled {t}", hit.toi);
                }
                if let Some(hit) = found {
                    prop_assert!(gap(p0, p1, tri, shift, hit.toi) <= sep + 1e-7, "reported contact is not a contact");
                    prop_assert!(hit.u >= 0.0 && hit.v >= 0.0 && hit.u + hit.v <= 1.0 + 1e-12);
                }
                let params = CcdParams { min_separation: sep, tolerance: 1e-9, max_iterations: 20_000, t_max: 1.0 };
                let [a1, b1, c1] = tri.map(|x| x + shift);
                if let Some(interval) = vertex_triangle(p0, a, b, c, p1, a1, b1, c1, &params) {
                    if interval.converged && gap(p0, p1, tri, shift, interval.toi + 1e-6) < sep - 1e-6 {
                        let hit = found.expect("the interval search found a contact the closed form missed");
                        prop_assert!(hit.toi <= interval.toi + 1e-6);
                    }
                }
            }
        }
    }
}
