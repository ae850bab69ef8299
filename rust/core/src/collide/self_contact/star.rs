//! Pairs in one vertex's star: which near pairs of skin elements two
//! polygons apart around a vertex are never contacts, whatever patch tree
//! gathers them (the [`super::hinge`] rule's argument, over a vertex's
//! whole star instead of two triangles).
//!
//! **The rule.** Let `v` be a vertex inside the skin (its polygons close
//! around it, each running the edges it shares with the next the other
//! way), every polygon around it a triangle or a quad. If one direction
//! `V` has a positive dot product with the normal of every triangle of
//! those polygons (a quad's four, both splits) at every moment of the
//! motion, margins included, and their angles at `v`, projected along `V`,
//! sum to one turn, then a side (vertex or edge) of one polygon around `v`
//! and a side of another never meet: the pair is never a contact and never
//! a crossing. Why:
//!
//! * projected along `V` every such triangle keeps its orientation, so a
//!   quad projects as a convex quadrilateral (all four triangles of its
//!   corners turn the same way) and a triangle as itself: each polygon
//!   lies in the wedge of its angle at `v`, touching the wedge's apex at
//!   `v` alone and its sides along its own two edges at `v`;
//! * the wedges follow one another round `v` (consecutive polygons share an
//!   edge at `v`), so their angles sum to a whole number of turns. While
//!   every triangle keeps its orientation that number cannot jump, so one
//!   turn at the start of the motion is one turn throughout: the wedges
//!   do not overlap, and two polygons' projections meet only along an edge
//!   at `v` that both hold;
//! * so a point of one polygon and a point of another that coincide lie on
//!   such a shared edge. A corner there is a corner of both polygons, and a
//!   triangle of a convex quad reaches none of its quad's corners but its
//!   own; an edge of a convex polygon reaches a side of it only at that
//!   side's ends or all along it. So a corner meeting a triangle is one of
//!   its corners, and two edges meeting share a corner: neighbours, never
//!   tested.
//!
//! Without the turn count the rule would be wrong: a star whose link winds
//! twice round `v` (a spiral ramp closing on itself) keeps every normal on
//! one side but laps over itself in projection.
//!
//! **Why it is decided here and not by the tree.** As for hinges: the tree
//! drops every pair inside a patch it accepts whole, so which near pairs of
//! a squeezed star were pushed apart depended on where its seams fell (on a
//! rolled grid squeezed along its quads' diagonals, an edge through a
//! corner against the far diagonal of the quad across that corner: 4
//! contacts only with the tree grouped on the dual graph, 28 only with
//! median cuts; issue 30, thirteenth round). Stars settle those pairs the
//! same way for every tree. Polygons of five or more corners are left out
//! (their fan from the first corner need not project into one wedge):
//! their pairs stay contacts where a seam lists them.

use std::sync::atomic::{AtomicU8, Ordering};

use glam::Vec3;

use super::bounds::{common_axis, one_side_axis, Cone, Motion};

/// The polygons around each vertex inside the skin, in order round it.
#[derive(Debug, Clone, Default)]
pub(super) struct Stars {
    /// Per polygon, its corners (a triangle's fourth is `u32::MAX`).
    corners: Vec<[u32; 4]>,
    /// Per polygon, the range of its triangles in `triangles`.
    triangle_offsets: Vec<u32>,
    /// Every polygon's triangles (a quad's four), polygon by polygon.
    triangles: Vec<[u32; 3]>,
    /// Per vertex, the range of its polygons in `around`.
    offsets: Vec<u32>,
    /// Per vertex, the polygons holding it; for a vertex with a star, in
    /// order round it, each with the corners before and after the vertex.
    around: Vec<Around>,
    /// Per vertex, whether its polygons make a star the rule applies to.
    star: Vec<bool>,
    /// Per triangle of `triangles`, its position in the patch tree (empty
    /// until [`Self::placed_in`]): where a gathering's bounds keep its cone.
    position: Vec<u32>,
}

#[derive(Debug, Clone, Copy)]
struct Around {
    polygon: u32,
    previous: u32,
    next: u32,
}

/// Each vertex's [`Stars::winds_once`] over one motion, worked out the
/// first time a pair asks for it: a gathering asks for the same star once
/// for every near pair round it (the star rule's cones were about a tenth
/// of the MakeHuman character's straight frames, issue 30, sixteenth
/// round), and the answer depends on the vertex and the motion alone.
pub(super) struct StarMemo<'c> {
    /// Per vertex: 0 not asked yet, else [`WINDS_ONCE`] or [`WINDS_OTHERWISE`].
    known: Vec<AtomicU8>,
    /// Per tree position, its triangle's normal cone over the motion, if the
    /// gathering's bounds made them ([`Stars::memo_over`]).
    cones: Option<&'c [Cone]>,
}

const WINDS_ONCE: u8 = 1;
const WINDS_OTHERWISE: u8 = 2;

/// Above this the projected angles at a vertex sum to two turns or more
/// (their sum is a whole number of turns: halfway between, for rounding).
const ONE_TURN_AT_MOST: f32 = 3.0 * std::f32::consts::PI;

impl Stars {
    /// The stars of the skin's polygons: `polygons[k]` the corners of polygon
    /// `k` in order, `triangles` each triangle of the skin with its polygon.
    pub(super) fn new(vertex_count: usize, polygons: &[&[u32]], triangles: &[[u32; 3]], polygon_of: &[u32]) -> Self {
        let mut corners = Vec::with_capacity(polygons.len());
        let mut triangle_offsets = vec![0u32; polygons.len() + 1];
        for &p in polygon_of {
            triangle_offsets[p as usize + 1] += 1;
        }
        for k in 0..polygons.len() {
            triangle_offsets[k + 1] += triangle_offsets[k];
        }
        // `polygon_of` runs polygon by polygon (the skin's triangulation).
        let triangles = triangles.to_vec();
        let mut usable = vec![true; polygons.len()];
        for (k, poly) in polygons.iter().enumerate() {
            let distinct = (0..poly.len()).all(|i| (i + 1..poly.len()).all(|j| poly[i] != poly[j]));
            usable[k] = (poly.len() == 3 || poly.len() == 4) && distinct;
            let mut c = [u32::MAX; 4];
            c[..poly.len().min(4)].copy_from_slice(&poly[..poly.len().min(4)]);
            corners.push(c);
        }
        let mut offsets = vec![0u32; vertex_count + 1];
        for poly in polygons {
            for &v in poly.iter() {
                offsets[v as usize + 1] += 1;
            }
        }
        for v in 0..vertex_count {
            offsets[v + 1] += offsets[v];
        }
        let mut fill = offsets.clone();
        let mut around = vec![Around { polygon: 0, previous: 0, next: 0 }; offsets[vertex_count] as usize];
        for (k, poly) in polygons.iter().enumerate() {
            let n = poly.len();
            for i in 0..n {
                let v = poly[i] as usize;
                around[fill[v] as usize] = Around { polygon: k as u32, previous: poly[(i + n - 1) % n], next: poly[(i + 1) % n] };
                fill[v] += 1;
            }
        }
        let mut star = vec![false; vertex_count];
        for v in 0..vertex_count {
            let list = &mut around[offsets[v] as usize..offsets[v + 1] as usize];
            star[v] = list.len() >= 3 && list.iter().all(|a| usable[a.polygon as usize]) && order_round(list);
        }
        Stars { corners, triangle_offsets, triangles, offsets, around, star, position: Vec::new() }
    }

    /// These stars with their triangles' positions in a patch tree whose
    /// position `k` holds triangle `order[k]` (as given to [`Self::new`]).
    pub(super) fn placed_in(mut self, order: &[u32]) -> Self {
        self.position = vec![0; self.triangles.len()];
        for (k, &t) in order.iter().enumerate() {
            self.position[t as usize] = k as u32;
        }
        self
    }

    /// An empty memo for one motion of this skin ([`Self::keep_apart`]),
    /// which makes each star's cones from the motion.
    #[cfg(test)]
    pub(super) fn memo(&self) -> StarMemo<'static> {
        StarMemo { known: (0..self.star.len()).map(|_| AtomicU8::new(0)).collect(), cones: None }
    }

    /// [`Self::memo`] for a motion whose triangle cones a gathering's bounds
    /// already made (`cones`, per tree position, [`Self::placed_in`]): a
    /// star's cone is then the union of its triangles' cones, read, where
    /// making them again was the most of the star rule once every triangle
    /// pair asks it (issue 30, twenty-third round). The same cones, in the
    /// same order: the same answers to the bit.
    pub(super) fn memo_over<'c>(&self, cones: &'c [Cone]) -> StarMemo<'c> {
        let cones = (self.position.len() == self.triangles.len()).then_some(cones);
        StarMemo { known: (0..self.star.len()).map(|_| AtomicU8::new(0)).collect(), cones }
    }

    fn polygon_corners(&self, p: u32) -> &[u32] {
        let c = &self.corners[p as usize];
        if c[3] == u32::MAX { &c[..3] } else { &c[..] }
    }

    /// The polygons holding every corner of `side`.
    fn holding<'s>(&'s self, side: &'s [u32]) -> impl Iterator<Item = u32> + 's {
        let v = side[0] as usize;
        self.around[self.offsets[v] as usize..self.offsets[v + 1] as usize]
            .iter()
            .map(|a| a.polygon)
            .filter(move |&p| side.iter().all(|c| self.polygon_corners(p).contains(c)))
    }

    /// Whether the sides `one` and `other` (a vertex and a triangle, or two
    /// edges) lie in two polygons of a star that keeps one side and winds
    /// once over `motion` (see the module documentation): never a contact.
    /// `memo` is this motion's ([`Self::memo`]).
    pub(super) fn keep_apart(&self, motion: &Motion<'_>, memo: &StarMemo, one: &[u32], other: &[u32]) -> bool {
        if self.star.is_empty() {
            return false;
        }
        for p in self.holding(one) {
            for q in self.holding(other) {
                if p == q {
                    continue;
                }
                let shared = self.polygon_corners(p).iter().filter(|c| self.polygon_corners(q).contains(c));
                for &v in shared {
                    if self.winds_once_memo(motion, memo, v) {
                        return true;
                    }
                }
            }
        }
        false
    }

    /// Whether every side of polygon `p` and every side of polygon `q` are
    /// kept apart by [`Self::keep_apart`]: the two are not one and share a
    /// corner whose star keeps one side and winds once over `motion`. Such a
    /// star's polygons are all triangles or quads, so `p` and `q` hold all
    /// their corners and each is among the polygons holding any of its
    /// sides: `keep_apart` finds the same pair and the same corner for each
    /// pair of their sides. One question for all the element pairs of two
    /// triangles, where `keep_apart` for each would look up their polygons.
    pub(super) fn polygons_apart(&self, motion: &Motion<'_>, memo: &StarMemo, p: u32, q: u32) -> bool {
        if self.star.is_empty() || p == q {
            return false;
        }
        let theirs = self.polygon_corners(q);
        self.polygon_corners(p).iter().any(|&c| theirs.contains(&c) && self.winds_once_memo(motion, memo, c))
    }

    /// [`Self::winds_once`], from `memo` if it was asked before. Threads
    /// asking at once may both work it out: the same answer either way.
    fn winds_once_memo(&self, motion: &Motion<'_>, memo: &StarMemo, v: u32) -> bool {
        let slot = &memo.known[v as usize];
        match slot.load(Ordering::Relaxed) {
            WINDS_ONCE => true,
            WINDS_OTHERWISE => false,
            _ => {
                let once = self.winds_once(motion, memo.cones, v);
                slot.store(if once { WINDS_ONCE } else { WINDS_OTHERWISE }, Ordering::Relaxed);
                once
            }
        }
    }

    /// Whether `v`'s star keeps one side over `motion` and its projected
    /// angles at `v` sum to one turn.
    /// `cones`: per tree position, its triangle's cone over `motion`, if made.
    fn winds_once(&self, motion: &Motion<'_>, cones: Option<&[Cone]>, v: u32) -> bool {
        let v = v as usize;
        if !self.star[v] {
            return false;
        }
        let around = &self.around[self.offsets[v] as usize..self.offsets[v + 1] as usize];
        let triangle_range = |a: &Around| {
            let p = a.polygon as usize;
            self.triangle_offsets[p] as usize..self.triangle_offsets[p + 1] as usize
        };
        let axis = match cones {
            Some(cones) => common_axis(around.iter().flat_map(triangle_range).map(|t| cones[self.position[t] as usize])),
            None => one_side_axis(motion, around.iter().flat_map(|a| &self.triangles[triangle_range(a)])),
        };
        let Some(axis) = axis else { return false };
        // Every triangle keeps its orientation over the motion, so the turn
        // count is the same at every moment: count it at the start.
        let x = motion.start;
        let turned: f32 = around
            .iter()
            .map(|a| {
                let (to_next, to_previous) = (x[a.next as usize] - x[v], x[a.previous as usize] - x[v]);
                let flat = |d: Vec3| d - d.dot(axis) * axis;
                axis.dot(to_next.cross(to_previous)).atan2(flat(to_next).dot(flat(to_previous)))
            })
            .sum();
        turned < ONE_TURN_AT_MOST
    }
}

/// Puts a vertex's polygons in order round it, each followed by the one
/// that runs its edge to `next` the other way; false unless they close into
/// one ring (a vertex inside a consistently oriented manifold).
fn order_round(list: &mut [Around]) -> bool {
    let n = list.len();
    for k in 0..n - 1 {
        let next = list[k].next;
        let Some(found) = (k + 1..n).find(|&j| list[j].previous == next) else { return false };
        list.swap(k + 1, found);
    }
    list[n - 1].next == list[0].previous && (0..n).all(|k| (0..n).filter(|&j| list[j].previous == list[k].previous).count() == 1)
}

#[cfg(test)]
mod tests {
    use super::super::bounds::NodeBounds;
    use super::super::tree::PatchTree;
    use super::*;

    /// Four quads round vertex 4 of a 3 × 3 grid of vertices (side 1),
    /// folded by `angle` along the middle row: the rows `y = 0` and `y = 2`
    /// turned up about it (a right angle brings them together above it).
    fn grid_star(angle: f32) -> (Vec<Vec3>, Stars) {
        let (s, c) = angle.sin_cos();
        let x: Vec<Vec3> = (0..9)
            .map(|i| {
                let column = (i % 3) as f32;
                match i / 3 {
                    0 => Vec3::new(column, 1.0 - c, s),
                    1 => Vec3::new(column, 1.0, 0.0),
                    _ => Vec3::new(column, 1.0 + c, s),
                }
            })
            .collect();
        (x, stars_of_quads(&[[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]]))
    }

    /// The stars of the 3 × 3 grid's vertices made of `quads`, each quad
    /// split into its four triangles as the skin's quads are.
    fn stars_of_quads(quads: &[[u32; 4]]) -> Stars {
        let polygons: Vec<&[u32]> = quads.iter().map(|q| &q[..]).collect();
        let (triangles, polygon_of) = split_quads(quads);
        Stars::new(9, &polygons, &triangles, &polygon_of)
    }

    #[test]
    fn sides_of_two_quads_across_a_corner_are_kept_apart_while_the_star_keeps_a_side() {
        let margin = [0.0; 9];
        let half_turn = std::f32::consts::FRAC_PI_2;
        for (angle, kept) in [(0.0, true), (0.5, true), (1.3, true), (-1.0, true), (half_turn, false), (1.9, true)] {
            let (x, stars) = grid_star(angle);
            let motion = Motion { start: &x, end: &x, margin: &margin };
            // Quads 0 1 4 3 and 4 5 8 7 meet only at vertex 4.
            assert_eq!(stars.keep_apart(&motion, &stars.memo(), &[0, 4], &[5, 7]), kept, "diagonals across 4 at {angle} rad");
            assert_eq!(stars.keep_apart(&motion, &stars.memo(), &[0], &[5, 8, 7]), kept, "corner against triangle across 4 at {angle} rad");
            assert_eq!(stars.keep_apart(&motion, &stars.memo(), &[1, 3], &[4, 5]), kept, "diagonal against a side across 4 at {angle} rad");
        }
        // Over a motion folding the star through itself (flat to 1.9 rad,
        // the two halves passing each other at a right angle), the normals
        // in between count.
        let (flat, stars) = grid_star(0.0);
        let (through, _) = grid_star(1.9);
        assert!(!stars.keep_apart(&Motion { start: &flat, end: &through, margin: &margin }, &stars.memo(), &[0, 4], &[5, 7]));
        // Nor when a margin could turn a quad over.
        let wide = [0.6; 9];
        assert!(!stars.keep_apart(&Motion { start: &flat, end: &flat, margin: &wide }, &stars.memo(), &[0, 4], &[5, 7]));
    }

    /// The grid's four quads, each split into its four triangles, as
    /// [`stars_of_quads`] makes them: triangles and their polygons.
    fn split_quads(quads: &[[u32; 4]]) -> (Vec<[u32; 3]>, Vec<u32>) {
        quads.iter().enumerate().flat_map(|(k, &[a, b, c, d])| [[a, b, c], [a, c, d], [a, b, d], [b, c, d]].map(|t| (t, k as u32))).unzip()
    }

    #[test]
    fn a_stars_cone_read_from_a_gatherings_bounds_answers_as_one_made_from_the_motion() {
        let quads = [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]];
        let (triangles, polygon_of) = split_quads(&quads);
        let polygons: Vec<&[u32]> = quads.iter().map(|q| &q[..]).collect();
        let (flat, _) = grid_star(0.0);
        let tree = PatchTree::build(&triangles, &flat);
        let stars = Stars::new(9, &polygons, &triangles, &polygon_of).placed_in(&tree.order);
        let mut answers = Vec::new();
        for angle in [0.0, 0.5, 1.3, -1.0, std::f32::consts::FRAC_PI_2, 1.9] {
            let (x, _) = grid_star(angle);
            for (start, margin) in [(&x, 0.0), (&flat, 0.0), (&flat, 0.05), (&x, 0.6)] {
                let margins = [margin; 9];
                let motion = Motion { start, end: &x, margin: &margins };
                let bounds = NodeBounds::new(&tree, &motion, None);
                let (made, read) = (stars.memo(), stars.memo_over(&bounds.triangle_cone));
                assert!(read.cones.is_some());
                for v in 0..9 {
                    let answer = stars.winds_once_memo(&motion, &read, v);
                    assert_eq!(answer, stars.winds_once_memo(&motion, &made, v), "vertex {v} at {angle} rad, margin {margin}");
                    answers.push(answer);
                }
            }
        }
        assert!(answers.contains(&true) && answers.contains(&false), "both answers asked");
    }

    #[test]
    fn two_polygons_kept_apart_keep_every_pair_of_their_sides_apart() {
        let quads = [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]];
        let margin = [0.0; 9];
        let mut apart = 0;
        for angle in [0.0, 0.5, 1.3, -1.0, std::f32::consts::FRAC_PI_2, 1.9] {
            let (x, stars) = grid_star(angle);
            let motion = Motion { start: &x, end: &x, margin: &margin };
            let memo = stars.memo();
            for p in 0..4 {
                for q in 0..4 {
                    if !stars.polygons_apart(&motion, &memo, p, q) {
                        continue;
                    }
                    apart += 1;
                    // Every corner and every side or diagonal of the one against the other's.
                    let sides = |k: usize| {
                        let c = quads[k];
                        let mut sides: Vec<Vec<u32>> = c.iter().map(|&v| vec![v]).collect();
                        sides.extend((0..4).flat_map(|i| (i + 1..4).map(move |j| vec![c[i], c[j]])));
                        sides.extend([[c[0], c[1], c[2]], [c[0], c[2], c[3]], [c[0], c[1], c[3]], [c[1], c[2], c[3]]].map(|t| t.to_vec()));
                        sides
                    };
                    for one in sides(p as usize) {
                        for other in sides(q as usize) {
                            assert!(stars.keep_apart(&motion, &memo, &one, &other), "{one:?} against {other:?} at {angle} rad");
                        }
                    }
                }
            }
        }
        // Every two of the four quads share vertex 4, whose star keeps a side but at the right angle.
        assert_eq!(apart, 5 * 12);
    }

    #[test]
    fn a_vertex_on_the_skins_boundary_has_no_star() {
        let (x, stars) = grid_star(0.0);
        let margin = [0.0; 9];
        let motion = Motion { start: &x, end: &x, margin: &margin };
        // Quads 0 1 4 3 and 1 2 5 4 share 1 (on the boundary) and 4: kept
        // apart through 4's star, never through 1's.
        assert!(stars.keep_apart(&motion, &stars.memo(), &[0], &[2, 5, 4]));
        assert!(!stars.winds_once(&motion, None, 1));
        assert!(stars.winds_once(&motion, None, 4));
        // Quads 0 1 4 3 and 1 2 5 4 seen without vertex 4's other quads: no star at all.
        let open = stars_of_quads(&[[0, 1, 4, 3], [1, 2, 5, 4]]);
        assert!(!open.keep_apart(&motion, &open.memo(), &[0], &[2, 5, 4]));
    }

    #[test]
    fn a_star_winding_twice_round_its_vertex_is_no_star_pair() {
        // Eight triangles round vertex 0 whose link turns by a quarter each,
        // twice round in all, climbing and coming down again: every normal
        // leans up, but the star laps over itself in projection.
        let link: Vec<Vec3> = (0..8)
            .map(|i| {
                let turn = std::f32::consts::FRAC_PI_2 * i as f32;
                Vec3::new(turn.cos(), turn.sin(), 0.3 * (1.0 - (0.5 * turn).cos()))
            })
            .collect();
        let mut x = vec![Vec3::ZERO];
        x.extend(link);
        let triangles: Vec<[u32; 3]> = (0..8).map(|i| [0, 1 + i, 1 + (i + 1) % 8]).collect();
        let polygons: Vec<&[u32]> = triangles.iter().map(|t| &t[..]).collect();
        let polygon_of: Vec<u32> = (0..8).collect();
        let stars = Stars::new(9, &polygons, &triangles, &polygon_of);
        let margin = [0.0; 9];
        let motion = Motion { start: &x, end: &x, margin: &margin };
        assert!(one_side_axis(&motion, triangles.iter()).is_some(), "every normal leans one way");
        // Vertex 5 sits over vertex 1's ray, above triangle 0 1 2's wedge.
        assert!(!stars.keep_apart(&motion, &stars.memo(), &[5], &[0, 1, 2]));
        // Once round (the first four triangles closed by a fifth), the same test passes.
        let once: Vec<[u32; 3]> = vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]];
        let flat: Vec<Vec3> = (0..5).map(|i| if i == 0 { Vec3::ZERO } else { Vec3::new(x[i].x, x[i].y, 0.0) }).collect();
        let polygons: Vec<&[u32]> = once.iter().map(|t| &t[..]).collect();
        let stars = Stars::new(5, &polygons, &once, &[0, 1, 2, 3]);
        let margin = [0.0; 5];
        assert!(stars.keep_apart(&Motion { start: &flat, end: &flat, margin: &margin }, &stars.memo(), &[3], &[0, 1, 2]));
    }
}
