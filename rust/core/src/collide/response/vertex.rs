//! Vertex–triangle contacts: the earliest hit along each skin vertex's path,
//! and its projection with friction.

use glam::{DVec3, Vec3};

use super::scratch::{Scratch, CANDIDATES};
use super::contact::open_side;
use super::{d, ColliderMotion, ColliderSet, ResolveParams, VertexHit};
use crate::collide::bvh::Bounds;
use crate::collide::ccd;
use crate::collide::friction::{friction, Hold, Slide};
use crate::collide::geometry::{point_triangle_distance_squared, triangle_normal};
use crate::collide::planes::resting_reference;
use crate::collide::proximity;
use crate::collide::slab::Patch;

impl<'a> ColliderSet<'a> {
    /// The projected end of the first vertex–triangle contact of `s → e`
    /// that needs one, and how friction left the vertex there. Not simply the earliest contact: one reported within
    /// the tolerance may need no correction, and the next one then decides.
    ///
    /// Candidates are tried in the order the path enters their leaf boxes
    /// (their boxes over the frame, grown by the thickness and here by the
    /// CCD's tolerance, so no contact of a triangle is reported before its
    /// entry): once a contact that needs a correction is found, a candidate
    /// entered later cannot come before it. A path that misses a leaf box
    /// cannot touch its triangle at all. A vertex pulled deep into a collider
    /// has a column of candidates but meets the nearest first.
    pub(super) fn vertex_correction(&self, s: Vec3, e: Vec3, params: &ResolveParams) -> Option<(Vec3, Hold)> {
        let motion = params.motion;
        let (from, to) = (Bounds::of_points(&[s]), Bounds::of_points(&[e]));
        let (s64, e64) = (d(s), d(e));
        let mut candidates = Scratch::lend(&CANDIDATES);
        let mut order: Vec<(f64, u32, u32)> = Vec::new();
        for (c, col) in self.colliders.iter().enumerate() {
            let ccd = self.ccd_params(col.settings().thickness as f64);
            self.candidate_triangles(c, motion, from, to, &mut candidates);
            if self.slab_apart(c, &candidates, &[s64], &[e64], motion, ccd.min_separation, false) {
                continue;
            }
            // Entry times in the trees' frame: distances, and so contacts,
            // are the same there at every instant.
            let grow = 4.0 * ccd.tolerance + 1e-6 * self.scale;
            let (ps, pe) = self.tree_path(c, motion, s64, e64);
            let tree = self.triangle_tree(c, motion);
            for &t in candidates.iter() {
                if let Some(entry) = tree.primitive_bounds(t as usize).entry_time(ps, pe, grow) {
                    order.push((entry, c as u32, t));
                }
            }
        }
        order.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut best: Option<(f64, (Vec3, Hold))> = None;
        for (entry, c, t) in order {
            if best.is_some_and(|(toi, _)| entry > toi) {
                break;
            }
            let (c, t) = (c as usize, t as usize);
            let Some(hit) = self.vertex_triangle_hit(s64, e64, c, t, motion) else { continue };
            if best.is_some_and(|(toi, _)| hit.toi >= toi) {
                continue;
            }
            if let Some(p) = self.project_vertex(s, e, &VertexHit { collider: c, triangle: t, hit }, params) {
                best = Some((hit.toi, p));
            }
        }
        best.map(|(_, p)| p)
    }

    /// The first contact of the path `s64 → e64` with triangle `t` of
    /// collider `c`, if any.
    pub(super) fn vertex_triangle_hit(&self, s64: DVec3, e64: DVec3, c: usize, t: usize, motion: ColliderMotion) -> Option<ccd::CcdHit> {
        let params = self.ccd_params(self.colliders[c].settings().thickness as f64);
        let ([a0, b0, c0], [a1, b1, c1]) = self.triangle_ends(c, t, motion);
        // A still or rigidly translating triangle has a closed-form
        // first contact, cheaper than sampling distances to prove
        // the pair apart; its deviation from a translation is added
        // to the separation so the answer stays conservative.
        let shift = a1 - a0;
        let deviation = (b1 - b0 - shift).length().max((c1 - c0 - shift).length());
        let translating = deviation <= params.tolerance;
        let apart = if translating { proximity::vertex_triangle_apart_by_plane } else { proximity::vertex_triangle_apart };
        if apart(s64, [a0, b0, c0], e64, [a1, b1, c1], params.min_separation) {
            return None;
        }
        if translating {
            let separation = params.min_separation + params.tolerance + deviation;
            ccd::vertex_triangle_translating(s64, e64, [a0, b0, c0], shift, separation, params.t_max)
        } else {
            proximity::vertex_triangle_advance(s64, [a0, b0, c0], e64, [a1, b1, c1], params.min_separation, params.tolerance, params.t_max)
                .filter(|hit| hit.converged)
                .or_else(|| ccd::vertex_triangle(s64, a0, b0, c0, e64, a1, b1, c1, &params))
        }
    }

    /// Collider `c`'s triangles whose boxes (grown by the thickness) meet
    /// a skin element's, into `out`: the only ones the element can reach
    /// while its corners move from `from` to `to` (see [`Self::query_box`]).
    pub(super) fn candidate_triangles(&self, c: usize, motion: ColliderMotion, from: Bounds, to: Bounds, out: &mut Vec<u32>) {
        out.clear();
        self.triangle_tree(c, motion).query(&self.query_box(c, motion, from, to), |t| {
            out.push(t as u32);
            true
        });
    }

    /// Whether a skin element (corners `start → end`, at most 3) provably
    /// stays farther than `separation` from all of collider `c`'s `triangles`
    /// over the step, by slabs (see [`Patch::apart`]; `sliced` allows a slab
    /// per part of the step when the collider sweeps).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn slab_apart(&self, c: usize, triangles: &[u32], start: &[DVec3], end: &[DVec3], motion: ColliderMotion, separation: f64, sliced: bool) -> bool {
        if triangles.is_empty() {
            return true;
        }
        let swept = motion == ColliderMotion::Swept;
        Patch::with(|patch| {
            patch.gather(self.colliders[c], triangles, swept);
            patch.apart(start, end, separation, sliced)
        })
    }

    /// The projected end position for a vertex–triangle contact and how
    /// friction left it there, or `None` if the end already satisfies it.
    pub(super) fn project_vertex(&self, s: Vec3, e: Vec3, h: &VertexHit, params: &ResolveParams) -> Option<(Vec3, Hold)> {
        let col = self.colliders[h.collider];
        let settings = col.settings();
        let sep = settings.thickness as f64;
        let ([a0, b0, c0], [a1, b1, c1]) = self.triangle_ends(h.collider, h.triangle, params.motion);
        let (t, u, v) = (h.hit.toi, h.hit.u, h.hit.v);
        let lerp = |p0: DVec3, p1: DVec3| p0 + t * (p1 - p0);
        let (at, bt, ct) = (lerp(a0, a1), lerp(b0, b1), lerp(c0, c1));
        let (s, e) = (d(s), d(e));
        let xt = lerp(s, e);
        let qt = at + u * (bt - at) + v * (ct - at);
        let q0 = a0 + u * (b0 - a0) + v * (c0 - a0);
        let q1 = a1 + u * (b1 - a1) + v * (c1 - a1);
        let n1 = triangle_normal(a1, b1, c1).or_else(|| triangle_normal(at, bt, ct))?;
        let side = match self.outward[h.collider] {
            o if o != 0.0 => o,
            _ => open_side(s, e, xt, qt, q0, q1, triangle_normal(at, bt, ct), triangle_normal(a0, b0, c0), n1, sep),
        };
        let n = side * n1;
        let dist = (e - q1).dot(n);
        if dist >= sep {
            return None;
        }
        let slack = self.slack(sep);
        let depth = sep + slack - dist;
        let mut out = e + depth * n;
        let mut hold = Hold::Sliding(Slide { normal: n.as_vec3(), friction: 0.0 });
        if params.friction && (settings.static_friction > 0.0 || settings.kinetic_friction > 0.0) {
            // On a still collider a vertex resting on it is held where it
            // rests, not where this step crossed the surface (see
            // `resting_reference`). Resting means near this triangle, not
            // merely level with its plane (a vertex beside the collider).
            let contact = match params.motion {
                ColliderMotion::AtCurrent => resting_reference(point_triangle_distance_squared(s, a1, b1, c1).sqrt() - sep, slack, s, xt),
                ColliderMotion::Swept => xt,
            };
            let change;
            (change, hold) = friction((out - contact) - (q1 - qt), n, depth, settings.static_friction as f64, settings.kinetic_friction as f64);
            out -= change;
        }
        let out = out.as_vec3();
        out.is_finite().then_some((out, hold))
    }
}
