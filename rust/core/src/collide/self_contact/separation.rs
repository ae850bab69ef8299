//! Patches that meet at a corner, or lie a ring apart, told apart by a
//! separating plane.
//!
//! The curvature criterion ([`super::bounds`]) joins two patches only where
//! they share one run of boundary edges. Patches that meet only at a corner
//! (every patch has such neighbours diagonally across a vertex) and patches
//! a ring or two apart, whose tilted boxes overlap, pass neither it nor the
//! box test, and without this test the traversal walks each such pair down
//! to its leaves, at every level of the tree, every search.
//!
//! The test: a direction `n` and, for every time of the motion, a plane
//! normal to it with one patch's vertices beyond it on one side and the
//! other's on the other, farther than the reach, margins included. Every
//! point of a triangle or an edge is a convex combination of its corners,
//! so its height along `n` lies between theirs, and two elements whose
//! heights stay more than the reach apart stay more than the reach apart.
//!
//! * Two patches sharing no vertex: the least height of one less the
//!   greatest of the other, at both ends of the motion. Each vertex's
//!   height is linear in time, so a least height is concave and a greatest
//!   convex, and a difference positive at both ends is positive throughout.
//! * Two patches sharing exactly one vertex `v`: the plane goes through `v`;
//!   every other vertex of one patch must stay more than the reach (and the
//!   margins) above `v`, and every other vertex of the other below it. Then
//!   every pair of elements of the two patches is that far apart, except
//!   pairs that both hold `v`, which are neighbours and never tested.
//!
//! Patches sharing two or more vertices are left to the curvature criterion
//! and to the traversal. The vertex lists are kept per node at bind
//! ([`PatchTree::vertices`], and the shorter [`PatchTree::exposed`] that
//! tells in a few steps which vertices two patches share); the direction is chosen each time from the
//! patches' boxes (the line between their centres, or through the shared
//! vertex, the bisector away from both), so the test holds under any motion
//! it is given: it re-checks the plane against every vertex, it assumes no
//! bound on how the skin moved since bind.

use glam::{DVec3, Vec3};

use super::bounds::{Motion, Span};
use super::tree::PatchTree;

/// The patches' shared vertices: none, one, or more (then `None`).
enum Shared {
    Disjoint,
    Corner(u32),
}

fn shared(a: &[u32], b: &[u32]) -> Option<Shared> {
    let (mut i, mut j) = (0, 0);
    let mut found = None;
    while i < a.len() && j < b.len() {
        match a[i].cmp(&b[j]) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                if found.replace(a[i]).is_some() {
                    return None;
                }
                i += 1;
                j += 1;
            }
        }
    }
    Some(found.map_or(Shared::Disjoint, Shared::Corner))
}

/// The middle of a span's box over the motion.
fn centre(span: &Span) -> DVec3 {
    let start = (span.start.min + span.start.max) * 0.5;
    let moved = (span.motion.min + span.motion.max) * 0.5;
    (start + 0.5 * moved).as_dvec3()
}

/// `sign · height − margin` of vertex `v` along `n` at the motion's start and end.
#[inline(always)]
fn height(motion: &Motion<'_>, v: u32, n: DVec3, sign: f64) -> [f64; 2] {
    let m = motion.margin[v as usize] as f64;
    let (s, e) = (motion.start[v as usize].as_dvec3(), motion.end[v as usize].as_dvec3());
    [sign * s.dot(n) - m, sign * e.dot(n) - m]
}

/// Heights along `n` of `vertices` (all but `skip`) at the motion's start
/// and end, less (`sign` < 0: plus) their margins: the least of `sign ·
/// height − margin` at each end; `None` as soon as the least so far
/// already `fails` at either end. The least only falls (NaN heights are
/// passed over by `min`), and rounded sums and differences are monotone, so
/// a test `≤ reach` that fails on the least so far fails on the whole
/// list: the answer is the full scan's. Most planes tried fail, on a vertex
/// near the other patch, and the rest of the list is not worth its heights
/// (issue 30, twenty-fourth round).
fn least_heights(motion: &Motion<'_>, vertices: &[u32], skip: Option<u32>, n: DVec3, sign: f64, fails: impl Fn(usize, f64) -> bool) -> Option<[f64; 2]> {
    let mut least = [f64::INFINITY; 2];
    for &v in vertices {
        if Some(v) == skip {
            continue;
        }
        let h = height(motion, v, n, sign);
        least[0] = least[0].min(h[0]);
        least[1] = least[1].min(h[1]);
        if fails(0, least[0]) || fails(1, least[1]) {
            return None;
        }
    }
    Some(least)
}

/// Whether nodes `a` and `b` (their spans `span_a`, `span_b`) provably stay
/// farther apart than `reach` over the motion, every pair of their elements
/// that does not share a vertex (see the module documentation). False when
/// a node keeps no vertex list or they share two vertices or more.
pub(super) fn separated(tree: &PatchTree, motion: &Motion<'_>, (a, span_a): (usize, &Span), (b, span_b): (usize, &Span), reach: f32) -> bool {
    let (va, vb) = (tree.vertices(a), tree.vertices(b));
    if va.is_empty() || vb.is_empty() {
        return false;
    }
    let Some(shared) = shared(tree.exposed(a), tree.exposed(b)) else { return false };
    let (ca, cb) = (centre(span_a), centre(span_b));
    let reach = reach as f64;
    match shared {
        Shared::Disjoint => {
            let Some(n) = (ca - cb).try_normalize() else { return false };
            // above = min(h − m) over a, below = min(−h − m) over b: the gap is their sum.
            // Any one vertex of b bounds `below` from above, so `above` may
            // fail early against it (a NaN height bounds nothing and fails nothing).
            let Some(some_below) = vb.first().map(|&w| height(motion, w, n, -1.0)) else { return false };
            let Some(above) = least_heights(motion, va, None, n, 1.0, |k, least| least + some_below[k] <= reach) else { return false };
            let Some(below) = least_heights(motion, vb, None, n, -1.0, |k, least| above[k] + least <= reach) else { return false };
            above[0] + below[0] > reach && above[1] + below[1] > reach
        }
        Shared::Corner(v) => {
            let (s, e): (Vec3, Vec3) = (motion.start[v as usize], motion.end[v as usize]);
            let middle = (0.5 * (s + e)).as_dvec3();
            let (Some(da), Some(db)) = ((ca - middle).try_normalize(), (cb - middle).try_normalize()) else { return false };
            let Some(n) = (da - db).try_normalize() else { return false };
            let m = motion.margin[v as usize] as f64;
            let at = [s.as_dvec3().dot(n), e.as_dvec3().dot(n)];
            // Each side on its own: both ends of each must clear the shared vertex.
            let Some(above) = least_heights(motion, va, Some(v), n, 1.0, |k, least| least - at[k] - m <= reach) else { return false };
            let Some(below) = least_heights(motion, vb, Some(v), n, -1.0, |k, least| least + at[k] - m <= reach) else { return false };
            (0..2).all(|k| above[k] - at[k] - m > reach && below[k] + at[k] - m > reach)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collide::geometry::{point_triangle_distance_squared, segment_segment_distance_squared};
    use crate::collide::self_contact::bounds::{relative_gap, NodeBounds};
    use crate::mesh::shapes::grid;

    /// The least distance, over the motion sampled finely and with no
    /// margins, between two elements of nodes `a` and `b` that share no
    /// vertex: brute force, sharing nothing with the test.
    fn least_distance(tree: &PatchTree, motion: &Motion<'_>, a: usize, b: usize) -> f64 {
        let mut least = f64::INFINITY;
        for k in 0..=16 {
            let t = k as f32 / 16.0;
            let x: Vec<DVec3> = motion.start.iter().zip(motion.end).map(|(s, e)| (*s + t * (*e - *s)).as_dvec3()).collect();
            for p in tree.nodes[a].range() {
                for q in tree.nodes[b].range() {
                    let (tp, tq) = (tree.triangles[p], tree.triangles[q]);
                    for (one, other) in [(tp, tq), (tq, tp)] {
                        for &v in &one {
                            if !other.contains(&v) {
                                let [i, j, k] = other.map(|w| x[w as usize]);
                                least = least.min(point_triangle_distance_squared(x[v as usize], i, j, k).sqrt());
                            }
                        }
                    }
                    for i in 0..3 {
                        for j in 0..3 {
                            let (e, f) = ([tp[i], tp[(i + 1) % 3]], [tq[j], tq[(j + 1) % 3]]);
                            if e.iter().any(|v| f.contains(v)) {
                                continue;
                            }
                            let squared = segment_segment_distance_squared(x[e[0] as usize], x[e[1] as usize], x[f[0] as usize], x[f[1] as usize]);
                            least = least.min(squared.sqrt());
                        }
                    }
                }
            }
        }
        least
    }

    #[test]
    fn patches_meeting_at_a_corner_of_a_flat_grid_are_separated_and_a_fold_is_not() {
        let g = grid(8, 8, 1.0);
        let tree = PatchTree::of_mesh(g.input());
        let zero = vec![0.0; g.positions.len()];
        let still = Motion { start: &g.positions, end: &g.positions, margin: &zero };
        let bounds = NodeBounds::new(&tree, &still, None);
        let edge = 1.0 / 8.0;
        let leaves = &tree.leaves;
        let mut corners = 0;
        for (i, &a) in leaves.iter().enumerate() {
            for &b in &leaves[i + 1..] {
                let (a, b) = (a as usize, b as usize);
                let corner = matches!(shared(tree.vertices(a), tree.vertices(b)), Some(Shared::Corner(_)));
                if corner {
                    corners += 1;
                    assert!(separated(&tree, &still, (a, &bounds.span[a]), (b, &bounds.span[b]), 0.3 * edge), "leaves {a} and {b} meet at a corner of a flat grid");
                }
            }
        }
        assert!(corners > 0, "a grid's leaves meet at corners");
        // Folded flat onto itself (x > 0 laid over x < 0 at 0.2 edge above): the halves are not separated.
        let folded: Vec<Vec3> = g.positions.iter().map(|p| if p.x > 0.0 { Vec3::new(-p.x, p.y, 0.2 * edge) } else { *p }).collect();
        let fold = Motion { start: &folded, end: &folded, margin: &zero };
        let bounds = NodeBounds::new(&tree, &fold, None);
        for (i, &a) in leaves.iter().enumerate() {
            for &b in &leaves[i + 1..] {
                let (a, b) = (a as usize, b as usize);
                if separated(&tree, &fold, (a, &bounds.span[a]), (b, &bounds.span[b]), 0.3 * edge) {
                    assert!(least_distance(&tree, &fold, a, b) > 0.3 * edge as f64);
                }
            }
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 64, ..Default::default() })]

        /// A grid bent about a random axis by a random angle from one
        /// random shape to another, with random margins: every pair of
        /// nodes the test calls separated keeps every pair of its elements
        /// that share no vertex farther apart than the reach all along the
        /// motion (brute force over the sampled motion), and the margins
        /// count.
        #[test]
        fn separated_nodes_stay_apart_along_any_bend(
            start_angle in 0.0f32..3.0, end_angle in 0.0f32..3.0,
            axis_at in 0.2f32..0.8, reach in 0.0f32..0.08,
            margin in 0.0f32..0.03, wobble in proptest::collection::vec(-0.02f32..0.02, 3 * 81),
        ) {
            let g = grid(8, 8, 1.0);
            let bend = |angle: f32, wobble: &[f32]| -> Vec<Vec3> {
                g.positions.iter().enumerate().map(|(i, p)| {
                    let w = Vec3::new(wobble[3 * i], wobble[3 * i + 1], wobble[3 * i + 2]);
                    // Bent about the line x = axis_at, z = 0 on the side x > axis_at.
                    let q = if p.x > axis_at - 0.5 {
                        let (r, s) = (p.x - (axis_at - 0.5), angle);
                        Vec3::new(axis_at - 0.5 + r * s.cos(), p.y, r * s.sin())
                    } else { *p };
                    q + w
                }).collect()
            };
            let start = bend(start_angle, &wobble);
            let end = bend(end_angle, &wobble.iter().rev().copied().collect::<Vec<_>>());
            let margins = vec![margin; start.len()];
            let motion = Motion { start: &start, end: &end, margin: &margins };
            let tree = PatchTree::of_mesh(g.input());
            let bounds = NodeBounds::new(&tree, &motion, None);
            let small: Vec<usize> = (0..tree.nodes.len()).filter(|&i| tree.nodes[i].count <= 16).collect();
            for (k, &a) in small.iter().enumerate() {
                for &b in &small[k + 1..] {
                    // Only pairs the traversal would test: boxes within the reach.
                    if relative_gap(&bounds.span[a], &bounds.span[b]) > reach || !separated(&tree, &motion, (a, &bounds.span[a]), (b, &bounds.span[b]), reach) {
                        continue;
                    }
                    let (na, nb) = (tree.nodes[a], tree.nodes[b]);
                    if na.range().start < nb.range().end && nb.range().start < na.range().end {
                        continue; // one holds the other: never a pair the traversal tests
                    }
                    let least = least_distance(&tree, &motion, a, b);
                    proptest::prop_assert!(least > (reach + 2.0 * margin) as f64 - 1e-6, "nodes {a}, {b}: {least} within reach {reach} + margins {margin}");
                }
            }
        }
    }
}
