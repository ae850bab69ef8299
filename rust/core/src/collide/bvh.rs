//! A bounding-volume hierarchy over axis-aligned boxes (`obvhs` BVH2, built by
//! PLOC), with refitting and a quality figure that decides when to rebuild.
//!
//! `obvhs` 0.4 speaks glam 0.34 while the crate uses glam 0.30, so boxes cross
//! the boundary as `[f32; 3]` arrays ([`Bounds`] is this crate's box).
//!
//! Quality is measured by the surface-area-heuristic cost of the tree,
//! normalised by the root's area: `Σ_inner A(n)/A(root) + Σ_leaf count·A(n)/A(root)`.
//! Rigid motion leaves it unchanged; deformation that makes refitted boxes
//! overlap more raises it. [`BoxTree::update`] refits, then rebuilds when the
//! cost exceeds [`BoxTree::rebuild_ratio`] times the cost right after the last
//! build.

use std::time::Duration;

use glam::{DVec3, Vec3};
use obvhs::aabb::Aabb;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::bvh2::Bvh2;
use obvhs::BvhBuildParams;
use rayon::prelude::*;

use crate::{Error, Result};

/// An axis-aligned box, `min ≤ max` component-wise when valid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    pub min: Vec3,
    pub max: Vec3,
}

impl Bounds {
    /// When the path `s → e` (parameter 0..1) first enters the box grown by
    /// `grow`, or `None` if it misses it.
    ///
    /// A ray cast walks a tree through this test many times (the compliant
    /// recessions' heading rays, issue 29): it is written out per axis with
    /// plain comparisons and stops at the first axis that leaves the path
    /// outside. No operand can be NaN (finite boxes and ends, a non-zero
    /// divisor), so it answers exactly as `max`/`min` over all three axes.
    pub fn entry_time(&self, s: DVec3, e: DVec3, grow: f64) -> Option<f64> {
        let direction = e - s;
        let (mut enter, mut leave) = (0.0f64, 1.0f64);
        for k in 0..3 {
            let (lo, hi) = (self.min[k] as f64 - grow, self.max[k] as f64 + grow);
            if direction[k] == 0.0 {
                if s[k] < lo || s[k] > hi {
                    return None;
                }
                continue;
            }
            let (a, b) = ((lo - s[k]) / direction[k], (hi - s[k]) / direction[k]);
            let (near, far) = if a <= b { (a, b) } else { (b, a) };
            if near > enter {
                enter = near;
            }
            if far < leave {
                leave = far;
            }
            // Rounding of the divisions: a path grazing a face may come out
            // just outside; the growth is far larger than that, so the order
            // still holds.
            if enter > leave {
                return None;
            }
        }
        Some(enter)
    }

    /// The box that contains nothing (union identity).
    pub const EMPTY: Bounds = Bounds { min: Vec3::splat(f32::INFINITY), max: Vec3::splat(f32::NEG_INFINITY) };

    /// The smallest box holding all `points`.
    pub fn of_points(points: &[Vec3]) -> Bounds {
        let mut b = Bounds::EMPTY;
        for &p in points {
            b.min = b.min.min(p);
            b.max = b.max.max(p);
        }
        b
    }

    /// A box holding all f64 `points`, rounded outward to f32 so that it
    /// contains them exactly.
    pub fn of_points_f64(points: &[DVec3]) -> Bounds {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for &p in points {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        Bounds {
            min: Vec3::new(round_down(lo.x), round_down(lo.y), round_down(lo.z)),
            max: Vec3::new(round_up(hi.x), round_up(hi.y), round_up(hi.z)),
        }
    }

    /// This box grown by `margin` on every side.
    pub fn inflated(self, margin: f32) -> Bounds {
        Bounds { min: self.min - Vec3::splat(margin), max: self.max + Vec3::splat(margin) }
    }

    pub fn union(self, other: Bounds) -> Bounds {
        Bounds { min: self.min.min(other.min), max: self.max.max(other.max) }
    }

    /// True when the closed boxes share a point.
    pub fn overlaps(&self, other: &Bounds) -> bool {
        self.min.cmple(other.max).all() && other.min.cmple(self.max).all()
    }

    pub fn contains(&self, p: Vec3) -> bool {
        self.min.cmple(p).all() && p.cmple(self.max).all()
    }

    pub fn is_valid(&self) -> bool {
        self.min.is_finite() && self.max.is_finite() && self.min.cmple(self.max).all()
    }

    fn half_area(&self) -> f64 {
        let d = (self.max - self.min).max(Vec3::ZERO).as_dvec3();
        d.x * d.y + d.y * d.z + d.z * d.x
    }

    fn to_aabb(self) -> Aabb {
        Aabb::new(self.min.to_array().into(), self.max.to_array().into())
    }

    fn from_aabb(aabb: &Aabb) -> Bounds {
        Bounds { min: Vec3::from_array(aabb.min.to_array()), max: Vec3::from_array(aabb.max.to_array()) }
    }
}

/// How much of box `b` is the `margin` its primitive's box was grown by (0
/// for a margin of 0). A query that measures from a box only to bound its
/// primitive learns more from the box less that: around a skin whose
/// triangles are smaller than twice the thickness, the grown boxes of a whole
/// patch come nearer a point than its nearest triangle, and each is then
/// measured. A relative 1e-6 of the margin is kept, for the f32 rounding of
/// the growth, so that the box less it still holds its primitive.
fn grown_by(b: &Bounds, margin: f64) -> f64 {
    grown_less(margin, rounding_of(b))
}

/// The allowance for the f32 rounding of box `b`: a relative 1e-6 of its
/// largest coordinate.
fn rounding_of(b: &Bounds) -> f64 {
    1e-6 * (1.0 + b.min.abs().max(b.max.abs()).max_element() as f64)
}

/// [`grown_by`] for a box whose [`rounding_of`] is known.
fn grown_less(margin: f64, rounding: f64) -> f64 {
    if margin <= 0.0 { 0.0 } else { (margin - rounding).max(0.0) }
}

/// Largest f32 not above `x`.
pub fn round_down(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) > x { next_toward_neg_inf(f) } else { f }
}

/// Smallest f32 not below `x`.
pub fn round_up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x { -next_toward_neg_inf(-f) } else { f }
}

fn next_toward_neg_inf(f: f32) -> f32 {
    if f.is_nan() || f == f32::NEG_INFINITY {
        return f;
    }
    if f == 0.0 {
        return -f32::from_bits(1);
    }
    let bits = f.to_bits();
    if f > 0.0 { f32::from_bits(bits - 1) } else { f32::from_bits(bits + 1) }
}

/// What one [`BoxTree::update`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpdateReport {
    /// SAH cost after refitting divided by the cost after the last build.
    pub cost_ratio: f64,
    /// Whether the tree was rebuilt.
    pub rebuilt: bool,
}

/// A BVH over a fixed number of boxes whose extents change over time.
#[derive(Clone)]
pub struct BoxTree {
    bvh: Option<Bvh2>,
    /// The primitive boxes (leaves hold up to 8, each tested on its own).
    boxes: Vec<Bounds>,
    count: usize,
    build_cost: f64,
    /// Rebuild when the SAH cost grows past this multiple of the built cost.
    pub rebuild_ratio: f64,
    rebuilds: usize,
    refits: usize,
}

fn check_boxes(boxes: &[Bounds]) -> Result<()> {
    if let Some(i) = boxes.iter().position(|b| !b.is_valid()) {
        return Err(Error::invalid(format!(
            "bounding box {i} is not finite or has min > max ({:?} .. {:?})",
            boxes[i].min.to_array(),
            boxes[i].max.to_array()
        )));
    }
    if boxes.len() >= u32::MAX as usize {
        return Err(Error::invalid(format!("{} boxes is more than a BVH supports", boxes.len())));
    }
    Ok(())
}

impl std::fmt::Debug for BoxTree {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BoxTree")
            .field("count", &self.count)
            .field("nodes", &self.bvh.as_ref().map_or(0, |b| b.nodes.len()))
            .field("build_cost", &self.build_cost)
            .field("rebuilds", &self.rebuilds)
            .field("refits", &self.refits)
            .finish()
    }
}

impl BoxTree {
    /// Default for [`BoxTree::rebuild_ratio`].
    pub const DEFAULT_REBUILD_RATIO: f64 = 1.4;

    /// Builds a tree over `boxes` (primitive `i` is `boxes[i]`).
    pub fn build(boxes: &[Bounds]) -> Result<Self> {
        check_boxes(boxes)?;
        let mut tree = BoxTree {
            bvh: None,
            boxes: boxes.to_vec(),
            count: boxes.len(),
            build_cost: 0.0,
            rebuild_ratio: Self::DEFAULT_REBUILD_RATIO,
            rebuilds: 0,
            refits: 0,
        };
        tree.rebuild(boxes);
        Ok(tree)
    }

    fn rebuild(&mut self, boxes: &[Bounds]) {
        if boxes.is_empty() {
            self.bvh = None;
            self.build_cost = 0.0;
            return;
        }
        let aabbs: Vec<Aabb> = boxes.iter().map(|b| b.to_aabb()).collect();
        let mut time = Duration::ZERO;
        let bvh = build_bvh2(&aabbs, BvhBuildParams::fast_build(), &mut time);
        self.bvh = Some(bvh);
        self.build_cost = self.sah_cost();
    }

    /// Number of boxes the tree was built over.
    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// How many times [`update`](Self::update) rebuilt / refitted.
    pub fn rebuild_count(&self) -> usize {
        self.rebuilds
    }
    pub fn refit_count(&self) -> usize {
        self.refits
    }

    /// Normalised SAH cost (see the module doc); 0 for an empty tree.
    pub fn sah_cost(&self) -> f64 {
        let Some(bvh) = &self.bvh else { return 0.0 };
        let root = Bounds::from_aabb(bvh.nodes[0].aabb()).half_area();
        if root <= 0.0 {
            return 1.0;
        }
        // Fixed chunks summed in order: the same cost, and so the same rebuild
        // decision, on any thread count (a parallel sum's order is not fixed).
        const CHUNK: usize = 4096;
        let partial: Vec<f64> = bvh
            .nodes
            .par_chunks(CHUNK)
            .map(|chunk| {
                chunk
                    .iter()
                    .map(|n| {
                        let a = Bounds::from_aabb(n.aabb()).half_area();
                        if n.is_leaf() { a * n.prim_count as f64 } else { a }
                    })
                    .sum::<f64>()
            })
            .collect();
        partial.iter().sum::<f64>() / root
    }

    /// Cost now divided by the cost right after the last build.
    pub fn cost_ratio(&self) -> f64 {
        if self.build_cost > 0.0 { self.sah_cost() / self.build_cost } else { 1.0 }
    }

    /// Replaces the boxes (same count, same order): refits, and rebuilds if
    /// the refitted tree's cost ratio exceeds [`rebuild_ratio`](Self::rebuild_ratio).
    pub fn update(&mut self, boxes: &[Bounds]) -> Result<UpdateReport> {
        if boxes.len() != self.count {
            return Err(Error::Topology(format!(
                "the BVH was built over {} boxes, the update gave {}",
                self.count,
                boxes.len()
            )));
        }
        check_boxes(boxes)?;
        self.boxes.copy_from_slice(boxes);
        self.refit(boxes);
        let cost_ratio = self.cost_ratio();
        let rebuilt = cost_ratio > self.rebuild_ratio;
        if rebuilt {
            self.rebuild(boxes);
            self.rebuilds += 1;
        }
        Ok(UpdateReport { cost_ratio, rebuilt })
    }

    /// Replaces the boxes of some primitives (`changed`: index and new box)
    /// and refits only their leaves and the leaves' ancestors, with no
    /// rebuild: work in proportion to what changed, for a tree whose boxes
    /// mostly stay (see [`super::Collider::rest_at`]). The tree's quality is
    /// not measured; a later [`Self::update`] rebuilds it if it degraded.
    pub fn update_some(&mut self, changed: &[(u32, Bounds)]) -> Result<()> {
        if let Some(&(i, _)) = changed.iter().find(|(i, _)| *i as usize >= self.count) {
            return Err(Error::Topology(format!("box {i} changed in a BVH over {} boxes", self.count)));
        }
        if let Some((i, b)) = changed.iter().find(|(_, b)| !b.is_valid()) {
            return Err(Error::invalid(format!("bounding box {i} is not finite or has min > max ({:?} .. {:?})", b.min.to_array(), b.max.to_array())));
        }
        for &(i, b) in changed {
            self.boxes[i as usize] = b;
        }
        let Some(bvh) = &mut self.bvh else { return Ok(()) };
        bvh.init_parents_if_uninit();
        bvh.init_primitives_to_nodes_if_uninit();
        let mut leaves: Vec<u32> = changed.iter().map(|&(i, _)| bvh.primitives_to_nodes[i as usize]).collect();
        leaves.sort_unstable();
        leaves.dedup();
        for &leaf in &leaves {
            let node = bvh.nodes[leaf as usize];
            let b = (node.first_index..node.first_index + node.prim_count)
                .fold(Bounds::EMPTY, |b, k| b.union(self.boxes[bvh.primitive_indices[k as usize] as usize]));
            bvh.nodes[leaf as usize].set_aabb(b.to_aabb());
        }
        // Every leaf is new before any walk: a node's last refit, on the last
        // walk through it, then sees both children final.
        for &leaf in &leaves {
            bvh.refit_from(leaf as usize);
        }
        self.refits += 1;
        Ok(())
    }

    /// Refits the leaves to the union of their boxes, then the inner nodes.
    fn refit(&mut self, boxes: &[Bounds]) {
        let Some(bvh) = &mut self.bvh else { return };
        let indices = &bvh.primitive_indices;
        bvh.nodes.par_iter_mut().filter(|n| n.is_leaf()).for_each(|node| {
            let mut b = Bounds::EMPTY;
            for k in node.first_index..node.first_index + node.prim_count {
                b = b.union(boxes[indices[k as usize] as usize]);
            }
            node.set_aabb(b.to_aabb());
        });
        bvh.refit_all();
        self.refits += 1;
    }

    /// Calls `visit(primitive)` for every box overlapping `query` (closed
    /// intervals: touching counts). Return false from `visit` to stop.
    pub fn query(&self, query: &Bounds, mut visit: impl FnMut(usize) -> bool) {
        let Some(bvh) = &self.bvh else { return };
        bvh.aabb_traverse(query.to_aabb(), |bvh, node_id| {
            let node = &bvh.nodes[node_id as usize];
            for k in node.first_index..node.first_index + node.prim_count {
                let prim = bvh.primitive_indices[k as usize] as usize;
                if self.boxes[prim].overlaps(query) && !visit(prim) {
                    return false;
                }
            }
            true
        });
    }

    /// The distance from `p` to the nearest primitive box (0 inside one), or
    /// `limit` if none is nearer. Subtrees whose box is no nearer than the
    /// best found so far are skipped, nearer children first, so a point
    /// beside a dense patch of boxes (a fan of triangles at a pole) does not
    /// measure every box of the patch.
    pub fn nearest_distance(&self, p: Vec3, limit: f64) -> f64 {
        let p64 = p.as_dvec3();
        let box_distance = |b: &Bounds| (b.min.as_dvec3() - p64).max(p64 - b.max.as_dvec3()).max(DVec3::ZERO).length();
        self.nearest(p, limit, 0.0, |i| box_distance(&self.boxes[i])).map_or(limit, |(_, d)| d)
    }

    /// The primitive nearest `p` by an exact distance: `distance(i)` is
    /// primitive `i`'s distance from `p`, at least that of its box (a box
    /// bounds its primitive). Best-first over the tree, so only primitives
    /// whose boxes come nearer than the best found so far are measured: a
    /// handful near the surface and deep inside a closed collider alike.
    /// Returns the primitive and its distance, or None for an empty tree or
    /// when nothing is nearer than `limit`.
    ///
    /// `margin` is what the boxes were grown by around their primitives (a
    /// collider's thickness; see [`grown_by`]): the boxes' distances are
    /// measured without it, so that they bound the primitives' as tightly
    /// as they can.
    pub fn nearest(&self, p: Vec3, limit: f64, margin: f64, mut distance: impl FnMut(usize) -> f64) -> Option<(usize, f64)> {
        let bvh = self.bvh.as_ref()?;
        let p64 = p.as_dvec3();
        let box_distance = |b: &Bounds| {
            let less = DVec3::splat(grown_by(b, margin));
            (b.min.as_dvec3() + less - p64).max(p64 - b.max.as_dvec3() + less).max(DVec3::ZERO).length()
        };
        let node_distance = |i: u32| box_distance(&Bounds::from_aabb(bvh.nodes[i as usize].aabb()));
        let mut best: Option<(usize, f64)> = None;
        let mut bound = limit;
        let mut stack: Vec<(u32, f64)> = Vec::with_capacity(64);
        stack.push((0, node_distance(0)));
        while let Some((i, d)) = stack.pop() {
            if d >= bound {
                continue;
            }
            let node = &bvh.nodes[i as usize];
            if node.is_leaf() {
                for k in node.first_index..node.first_index + node.prim_count {
                    let primitive = bvh.primitive_indices[k as usize] as usize;
                    if box_distance(&self.boxes[primitive]) >= bound {
                        continue;
                    }
                    let exact = distance(primitive);
                    if exact < bound {
                        bound = exact;
                        best = Some((primitive, exact));
                    }
                }
                continue;
            }
            let (left, right) = (node.first_index, node.first_index + 1);
            let (dl, dr) = (node_distance(left), node_distance(right));
            // The nearer child is popped first.
            if dl <= dr {
                stack.push((right, dr));
                stack.push((left, dl));
            } else {
                stack.push((left, dl));
                stack.push((right, dr));
            }
        }
        best
    }

    /// The first primitive along the segment `p → q`: `hit(i)` is where the
    /// segment meets primitive `i`, as a fraction of the way from `p` (None
    /// if it misses). Only nodes the segment passes through are opened,
    /// nearest first, and none that start beyond the first hit found: a long
    /// segment across a large mesh meets a few boxes, where the box around
    /// it would hold much of the mesh. `margin` is what the boxes were grown
    /// by around their primitives, as for [`Self::nearest`].
    pub fn first_along(&self, p: Vec3, q: Vec3, margin: f64, mut hit: impl FnMut(usize) -> Option<f64>) -> Option<(usize, f64)> {
        let bvh = self.bvh.as_ref()?;
        let (p64, q64) = (p.as_dvec3(), q.as_dvec3());
        // Where the segment enters a box, as a fraction of it; None if it
        // misses. The box, less the margin, is grown by a relative 1e-6 so
        // that rounding can only let more boxes through.
        let entry = |b: &Bounds| -> Option<f64> {
            // The box's magnitude measured once for both terms.
            let rounding = rounding_of(b);
            b.entry_time(p64, q64, rounding - grown_less(margin, rounding))
        };
        let node_entry = |i: u32| entry(&Bounds::from_aabb(bvh.nodes[i as usize].aabb()));
        let mut best: Option<(usize, f64)> = None;
        let mut stack: Vec<(u32, f64)> = Vec::with_capacity(64);
        if let Some(t) = node_entry(0) {
            stack.push((0, t));
        }
        while let Some((i, t)) = stack.pop() {
            if best.is_some_and(|(_, b)| t > b) {
                continue;
            }
            let node = &bvh.nodes[i as usize];
            if node.is_leaf() {
                for k in node.first_index..node.first_index + node.prim_count {
                    let primitive = bvh.primitive_indices[k as usize] as usize;
                    if entry(&self.boxes[primitive]).is_none() {
                        continue;
                    }
                    if let Some(along) = hit(primitive) {
                        if best.is_none_or(|(_, b)| along < b) {
                            best = Some((primitive, along));
                        }
                    }
                }
                continue;
            }
            let (left, right) = (node.first_index, node.first_index + 1);
            match (node_entry(left), node_entry(right)) {
                // The nearer child is popped first.
                (Some(l), Some(r)) if l <= r => stack.extend([(right, r), (left, l)]),
                (Some(l), Some(r)) => stack.extend([(left, l), (right, r)]),
                (Some(l), None) => stack.push((left, l)),
                (None, Some(r)) => stack.push((right, r)),
                (None, None) => {}
            }
        }
        best
    }

    /// The box of primitive `i` as last given.
    pub fn primitive_bounds(&self, i: usize) -> Bounds {
        self.boxes[i]
    }

    /// Box of the whole tree (EMPTY when there are no boxes).
    pub fn bounds(&self) -> Bounds {
        match &self.bvh {
            Some(bvh) => Bounds::from_aabb(bvh.nodes[0].aabb()),
            None => Bounds::EMPTY,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Changing some boxes and refitting only their leaves and ancestors
    /// finds what a tree built over the new boxes finds.
    #[test]
    fn updating_some_boxes_queries_as_a_new_tree() {
        let mut boxes = grid_boxes(20, 0.0);
        let mut tree = BoxTree::build(&boxes).unwrap();
        let changed: Vec<(u32, Bounds)> = (0..boxes.len() as u32)
            .filter(|i| i % 13 == 0)
            .map(|i| {
                let p = Vec3::new((i % 7) as f32 * 3.0, (i % 5) as f32 * 4.0, (i % 3) as f32);
                (i, Bounds { min: p, max: p + Vec3::splat(0.25) })
            })
            .collect();
        tree.update_some(&changed).unwrap();
        for &(i, b) in &changed {
            boxes[i as usize] = b;
        }
        let fresh = BoxTree::build(&boxes).unwrap();
        assert_eq!(tree.bounds(), fresh.bounds());
        for k in 0..60 {
            let p = Vec3::new((k % 11) as f32 * 2.0 - 1.0, (k % 9) as f32 * 2.5, (k % 4) as f32 * 0.7);
            let query = Bounds { min: p, max: p + Vec3::splat(1.3) };
            let found = |t: &BoxTree| {
                let mut hits = Vec::new();
                t.query(&query, |i| {
                    hits.push(i);
                    true
                });
                hits.sort_unstable();
                hits
            };
            assert_eq!(found(&tree), found(&fresh), "query {k}");
            assert_eq!(tree.nearest_distance(p, 50.0), fresh.nearest_distance(p, 50.0), "point {k}");
        }
        assert!(tree.update_some(&[(boxes.len() as u32, changed[0].1)]).is_err());
        let bad = Bounds { min: Vec3::ONE, max: Vec3::ZERO };
        assert!(tree.update_some(&[(0, bad)]).is_err());
    }

    /// The cost that decides a rebuild is the same on any thread count,
    /// to the bit: the rebuild decision, and so the tree, never depends on it.
    #[test]
    fn the_cost_is_the_same_on_any_thread_count() {
        let boxes = grid_boxes(120, 0.37); // 14,400 boxes: several chunks of nodes
        let tree = BoxTree::build(&boxes).unwrap();
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| tree.sah_cost())
        };
        let one = on(1);
        assert!(one.is_finite() && one > 1.0);
        for threads in [2, 3, 8] {
            assert_eq!(on(threads).to_bits(), one.to_bits(), "{threads} threads");
        }
    }

    fn grid_boxes(n: usize, offset: f32) -> Vec<Bounds> {
        let mut boxes = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let p = Vec3::new(i as f32 + offset * j as f32, j as f32, 0.0);
                boxes.push(Bounds { min: p, max: p + Vec3::splat(0.5) });
            }
        }
        boxes
    }

    fn brute(boxes: &[Bounds], q: &Bounds) -> Vec<usize> {
        (0..boxes.len()).filter(|&i| boxes[i].overlaps(q)).collect()
    }

    fn found(tree: &BoxTree, q: &Bounds) -> Vec<usize> {
        let mut out = Vec::new();
        tree.query(q, |i| {
            out.push(i);
            true
        });
        out.sort();
        out
    }

    proptest::proptest! {
        /// The pruned search finds exactly the brute-force nearest box
        /// distance (capped at the limit), refitted boxes included.
        #[test]
        fn nearest_distance_is_the_brute_force_one(px in -5.0f32..45.0, py in -5.0f32..45.0, pz in -3.0f32..3.0,
                                                   limit in 0.0f64..20.0, shear in 0.0f32..0.05) {
            let boxes = grid_boxes(40, shear);
            let mut tree = BoxTree::build(&grid_boxes(40, 0.0)).unwrap();
            tree.update(&boxes).unwrap();
            let p = Vec3::new(px, py, pz);
            let brute = boxes
                .iter()
                .map(|b| (b.min.as_dvec3() - p.as_dvec3()).max(p.as_dvec3() - b.max.as_dvec3()).max(DVec3::ZERO).length())
                .fold(limit, f64::min);
            proptest::prop_assert_eq!(tree.nearest_distance(p, limit), brute);
        }
    }

    #[test]
    fn query_matches_brute_force_before_and_after_refit_and_rebuild() {
        let boxes = grid_boxes(40, 0.0);
        let mut tree = BoxTree::build(&boxes).unwrap();
        let queries = [
            Bounds { min: Vec3::new(3.2, 4.1, -1.0), max: Vec3::new(7.7, 5.0, 1.0) },
            Bounds { min: Vec3::new(-5.0, -5.0, -5.0), max: Vec3::new(0.5, 0.5, 0.0) },
            Bounds { min: Vec3::new(100.0, 0.0, 0.0), max: Vec3::new(101.0, 1.0, 1.0) },
        ];
        for q in &queries {
            assert_eq!(found(&tree, q), brute(&boxes, q));
        }
        // Small shear: refit only, still exact.
        let moved = grid_boxes(40, 0.01);
        let report = tree.update(&moved).unwrap();
        assert!(!report.rebuilt, "{report:?}");
        for q in &queries {
            assert_eq!(found(&tree, q), brute(&moved, q));
        }
        // Scramble: every box jumps far from its neighbours -> degraded, rebuilt.
        let scrambled: Vec<Bounds> = moved
            .iter()
            .enumerate()
            .map(|(i, b)| {
                let shift = Vec3::new(((i * 7919) % 40) as f32, ((i * 104729) % 40) as f32, 0.0);
                Bounds { min: b.min * 0.0 + shift, max: b.min * 0.0 + shift + Vec3::splat(0.5) }
            })
            .collect();
        let report = tree.update(&scrambled).unwrap();
        assert!(report.cost_ratio > BoxTree::DEFAULT_REBUILD_RATIO && report.rebuilt, "{report:?}");
        assert!(tree.cost_ratio() < 1.0 + 1e-9);
        for q in &queries {
            assert_eq!(found(&tree, q), brute(&scrambled, q));
        }
    }

    #[test]
    fn bad_boxes_and_count_changes_are_errors() {
        let mut boxes = grid_boxes(3, 0.0);
        let mut tree = BoxTree::build(&boxes).unwrap();
        assert!(matches!(tree.update(&boxes[..5]), Err(Error::Topology(_))));
        boxes[4].min.x = f32::NAN;
        let err = tree.update(&boxes).unwrap_err().to_string();
        assert!(err.contains("bounding box 4"), "{err}");
        let empty = BoxTree::build(&[]).unwrap();
        assert!(found(&empty, &boxes[0]).is_empty());
    }

    #[test]
    fn outward_rounding_contains_the_f64_points() {
        for &x in &[0.1f64, -0.1, 1e-30, -1e-30, 0.0, 3.0, 1.0 / 3.0, -7.0 / 3.0] {
            assert!((round_down(x) as f64) <= x && (round_up(x) as f64) >= x, "{x}");
        }
    }
}
