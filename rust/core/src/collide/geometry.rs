//! Small f64 geometric helpers shared by the response and the audit.

use glam::DVec3;

/// Unit normal of triangle `(a, b, c)` (right-handed winding), or `None` when
/// its area is too small to give a direction.
pub fn triangle_normal(a: DVec3, b: DVec3, c: DVec3) -> Option<DVec3> {
    let n = (b - a).cross(c - a);
    let len = n.length();
    let scale = (b - a).length_squared().max((c - a).length_squared());
    if len > 1e-12 * scale && len.is_finite() && len > 0.0 {
        Some(n / len)
    } else {
        None
    }
}

/// Unit vector along `v`, or `None` if `v` is (nearly) zero or not finite.
pub fn unit(v: DVec3) -> Option<DVec3> {
    let len = v.length();
    if len > 1e-300 && len.is_finite() { Some(v / len) } else { None }
}

/// Sign of the volume of tetrahedron `(a, b, c, d)`: positive when `d` lies on
/// the side of `(a, b, c)` its right-handed normal points to. f64, not exact.
pub fn orient3d(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    (b - a).cross(c - a).dot(d - a)
}

/// True when segment `p q` properly crosses triangle `a b c`: the endpoints are
/// strictly on opposite sides of its plane and the crossing point strictly
/// inside it. Touching contacts do not count.
pub fn segment_crosses_triangle(p: DVec3, q: DVec3, a: DVec3, b: DVec3, c: DVec3) -> bool {
    let sp = orient3d(a, b, c, p);
    let sq = orient3d(a, b, c, q);
    if !(sp > 0.0 && sq < 0.0 || sp < 0.0 && sq > 0.0) {
        return false;
    }
    let s1 = orient3d(p, q, a, b);
    let s2 = orient3d(p, q, b, c);
    let s3 = orient3d(p, q, c, a);
    (s1 > 0.0 && s2 > 0.0 && s3 > 0.0) || (s1 < 0.0 && s2 < 0.0 && s3 < 0.0)
}

/// Squared distance from `p` to triangle `a b c` (Ericson, Real-Time Collision
/// Detection, 5.1.5), robust to degenerate triangles.
pub fn point_triangle_distance_squared(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let (v, w) = closest_on_triangle(p, a, b, c);
    (p - (a + v * (b - a) + w * (c - a))).length_squared()
}

/// Barycentric weights `(v, w)` of `b` and `c` of the point of triangle
/// `a b c` closest to `p` (Ericson, Real-Time Collision Detection, 5.1.5);
/// for a degenerate triangle, the closest point of its three edges.
pub fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> (f64, f64) {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (0.0, 0.0);
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (1.0, 0.0);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return (d1 / (d1 - d3), 0.0);
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (0.0, 1.0);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return (0.0, d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (1.0 - w, w);
    }
    let denom = va + vb + vc;
    if denom.abs() < 1e-300 || !denom.is_finite() {
        // Degenerate triangle: the closest point of its three edges.
        let on = |x: DVec3, y: DVec3| {
            let xy = y - x;
            let len2 = xy.length_squared();
            let t = if len2 > 0.0 { ((p - x).dot(xy) / len2).clamp(0.0, 1.0) } else { 0.0 };
            (t, (p - (x + t * xy)).length_squared())
        };
        let (t_ab, d_ab) = on(a, b);
        let (t_bc, d_bc) = on(b, c);
        let (t_ca, d_ca) = on(c, a);
        return if d_ab <= d_bc && d_ab <= d_ca {
            (t_ab, 0.0)
        } else if d_bc <= d_ca {
            (1.0 - t_bc, t_bc)
        } else {
            (0.0, 1.0 - t_ca)
        };
    }
    (vb / denom, vc / denom)
}

/// Squared distance between segments `p0 p1` and `q0 q1`.
pub fn segment_segment_distance_squared(p0: DVec3, p1: DVec3, q0: DVec3, q1: DVec3) -> f64 {
    closest_on_segments(p0, p1, q0, q1).2
}

/// Parameters `(s, t)` of the closest points `p0 + s (p1 − p0)` and
/// `q0 + t (q1 − q0)` of two segments, and their squared distance (Ericson,
/// Real-Time Collision Detection, 5.1.9). The clamped pair is compared with
/// the four endpoint projections, so the result is the true minimum up to
/// rounding also where rounding pushed a parameter across a bound, and for
/// parallel and zero-length segments.
pub fn closest_on_segments(p0: DVec3, p1: DVec3, q0: DVec3, q1: DVec3) -> (f64, f64, f64) {
    let d1 = p1 - p0;
    let d2 = q1 - q0;
    let r = p0 - q0;
    let a = d1.length_squared();
    let e = d2.length_squared();
    let f = d2.dot(r);
    let c = d1.dot(r);
    let b = d1.dot(d2);
    let on = |x: DVec3, from: DVec3, dir: DVec3, len2: f64| {
        if len2 > 0.0 { ((x - from).dot(dir) / len2).clamp(0.0, 1.0) } else { 0.0 }
    };
    let mut best = (0.0, 0.0, f64::INFINITY);
    let mut consider = |s: f64, t: f64| {
        let d = (p0 + d1 * s - (q0 + d2 * t)).length_squared();
        if d < best.2 {
            best = (s, t, d);
        }
    };
    if a > f64::MIN_POSITIVE && e > f64::MIN_POSITIVE {
        let denom = a * e - b * b;
        // Closest point on the first line to the second, clamped; for
        // parallel segments any s works, 0 is as good as any.
        let mut s = if denom > 0.0 { ((b * f - c * e) / denom).clamp(0.0, 1.0) } else { 0.0 };
        let mut t = (b * s + f) / e;
        if t < 0.0 {
            t = 0.0;
            s = (-c / a).clamp(0.0, 1.0);
        } else if t > 1.0 {
            t = 1.0;
            s = ((b - c) / a).clamp(0.0, 1.0);
        }
        consider(s, t);
    }
    consider(0.0, on(p0, q0, d2, e));
    consider(1.0, on(p1, q0, d2, e));
    consider(on(q0, p0, d1, a), 0.0);
    consider(on(q1, p0, d1, a), 1.0);
    best
}

/// Whether the ray from `p` towards +z crosses triangle `a b c`, decided with
/// an exact 2D containment test (f64 products of f32 differences are exact)
/// and a symbolic perturbation of `p` by (ε, ε²) so that every ray crosses a
/// closed, consistently oriented surface an exact number of times even when it
/// passes through an edge or a vertex. Only the "above `p`" test is inexact;
/// it can only err for points within rounding distance of the triangle.
pub fn ray_up_crosses(p: [f32; 3], a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> bool {
    let o = |u: [f32; 3], v: [f32; 3]| -> f64 {
        // orient2d(u, v, p) with p perturbed by (ε, ε²).
        let (ux, uy) = (u[0] as f64 - p[0] as f64, u[1] as f64 - p[1] as f64);
        let (vx, vy) = (v[0] as f64 - p[0] as f64, v[1] as f64 - p[1] as f64);
        let det = ux * vy - uy * vx;
        if det != 0.0 {
            return det;
        }
        // d/dε of orient2d(u, v, p + (ε, ε²)) = (u.y − v.y); then (v.x − u.x).
        let dy = u[1] as f64 - v[1] as f64;
        if dy != 0.0 {
            return dy;
        }
        v[0] as f64 - u[0] as f64
    };
    let (s1, s2, s3) = (o(a, b), o(b, c), o(c, a));
    let inside = (s1 > 0.0 && s2 > 0.0 && s3 > 0.0) || (s1 < 0.0 && s2 < 0.0 && s3 < 0.0);
    if !inside {
        return false;
    }
    // Height of the triangle's plane above p at p's (x, y).
    let [a, b, c] = [a, b, c].map(|v| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64));
    let p = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
    let n = (b - a).cross(c - a);
    if n.z == 0.0 {
        return false;
    }
    let z = a.z - (n.x * (p.x - a.x) + n.y * (p.y - a.y)) / n.z;
    z > p.z
}

/// Points spread over triangle `a b c` (corners, edge midpoints, centroid):
/// where the property tests sample a skin triangle's distance.
#[cfg(test)]
pub(crate) fn triangle_samples(a: DVec3, b: DVec3, c: DVec3) -> Vec<DVec3> {
    [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0 / 3.0, 1.0 / 3.0), (0.5, 0.5), (0.5, 0.0), (0.0, 0.5)]
        .iter()
        .map(|&(u, v)| a * (1.0 - u - v) + b * u + c * v)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crossing_and_touching_segments() {
        let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        let z = DVec3::Z;
        assert!(segment_crosses_triangle(DVec3::new(0.2, 0.2, 1.0), DVec3::new(0.2, 0.2, -1.0), a, b, c));
        assert!(!segment_crosses_triangle(DVec3::new(0.8, 0.8, 1.0), DVec3::new(0.8, 0.8, -1.0), a, b, c));
        assert!(!segment_crosses_triangle(DVec3::new(0.2, 0.2, 1.0), DVec3::new(0.2, 0.2, 0.0), a, b, c));
        assert!(!segment_crosses_triangle(z, 2.0 * z, a, b, c));
    }

    #[test]
    fn distances() {
        let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        assert!((point_triangle_distance_squared(DVec3::new(0.2, 0.2, 2.0), a, b, c) - 4.0).abs() < 1e-12);
        assert!((point_triangle_distance_squared(DVec3::new(-1.0, 0.0, 0.0), a, b, c) - 1.0).abs() < 1e-12);
        assert!((point_triangle_distance_squared(DVec3::new(1.0, 1.0, 0.0), a, b, c) - 0.5).abs() < 1e-12);
        // Degenerate triangle (a segment).
        assert!((point_triangle_distance_squared(DVec3::new(0.5, 1.0, 0.0), a, b, b) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn ray_through_a_shared_edge_counts_once() {
        // Two triangles of a square split along its diagonal; rays through the
        // diagonal, a vertex and the interior must cross exactly once.
        let (a, b, c, d) = ([0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.0, 1.0, 1.0]);
        for p in [[0.5f32, 0.5, 0.0], [0.0, 0.0, 0.0], [0.25, 0.75, 0.0], [1.0, 0.5, 0.0], [0.5, 0.0, 0.0]] {
            let hits = ray_up_crosses(p, a, b, c) as u32 + ray_up_crosses(p, a, c, d) as u32;
            assert!(hits <= 1, "{p:?}");
        }
        assert_eq!(ray_up_crosses([0.5, 0.5, 0.0], a, b, c) as u32 + ray_up_crosses([0.5, 0.5, 0.0], a, c, d) as u32, 1);
        assert!(!ray_up_crosses([0.5, 0.5, 2.0], a, b, c) && !ray_up_crosses([0.5, 0.5, 2.0], a, c, d));
    }
}
