//! Edge–edge contacts: skin edges against collider edges.

use glam::{DVec3, Vec3};

use super::scratch::{Scratch, CANDIDATES, SEEN};
use super::contact::contact_normal;
use super::{d, ColliderSet, ResolveParams};
use crate::collide::bvh::Bounds;
use crate::collide::ccd;
use crate::collide::friction::Hold;
use crate::collide::geometry::{triangle_normal, unit};
use crate::collide::proximity;

impl<'a> ColliderSet<'a> {
    /// Earliest contact of skin edge `(ia, ib)` against collider edges, and
    /// the corrections of its two end positions.
    pub(super) fn edge_correction(
        &self,
        start: &[Vec3],
        end: &[Vec3],
        edge: [u32; 2],
        masses: [f64; 2],
        params: &ResolveParams,
    ) -> Option<((DVec3, DVec3), Hold)> {
        let [ia, ib] = edge.map(|v| v as usize);
        let (sa, sb, ea, eb) = (d(start[ia]), d(start[ib]), d(end[ia]), d(end[ib]));
        let (from, to) = (Bounds::of_points(&[start[ia], start[ib]]), Bounds::of_points(&[end[ia], end[ib]]));
        let mut hits: Vec<(usize, usize, ccd::CcdHit)> = Vec::new();
        let mut seen = Scratch::lend(&SEEN);
        let mut candidates = Scratch::lend(&CANDIDATES);
        for (c, col) in self.colliders.iter().enumerate() {
            let ccd_params = self.ccd_params(col.settings().thickness as f64);
            self.candidate_triangles(c, params.motion, from, to, &mut candidates);
            if self.slab_apart(c, &candidates, &[sa, sb], &[ea, eb], params.motion, ccd_params.min_separation, true) {
                continue;
            }
            seen.clear();
            for &t in candidates.iter() {
                let t = t as usize;
                let (tri0, tri1) = self.triangle_ends(c, t, params.motion);
                if proximity::beyond_triangle_plane(tri0, tri1, &[sa, sb], &[ea, eb], ccd_params.min_separation) {
                    // Apart from the triangle's plane, so from its three edges.
                    for &e in &col.triangle_edges()[t] {
                        if !seen.contains(&e) {
                            seen.push(e);
                        }
                    }
                    continue;
                }
                for &e in &col.triangle_edges()[t] {
                    if seen.contains(&e) {
                        continue;
                    }
                    seen.push(e);
                    let ([c0, c1], [c0e, c1e]) = self.edge_ends(c, e as usize, params.motion);
                    if proximity::edge_edge_apart([sa, sb], [c0, c1], [ea, eb], [c0e, c1e], ccd_params.min_separation) {
                        continue;
                    }
                    let advanced = proximity::edge_edge_advance([sa, sb], [c0, c1], [ea, eb], [c0e, c1e], ccd_params.min_separation, ccd_params.tolerance, ccd_params.t_max);
                    // Advancement that ran out of steps is only a lower bound on the
                    // time; the interval search then finds where the contact is.
                    let found = match advanced {
                        Some(hit) if !hit.converged => ccd::edge_edge(sa, sb, c0, c1, ea, eb, c0e, c1e, &ccd_params),
                        other => other,
                    };
                    if let Some(hit) = found {
                        hits.push((c, e as usize, hit));
                    }
                }
            }
        }
        hits.sort_by(|a, b| a.2.toi.total_cmp(&b.2.toi));
        hits.into_iter().find_map(|(c, e, hit)| self.edge_contact_correction(sa, sb, ea, eb, c, e, hit, masses, params))
    }

    /// Corrections of a skin edge's two ends for one edge–edge contact, and
    /// how friction left its contact point, or `None` if its end positions
    /// already keep the separation.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn edge_contact_correction(
        &self,
        sa: DVec3,
        sb: DVec3,
        ea: DVec3,
        eb: DVec3,
        c: usize,
        e: usize,
        hit: ccd::CcdHit,
        [ma, mb]: [f64; 2],
        params: &ResolveParams,
    ) -> Option<((DVec3, DVec3), Hold)> {
        let col = self.colliders[c];
        let sep = col.settings().thickness as f64;
        let ([c0, c1], [c0e, c1e]) = self.edge_ends(c, e, params.motion);
        let (t, u, v) = (hit.toi, hit.u, hit.v);
        let lerp = |p0: DVec3, p1: DVec3| p0 + t * (p1 - p0);
        let pt = lerp(sa, ea) + u * (lerp(sb, eb) - lerp(sa, ea));
        let rt = lerp(c0, c0e) + v * (lerp(c1, c1e) - lerp(c0, c0e));
        let p1 = ea + u * (eb - ea);
        let r1 = c0e + v * (c1e - c0e);
        let p0 = sa + u * (sb - sa);
        let r0 = c0 + v * (c1 - c0);
        let cross1 = unit((eb - ea).cross(c1e - c0e));
        // Closed collider: the outside is known from the adjacent faces.
        let n = contact_normal(self.outward[c] != 0.0, || self.edge_outward(c, e), cross1, [pt, rt], [p0, r0], [p1, r1], sep)?;
        let dist = (p1 - r1).dot(n);
        if dist >= sep {
            return None;
        }
        let depth = sep + self.slack(sep) - dist;
        let (change, hold) = self.shared_contact_change(c, params, n, depth, [pt, rt], [p0, r0], [p1, r1]);
        // The minimum-norm change under the inverse masses (PBD) that moves
        // the contact point by `change`.
        let (wa, wb) = (1.0 - u, u);
        let denominator = ma * wa * wa + mb * wb * wb;
        if !(denominator > 1e-12) {
            return None;
        }
        let (da, db) = (ma * wa / denominator * change, mb * wb / denominator * change);
        (da.is_finite() && db.is_finite()).then_some(((da, db), hold))
    }

    /// Outward direction at collider edge `e`: the normalised sum of its
    /// faces' outward normals at the current positions.
    pub(super) fn edge_outward(&self, c: usize, e: usize) -> Option<DVec3> {
        self.mean_outward(c, self.colliders[c].edge_triangles(e))
    }

    /// Unit mean of the current normals of collider `c`'s `triangles`,
    /// turned to face out of the collider.
    pub(super) fn mean_outward(&self, c: usize, triangles: &[u32]) -> Option<DVec3> {
        let col = self.colliders[c];
        let mut sum = DVec3::ZERO;
        for &t in triangles {
            let [a, b, cc] = col.triangles()[t as usize].map(|v| d(col.current()[v as usize]));
            if let Some(n) = triangle_normal(a, b, cc) {
                sum += n;
            }
        }
        unit(sum * self.outward[c])
    }
}
