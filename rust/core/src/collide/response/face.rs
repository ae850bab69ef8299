//! Collider vertices against skin triangles (sharp collider corners).

use glam::{DVec3, Vec3};

use super::scratch::{Scratch, CANDIDATES};
use super::contact::contact_normal;
use super::{d, ColliderMotion, ColliderSet, ResolveParams};
use crate::collide::bvh::Bounds;
use crate::collide::ccd;
use crate::collide::friction::Hold;
use crate::collide::geometry::triangle_normal;
use crate::collide::proximity;
use crate::collide::slab::SLICES;

impl<'a> ColliderSet<'a> {
    /// Earliest contact of a collider vertex with skin triangle `tri`, and
    /// the corrections of the triangle's three end positions.
    pub(super) fn face_correction(
        &self,
        start: &[Vec3],
        end: &[Vec3],
        tri: [u32; 3],
        masses: [f64; 3],
        params: &ResolveParams,
    ) -> Option<([DVec3; 3], Hold)> {
        let [i0, i1, i2] = tri.map(|v| v as usize);
        let (s0, s1, s2) = (d(start[i0]), d(start[i1]), d(start[i2]));
        let (e0, e1, e2) = (d(end[i0]), d(end[i1]), d(end[i2]));
        let (from, to) = (Bounds::of_points(&[start[i0], start[i1], start[i2]]), Bounds::of_points(&[end[i0], end[i1], end[i2]]));
        let mut hits: Vec<(usize, usize, ccd::CcdHit)> = Vec::new();
        let mut candidates = Scratch::lend(&CANDIDATES);
        // A skin triangle resting on a collider faces it: its own normal is
        // the direction of a slab that proves all nearby collider vertices
        // apart at once. Over a part `t0..t1` of the step, the normal is the
        // triangle's halfway through it, and the frame moves with the first
        // candidate vertex.
        let skin_at = |t: f64| [s0 + t * (e0 - s0), s1 + t * (e1 - s1), s2 + t * (e2 - s2)];
        let slab = |c: usize, candidates: &[u32], t0: f64, t1: f64| {
            let [m0, m1, m2] = skin_at(0.5 * (t0 + t1));
            let Some(n) = triangle_normal(m0, m1, m2) else { return false };
            let vertex_at = |v: u32| {
                let (r0, r1) = self.vertex_ends(c, v as usize, params.motion);
                (r0 + t0 * (r1 - r0), r0 + t1 * (r1 - r0))
            };
            let (r0, r1) = vertex_at(candidates[0]);
            proximity::separated_along(n, r1 - r0, &skin_at(t0), &skin_at(t1), candidates.iter().map(|&v| vertex_at(v)), self.colliders[c].settings().thickness as f64)
        };
        for (c, col) in self.colliders.iter().enumerate() {
            let ccd_params = self.ccd_params(col.settings().thickness as f64);
            candidates.clear();
            self.vertex_tree(c, params.motion).query(&self.query_box(c, params.motion, from, to), |v| {
                candidates.push(v as u32);
                true
            });
            if candidates.is_empty() {
                continue;
            }
            let swept = params.motion == ColliderMotion::Swept;
            if slab(c, &candidates, 0.0, 1.0)
                || (swept && (0..SLICES).all(|k| slab(c, &candidates, k as f64 / SLICES as f64, (k + 1) as f64 / SLICES as f64)))
            {
                continue;
            }
            for &v in candidates.iter() {
                let v = v as usize;
                let (r0, r1) = self.vertex_ends(c, v, params.motion);
                if proximity::vertex_triangle_apart(r0, [s0, s1, s2], r1, [e0, e1, e2], ccd_params.min_separation) {
                    continue;
                }
                let advanced = proximity::vertex_triangle_advance(r0, [s0, s1, s2], r1, [e0, e1, e2], ccd_params.min_separation, ccd_params.tolerance, ccd_params.t_max);
                let found = match advanced {
                    Some(hit) if !hit.converged => ccd::vertex_triangle(r0, s0, s1, s2, r1, e0, e1, e2, &ccd_params),
                    other => other,
                };
                if let Some(hit) = found {
                    hits.push((c, v, hit));
                }
            }
        }
        hits.sort_by(|a, b| a.2.toi.total_cmp(&b.2.toi));
        let ends = ([s0, s1, s2], [e0, e1, e2]);
        hits.into_iter().find_map(|(c, v, hit)| self.face_contact_correction(ends, c, v, hit, masses, params))
    }

    /// Corrections of a skin triangle's corners for one collider-vertex
    /// contact, and how friction left its contact point, or `None` if its
    /// end positions already keep the separation.
    pub(super) fn face_contact_correction(
        &self,
        ([s0, s1, s2], [e0, e1, e2]): ([DVec3; 3], [DVec3; 3]),
        c: usize,
        v: usize,
        hit: ccd::CcdHit,
        masses: [f64; 3],
        params: &ResolveParams,
    ) -> Option<([DVec3; 3], Hold)> {
        let sep = self.colliders[c].settings().thickness as f64;
        let (r0, r1) = self.vertex_ends(c, v, params.motion);
        let (t, u, w) = (hit.toi, hit.u, hit.v);
        let weights = [1.0 - u - w, u, w];
        let at = |a: DVec3, b: DVec3, c: DVec3| weights[0] * a + weights[1] * b + weights[2] * c;
        let lerp = |p0: DVec3, p1: DVec3| p0 + t * (p1 - p0);
        let (p0, p1) = (at(s0, s1, s2), at(e0, e1, e2));
        let pt = at(lerp(s0, e0), lerp(s1, e1), lerp(s2, e2));
        let rt = lerp(r0, r1);
        let n1 = triangle_normal(e0, e1, e2).or_else(|| triangle_normal(lerp(s0, e0), lerp(s1, e1), lerp(s2, e2)));
        let n = contact_normal(self.outward[c] != 0.0, || self.vertex_outward(c, v), n1, [pt, rt], [p0, r0], [p1, r1], sep)?;
        let dist = (p1 - r1).dot(n);
        if dist >= sep {
            return None;
        }
        let depth = sep + self.slack(sep) - dist;
        let (change, hold) = self.shared_contact_change(c, params, n, depth, [pt, rt], [p0, r0], [p1, r1]);
        let denominator: f64 = weights.iter().zip(&masses).map(|(w, m)| m * w * w).sum();
        if !(denominator > 1e-12) {
            return None;
        }
        let mut out = [DVec3::ZERO; 3];
        for k in 0..3 {
            out[k] = masses[k] * weights[k] / denominator * change;
        }
        out.iter().all(|x| x.is_finite()).then_some((out, hold))
    }

    pub(super) fn vertex_ends(&self, c: usize, v: usize, motion: ColliderMotion) -> (DVec3, DVec3) {
        let col = self.colliders[c];
        let end = d(col.current()[v]);
        match motion {
            ColliderMotion::Swept => (d(col.previous()[v]), end),
            ColliderMotion::AtCurrent => (end, end),
        }
    }

    /// Outward direction at collider vertex `v` (sum of its faces' normals).
    pub(super) fn vertex_outward(&self, c: usize, v: usize) -> Option<DVec3> {
        self.mean_outward(c, self.colliders[c].vertex_triangles(v))
    }
}
