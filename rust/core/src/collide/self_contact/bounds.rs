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
//! * **Boxes.** Per node, the box of its start positions, the box of its
//!   displacements and its largest margin. Two vertices share their time
//!   parameter, so the difference of two points of two nodes lies in
//!   `start_A − start_B + t·(motion_A − motion_B)`, `t ∈ [0, 1]`, give or
//!   take the two margins: the relative box of [`relative_gap`]. A rigidly
//!   moving limb moves its patches alike, and their relative box stays put.
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
//!   boundary whose turning stays below 4π over the whole motion proves it
//!   (each exterior angle bounded over the motion, [`winds_once`]).

use glam::{DVec3, Vec2, Vec3};
use rayon::prelude::*;

use super::tree::PatchTree;
use crate::collide::bvh::Bounds;
use crate::collide::geometry::{point_triangle_distance_squared, segment_segment_distance_squared};

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

/// Where an element or a node starts, how it moves, and how far beyond that
/// it may stray.
#[derive(Debug, Clone, Copy)]
pub(super) struct Span {
    pub start: Bounds,
    pub motion: Bounds,
    pub margin: f32,
}

impl Span {
    pub(super) const EMPTY: Span = Span { start: Bounds::EMPTY, motion: Bounds::EMPTY, margin: 0.0 };

    pub(super) fn union(self, o: Span) -> Span {
        Span { start: self.start.union(o.start), motion: self.motion.union(o.motion), margin: self.margin.max(o.margin) }
    }
}

/// The bounds of every node of a tree over one motion.
#[derive(Debug, Clone)]
pub(super) struct NodeBounds {
    pub span: Vec<Span>,
    pub cone: Vec<Cone>,
    /// Whether the node holds a triangle taking part (the weights' region).
    pub active: Vec<bool>,
    /// Per tree position, its triangle's span: fitted with the leaves, so
    /// that a gathering's leaf pairs and vertex–triangle pairs read it
    /// instead of making it again for every leaf pair it takes part in (a
    /// whole gathering on the MakeHuman character visits about 17k leaf
    /// pairs of 8 triangles for 53k triangles, issue 30, eleventh round).
    pub triangle: Vec<Span>,
    /// Per tree position, its triangle's normal cone, kept for the same
    /// reason: the star rule unions the cones of a vertex's triangles
    /// ([`super::star::Stars::memo_over`]).
    pub triangle_cone: Vec<Cone>,
}

/// Per-vertex inputs of a motion.
#[derive(Clone, Copy)]
pub(super) struct Motion<'a> {
    pub start: &'a [Vec3],
    pub end: &'a [Vec3],
    pub margin: &'a [f32],
}

impl Motion<'_> {
    /// The span of an element with these corners.
    pub(super) fn span(&self, corners: &[u32]) -> Span {
        corners.iter().fold(Span::EMPTY, |b, &v| {
            let (s, e) = (self.start[v as usize], self.end[v as usize]);
            let d = e - s;
            Span {
                start: Bounds { min: b.start.min.min(s), max: b.start.max.max(s) },
                motion: Bounds { min: b.motion.min.min(d), max: b.motion.max.max(d) },
                margin: b.margin.max(self.margin[v as usize]),
            }
        })
    }
}

/// A lower bound of the distance between any point of `a` and any point of
/// `b` over the motion (0 when they may meet): the distance from the origin
/// to their relative box, less the two margins.
pub(super) fn relative_gap(a: &Span, b: &Span) -> f32 {
    let drift_lo = (a.motion.min - b.motion.max).min(Vec3::ZERO);
    let drift_hi = (a.motion.max - b.motion.min).max(Vec3::ZERO);
    let lo = (a.start.min - b.start.max) + drift_lo;
    let hi = (a.start.max - b.start.min) + drift_hi;
    (Vec3::ZERO.max(lo).max(-hi).length() - a.margin - b.margin).max(0.0)
}

/// A lower bound of the distance between two elements (a vertex and a
/// triangle, or two edges: `one`, `other`) over the motion, from their exact
/// distances at its two ends. For any fixed pair of points of the two
/// elements (fixed barycentric weights) the difference moves by a convex
/// combination of the corners' relative displacements, so the distance
/// changes at most `K = max |d_i − d_j|` over the motion (`i` of one side,
/// `j` of the other): at `t` it is at least `max(d₀ − tK, d₁ − (1 − t)K)`,
/// and the least of that over `t`, less the two sides' margins, bounds it
/// everywhere. Elements carried along together (a limb moving as a whole,
/// turning little over an element's size) keep about their distance, where
/// their boxes would not show it: tilted triangles' axis-aligned boxes
/// overlap across a ring of neighbours.
/// Gatherings ask [`element_within`], which answers as this does.
#[cfg(test)]
pub(super) fn element_gap(motion: &Motion<'_>, one: &[u32], other: &[u32]) -> f64 {
    let (d0, d1) = (end_distance(motion.start, one, other), end_distance(motion.end, one, other));
    let (m0, m1) = element_margins(motion, one, other);
    let k = relative_motion(motion, one, other);
    // A K-Lipschitz distance that is d0 and d1 at the ends is at least
    // (d0 + d1 − K) / 2 in between; the ends themselves bound it where
    // rounding leaves |d0 − d1| a hair above K.
    let least = (0.5 * (d0 + d1 - k)).min(d0).min(d1);
    least - m0 as f64 - m1 as f64
}

/// Whether `element_gap` is not above `reach` (`!(gap > reach)`, a NaN
/// gap included), worked out with as little as decides it: the gap is at
/// most either end's distance less the margins, so a pair within the
/// reach at the start needs neither the end nor `K` (the rounded
/// subtractions are monotone, so the answer is `element_gap`'s to the bit).
/// A gathering's near pairs are mostly within the reach at both ends.
pub(super) fn element_within(motion: &Motion<'_>, one: &[u32], other: &[u32], reach: f64) -> bool {
    let (m0, m1) = element_margins(motion, one, other);
    let less_margins = |d: f64| d - m0 as f64 - m1 as f64;
    let d0 = end_distance(motion.start, one, other);
    if less_margins(d0) <= reach {
        return true;
    }
    let d1 = end_distance(motion.end, one, other);
    if less_margins(d1) <= reach {
        return true;
    }
    let k = relative_motion(motion, one, other);
    let least = (0.5 * (d0 + d1 - k)).min(d0).min(d1);
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // a NaN gap is within, as `element_gap > reach` lets it through
    let within = !(less_margins(least) > reach);
    within
}

/// The distance between two elements (a vertex and a triangle, or two
/// edges) at `positions`, or a lower bound of it for a sliver
/// ([`point_triangle_lower_bound`]).
fn end_distance(positions: &[Vec3], one: &[u32], other: &[u32]) -> f64 {
    let at = |corners: &[u32]| -> [DVec3; 3] {
        let mut p = [DVec3::ZERO; 3];
        for (k, &v) in corners.iter().enumerate() {
            p[k] = positions[v as usize].as_dvec3();
        }
        p
    };
    let (a, b) = (at(one), at(other));
    match (one.len(), other.len()) {
        (1, 3) => point_triangle_lower_bound(a[0], b),
        (3, 1) => point_triangle_lower_bound(b[0], a),
        _ => segment_segment_distance_squared(a[0], a[1], b[0], b[1]).sqrt(),
    }
}

/// `K`: the largest relative displacement of a corner of one element and a
/// corner of the other, in f64 from the f32 ends, so that it is not
/// rounded below the true relative motion.
fn relative_motion(motion: &Motion<'_>, one: &[u32], other: &[u32]) -> f64 {
    let displacement = |v: u32| motion.end[v as usize].as_dvec3() - motion.start[v as usize].as_dvec3();
    let mut k = 0.0f64;
    for &i in one {
        for &j in other {
            k = k.max((displacement(i) - displacement(j)).length());
        }
    }
    k
}

/// The largest margin of each element's corners.
fn element_margins(motion: &Motion<'_>, one: &[u32], other: &[u32]) -> (f32, f32) {
    let most = |corners: &[u32]| corners.iter().fold(0.0f32, |m, &v| m.max(motion.margin[v as usize]));
    (most(one), most(other))
}

/// A lower bound on the distance from `p` to triangle `t`: the exact
/// distance where the triangle is well shaped, and, for a sliver (height
/// over its longest edge below 1/1000 of that edge, where the closest-point
/// arithmetic loses its accuracy), the distance to its longest edge less
/// that height, which every point of the triangle is within.
fn point_triangle_lower_bound(p: DVec3, t: [DVec3; 3]) -> f64 {
    let edges = [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])];
    let (a, b) = edges.into_iter().max_by(|x, y| (x.1 - x.0).length_squared().total_cmp(&(y.1 - y.0).length_squared())).unwrap_or(edges[0]);
    let longest = (b - a).length();
    let height = (t[1] - t[0]).cross(t[2] - t[0]).length() / longest.max(f64::MIN_POSITIVE);
    if height >= 1e-3 * longest {
        return point_triangle_distance_squared(p, t[0], t[1], t[2]).sqrt();
    }
    segment_segment_distance_squared(p, p, a, b).sqrt() - height
}

/// Whether one direction has a positive dot product with the normal of
/// every one of `triangles` at every moment of the motion (margins
/// included): they all keep one side, and project along it without
/// turning over.
pub(super) fn keep_one_side(motion: &Motion<'_>, triangles: &[[u32; 3]]) -> bool {
    one_side_axis(motion, triangles).is_some()
}

/// The direction of [`keep_one_side`], if there is one.
pub(super) fn one_side_axis<'t>(motion: &Motion<'_>, triangles: impl IntoIterator<Item = &'t [u32; 3]>) -> Option<Vec3> {
    common_axis(triangles.into_iter().map(|&t| triangle_cone(motion, t)))
}

/// [`one_side_axis`] from the triangles' cones, already made.
pub(super) fn common_axis(cones: impl IntoIterator<Item = Cone>) -> Option<Vec3> {
    cones.into_iter().fold(Cone::EMPTY, Cone::union).axis()
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
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // a NaN height must give the wide cone
    if !(h > 1e-5 * scale) {
        return Cone::WIDE;
    }
    let m = motion.margin[a].max(motion.margin[b]).max(motion.margin[c]);
    let mut theta = ANGLE_SLACK;
    if m > 0.0 {
        let lengths = e1s.length().max(e1e.length()) + e2s.length().max(e2e.length());
        let x = (2.0 * m * lengths + 4.0 * m * m) / h;
        #[allow(clippy::neg_cmp_op_on_partial_ord)] // a NaN widening must give the wide cone
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
        let mut bounds = NodeBounds { span: vec![Span::EMPTY; count], cone: vec![Cone::EMPTY; count], active: vec![false; count], triangle: vec![Span::EMPTY; tree.triangles.len()], triangle_cone: vec![Cone::EMPTY; tree.triangles.len()] };
        bounds.fit_leaves(tree, motion, takes_part, &tree.leaves);
        bounds.fit_parents(tree);
        bounds
    }

    /// The bounds [`Self::new`] gives for `motion`, from those of a motion
    /// that differed from it only at the vertices flagged in `changed`: only
    /// the leaves with such a corner and their ancestors are fitted again,
    /// found from those vertices ([`PatchTree::around`]).
    /// Every node is the same function of its leaves' triangles as in
    /// `new`, evaluated in the same order (a parent after both its
    /// children), and a leaf with no changed corner has the same triangles'
    /// paths and margins: the result is `new`'s, bit for bit.
    pub(super) fn refit_around(&mut self, tree: &PatchTree, motion: &Motion<'_>, takes_part: Option<&[bool]>, changed: &[bool]) {
        let around = tree.around(changed);
        let (leaves, parents): (Vec<u32>, Vec<u32>) = around.nodes.iter().partition(|&&i| tree.nodes[i as usize].is_leaf());
        self.fit_leaves(tree, motion, takes_part, &leaves);
        for i in parents {
            self.fit_parent(tree, i as usize);
        }
    }

    /// Fits the bounds of these leaves.
    fn fit_leaves(&mut self, tree: &PatchTree, motion: &Motion<'_>, takes_part: Option<&[bool]>, leaves: &[u32]) {
        // Per leaf: its span, cone and whether it takes part, and its triangles' spans and cones.
        type Fitted = (Span, Cone, bool, Vec<Span>, Vec<Cone>);
        let fitted: Vec<Fitted> = leaves
            .par_iter()
            .with_min_len(64)
            .map(|&leaf| {
                let node = tree.nodes[leaf as usize];
                let (mut span, mut cone, mut active) = (Span::EMPTY, Cone::EMPTY, false);
                let mut triangles = Vec::with_capacity(node.range().len());
                let mut cones = Vec::with_capacity(node.range().len());
                for p in node.range() {
                    let t = tree.triangles[p];
                    let triangle = motion.span(&t);
                    triangles.push(triangle);
                    span = span.union(triangle);
                    let normals = triangle_cone(motion, t);
                    cones.push(normals);
                    cone = cone.union(normals);
                    active |= takes_part.is_none_or(|flags| flags[p]);
                }
                (span, cone, active, triangles, cones)
            })
            .collect();
        for (&leaf, (span, cone, active, triangles, cones)) in leaves.iter().zip(fitted) {
            let i = leaf as usize;
            (self.span[i], self.cone[i], self.active[i]) = (span, cone, active);
            self.triangle[tree.nodes[i].range()].copy_from_slice(&triangles);
            self.triangle_cone[tree.nodes[i].range()].copy_from_slice(&cones);
        }
    }

    /// Fits every inner node from its children (children come after their
    /// parent in the tree's order).
    fn fit_parents(&mut self, tree: &PatchTree) {
        for i in (0..tree.nodes.len()).rev() {
            if !tree.nodes[i].is_leaf() {
                self.fit_parent(tree, i);
            }
        }
    }

    /// Fits inner node `i` from its children.
    fn fit_parent(&mut self, tree: &PatchTree, i: usize) {
        let (l, r) = (tree.nodes[i].left as usize, tree.nodes[i].left as usize + 1);
        self.span[i] = self.span[l].union(self.span[r]);
        self.cone[i] = self.cone[l].union(self.cone[r]);
        self.active[i] = self.active[l] || self.active[r];
    }

    /// Whether node `i` provably cannot touch itself anywhere over the
    /// motion: a disk whose normal cone has an axis and whose projected
    /// boundary turns by less than 4π (see the module documentation).
    pub(super) fn cannot_touch_itself(&self, tree: &PatchTree, motion: &Motion<'_>, i: usize) -> bool {
        if !tree.disk[i] {
            return false;
        }
        let Some(v) = self.cone[i].axis() else { return false };
        let ring = tree.boundary(i);
        winds_once(v, ring.len(), |j| ring[j], motion)
    }

    /// Whether nodes `a` and `b` provably cannot touch each other: two
    /// disks sharing one run of boundary edges (Tang et al.'s adjacent
    /// patches) make a disk, which cannot touch itself if its normal cone
    /// has an axis and its boundary winds once. Which pairs join, and
    /// where, is topology: the tree keeps it from the bind
    /// ([`PatchTree::joined`]).
    pub(super) fn cannot_touch_each_other(&self, tree: &PatchTree, motion: &Motion<'_>, a: usize, b: usize) -> bool {
        let Some(ring) = tree.joined(a, b) else { return false };
        let Some(v) = self.cone[a].union(self.cone[b]).axis() else { return false };
        winds_once(v, ring.len(), |j| ring.vertex(j), motion)
    }
}

/// Whether a closed boundary `ring`, projected along `v` over the motion,
/// turns by less than 4π in all: it then winds at most once around any point
/// (see the module documentation).
///
/// The turning is the sum of the exterior angles, each the angle between two
/// consecutive projected edges `u(t)`, `w(t)`. Both are linear in `t`, so
/// `u × w` and `u · w` are quadratics whose ranges over `[0, 1]` bound the
/// angle, `|angle| ≤ atan2(max |u × w|, min u · w)` while the dot product
/// stays positive (π otherwise), widened for the margins. A ring that only
/// moves rigidly keeps every bound at its exact angle.
/// The ring has `k` vertices, `ring(j)` the `j`-th.
fn winds_once(v: Vec3, k: usize, ring: impl Fn(usize) -> u32, motion: &Motion<'_>) -> bool {
    if k < 3 {
        return false;
    }
    let (b1, b2) = v.any_orthonormal_pair();
    // Ring vertex j projected at the start and the end, with its margin:
    // each once, carried from one edge to the next (the contours were about
    // a twentieth of the MakeHuman character's straight frames, half of it
    // projecting every vertex twice; issue 30, sixteenth round).
    let corner = |j: usize| {
        let v = ring(j) as usize;
        let (s, e) = (motion.start[v], motion.end[v]);
        (Vec2::new(s.dot(b1), s.dot(b2)), Vec2::new(e.dot(b1), e.dot(b2)), motion.margin[v])
    };
    // The projected edge from one corner to the next at the start, its
    // change, its margin, and its longer length of the two ends (each edge
    // is the next one of one angle and the previous one of the next: its
    // lengths made once).
    let edge = |(a0, a1, ma): (Vec2, Vec2, f32), (b0, b1, mb): (Vec2, Vec2, f32)| {
        let (e0, e1) = (b0 - a0, b1 - a1);
        let de = e1 - e0;
        (e0, de, ma + mb, e0.length().max((e0 + de).length()))
    };
    let limit = 4.0 * std::f32::consts::PI - 1e-3;
    // Each exterior angle's (range of u × w, least u · w), widened for the margins, to `add` until it stops.
    let walk = |add: &mut dyn FnMut((f32, f32), f32) -> bool| {
        let first = corner(0);
        let mut previous = edge(corner(k - 1), first);
        let mut here = first;
        for j in 0..k {
            let there = if j + 1 == k { first } else { corner(j + 1) };
            let next = edge(here, there);
            here = there;
            let ((u0, du, mu, lu), (w0, dw, mw, lw)) = (previous, next);
            let cross = quadratic_range(u0.perp_dot(w0), u0.perp_dot(dw) + du.perp_dot(w0), du.perp_dot(dw));
            let dot = quadratic_range(u0.dot(w0), u0.dot(dw) + du.dot(w0), du.dot(dw));
            let spread = lu * mw + lw * mu + mu * mw;
            if add((cross.0 - spread, cross.1 + spread), dot.0 - spread) {
                return;
            }
            previous = next;
        }
    };
    // First from bounds of each angle, without `atan2f` (its calls were
    // 209M instructions of the MakeHuman character's frames 1–3 in the
    // joined-disk test alone, issue 30, twenty-fourth round (b)); the exact
    // loop runs only where they do not decide. Why they decide as it does:
    // each term `angle + ANGLE_SLACK` is non-negative, and the sums are
    // made in the same order with the same association, so with `lo ≤
    // angle` for every term and `angle ≤ up` wherever `up` is a number
    // ([`angle_bounds`]) and rounding monotone (`x ≤ y` ⇒ `fl(x) ≤
    // fl(y)`), every partial `lower ≤ turning ≤ upper`.
    // A `lower` at the limit puts the exact sum there too (it would stop
    // there or earlier: `false`); an `upper` below it at the end keeps the
    // exact sum below (`true`). A NaN angle makes its `up` NaN, so `upper`
    // stays NaN and never proves `true`, as the exact loop's NaN turning
    // never does; only a straddle or a NaN falls through to it.
    let (mut lower, mut upper) = (0.0f32, 0.0f32);
    let mut over = false;
    walk(&mut |cross, dot_min| {
        let (lo, up) = angle_bounds(cross, dot_min);
        lower += lo + ANGLE_SLACK;
        upper += up + ANGLE_SLACK;
        over = lower >= limit;
        over
    });
    if over {
        return false;
    }
    if upper < limit {
        return true;
    }
    let mut turning = 0.0f32;
    walk(&mut |cross, dot_min| {
        turning += largest_angle(cross, dot_min) + ANGLE_SLACK;
        over = turning >= limit;
        over
    });
    !over && turning < limit
}

/// Bounds `(lo, up)` of [`largest_angle`]'s f32 value, without `atan2`,
/// branch for branch: each of its values is `atan z` or `π − atan z` of a
/// ratio `z ≥ 0` of its inputs, and for `z ≥ 0` the alternating series
/// gives `z − z³/3 ≤ atan z ≤ z` (the derivative `1/(1 + z²)` lies between
/// `1 − z²` and 1), used for `z ≤ 1`, and `atan z = π/2 − atan(1/z)` above
/// (where `1/z < 1` keeps the cube small). The ratio and the series are
/// worked in f64 from the exact f32 inputs, their rounding ~1e-16; glibc's
/// `atan2f` is within a few ulps of the true angle (an ulp is 2.4e-7 rad
/// at π), so the bounds widened by 2e-6 rad hold its value, and their own
/// rounding to f32 (half an ulp). The width left is the series' remainder,
/// `min(z, 1/z)³/3`: at most a third at 45°, and for a small angle `a`
/// about `a³/3`, which is what a nearly straight contour's angles are.
/// `lo` is never NaN (0 where `largest_angle` is NaN) and `up` is NaN
/// where `largest_angle` is (and where a ratio is ∞/∞).
fn angle_bounds((y_lo, y_hi): (f32, f32), dot_min: f32) -> (f32, f32) {
    use std::f64::consts::{FRAC_PI_2, PI};
    // Bounds of atan(y / x) for y ≥ 0, x ≥ 0.
    let atan = |y: f32, x: f32| -> (f64, f64) {
        let z = y as f64 / x as f64;
        if z.is_nan() {
            (f64::NAN, f64::NAN)
        } else if z.is_infinite() {
            (FRAC_PI_2, FRAC_PI_2)
        } else if z <= 1.0 {
            (z - z * z * z / 3.0, z)
        } else {
            let w = 1.0 / z;
            (FRAC_PI_2 - w, FRAC_PI_2 - (w - w * w * w / 3.0))
        }
    };
    let (lo, up) = if y_lo > 0.0 || y_hi < 0.0 {
        let (near, far) = if y_lo > 0.0 { (y_lo, y_hi) } else { (-y_hi, -y_lo) };
        if dot_min >= 0.0 {
            atan(far, dot_min)
        } else {
            let (lo, up) = atan(near, -dot_min);
            (PI - up, PI - lo)
        }
    } else if dot_min > 0.0 {
        atan(y_lo.abs().max(y_hi.abs()), dot_min)
    } else {
        return (std::f32::consts::PI, std::f32::consts::PI);
    };
    (((lo - 2e-6).max(0.0)) as f32, (up + 2e-6) as f32)
}

/// The largest `|atan2(y, x)|` for `y` in `cross` and `x ≥ dot_min`.
fn largest_angle((y_lo, y_hi): (f32, f32), dot_min: f32) -> f32 {
    if y_lo > 0.0 || y_hi < 0.0 {
        // One turning sense throughout: nearest π where x is least and |y| too (x < 0), or |y| most (x ≥ 0).
        let (near, far) = if y_lo > 0.0 { (y_lo, y_hi) } else { (-y_hi, -y_lo) };
        if dot_min >= 0.0 { far.atan2(dot_min) } else { near.atan2(dot_min) }
    } else if dot_min > 0.0 {
        y_lo.abs().max(y_hi.abs()).atan2(dot_min)
    } else {
        std::f32::consts::PI
    }
}

/// `(min, max)` of `a + b·t + c·t²` over `t ∈ [0, 1]`.
fn quadratic_range(a: f32, b: f32, c: f32) -> (f32, f32) {
    let mut lo = a.min(a + b + c);
    let mut hi = a.max(a + b + c);
    if c != 0.0 {
        let t = -b / (2.0 * c);
        if t > 0.0 && t < 1.0 {
            let y = a + b * t + c * t * t;
            lo = lo.min(y);
            hi = hi.max(y);
        }
    }
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collide::self_contact::tree::{joined, loop_index};
    use crate::mesh::shapes::grid;
    use crate::mesh::MeshInput;

    #[test]
    fn bounds_refitted_around_a_few_vertices_are_those_fitted_afresh() {
        let g = grid(24, 24, 1.0);
        let tree = PatchTree::of_mesh(g.input());
        let n = g.positions.len();
        let bent: Vec<Vec3> = g.positions.iter().map(|p| Vec3::new(p.x, p.y, 0.3 * (2.0 * p.x).sin() * p.y)).collect();
        let margin: Vec<f32> = (0..n).map(|v| 1e-3 * (v % 7) as f32).collect();
        let mut bounds = NodeBounds::new(&tree, &Motion { start: &g.positions, end: &bent, margin: &margin }, None);
        // A few vertices get a new start, end and margin, as a gathering
        // around them gives them.
        let changed: Vec<bool> = (0..n).map(|v| v % 97 == 5 || v == n / 2).collect();
        let (mut start, mut end, mut wider) = (g.positions.clone(), bent.clone(), margin.clone());
        for v in (0..n).filter(|&v| changed[v]) {
            start[v] += Vec3::new(0.01, -0.02, 0.03);
            end[v] += Vec3::new(-0.04, 0.0, 0.2);
            wider[v] = 0.05;
        }
        let moved = Motion { start: &start, end: &end, margin: &wider };
        let before = format!("{bounds:?}");
        bounds.refit_around(&tree, &moved, None, &changed);
        let afresh = NodeBounds::new(&tree, &moved, None);
        assert_ne!(before, format!("{afresh:?}"), "the change must show in the bounds");
        assert_eq!(format!("{bounds:?}"), format!("{afresh:?}"), "refitted around the changed vertices, bit for bit");
    }

    #[test]
    fn a_flat_grid_cannot_touch_itself_a_folded_one_can() {
        let g = grid(10, 10, 1.0);
        let tree = PatchTree::of_mesh(g.input());
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
    fn two_adjacent_disks_join_into_one_along_their_shared_run() {
        // Squares 0-1-4-3 and 1-2-5-4 of a 3 × 2 vertex grid, counter-clockwise.
        let a = [0, 1, 4, 3];
        let b = [1, 2, 5, 4];
        let ring = joined(&a, &b, &loop_index(&b)).expect("they share edge 1-4");
        assert_eq!(ring.len(), 6);
        let mut sorted = ring.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, vec![0, 1, 2, 3, 4, 5]);
        // Touching at a vertex only, or not at all: no union disk.
        assert!(joined(&[0, 1, 4, 3], &[4, 5, 8, 7], &loop_index(&[4, 5, 8, 7])).is_none());
        assert!(joined(&[0, 1, 4, 3], &[10, 11, 14, 13], &loop_index(&[10, 11, 14, 13])).is_none());
        // A grid split in two halves joins back to its whole boundary.
        let g = grid(8, 4, 1.0);
        let tree = PatchTree::of_mesh(g.input());
        let zero = vec![0.0; g.positions.len()];
        let still = Motion { start: &g.positions, end: &g.positions, margin: &zero };
        let bounds = NodeBounds::new(&tree, &still, None);
        let (l, r) = (tree.nodes[0].left as usize, tree.nodes[0].left as usize + 1);
        assert!(bounds.cannot_touch_each_other(&tree, &still, l, r));
        assert_eq!(joined(tree.boundary(l), tree.boundary(r), tree.boundary_index(r)).map(|r| r.len()), Some(tree.boundary(0).len()));
    }

    fn exact_distance(x: &[Vec3], one: &[u32], other: &[u32]) -> f64 {
        let p = |v: u32| x[v as usize].as_dvec3();
        let squared = if one.len() == 1 {
            point_triangle_distance_squared(p(one[0]), p(other[0]), p(other[1]), p(other[2]))
        } else {
            segment_segment_distance_squared(p(one[0]), p(one[1]), p(other[0]), p(other[1]))
        };
        squared.sqrt()
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 512, ..Default::default() })]

        /// The exact-distance bound never exceeds the distance the two
        /// elements reach anywhere along their straight paths (sampled
        /// finely), nor that less the margins when they stray.
        #[test]
        fn element_gap_never_exceeds_the_distance_along_the_motion(
            coordinates in proptest::collection::vec(-1.0f32..1.0, 24),
            margins in proptest::collection::vec(0.0f32..0.05, 4),
            edge_edge in proptest::bool::ANY,
        ) {
            let start: Vec<Vec3> = coordinates[..12].chunks(3).map(|c| Vec3::new(c[0], c[1], c[2])).collect();
            let end: Vec<Vec3> = coordinates[12..].chunks(3).zip(&start).map(|(c, s)| *s + 0.5 * Vec3::new(c[0], c[1], c[2])).collect();
            let motion = Motion { start: &start, end: &end, margin: &margins };
            let (one, other): (&[u32], &[u32]) = if edge_edge { (&[0, 1], &[2, 3]) } else { (&[0], &[1, 2, 3]) };
            let gap = element_gap(&motion, one, other);
            let least_margins = |side: &[u32]| side.iter().map(|&v| margins[v as usize]).fold(0.0f32, f32::max) as f64;
            let mut least = f64::INFINITY;
            for k in 0..=256 {
                let t = k as f32 / 256.0;
                let at: Vec<Vec3> = start.iter().zip(&end).map(|(s, e)| *s + t * (*e - *s)).collect();
                least = least.min(exact_distance(&at, one, other));
            }
            proptest::prop_assert!(gap <= least + 1e-5, "bound {gap} above the least distance {least}");
            proptest::prop_assert!(gap <= least - least_margins(one) - least_margins(other) + 1e-5);
        }

        /// The gatherings' question, answered from as few ends as decide
        /// it, is the gap's to the bit: reaches around the gap itself, at
        /// it exactly, and at each end's distance less the margins.
        #[test]
        #[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(gap > reach)` is the gatherings' old test, NaN included
        fn element_within_answers_as_the_gap_does(
            coordinates in proptest::collection::vec(-1.0f32..1.0, 24),
            margins in proptest::collection::vec(0.0f32..0.05, 4),
            edge_edge in proptest::bool::ANY,
            spread in 0.0f64..0.5,
        ) {
            let start: Vec<Vec3> = coordinates[..12].chunks(3).map(|c| Vec3::new(c[0], c[1], c[2])).collect();
            let end: Vec<Vec3> = coordinates[12..].chunks(3).zip(&start).map(|(c, s)| *s + 0.5 * Vec3::new(c[0], c[1], c[2])).collect();
            let motion = Motion { start: &start, end: &end, margin: &margins };
            let (one, other): (&[u32], &[u32]) = if edge_edge { (&[0, 1], &[2, 3]) } else { (&[0], &[1, 2, 3]) };
            let gap = element_gap(&motion, one, other);
            let (m0, m1) = element_margins(&motion, one, other);
            let ends = [end_distance(&start, one, other), end_distance(&end, one, other)].map(|d| d - m0 as f64 - m1 as f64);
            for reach in [gap, gap - spread, gap + spread, gap - 1e-12, gap + 1e-12, ends[0], ends[1], ends[0] - 1e-12, ends[1] - 1e-12, 0.0] {
                proptest::prop_assert_eq!(element_within(&motion, one, other, reach), !(gap > reach), "reach {} gap {}", reach, gap);
            }
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 4096, ..Default::default() })]

        /// The contour's angle bounds hold `atan2f`'s own value between
        /// them, over every scale of cross and dot products, both signs,
        /// and are as tight as their argument says: the series' remainder
        /// `min(z, 1/z)³/3` is at most a third (at 45°), and for an angle
        /// `a ≤ 0.5` rad, `z = tan a ≤ 1.093 a`, so at most `0.44 a³`
        /// (1.093³/3 = 0.435), besides the 4e-6 rad of widening.
        #[test]
        fn an_angles_bounds_hold_its_value(y in -1e3f32..1e3, dy in 0.0f32..1e3, x in -1e3f32..1e3, scale in -30i32..30) {
            let k = 2f32.powi(scale);
            let (cross, dot) = ((y * k, (y + dy) * k), x * k);
            let exact = largest_angle(cross, dot);
            let (lo, up) = angle_bounds(cross, dot);
            proptest::prop_assert!(lo <= exact && exact <= up, "{lo} ≤ {exact} ≤ {up} for {cross:?}, {dot}");
            proptest::prop_assert!(up - lo <= 1.0 / 3.0 + 5e-6, "bounds {lo}, {up} wider than the series' remainder at 45°");
            proptest::prop_assert!(exact > 0.5 || up - lo <= 0.44 * exact.powi(3) + 5e-6, "bounds {lo}, {up} too loose for a small angle {exact}");
        }
    }

    /// Where `largest_angle` meets an infinity, a zero or a NaN, the bounds
    /// still hold it wherever `up` is a number, and a NaN angle leaves `up`
    /// NaN: a contour with one is never proven to wind once by the bounds
    /// alone (`winds_once`'s argument needs no more).
    #[test]
    fn an_angles_bounds_hold_at_infinities_and_nan() {
        let (inf, nan) = (f32::INFINITY, f32::NAN);
        let cases = [
            ((1.0, 2.0), 0.0),
            ((0.0, 0.0), 1.0),
            ((-1.0, 1.0), 0.0),
            ((-1.0, 1.0), -1.0),
            ((1.0, inf), 1.0),
            ((-inf, inf), 1.0),
            ((1.0, 2.0), inf),
            ((1.0, 2.0), -inf),
            ((-2.0, -1.0), -inf),
            ((1.0, f32::MAX), f32::MIN_POSITIVE),
            ((1e-30, 1e-30), 1e30),
            ((inf, inf), inf),
            ((nan, 1.0), 1.0),
            ((1.0, nan), 1.0),
            ((nan, -1.0), -1.0),
            ((1.0, 2.0), nan),
            ((nan, nan), 1.0),
        ];
        let mut nan_angles = 0;
        for (cross, dot) in cases {
            let exact = largest_angle(cross, dot);
            let (lo, up) = angle_bounds(cross, dot);
            assert!(!lo.is_nan() && !(lo > exact), "{lo} above {exact} for {cross:?}, {dot}");
            if exact.is_nan() {
                assert!(up.is_nan(), "the NaN angle of {cross:?}, {dot} has an upper bound {up}");
                nan_angles += 1;
            } else if !up.is_nan() {
                assert!(exact <= up, "{exact} above {up} for {cross:?}, {dot}");
            }
        }
        assert!(nan_angles >= 3, "the cases must hold NaN angles");
    }

    /// A sliver (a quad's diagonal split of nearly collinear corners) keeps
    /// a bound below its true distance, where the closest-point arithmetic
    /// alone could overshoot it, and close to it.
    #[test]
    fn a_sliver_triangle_gets_a_bound_below_its_distance() {
        let t = [DVec3::ZERO, DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.37, 2e-7, 0.0)];
        for p in [DVec3::new(0.37, 1e-7, 1e-6), DVec3::new(0.5, -1e-6, 0.0), DVec3::new(0.1, 3e-7, 2e-7), DVec3::new(1.2, 0.1, 0.0)] {
            let bound = point_triangle_lower_bound(p, t);
            let steps = 400;
            let mut least = f64::INFINITY;
            for i in 0..=steps {
                for j in 0..=steps - i {
                    let (u, v) = (i as f64 / steps as f64, j as f64 / steps as f64);
                    least = least.min((p - (t[0] + u * (t[1] - t[0]) + v * (t[2] - t[0]))).length());
                }
            }
            // The sampling spacing (1/400 along the long edge) bounds how far
            // the sampled least lies above the true one.
            assert!(bound <= least + 1e-12, "bound {bound} above the sampled distance {least} for {p}");
            assert!(bound >= least - 2.0 / steps as f64, "bound {bound} far below the distance {least} for {p}");
        }
    }

    #[test]
    fn neighbours_carried_together_keep_their_exact_gap_where_their_boxes_overlap() {
        // A vertex 0.09 from a tilted triangle, both carried along and turned
        // 1° (a limb moving as a whole): their axis-aligned boxes overlap,
        // their distance stays 0.09, and the bound loses only what the turn
        // could change it by (half of K, about 0.04 here).
        let start = vec![Vec3::new(0.0, 0.0, 0.1), Vec3::new(-1.0, -1.0, -0.5), Vec3::new(1.0, -1.0, 0.5), Vec3::new(0.0, 1.0, 0.0)];
        let turn = glam::Quat::from_rotation_z(1f32.to_radians());
        let end: Vec<Vec3> = start.iter().map(|p| turn * *p + Vec3::new(0.5, 0.3, 0.2)).collect();
        let zero = [0.0; 4];
        let motion = Motion { start: &start, end: &end, margin: &zero };
        assert_eq!(relative_gap(&motion.span(&[0]), &motion.span(&[1, 2, 3])), 0.0, "the boxes overlap");
        let exact = exact_distance(&start, &[0], &[1, 2, 3]);
        let gap = element_gap(&motion, &[0], &[1, 2, 3]);
        assert!(gap <= exact && gap > 0.04, "gap {gap}, exact {exact}");
        // Still (no motion): the bound is the distance itself.
        let still = Motion { start: &start, end: &start, margin: &zero };
        assert!((element_gap(&still, &[0], &[1, 2, 3]) - exact).abs() < 1e-12);
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
        let tree = PatchTree::of_mesh(mesh);
        let zero = vec![0.0; positions.len()];
        let still = Motion { start: &positions, end: &positions, margin: &zero };
        let bounds = NodeBounds::new(&tree, &still, None);
        assert!(tree.disk[0]);
        assert!(bounds.cone[0].axis().is_some(), "the normals fit a cone: the contour has to decide");
        assert!(!bounds.cannot_touch_itself(&tree, &still, 0));
    }
}
