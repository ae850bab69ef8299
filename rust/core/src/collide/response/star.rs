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
use crate::collide::geometry::triangle_normal;
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
        // The star's corners: the vertex and every corner of its edges and triangles.
        let mut corners: Vec<u32> = Vec::with_capacity(16);
        corners.push(v);
        let around = skin.edges_of(v).iter().flat_map(|&k| skin.edges()[k as usize]).chain(skin.triangles_of(v).iter().flat_map(|&k| skin.triangles()[k as usize]));
        for w in around {
            if !corners.contains(&w) {
                corners.push(w);
            }
        }
        let from: Vec<DVec3> = corners.iter().map(|&w| d(start[w as usize])).collect();
        let to: Vec<DVec3> = corners.iter().map(|&w| d(end[w as usize])).collect();
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
            let separation = self.ccd_params(col.settings().thickness as f64).min_separation;
            candidates.is_empty() || self.star_beyond_slab(c, &candidates, &from, &to, separation)
        })
    }

    /// Whether the star's corners (`from → to`) stay beyond one slab from
    /// collider `c`'s `candidates` (standing still), farther than
    /// `separation`. The slab's direction is the normal of the candidate
    /// whose centroid is nearest the star's centre: under a vertex resting a
    /// little beyond the thickness over a smooth collider, the tangent plane
    /// there bounds the whole patch. Each element of the star is the convex
    /// hull of its corners, which move linearly, and each candidate that of
    /// its own, so corners beyond the slab at both ends keep them apart.
    /// (The corners are read straight from the collider, each as often as
    /// its triangles list it: gathering them once, as the per-element slabs
    /// do, cost more than the repeats on the flesh bench.)
    fn star_beyond_slab(&self, c: usize, candidates: &[u32], from: &[DVec3], to: &[DVec3], separation: f64) -> bool {
        let col = self.colliders[c];
        let corners = |t: u32| col.triangles()[t as usize].map(|v| d(col.current()[v as usize]));
        let centre = from.iter().chain(to).copied().sum::<DVec3>() / (from.len() + to.len()) as f64;
        let mut nearest = (f64::INFINITY, candidates[0]);
        for &t in candidates {
            let [a, b, q] = corners(t);
            let gap = ((a + b + q) / 3.0 - centre).length_squared();
            if gap < nearest.0 {
                nearest = (gap, t);
            }
        }
        let [a, b, q] = corners(nearest.1);
        let Some(n) = triangle_normal(a, b, q) else { return false };
        let patch = candidates.iter().flat_map(|&t| corners(t)).map(|p| (p, p));
        proximity::separated_along(n, DVec3::ZERO, from, to, patch, separation)
    }
}
