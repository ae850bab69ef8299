//! Candidate pairs: the pairs of skin elements (vertex–triangle, edge–edge)
//! that may come within the thickness over a motion, found by a
//! self-traversal of the patch tree (Volino and Magnenat-Thalmann; Tang et
//! al. 2009):
//!
//! * a node that provably cannot touch itself (a disk with a normal cone and
//!   a contour that winds once, [`NodeBounds::cannot_touch_itself`]) holds
//!   no candidate: the flat and gently curved skin, almost all of it, is
//!   left after a few nodes;
//! * otherwise its two children are tested each on its own and against
//!   each other; two nodes whose relative box ([`relative_gap`]) stays
//!   farther apart than the reach hold none, nor do two adjacent disks whose
//!   union cannot touch itself
//!   ([`NodeBounds::cannot_touch_each_other`], Tang et al.'s
//!   connectivity culling: without it every shared border would be walked
//!   down to its leaves), nor two that meet at a corner or lie a ring apart
//!   and that a plane keeps farther apart than the reach
//!   ([`separated`]);
//! * two leaves: their triangles' relative boxes, then each element pair's,
//!   then its exact distances at both ends of the motion less how much the
//!   relative motion can change them ([`element_within`]): at rest most
//!   element pairs whose boxes overlap (neighbours a ring or two apart) are
//!   an edge apart, and none of them is listed.
//!
//! Each vertex and each edge is *owned* by the first triangle of the tree's
//! order that holds it, and an element pair is listed from the pair of
//! triangles owning it and holding it: each pair once, without sorting.
//!
//! Recursion splits into parallel tasks near the top and concatenates them
//! in a fixed order: the list is the same for any number of threads.

use glam::Vec3;

use super::bounds::{element_within, relative_gap, Motion, NodeBounds, Span};
use super::hinge::Hinges;
use super::separation::separated;
use super::star::{StarMemo, Stars};
use super::tree::PatchTree;

/// A pair of elements: a vertex and a triangle (`corners = [v, a, b, c]`)
/// or two edges (`[a0, a1, b0, b1]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub(super) struct ElementPair {
    pub edge_edge: bool,
    pub corners: [u32; 4],
}

/// Which corners (bits 0–2) and edges (bits 3–5, edge `k` from corner `k`
/// to corner `k + 1`) each tree position owns.
pub(super) fn ownership(tree: &PatchTree, vertex_count: usize) -> Vec<u8> {
    let mut vertex_owned = vec![false; vertex_count];
    let mut edges_seen = std::collections::HashSet::new();
    tree.triangles
        .iter()
        .map(|t| {
            let mut bits = 0u8;
            for k in 0..3 {
                if !std::mem::replace(&mut vertex_owned[t[k] as usize], true) {
                    bits |= 1 << k;
                }
                let (a, b) = (t[k], t[(k + 1) % 3]);
                if edges_seen.insert((a.min(b), a.max(b))) {
                    bits |= 1 << (3 + k);
                }
            }
            bits
        })
        .collect()
}

/// Where a gathering looks: only pairs with a triangle of this set (per
/// tree position), and the nodes holding one. What lies elsewhere was
/// decided by an earlier gathering and has not changed since, so a re-check
/// around a few vertices costs a refit and a traversal that drops every
/// subtree without one, not a search of the whole skin.
pub(super) struct Focus {
    triangles: Vec<bool>,
    nodes: Vec<bool>,
    /// The nodes in focus, children before their parents.
    listed: Vec<u32>,
}

impl Focus {
    /// The triangles with a corner among `vertices` (flags per vertex),
    /// found from those vertices ([`PatchTree::around`]).
    pub(super) fn around(tree: &PatchTree, vertices: &[bool]) -> Self {
        let around = tree.around(vertices);
        Focus { triangles: around.triangles, nodes: around.holds, listed: around.nodes }
    }

    /// Whether nothing is in focus.
    pub(super) fn is_empty(&self) -> bool {
        self.nodes.first().is_none_or(|&n| !n)
    }

    /// Per node, the union of its triangles in focus' spans (`bounds`' per
    /// tree position), [`Span::EMPTY`] where it holds none.
    fn spans(&self, tree: &PatchTree, bounds: &NodeBounds) -> Vec<Span> {
        let mut spans = vec![Span::EMPTY; tree.nodes.len()];
        for &i in &self.listed {
            let i = i as usize;
            let node = tree.nodes[i];
            spans[i] = if node.is_leaf() {
                node.range().filter(|&p| self.triangles[p]).fold(Span::EMPTY, |s, p| s.union(bounds.triangle[p]))
            } else {
                spans[node.left as usize].union(spans[node.left as usize + 1])
            };
        }
        spans
    }
}

/// A focus over one gathering: where it is, and the spans of its triangles
/// per node ([`Focus::spans`]). A pair of nodes holds a listed pair only if
/// a focus triangle of one comes within the reach of the other, so the
/// focus triangles' own box prunes where the nodes' boxes, holding the
/// skin around the focus, overlap (a gathering around a few vertices
/// otherwise walked every node pair near the focus's ancestors, issue 30,
/// twenty-fourth round).
struct InFocus<'f> {
    focus: &'f Focus,
    span: Vec<Span>,
}

/// One gathering: what it traverses and what it keeps.
pub(super) struct Gather<'a> {
    pub tree: &'a PatchTree,
    pub owns: &'a [u8],
    pub bounds: &'a NodeBounds,
    pub motion: Motion<'a>,
    /// Pairs whose relative box stays farther apart than this are dropped.
    pub reach: f32,
    /// Whether nodes that cannot touch themselves are skipped, and with them
    /// the pairs one hinge apart or two polygons apart round a vertex
    /// anywhere ([`Hinges`], [`Stars`]: the same rules for any tree); off to
    /// find every pair within the reach, not only those that may intersect.
    pub cull: bool,
    /// The skin's triangles by directed edge, for the hinge rule `cull` applies.
    pub hinges: &'a Hinges,
    /// The polygons round each vertex, for the star rule `cull` applies.
    pub stars: &'a Stars,
    /// Per tree position, the polygon its triangle comes from (the stars' numbering).
    pub polygon: &'a [u32],
    /// The stars' answers over this gathering's motion ([`Stars::memo`]).
    pub star_memo: StarMemo<'a>,
    /// Per tree position: whether its triangle takes part (None: all do).
    pub takes_part: Option<&'a [bool]>,
    /// Whether two sides are tested at all (neighbours, tangles).
    pub accept: &'a (dyn Fn(&[u32], &[u32]) -> bool + Sync),
    /// Only pairs with a triangle in focus (None: every pair).
    pub focus: Option<&'a Focus>,
}

/// Below this many triangles a subtree is traversed on one thread.
const PARALLEL_BELOW: u32 = 2048;

/// What a gathering lists for each pair of triangles whose relative box
/// comes within the reach: its element pairs, or the triangle pair itself.
pub(super) trait Found: Sized + Send {
    fn list(gather: &Gather<'_>, p: usize, q: usize, out: &mut Vec<Self>);
}

impl Found for ElementPair {
    fn list(gather: &Gather<'_>, p: usize, q: usize, out: &mut Vec<Self>) {
        gather.element_pairs(p, q, out);
    }
}

/// Tree positions of two triangles, not neighbours.
impl Found for [u32; 2] {
    fn list(gather: &Gather<'_>, p: usize, q: usize, out: &mut Vec<Self>) {
        if (gather.accept)(&gather.tree.triangles[p], &gather.tree.triangles[q]) {
            out.push([p as u32, q as u32]);
        }
    }
}

impl Gather<'_> {
    /// The element pairs within the reach.
    pub(super) fn run(&self) -> Vec<ElementPair> {
        self.all()
    }

    /// The pairs of triangles (tree positions) within the reach.
    pub(super) fn triangle_pairs(&self) -> Vec<[u32; 2]> {
        self.all()
    }

    fn all<O: Found>(&self) -> Vec<O> {
        if self.tree.nodes.is_empty() {
            return Vec::new();
        }
        let focus = self.focus.map(|focus| InFocus { focus, span: focus.spans(self.tree, self.bounds) });
        self.self_test(0, focus.as_ref())
    }

    fn self_test<O: Found>(&self, i: usize, focus: Option<&InFocus<'_>>) -> Vec<O> {
        let node = self.tree.nodes[i];
        if !self.bounds.active[i] || node.count < 2 || focus.is_some_and(|f| !f.focus.nodes[i]) {
            return Vec::new();
        }
        if node.is_leaf() {
            let mut out = Vec::new();
            self.leaf_pair(i, i, focus, &mut out);
            return out;
        }
        if self.cull && self.bounds.cannot_touch_itself(self.tree, &self.motion, i) {
            return Vec::new();
        }
        let (l, r) = (node.left as usize, node.left as usize + 1);
        if node.count < PARALLEL_BELOW {
            let mut out = self.self_test(l, focus);
            out.extend(self.self_test(r, focus));
            self.pair_test(l, r, true, focus, &mut out);
            return out;
        }
        let ((mut out, right), between) = rayon::join(
            || rayon::join(|| self.self_test(l, focus), || self.self_test(r, focus)),
            || {
                let mut between = Vec::new();
                self.pair_test(l, r, true, focus, &mut between);
                between
            },
        );
        out.extend(right);
        out.extend(between);
        out
    }

    /// The pairs between nodes `a` and `b`; `siblings` when their union is
    /// their parent, which already failed the curvature test.
    fn pair_test<O: Found>(&self, a: usize, b: usize, siblings: bool, focus: Option<&InFocus<'_>>, out: &mut Vec<O>) {
        let bounds = self.bounds;
        if !(bounds.active[a] && bounds.active[b]) || focus.is_some_and(|f| !(f.focus.nodes[a] || f.focus.nodes[b])) {
            return;
        }
        if relative_gap(&bounds.span[a], &bounds.span[b]) > self.reach {
            return;
        }
        // Only a triangle pair with one in focus is listed, and only if
        // their own spans come within the reach, which the spans holding
        // them bound: boxes within boxes and margins within margins give a
        // gap at least as large, in f32 too (every step of `relative_gap`
        // is monotone), so nothing listed is pruned here.
        if let Some(f) = focus {
            if relative_gap(&f.span[a], &bounds.span[b]) > self.reach && relative_gap(&bounds.span[a], &f.span[b]) > self.reach {
                return;
            }
        }
        // The plane first: it settles corners and near neighbours, and
        // fails in a few steps on patches sharing an edge, which the
        // curvature criterion then decides.
        if self.cull && separated(self.tree, &self.motion, (a, &bounds.span[a]), (b, &bounds.span[b]), self.reach) {
            return;
        }
        if self.cull && !siblings && bounds.cannot_touch_each_other(self.tree, &self.motion, a, b) {
            return;
        }
        let (na, nb) = (self.tree.nodes[a], self.tree.nodes[b]);
        match (na.is_leaf(), nb.is_leaf()) {
            (true, true) => self.leaf_pair(a, b, focus, out),
            (false, leaf_b) if leaf_b || na.count >= nb.count => {
                self.pair_test(na.left as usize, b, false, focus, out);
                self.pair_test(na.left as usize + 1, b, false, focus, out);
            }
            _ => {
                self.pair_test(a, nb.left as usize, false, focus, out);
                self.pair_test(a, nb.left as usize + 1, false, focus, out);
            }
        }
    }

    /// The element pairs between two leaves (or within one, `a == b`).
    fn leaf_pair<O: Found>(&self, a: usize, b: usize, focus: Option<&InFocus<'_>>, out: &mut Vec<O>) {
        let (ra, rb) = (self.tree.nodes[a].range(), self.tree.nodes[b].range());
        let span = &self.bounds.triangle;
        let part = |p: usize| self.takes_part.is_none_or(|flags| flags[p]);
        let focused = |p: usize, q: usize| focus.is_none_or(|f| f.focus.triangles[p] || f.focus.triangles[q]);
        for p in ra {
            if !part(p) {
                continue;
            }
            for q in rb.clone() {
                if (a == b && q <= p) || !part(q) || !focused(p, q) {
                    continue;
                }
                if relative_gap(&span[p], &span[q]) > self.reach {
                    continue;
                }
                O::list(self, p, q, out);
            }
        }
    }

    /// The element pairs owned by tree positions `p` and `q`.
    fn element_pairs(&self, p: usize, q: usize, out: &mut Vec<ElementPair>) {
        let (tp, tq) = (self.tree.triangles[p], self.tree.triangles[q]);
        // Two triangles in two polygons of a star that keeps one side and
        // winds once: each of their element pairs has its sides in those two
        // polygons, so the star rule keeps every one of them apart. Asked once
        // for the triangle pair, before any span or exact gap: most triangle
        // pairs whose boxes meet are neighbours a polygon apart round a vertex
        // (issue 30, twenty-third round).
        if self.cull && self.stars.polygons_apart(&self.motion, &self.star_memo, self.polygon[p], self.polygon[q]) {
            return;
        }
        let (op, oq) = (self.owns[p], self.owns[q]);
        // A vertex–triangle pair's triangle is `tp` or `tq`: its span is the bounds'.
        let mut consider = |one: &[u32], other: &[u32], other_span: Option<&Span>, edge_edge: bool| {
            if !(self.accept)(one, other) {
                return;
            }
            let other_span = other_span.copied().unwrap_or_else(|| self.motion.span(other));
            if relative_gap(&self.motion.span(one), &other_span) > self.reach {
                return;
            }
            // The boxes overlap; the exact distances at both ends decide
            // (the reach already carries the f32 rounding allowance).
            if !element_within(&self.motion, one, other, self.reach as f64) {
                return;
            }
            if self.cull && (self.hinges.keep_apart(&self.motion, one, other) || self.stars.keep_apart(&self.motion, &self.star_memo, one, other)) {
                return;
            }
            let corners = if edge_edge { [one[0], one[1], other[0], other[1]] } else { [one[0], other[0], other[1], other[2]] };
            out.push(ElementPair { edge_edge, corners });
        };
        for k in 0..3 {
            if op & (1 << k) != 0 {
                consider(&[tp[k]], &tq, Some(&self.bounds.triangle[q]), false);
            }
            if oq & (1 << k) != 0 {
                consider(&[tq[k]], &tp, Some(&self.bounds.triangle[p]), false);
            }
        }
        for i in 0..3 {
            if op & (8 << i) == 0 {
                continue;
            }
            let e = [tp[i], tp[(i + 1) % 3]];
            for j in 0..3 {
                if oq & (8 << j) != 0 {
                    consider(&e, &[tq[j], tq[(j + 1) % 3]], None, true);
                }
            }
        }
    }
}

/// Largest absolute coordinate of a set of positions (at least 1e-3): the
/// scale the f32 rounding allowances are relative to.
pub(super) fn scale_of(positions: &[Vec3]) -> f32 {
    positions.iter().map(|p| p.abs().max_element()).fold(1e-3, f32::max)
}
