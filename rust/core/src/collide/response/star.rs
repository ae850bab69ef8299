//! Whole stars proven apart at once: a moving vertex with all its edges and
//! triangles, by one slab against colliders standing still, before any
//! element is tested on its own ([`ResolveParams::star_slabs`]).
//!
//! Where a mesh rests a little beyond the thickness over a smooth collider
//! (a compliant collider receding from the skin: its resting vertices head
//! for twice the thickness), each of its edges and triangles is otherwise
//! looked up and proven apart by a slab of its own, and an edge's lookup is
//! the costly one (issue 29: ~11,000 instructions an edge on the flesh
//! bench, three edges and two triangles a vertex). One lookup around the
//! star and one slab prove the vertex and everything around it.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::scratch::{Scratch, CANDIDATES};
use super::{d, ColliderMotion, ColliderSet, ResolveParams};
use crate::collide::bvh::Bounds;
use crate::collide::geometry::unit;
use crate::collide::proximity;
use crate::collide::skin::Skin;

impl<'a> ColliderSet<'a> {
    /// Per skin vertex: whether it is one of `vertices` whose star (the
    /// vertex, every edge and triangle around it) provably stays farther
    /// than each collider's thickness from it over the step `start → end`.
    /// The colliders stand still (`params.motion` is
    /// [`ColliderMotion::AtCurrent`]); a star no slab proves is left to the
    /// pairwise tests.
    pub(super) fn stars_apart(&self, start: &[Vec3], end: &[Vec3], skin: &Skin, vertices: &[u32], params: &ResolveParams) -> Vec<bool> {
        debug_assert_eq!(params.motion, ColliderMotion::AtCurrent);
        let proven: Vec<u32> = vertices.par_iter().copied().filter(|&v| self.star_apart(start, end, skin, v)).collect();
        let mut apart = vec![false; start.len()];
        for v in proven {
            apart[v as usize] = true;
        }
        apart
    }

    /// [`Self::stars_apart`] for one vertex.
    fn star_apart(&self, start: &[Vec3], end: &[Vec3], skin: &Skin, v: u32) -> bool {
        // The star's corners (the vertex and every corner of its edges and
        // triangles) at both ends of the step.
        let mut corners: Vec<u32> = Vec::with_capacity(16);
        corners.push(v);
        let around = skin.edges_of(v).iter().flat_map(|&k| skin.edges()[k as usize]).chain(skin.triangles_of(v).iter().flat_map(|&k| skin.triangles()[k as usize]));
        for w in around {
            if !corners.contains(&w) {
                corners.push(w);
            }
        }
        let ends: Vec<DVec3> = corners.iter().flat_map(|&w| [d(start[w as usize]), d(end[w as usize])]).collect();
        // The slab's direction: the star's own normal where it ends. A
        // vertex resting a little beyond the thickness over a smooth
        // collider lies, with its star, nearly parallel to the collider's
        // surface there, which then stays on one side of the star's plane.
        let normal = skin.triangles_of(v).iter().fold(DVec3::ZERO, |sum, &k| {
            let [a, b, c] = skin.triangles()[k as usize].map(|w| d(end[w as usize]));
            sum + (b - a).cross(c - a)
        });
        let n = unit(normal);
        let reach = corners.iter().fold(Bounds::EMPTY, |b, &w| b.union(Bounds::of_points(&[start[w as usize], end[w as usize]])));
        let mut candidates = Scratch::lend(&CANDIDATES);
        self.colliders.iter().enumerate().all(|(c, col)| {
            // Leaf boxes hold their triangles grown by the thickness: one
            // that misses the star's box is farther than that from the star.
            candidates.clear();
            self.triangle_tree(c, ColliderMotion::AtCurrent).query(&reach, |t| {
                candidates.push(t as u32);
                true
            });
            // Each candidate is the convex hull of its corners, each element
            // of the star that of its own, which move linearly: corners on
            // either side of the slab at both ends keep them apart. (Corners
            // are read as often as their triangles list them: gathering each
            // once cost more than the repeats.)
            let separation = self.ccd_params(col.settings().thickness as f64).min_separation;
            let patch = candidates.iter().flat_map(|&t| col.triangles()[t as usize]).map(|w| d(col.current()[w as usize]));
            candidates.is_empty() || n.is_some_and(|n| proximity::separated_along_still(n, &ends, patch, self.scale, separation))
        })
    }
}
