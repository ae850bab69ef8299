//! Per-gather bounds of every node of the patch tree over a motion: where
//! its triangles start, how far they move, and which way their normals
//! point, over the whole motion.
//!
//! A motion is every vertex going linearly from `start` to `end` over the
//! pass, plus, anywhere along the way, an extra offset of at most its
//! `margin` (the corrections a pass's rounds may still add, or for the
//! in-loop passes the whole motion: `start = end` = the reference and the
//! margin how far a vertex may stray from it before the candidates are
//! gathered again).
//!
//! * **Boxes.** Per node, the box of its start positions and the box of its
//!   displacements (with 0, grown by the margins). Two vertices share their
//!   time parameter, so the difference of two points of two nodes lies in
//!   `start_A − start_B + t·(motion_A − motion_B)`, `t ∈ [0, 1]`: the
//!   relative box of [`relative_gap`].
//! * **Normal cones** (Tang et al. 2009, continuous normal cones). A
//!   triangle's normal `(b − a) × (c − a)` is quadratic in `t`; in Bernstein
//!   form it is a non-negative combination of `n₀`, `(e₁(0) × e₂(1) + e₁(1) ×
//!   e₂(0))/2` and `n₁`, so every normal over the motion lies in the cone
//!   those three span. The node keeps the box of their unit directions: a
//!   direction `V` with a positive dot product with every corner of the box
//!   has one with every normal. The margins turn a normal by at most
//!   `asin((2m(|e₁| + |e₂|) + 4m²) / h)` (`h` a lower bound of `|n(t)|`),
//!   kept as the cone's widening `theta`.
//! * **The contour criterion** ([`Self::cannot_touch_itself`]): Volino and
//!   Magnenat-Thalmann (1994): a disk whose normals all have a positive dot
//!   product with `V` projects along `V` onto a plane as an
//!   orientation-preserving immersion, so each point of the plane has as many
//!   preimages as its boundary winds around it. If no point is wound around
//!   twice, the disk cannot touch itself. A closed curve that winds twice
//!   around a point turns by at least 4π in all (its height in any direction
//!   has at least four critical points; Fáry–Milnor), so a projected
//!   boundary whose turning stays below 4π over the whole motion proves it.
//!   Each edge's projected direction turns by at most the angle between its
//!   ends' projections (plus its margins' share), so the turning at the
//!   start plus twice those bounds is a bound over the motion.

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::tree::PatchTree;
use crate::collide::bvh::Bounds;

/// The unit-normal box of a node and how far its margins may turn them.
#[derive(Debug, Clone, Copy)]
pub(super) struct Cone {
    lo: Vec3,
    hi: Vec3,
    theta: f32,
    /// Some normal is undefined or turns too far: no direction to test.
    wide: bool,
}

impl Cone {
    const EMPTY: Cone = Cone { lo: Vec3::splat(f32::INFINITY), hi: Vec3::splat(f32::NEG_INFINITY), theta: 0.0, wide: false };
    const WIDE: Cone = Cone { lo: Vec3::splat(f32::INFINITY), hi: Vec3::splat(f32::NEG_INFINITY), theta: 0.0, wide: true };

    fn union(self, o: Cone) -> Cone {
        Cone { lo: self.lo.min(o.lo), hi: self.hi.max(o.hi), theta: self.theta.max(o.theta), wide: self.wide || o.wide }
    }

    fn add(&mut self, n: Vec3) {
        self.lo = self.lo.min(n);
        self.hi = self.hi.max(n);
    }

    /// A direction with a positive dot product with every normal the cone
    /// holds, turned by its `theta`, if the box's centre is one.
    fn axis(&self) -> Option<Vec3> {
        if self.wide || !(self.lo.cmple(self.hi).all()) {
            return None;
        }
        let v = ((self.lo + self.hi) * 0.5).try_normalize()?;
        let mut least = f32::INFINITY;
        for k in 0..8 {
            let corner = Vec3::new(
                if k & 1 == 0 { self.lo.x } else { self.hi.x },
                if k & 2 == 0 { self.lo.y } else { self.hi.y },
                if k & 4 == 0 { self.lo.z } else { self.hi.z },
            );
            least = least.min(corner.dot(v));
        }
        // Every normal is within acos(least) of v; turned by theta it must
        // stay short of 90° (with room for the f32 arithmetic).
        (least > self.theta.sin() + 1e-4).then_some(v)
    }
}

/// Slack on angles and boxes for the f32 arithmetic of the bounds.
const ANGLE_SLACK: f32 = 1e-4;

/// The bounds of every node of a tree over one motion.
pub(super) struct NodeBounds {
    pub start: Vec<Bounds>,
    pub motion: Vec<Bounds>,
    pub cone: Vec<Cone>,
    /// Whether the node holds a triangle taking part (the weights' region).
    pub active: Vec<bool>,
}

/// Per-vertex inputs of a motion.
#[derive(Clone, Copy)]
pub(super) struct Motion<'a> {
    pub start: &'a [Vec3],
    pub end: &'a [Vec3],
    pub margin: &'a [f32],
}

impl Motion<'_> {
    /// The box of vertex `v`'s displacements, with 0, grown by its margin.
    pub(super) fn displacement(&self, v: u32) -> Bounds {
        let d = self.end[v as usize] - self.start[v as usize];
        let m = Vec3::splat(self.margin[v as usize]);
        Bounds { min: d.min(Vec3::ZERO) - m, max: d.max(Vec3::ZERO) + m }
    }

    pub(super) fn start_box(&self, corners: &[u32]) -> Bounds {
        corners.iter().fold(Bounds::EMPTY, |b, &v| {
            let p = self.start[v as usize];
            Bounds { min: b.min.min(p), max: b.max.max(p) }
        })
    }

    pub(super) fn motion_box(&self, corners: &[u32]) -> Bounds {
        corners.iter().fold(Bounds::EMPTY, |b, &v| b.union(self.displacement(v)))
    }
}

/// The distance from the origin to the box that holds every difference of a
/// point of `A` and a point of `B` over the motion (0 when they may meet).
pub(super) fn relative_gap(start_a: &Bounds, motion_a: &Bounds, start_b: &Bounds, motion_b: &Bounds) -> f32 {
    let lo = (start_a.min - start_b.max) + (motion_a.min - motion_b.max);
    let hi = (start_a.max - start_b.min) + (motion_a.max - motion_b.min);
    Vec3::ZERO.max(lo).max(-hi).length()
}

/// Bounds of one triangle: normals over the motion and their widening.
fn triangle_cone(motion: &Motion<'_>, t: [u32; 3]) -> Cone {
    let [a, b, c] = t.map(|v| v as usize);
    let (s, e) = (motion.start, motion.end);
    let (e1s, e2s, e1e, e2e) = (s[b] - s[a], s[c] - s[a], e[b] - e[a], e[c] - e[a]);
    let n0 = e1s.cross(e2s);
    let n1 = e1e.cross(e2e);
    let nm = 0.5 * (e1s.cross(e2e) + e1e.cross(e2s));
    let Some(u) = (n0 + nm + n1).try_normalize() else { return Cone::WIDE };
    let h = n0.dot(u).min(nm.dot(u)).min(n1.dot(u));
    let scale = n0.length() + n1.length() + nm.length();
    if !(h > 1e-5 * scale) {
        return Cone::WIDE;
    }
    let m = motion.margin[a].max(motion.margin[b]).max(motion.margin[c]);
    let mut theta = ANGLE_SLACK;
    if m > 0.0 {
        let lengths = e1s.length().max(e1e.length()) + e2s.length().max(e2e.length());
        let x = (2.0 * m * lengths + 4.0 * m * m) / h;
        if !(x < 0.99) {
            return Cone::WIDE;
        }
        theta += x.asin();
    }
    let mut cone = Cone { theta, ..Cone::EMPTY };
    for n in [n0, n1, nm] {
        // A zero middle term adds nothing to the cone the other two span.
        if let Some(n) = n.try_normalize() {
            cone.add(n);
        }
    }
    cone
}

impl NodeBounds {
    /// Bounds of every node over `motion`; `takes_part[p]` says whether the
    /// triangle at tree position `p` is tested at all (None: all are).
    pub(super) fn new(tree: &PatchTree, motion: &Motion<'_>, takes_part: Option<&[bool]>) -> Self {
        let count = tree.nodes.len();
        let leaf_bounds: Vec<(Bounds, Bounds, Cone, bool)> = tree
            .leaves
            .par_iter()
            .with_min_len(64)
            .map(|&leaf| {
                let node = tree.nodes[leaf as usize];
                let (mut start, mut moved, mut cone, mut active) = (Bounds::EMPTY, Bounds::EMPTY, Cone::EMPTY, false);
                for p in node.range() {
                    let t = tree.triangles[p];
                    start = start.union(motion.start_box(&t));
                    moved = moved.union(motion.motion_box(&t));
                    cone = cone.union(triangle_cone(motion, t));
                    active |= takes_part.is_none_or(|flags| flags[p]);
                }
                (start, moved, cone, active)
            })
            .collect();
        let mut bounds = NodeBounds {
            start: vec![Bounds::EMPTY; count],
            motion: vec![Bounds::EMPTY; count],
            cone: vec![Cone::EMPTY; count],
            active: vec![false; count],
        };
        for (&leaf, (start, moved, cone, active)) in tree.leaves.iter().zip(leaf_bounds) {
            let i = leaf as usize;
            (bounds.start[i], bounds.motion[i], bounds.cone[i], bounds.active[i]) = (start, moved, cone, active);
        }
        for i in (0..count).rev() {
            let node = tree.nodes[i];
            if node.is_leaf() {
                continue;
            }
            let (l, r) = (node.left as usize, node.left as usize + 1);
            bounds.start[i] = bounds.start[l].union(bounds.start[r]);
            bounds.motion[i] = bounds.motion[l].union(bounds.motion[r]);
            bounds.cone[i] = bounds.cone[l].union(bounds.cone[r]);
            bounds.active[i] = bounds.active[l] || bounds.active[r];
        }
        bounds
    }

    /// Whether node `i` provably cannot touch itself anywhere over the
    /// motion: a disk whose normal cone has an axis and whose projected
    /// boundary turns by less than 4π (see the module documentation).
    pub(super) fn cannot_touch_itself(&self, tree: &PatchTree, motion: &Motion<'_>, i: usize) -> bool {
        if !tree.disk[i] {
            return false;
        }
        let Some(v) = self.cone[i].axis() else { return false };
        let (b1, b2) = v.any_orthonormal_pair();
        let project = |p: Vec3| Vec2::new(p.dot(b1), p.dot(b2));
        let ring = tree.boundary(i);
        let k = ring.len();
        let edge = |j: usize, positions: &[Vec3]| project(positions[ring[(j + 1) % k] as usize]) - project(positions[ring[j] as usize]);
        let mut turning = 0.0f32;
        let mut drift = 0.0f32;
        let mut previous = edge(k - 1, motion.start);
        for j in 0..k {
            let (e0, e1) = (edge(j, motion.start), edge(j, motion.end));
            let m = motion.margin[ring[j] as usize] + motion.margin[ring[(j + 1) % k] as usize];
            // The nearest the projected edge vector comes to zero over the motion.
            let d = e1 - e0;
            let t = if d.length_squared() > 0.0 { (-e0.dot(d) / d.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
            let r = (e0 + t * d).length();
            if !(r > m * (1.0 + 1e-3) + 1e-12) {
                return false;
            }
            drift += e0.perp_dot(e1).abs().atan2(e0.dot(e1)) + (m / r).min(1.0).asin();
            turning += previous.perp_dot(e0).atan2(previous.dot(e0)).abs();
            previous = e0;
        }
        let bound = turning + 2.0 * drift + ANGLE_SLACK * k as f32;
        bound < 4.0 * std::f32::consts::PI - 1e-3
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::shapes::grid;
    use crate::mesh::{fan_triangles, MeshInput};

    fn tree_of(mesh: MeshInput<'_>) -> PatchTree {
        PatchTree::build(&fan_triangles(mesh.corner_verts, &mesh.validate().unwrap()), mesh.positions)
    }

    #[test]
    fn a_flat_grid_cannot_touch_itself_a_folded_one_can() {
        let g = grid(10, 10, 1.0);
        let tree = tree_of(g.input());
        let zero = vec![0.0; g.positions.len()];
        let still = Motion { start: &g.positions, end: &g.positions, margin: &zero };
        let bounds = NodeBounds::new(&tree, &still, None);
        assert!(bounds.cannot_touch_itself(&tree, &still, 0));
        // Folded in half over x = 0 onto itself: normals on both sides.
        let folded: Vec<Vec3> = g.positions.iter().map(|p| if p.x > 0.0 { Vec3::new(-p.x, p.y, 0.02) } else { *p }).collect();
        let fold = Motion { start: &g.positions, end: &folded, margin: &zero };
        let bounds = NodeBounds::new(&tree, &fold, None);
        assert!(!bounds.cannot_touch_itself(&tree, &fold, 0));
        // A margin as large as the mesh leaves nothing proven.
        let big = vec![0.5; g.positions.len()];
        let loose = Motion { start: &g.positions, end: &g.positions, margin: &big };
        let bounds = NodeBounds::new(&tree, &loose, None);
        assert!(!bounds.cannot_touch_itself(&tree, &loose, 0));
    }

    #[test]
    fn a_flat_spiral_ramp_is_caught_by_the_contour() {
        // A strip wound 1.5 times around the z axis, rising slowly: every
        // normal points up, yet it lies over itself. The normal test alone
        // would pass it; the projected boundary turns far more than 4π.
        let (around, across) = (90usize, 3usize);
        let mut positions = Vec::new();
        for i in 0..around {
            let angle = 3.0 * std::f32::consts::PI * i as f32 / (around - 1) as f32;
            for j in 0..across {
                let r = 1.0 + 0.2 * j as f32;
                positions.push(Vec3::new(r * angle.cos(), r * angle.sin(), 0.05 * angle));
            }
        }
        let mut corners = Vec::new();
        for i in 0..around - 1 {
            for j in 0..across - 1 {
                let at = |i: usize, j: usize| (i * across + j) as i32;
                corners.extend_from_slice(&[at(i, j), at(i, j + 1), at(i + 1, j + 1), at(i + 1, j)]);
            }
        }
        let sizes = vec![4; corners.len() / 4];
        let mesh = MeshInput { positions: &positions, corner_verts: &corners, polygon_sizes: &sizes };
        let tree = tree_of(mesh);
        let zero = vec![0.0; positions.len()];
        let still = Motion { start: &positions, end: &positions, margin: &zero };
        let bounds = NodeBounds::new(&tree, &still, None);
        assert!(tree.disk[0]);
        assert!(bounds.cone[0].axis().is_some(), "the normals fit a cone: the contour has to decide");
        assert!(!bounds.cannot_touch_itself(&tree, &still, 0));
    }
}
