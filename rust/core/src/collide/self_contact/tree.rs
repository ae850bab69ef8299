//! The patch tree: the skin's triangles split at rest, by median cuts of
//! their centroids along the longest axis, into a binary tree of spatially
//! compact patches (leaves of at most [`LEAF`] triangles, or one polygon's,
//! each a contiguous range of the tree's triangle order; a polygon's
//! triangles never part). Built once per bind; every pass
//! refits its boxes and normal cones ([`super::bounds`]).
//!
//! Volino and Magnenat-Thalmann's curvature criterion needs to know which
//! patches are **disks** (connected, manifold, consistently oriented, one
//! boundary loop, Euler characteristic 1): a disk whose normals all lie on
//! one side of a plane and whose boundary, projected along that plane's
//! normal, winds at most once around any point cannot touch itself
//! ([`super::bounds`] says why). Which nodes are disks, and their boundary
//! loops, are found here bottom-up: a node's boundary is its children's with
//! the edges they share cancelled, which is what makes it cheap.

use glam::Vec3;

/// Most triangles of a leaf.
pub(super) const LEAF: usize = 8;

/// Boundary loops longer than this are not kept: such a patch is large, its
/// normals rarely fit a cone, and its parents are not disks either.
const MAX_LOOP: usize = 8192;

pub(super) const NONE: u32 = u32::MAX;

#[derive(Debug, Clone, Copy)]
pub(super) struct Node {
    /// First position in the tree's triangle order, and how many.
    pub first: u32,
    pub count: u32,
    /// Left child (the right one follows it), or [`NONE`] for a leaf.
    pub left: u32,
}

impl Node {
    pub(super) fn is_leaf(&self) -> bool {
        self.left == NONE
    }
    pub(super) fn range(&self) -> std::ops::Range<usize> {
        self.first as usize..(self.first + self.count) as usize
    }
}

#[derive(Debug, Clone)]
pub(super) struct PatchTree {
    /// Parents before their children (index order is a preorder).
    pub nodes: Vec<Node>,
    /// The skin's triangles in tree order.
    pub triangles: Vec<[u32; 3]>,
    /// Tree position → the skin's triangle index.
    pub order: Vec<u32>,
    /// The leaves' node indices, ascending.
    pub leaves: Vec<u32>,
    /// Per node: whether it is a disk ([`Self::boundary`] then holds its loop).
    pub disk: Vec<bool>,
    loop_offsets: Vec<u32>,
    loop_vertices: Vec<u32>,
    /// Per node, its loop's [`loop_index`] (same offsets).
    loop_index: Vec<(u32, u32)>,
    /// Per node of at most [`SEPARABLE`] triangles, its vertices, sorted
    /// (empty for larger nodes): what [`super::separation`] projects
    /// (offsets, then the lists).
    vertices: (Vec<u32>, Vec<u32>),
    /// The same nodes' exposed vertices: those another node can share.
    exposed: (Vec<u32>, Vec<u32>),
    /// Per node `a` (offsets, then `(b, join)` sorted by `b`), the disks `b`
    /// a traversal may pair it with whose loop joins `a`'s ([`Self::joined`]).
    joins: (Vec<u32>, Vec<(u32, Join)>),
    /// Per vertex (offsets, then tree positions ascending), the triangles
    /// with it as a corner; per tree position, its leaf; per node, its
    /// parent ([`NONE`] at the root): what [`Self::around`] walks, so that
    /// a gathering around a few vertices pays for those vertices, not for
    /// a pass over every triangle and node (issue 30, twenty-fifth round).
    at_vertex: (Vec<u32>, Vec<u32>),
    leaf_of: Vec<u32>,
    parent: Vec<u32>,
}

/// The part of the tree around a few vertices ([`PatchTree::around`]).
pub(super) struct Around {
    /// Per tree position: whether its triangle has a corner among them.
    pub triangles: Vec<bool>,
    /// Per node: whether it holds such a triangle.
    pub holds: Vec<bool>,
    /// The nodes that do, in descending index order: children before their
    /// parents (index order is a preorder).
    pub nodes: Vec<u32>,
}

/// Where two disks' loops join along the one run of edges they share: on
/// `a`'s loop the place where the run ends and the run's edge count, on
/// `b`'s the place where it starts ([`join_of`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Join {
    last: u32,
    count: u32,
    start_b: u32,
}

/// The loop of two joined disks, read in place from theirs: `a`'s from the
/// run's end round to its start, then `b`'s from there back to the run's end.
#[derive(Debug, Clone, Copy)]
pub(super) struct JoinedLoop<'t> {
    a: &'t [u32],
    b: &'t [u32],
    join: Join,
}

impl JoinedLoop<'_> {
    pub(super) fn len(&self) -> usize {
        self.a.len() + self.b.len() - 2 * self.join.count as usize
    }

    /// The loop's `j`-th vertex (`j < len`).
    pub(super) fn vertex(&self, j: usize) -> u32 {
        let (na, nb) = (self.a.len(), self.b.len());
        let on_a = na - self.join.count as usize; // a's edges off the run
        if j <= on_a {
            self.a[(self.join.last as usize + j) % na]
        } else {
            self.b[(self.join.start_b as usize + j - on_a) % nb]
        }
    }
}

/// Nodes up to this many triangles keep their vertex lists for the
/// separating-plane test; larger pairs are cheaper to split than to scan.
pub(super) const SEPARABLE: u32 = 1024;

/// A node's surface as the bottom-up pass sees it.
struct Shape {
    /// Directed boundary edges (from the triangles' winding).
    boundary: Vec<[u32; 2]>,
    vertices: i64,
    edges: i64,
    faces: i64,
    /// Not a manifold, consistently oriented patch (or too large to say).
    tainted: bool,
}

impl PatchTree {
    /// The tree of single triangles (every triangle is surface).
    #[cfg(test)]
    pub(super) fn build(triangles: &[[u32; 3]], rest: &[Vec3]) -> Self {
        let units: Vec<u32> = (0..=triangles.len() as u32).collect();
        Self::build_in_units(triangles, &units, &vec![true; triangles.len()], rest)
    }

    /// The tree of a test mesh's polygons, fanned.
    #[cfg(test)]
    pub(super) fn of_mesh(mesh: crate::mesh::MeshInput<'_>) -> Self {
        Self::build(&crate::mesh::fan_triangles(mesh.corner_verts, &mesh.validate().unwrap()), mesh.positions)
    }

    /// The tree of `triangles` cut between *units*, runs of triangles
    /// (`unit_offsets`, compressed rows) that stay in one leaf: a polygon's.
    /// Only the triangles flagged in `surface` (one split of each polygon)
    /// decide which nodes are disks: a quad split both ways is four
    /// triangles over one surface, and with whole quads in a node every
    /// choice of their splits has the same boundary, so what is proven for
    /// one split of the node ([`super::bounds`], its cones covering all
    /// four triangles) holds for every split.
    pub(super) fn build_in_units(triangles: &[[u32; 3]], unit_offsets: &[u32], surface: &[bool], rest: &[Vec3]) -> Self {
        let unit_count = unit_offsets.len().saturating_sub(1);
        let size = |u: u32| unit_offsets[u as usize + 1] - unit_offsets[u as usize];
        let centroid: Vec<Vec3> = (0..unit_count)
            .map(|u| {
                let range = unit_offsets[u] as usize..unit_offsets[u + 1] as usize;
                let sum = triangles[range.clone()].iter().fold(Vec3::ZERO, |acc, t| acc + rest[t[0] as usize] + rest[t[1] as usize] + rest[t[2] as usize]);
                sum / (3 * range.len().max(1)) as f32
            })
            .collect();
        let mut units: Vec<u32> = (0..unit_count as u32).collect();
        // Built over units (first unit, count of units, triangles); turned into triangle ranges below.
        let mut built: Vec<(u32, u32, u32, u32)> = vec![(0, unit_count as u32, triangles.len() as u32, NONE)];
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let (first, count, triangle_count, _) = built[i];
            if triangle_count as usize <= LEAF || count < 2 {
                continue;
            }
            let slice = &mut units[first as usize..(first + count) as usize];
            let (lo, hi) = slice.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &u| {
                let c = centroid[u as usize];
                (lo.min(c), hi.max(c))
            });
            let extent = hi - lo;
            let axis = if extent.x >= extent.y && extent.x >= extent.z { 0 } else if extent.y >= extent.z { 1 } else { 2 };
            let mid = count / 2;
            slice.select_nth_unstable_by(mid as usize, |&a, &b| {
                centroid[a as usize][axis].total_cmp(&centroid[b as usize][axis]).then(a.cmp(&b))
            });
            let left_triangles: u32 = slice[..mid as usize].iter().map(|&u| size(u)).sum();
            let left = built.len();
            built[i].3 = left as u32;
            built.push((first, mid, left_triangles, NONE));
            built.push((first + mid, count - mid, triangle_count - left_triangles, NONE));
            stack.push(left);
            stack.push(left + 1);
        }
        let mut unit_start = Vec::with_capacity(unit_count + 1);
        let mut order: Vec<u32> = Vec::with_capacity(triangles.len());
        for &u in &units {
            unit_start.push(order.len() as u32);
            order.extend(unit_offsets[u as usize]..unit_offsets[u as usize + 1]);
        }
        unit_start.push(order.len() as u32);
        let nodes: Vec<Node> = built.iter().map(|&(first, _, count, left)| Node { first: unit_start[first as usize], count, left }).collect();
        let tree_triangles: Vec<[u32; 3]> = order.iter().map(|&t| triangles[t as usize]).collect();
        let tree_surface: Vec<bool> = order.iter().map(|&t| surface[t as usize]).collect();
        let leaves: Vec<u32> = (0..nodes.len() as u32).filter(|&i| nodes[i as usize].is_leaf()).collect();

        // Bottom-up: a node's shape from its children's (children follow their parent).
        let mut shapes: Vec<Option<Shape>> = (0..nodes.len()).map(|_| None).collect();
        let mut disk = vec![false; nodes.len()];
        let mut loops: Vec<Vec<u32>> = vec![Vec::new(); nodes.len()];
        for i in (0..nodes.len()).rev() {
            let node = nodes[i];
            let shape = if node.is_leaf() {
                let range = node.range();
                let on_surface: Vec<[u32; 3]> = tree_triangles[range.clone()].iter().zip(&tree_surface[range]).filter(|(_, &s)| s).map(|(t, _)| *t).collect();
                leaf_shape(&on_surface)
            } else {
                let l = shapes[node.left as usize].take().expect("children come after their parent");
                let r = shapes[node.left as usize + 1].take().expect("children come after their parent");
                merge(l, r)
            };
            if !shape.tainted && shape.vertices - shape.edges + shape.faces == 1 {
                if let Some(cycle) = single_cycle(&shape.boundary) {
                    disk[i] = true;
                    loops[i] = cycle;
                }
            }
            shapes[i] = Some(shape);
        }
        let mut loop_offsets = Vec::with_capacity(nodes.len() + 1);
        loop_offsets.push(0u32);
        let mut loop_vertices = Vec::new();
        let mut loop_index_all = Vec::new();
        for l in loops {
            loop_vertices.extend_from_slice(&l);
            loop_index_all.extend(loop_index(&l));
            loop_offsets.push(loop_vertices.len() as u32);
        }
        let vertex_count = rest.len().max(tree_triangles.iter().flatten().map(|&v| v as usize + 1).max().unwrap_or(0));
        let [vertices, exposed] = node_vertices(&nodes, &tree_triangles, vertex_count);
        let at_vertex = positions_at_vertices(&tree_triangles, vertex_count);
        let mut leaf_of = vec![NONE; tree_triangles.len()];
        for &leaf in &leaves {
            leaf_of[nodes[leaf as usize].range()].fill(leaf);
        }
        let mut parent = vec![NONE; nodes.len()];
        for (i, node) in nodes.iter().enumerate().filter(|(_, n)| !n.is_leaf()) {
            parent[node.left as usize] = i as u32;
            parent[node.left as usize + 1] = i as u32;
        }
        let mut tree = PatchTree {
            nodes,
            triangles: tree_triangles,
            order,
            leaves,
            disk,
            loop_offsets,
            loop_vertices,
            loop_index: loop_index_all,
            vertices,
            exposed,
            joins: (Vec::new(), Vec::new()),
            at_vertex,
            leaf_of,
            parent,
        };
        tree.joins = tree.adjacent_joins();
        tree
    }

    /// The triangles with a corner among `vertices` (flags per vertex) and
    /// the nodes holding one, found from those vertices' triangles up their
    /// leaves' parent links (each node once: a walk stops at a node already
    /// found, whose ancestors are), so it costs what lies around them.
    pub(super) fn around(&self, vertices: &[bool]) -> Around {
        let mut triangles = vec![false; self.triangles.len()];
        let mut holds = vec![false; self.nodes.len()];
        let mut nodes = Vec::new();
        for v in (0..vertices.len()).filter(|&v| vertices[v]) {
            for &p in &self.at_vertex.1[self.at_vertex.0[v] as usize..self.at_vertex.0[v + 1] as usize] {
                triangles[p as usize] = true;
                let mut i = self.leaf_of[p as usize];
                while i != NONE && !std::mem::replace(&mut holds[i as usize], true) {
                    nodes.push(i);
                    i = self.parent[i as usize];
                }
            }
        }
        nodes.sort_unstable_by(|a, b| b.cmp(a));
        Around { triangles, holds, nodes }
    }

    /// The joined loop of disks `a` and `b` if a traversal may pair them
    /// (`a` from the left of their lowest common ancestor) and their loops
    /// join along one run of shared edges ([`join_of`]), found at bind.
    pub(super) fn joined(&self, a: usize, b: usize) -> Option<JoinedLoop<'_>> {
        let list = &self.joins.1[self.joins.0[a] as usize..self.joins.0[a + 1] as usize];
        let k = list.binary_search_by_key(&(b as u32), |&(partner, _)| partner).ok()?;
        Some(JoinedLoop { a: self.boundary(a), b: self.boundary(b), join: list[k].1 })
    }

    /// Every pair of nodes a traversal's node pairs may reach whose loops
    /// join ([`join_of`]), per first node. A traversal pairs two siblings,
    /// then splits one node of a pair at a time (the larger, the first on
    /// a tie, [`super::gather`]), so the pairs holding two given leaves form
    /// one chain from their lowest common ancestor's children down. Two
    /// loops that join share an edge of the skin, held by a triangle of
    /// each, so the pair lies on the chain of two leaves sharing an edge:
    /// walking the pairs that hold such two leaves, as a traversal would,
    /// finds every pair that can join. Asked of every
    /// adjacent pair of disks of every gathering, the join cost binary
    /// searches over both loops each time (a tenth of a quiet frame of the
    /// MakeHuman character, issue 30, twenty-fourth round).
    fn adjacent_joins(&self) -> (Vec<u32>, Vec<(u32, Join)>) {
        // The leaves holding each edge of the skin, the edges bucketed by
        // their lower vertex, each bucket holding (higher vertex, leaf's first position).
        let mut leaf_first = vec![0u32; self.triangles.len()];
        for &leaf in &self.leaves {
            let node = self.nodes[leaf as usize];
            leaf_first[node.range()].fill(node.first);
        }
        let edge = |t: &[u32; 3], k: usize| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]));
        let vertex_count = self.triangles.iter().flatten().map(|&v| v as usize + 1).max().unwrap_or(0);
        let mut offsets = vec![0u32; vertex_count + 1];
        for t in &self.triangles {
            for k in 0..3 {
                offsets[edge(t, k).0 as usize + 1] += 1;
            }
        }
        for v in 0..vertex_count {
            offsets[v + 1] += offsets[v];
        }
        let mut fill = offsets.clone();
        let mut buckets = vec![(0u32, 0u32); offsets[vertex_count] as usize];
        for (p, t) in self.triangles.iter().enumerate() {
            for k in 0..3 {
                let (low, high) = edge(t, k);
                buckets[fill[low as usize] as usize] = (high, leaf_first[p]);
                fill[low as usize] += 1;
            }
        }
        // Pairs of leaves sharing an edge, by their first positions, lower first.
        let mut leaf_pairs: Vec<(u32, u32)> = Vec::new();
        for v in 0..vertex_count {
            let bucket = &mut buckets[offsets[v] as usize..offsets[v + 1] as usize];
            bucket.sort_unstable();
            for group in bucket.chunk_by(|e, f| e.0 == f.0) {
                for (i, e) in group.iter().enumerate() {
                    leaf_pairs.extend(group[i + 1..].iter().filter(|f| f.1 != e.1).map(|f| (e.1.min(f.1), e.1.max(f.1))));
                }
            }
        }
        let mut joins: Vec<(u32, u32, Join)> = Vec::new();
        if !self.nodes.is_empty() {
            self.joins_within(0, &mut leaf_pairs, &mut joins);
        }
        joins.sort_unstable_by_key(|&(a, b, _)| (a, b));
        let mut offsets = vec![0u32; self.nodes.len() + 1];
        for &(a, _, _) in &joins {
            offsets[a as usize + 1] += 1;
        }
        for i in 0..self.nodes.len() {
            offsets[i + 1] += offsets[i];
        }
        (offsets, joins.into_iter().map(|(_, b, join)| (b, join)).collect())
    }

    /// [`Self::adjacent_joins`] under node `i`: `leaf_pairs` (first
    /// positions, lower first) are the pairs of its leaves sharing an edge.
    fn joins_within(&self, i: usize, leaf_pairs: &mut [(u32, u32)], joins: &mut Vec<(u32, u32, Join)>) {
        let node = self.nodes[i];
        if node.is_leaf() || leaf_pairs.is_empty() {
            return;
        }
        let (l, r) = (node.left as usize, node.left as usize + 1);
        let mid = self.nodes[r].first;
        // Both in the left child, both in the right, then across.
        let left = partition(leaf_pairs, |&(_, y)| y < mid);
        let (in_left, rest) = leaf_pairs.split_at_mut(left);
        let right = partition(rest, |&(x, _)| x >= mid);
        let (in_right, across) = rest.split_at_mut(right);
        self.joins_within(l, in_left, joins);
        self.joins_within(r, in_right, joins);
        self.joins_between(l, r, across, joins);
    }

    /// [`Self::adjacent_joins`] of the pair `(a, b)` and the pairs a
    /// traversal splits it into that hold one of `leaf_pairs` (first
    /// positions, one under `a`, the other under `b`).
    fn joins_between(&self, a: usize, b: usize, leaf_pairs: &mut [(u32, u32)], joins: &mut Vec<(u32, u32, Join)>) {
        if leaf_pairs.is_empty() {
            return;
        }
        if self.disk[a] && self.disk[b] {
            if let Some(join) = join_of(self.boundary(a), self.boundary(b), self.boundary_index(b)) {
                joins.push((a as u32, b as u32, join));
            }
        }
        let (na, nb) = (self.nodes[a], self.nodes[b]);
        match (na.is_leaf(), nb.is_leaf()) {
            (true, true) => {}
            (false, leaf_b) if leaf_b || na.count >= nb.count => {
                let mid = self.nodes[na.left as usize + 1].first;
                let k = partition(leaf_pairs, |&(x, _)| x < mid);
                let (first, second) = leaf_pairs.split_at_mut(k);
                self.joins_between(na.left as usize, b, first, joins);
                self.joins_between(na.left as usize + 1, b, second, joins);
            }
            _ => {
                let mid = self.nodes[nb.left as usize + 1].first;
                let k = partition(leaf_pairs, |&(_, y)| y < mid);
                let (first, second) = leaf_pairs.split_at_mut(k);
                self.joins_between(a, nb.left as usize, first, joins);
                self.joins_between(a, nb.left as usize + 1, second, joins);
            }
        }
    }

    /// The vertices of node `i`, sorted, if it has at most [`SEPARABLE`]
    /// triangles (empty otherwise).
    pub(super) fn vertices(&self, i: usize) -> &[u32] {
        &self.vertices.1[self.vertices.0[i] as usize..self.vertices.0[i + 1] as usize]
    }

    /// The vertices of node `i` that a triangle outside it holds too,
    /// sorted (empty for nodes above [`SEPARABLE`] triangles): every vertex
    /// it shares with another node is one.
    pub(super) fn exposed(&self, i: usize) -> &[u32] {
        &self.exposed.1[self.exposed.0[i] as usize..self.exposed.0[i + 1] as usize]
    }

    /// The boundary loop of disk node `i` (vertices in order), empty otherwise.
    pub(super) fn boundary(&self, i: usize) -> &[u32] {
        &self.loop_vertices[self.loop_offsets[i] as usize..self.loop_offsets[i + 1] as usize]
    }

    /// [`Self::boundary`]'s vertices with their places on it, sorted by vertex.
    pub(super) fn boundary_index(&self, i: usize) -> &[(u32, u32)] {
        &self.loop_index[self.loop_offsets[i] as usize..self.loop_offsets[i + 1] as usize]
    }
}

/// Every node's sorted vertex list and the part of it *exposed* (held by
/// a triangle outside the node too: the only vertices another node can
/// share with it, whatever the topology), for nodes up to [`SEPARABLE`]
/// triangles, bottom-up: a parent's counts are its children's summed.
fn node_vertices(nodes: &[Node], triangles: &[[u32; 3]], vertex_count: usize) -> [(Vec<u32>, Vec<u32>); 2] {
    let mut total = vec![0u32; vertex_count];
    for &v in triangles.iter().flatten() {
        total[v as usize] += 1;
    }
    // Per node: (vertex, triangles of the node holding it), sorted by vertex.
    let mut counts: Vec<Vec<(u32, u32)>> = vec![Vec::new(); nodes.len()];
    for i in (0..nodes.len()).rev() {
        let node = nodes[i];
        if node.count > SEPARABLE {
            continue;
        }
        let mut list: Vec<(u32, u32)> = if node.is_leaf() {
            triangles[node.range()].iter().flatten().map(|&v| (v, 1)).collect()
        } else {
            let (l, r) = (node.left as usize, node.left as usize + 1);
            counts[l].iter().chain(&counts[r]).copied().collect()
        };
        list.sort_unstable();
        let mut merged: Vec<(u32, u32)> = Vec::with_capacity(list.len());
        for (v, k) in list {
            match merged.last_mut() {
                Some(last) if last.0 == v => last.1 += k,
                _ => merged.push((v, k)),
            }
        }
        counts[i] = merged;
    }
    let mut all = (vec![0u32], Vec::new());
    let mut exposed = (vec![0u32], Vec::new());
    for list in counts {
        all.1.extend(list.iter().map(|&(v, _)| v));
        all.0.push(all.1.len() as u32);
        exposed.1.extend(list.iter().filter(|&&(v, k)| k < total[v as usize]).map(|&(v, _)| v));
        exposed.0.push(exposed.1.len() as u32);
    }
    [all, exposed]
}

/// Per vertex (offsets, then tree positions ascending), the triangles with
/// it as a corner: its corners grouped by vertex, each corner `3p + k`
/// standing for position `p`.
fn positions_at_vertices(triangles: &[[u32; 3]], vertex_count: usize) -> (Vec<u32>, Vec<u32>) {
    let corners: Vec<u32> = triangles.iter().flatten().copied().collect();
    let (offsets, mut positions) = crate::mesh::group_members(&corners, vertex_count);
    positions.iter_mut().for_each(|corner| *corner /= 3);
    (offsets, positions)
}

/// The loop [`join_of`] joins, as a list.
#[cfg(test)]
pub(super) fn joined(a: &[u32], b: &[u32], b_at: &[(u32, u32)]) -> Option<Vec<u32>> {
    let join = join_of(a, b, b_at)?;
    let ring = JoinedLoop { a, b, join };
    Some((0..ring.len()).map(|j| ring.vertex(j)).collect())
}

/// Where the boundary loops `a` and `b` of two disks (vertex cycles in the
/// triangles' winding) join along the boundary they share, if that is one
/// run of edges and they touch nowhere else: then their union is a disk,
/// its loop [`JoinedLoop`]. `b_at` is `b`'s loop index
/// ([`PatchTree::boundary_index`]).
fn join_of(a: &[u32], b: &[u32], b_at: &[(u32, u32)]) -> Option<Join> {
    let (na, nb) = (a.len(), b.len());
    if na < 3 || nb < 3 {
        return None;
    }
    // Where a vertex sits on b's loop; a shared edge x → y of a is y → x on b.
    let on_b = |v: u32| b_at.binary_search_by_key(&v, |&(w, _)| w).ok().map(|k| b_at[k].1 as usize);
    let shared = |i: usize| {
        let (x, y) = (a[i], a[(i + 1) % na]);
        on_b(y).is_some_and(|j| b[(j + 1) % nb] == x)
    };
    // The shared edges' count and the run's first edge (shared, its
    // predecessor not; exactly one such), in one pass without a list of
    // flags: a traversal asks this of every pair of adjacent disks it meets
    // (issue 30, twenty-third round).
    let (mut count, mut starts, mut first) = (0, 0, 0);
    let closing = shared(na - 1);
    let mut previous = closing;
    for i in 0..na {
        let here = if i == na - 1 { closing } else { shared(i) };
        count += here as usize;
        if here && !previous {
            starts += 1;
            first = i;
        }
        previous = here;
    }
    if count == 0 || count == na || starts != 1 {
        return None;
    }
    let last = (first + count) % na; // the vertex where the run ends
    // Touching anywhere else (a vertex of a off the run on b's loop) makes a pinch.
    if (1..na - count).any(|k| on_b(a[(last + k) % na]).is_some()) {
        return None;
    }
    // a from the run's end round to its start, then b from there back to the run's end.
    let start_b = on_b(a[first]).expect("a shared edge's end is on b");
    Some(Join { last: last as u32, count: count as u32, start_b: start_b as u32 })
}

/// Moves the items for which `first` holds to the front, returning how many.
fn partition<T>(items: &mut [T], first: impl Fn(&T) -> bool) -> usize {
    let mut k = 0;
    for i in 0..items.len() {
        if first(&items[i]) {
            items.swap(i, k);
            k += 1;
        }
    }
    k
}

/// A boundary loop's vertices with their places on it, sorted by vertex.
pub(super) fn loop_index(ring: &[u32]) -> Vec<(u32, u32)> {
    let mut at: Vec<(u32, u32)> = ring.iter().enumerate().map(|(k, &v)| (v, k as u32)).collect();
    at.sort_unstable();
    at
}

fn leaf_shape(triangles: &[[u32; 3]]) -> Shape {
    let half_edges: Vec<[u32; 2]> = triangles.iter().flat_map(|&[a, b, c]| [[a, b], [b, c], [c, a]]).collect();
    let (boundary, _, tainted) = cancel(half_edges);
    let mut vertices: Vec<u32> = triangles.iter().flatten().copied().collect();
    vertices.sort_unstable();
    vertices.dedup();
    let faces = triangles.len() as i64;
    Shape { edges: (3 * faces + boundary.len() as i64) / 2, vertices: vertices.len() as i64, faces, tainted, boundary }
}

fn merge(l: Shape, r: Shape) -> Shape {
    let tainted = l.tainted || r.tainted;
    let common = {
        let ends = |s: &Shape| {
            let mut v: Vec<u32> = s.boundary.iter().flatten().copied().collect();
            v.sort_unstable();
            v.dedup();
            v
        };
        let (a, b) = (ends(&l), ends(&r));
        a.iter().filter(|v| b.binary_search(v).is_ok()).count() as i64
    };
    let mut half_edges = l.boundary;
    half_edges.extend_from_slice(&r.boundary);
    let (boundary, shared, cancelled_badly) = cancel(half_edges);
    let too_big = boundary.len() > MAX_LOOP;
    Shape {
        boundary: if too_big { Vec::new() } else { boundary },
        vertices: l.vertices + r.vertices - common,
        edges: l.edges + r.edges - shared as i64,
        faces: l.faces + r.faces,
        tainted: tainted || cancelled_badly || too_big,
    }
}

/// Cancels pairs of opposite half-edges: returns the rest (the boundary),
/// the number of pairs cancelled, and whether some edge was used twice in
/// the same direction or more than twice (not a consistently oriented
/// manifold there).
fn cancel(mut half_edges: Vec<[u32; 2]>) -> (Vec<[u32; 2]>, usize, bool) {
    half_edges.sort_unstable_by_key(|&[a, b]| (a.min(b), a.max(b), a));
    let mut boundary = Vec::new();
    let (mut pairs, mut bad) = (0, false);
    let mut i = 0;
    while i < half_edges.len() {
        let key = |e: [u32; 2]| (e[0].min(e[1]), e[0].max(e[1]));
        let mut j = i + 1;
        while j < half_edges.len() && key(half_edges[j]) == key(half_edges[i]) {
            j += 1;
        }
        match j - i {
            1 => boundary.push(half_edges[i]),
            2 if half_edges[i][0] == half_edges[i + 1][1] => pairs += 1,
            _ => bad = true,
        }
        i = j;
    }
    (boundary, pairs, bad)
}

/// The boundary's vertices in order if its half-edges form one simple cycle.
fn single_cycle(boundary: &[[u32; 2]]) -> Option<Vec<u32>> {
    if boundary.len() < 3 {
        return None;
    }
    let mut by_start = boundary.to_vec();
    by_start.sort_unstable();
    if by_start.windows(2).any(|w| w[0][0] == w[1][0]) {
        return None; // a vertex where the boundary touches itself
    }
    let next = |v: u32| by_start.binary_search_by_key(&v, |e| e[0]).ok().map(|k| by_start[k][1]);
    let start = by_start[0][0];
    let mut cycle = vec![start];
    let mut at = next(start)?;
    while at != start {
        if cycle.len() >= boundary.len() {
            return None;
        }
        cycle.push(at);
        at = next(at)?;
    }
    (cycle.len() == boundary.len()).then_some(cycle)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::shapes::{grid, quad_sphere};
    use crate::mesh::{fan_triangles, MeshInput};

    fn triangles(mesh: MeshInput<'_>) -> Vec<[u32; 3]> {
        fan_triangles(mesh.corner_verts, &mesh.validate().unwrap())
    }

    #[test]
    fn a_grid_is_a_disk_at_every_node_and_leaves_cover_each_triangle_once() {
        let g = grid(12, 12, 1.0);
        let tris = triangles(g.input());
        let tree = PatchTree::build(&tris, &g.positions);
        assert!(tree.disk[0], "the whole grid is a disk");
        let mut seen = vec![0; tris.len()];
        for &leaf in &tree.leaves {
            let node = tree.nodes[leaf as usize];
            assert!(node.count as usize <= LEAF && node.count > 0);
            for p in node.range() {
                seen[tree.order[p] as usize] += 1;
                assert_eq!(tree.triangles[p], tris[tree.order[p] as usize]);
            }
        }
        assert!(seen.iter().all(|&k| k == 1));
        assert_eq!(tree.boundary(0).len(), 4 * 12);
    }

    #[test]
    fn a_grid_of_quads_split_both_ways_is_still_a_disk_and_no_quad_parts() {
        let g = grid(12, 12, 1.0);
        let offsets = g.input().validate().unwrap();
        let (tris, _) = crate::mesh::either_split_triangles(g.corner_verts.as_slice(), &offsets);
        let units: Vec<u32> = (0..=tris.len() as u32 / 4).map(|u| 4 * u).collect();
        let surface: Vec<bool> = (0..tris.len()).map(|t| t % 4 < 2).collect();
        let triangles: Vec<[u32; 3]> = tris.iter().map(|(t, _)| *t).collect();
        let tree = PatchTree::build_in_units(&triangles, &units, &surface, &g.positions);
        assert!(tree.disk[0], "the whole grid is a disk under one split, so under both");
        assert_eq!(tree.boundary(0).len(), 4 * 12);
        for &leaf in &tree.leaves {
            let node = tree.nodes[leaf as usize];
            assert_eq!((node.first % 4, node.count % 4), (0, 0), "a quad's four triangles share a leaf");
        }
    }

    /// Every pair of nodes a traversal can reach (siblings, then the larger
    /// split, as [`super::super::gather`] does), without any culling.
    fn every_traversal_pair(tree: &PatchTree) -> Vec<(usize, usize)> {
        let mut pairs = Vec::new();
        let mut stack: Vec<(usize, usize)> = tree.nodes.iter().filter(|n| !n.is_leaf()).map(|n| (n.left as usize, n.left as usize + 1)).collect();
        while let Some((a, b)) = stack.pop() {
            pairs.push((a, b));
            let (na, nb) = (tree.nodes[a], tree.nodes[b]);
            match (na.is_leaf(), nb.is_leaf()) {
                (true, true) => {}
                (false, leaf_b) if leaf_b || na.count >= nb.count => stack.extend([(na.left as usize, b), (na.left as usize + 1, b)]),
                _ => stack.extend([(a, nb.left as usize), (a, nb.left as usize + 1)]),
            }
        }
        pairs
    }

    #[test]
    fn the_joins_kept_from_the_bind_are_those_worked_out_for_every_pair_a_traversal_reaches() {
        let g = grid(12, 12, 1.0);
        let s = quad_sphere(6, 1.0);
        for mesh in [g.input(), s.input()] {
            let tree = PatchTree::build(&triangles(mesh), mesh.positions);
            let (mut joins, mut checked) = (0, 0);
            for (a, b) in every_traversal_pair(&tree) {
                let kept = tree.joined(a, b).map(|ring| (0..ring.len()).map(|j| ring.vertex(j)).collect::<Vec<u32>>());
                let afresh = if tree.disk[a] && tree.disk[b] { joined(tree.boundary(a), tree.boundary(b), tree.boundary_index(b)) } else { None };
                assert_eq!(kept, afresh, "nodes {a} and {b}");
                joins += afresh.is_some() as usize;
                checked += 1;
            }
            assert!(joins > 10 && checked > 10 * joins, "{joins} joins of {checked} pairs: the test must see both kinds");
        }
    }

    #[test]
    fn the_part_around_a_few_vertices_is_what_a_pass_over_every_triangle_and_node_finds() {
        let s = quad_sphere(6, 1.0);
        let tree = PatchTree::build(&triangles(s.input()), &s.positions);
        let n = s.positions.len();
        for picked in [vec![], vec![0], vec![3, 4, n / 2], (0..n).filter(|v| v % 5 == 1).collect()] {
            let mut flags = vec![false; n];
            for &v in &picked {
                flags[v] = true;
            }
            let around = tree.around(&flags);
            // Every triangle, then every node from its children, as a pass over the tree finds them.
            let triangles: Vec<bool> = tree.triangles.iter().map(|t| t.iter().any(|&v| flags[v as usize])).collect();
            let mut holds = vec![false; tree.nodes.len()];
            for i in (0..tree.nodes.len()).rev() {
                let node = tree.nodes[i];
                holds[i] = if node.is_leaf() { node.range().any(|p| triangles[p]) } else { holds[node.left as usize] || holds[node.left as usize + 1] };
            }
            let listed: Vec<u32> = (0..tree.nodes.len() as u32).rev().filter(|&i| holds[i as usize]).collect();
            assert_eq!(around.triangles, triangles, "around {picked:?}");
            assert_eq!(around.holds, holds, "around {picked:?}");
            assert_eq!(around.nodes, listed, "around {picked:?}: each node once, children first");
            assert_eq!(picked.is_empty(), listed.is_empty());
        }
    }

    #[test]
    fn a_closed_sphere_is_not_a_disk_but_its_small_patches_are() {
        let s = quad_sphere(6, 1.0);
        let tris = triangles(s.input());
        let tree = PatchTree::build(&tris, &s.positions);
        assert!(!tree.disk[0], "a closed surface has no boundary loop");
        let disks = tree.leaves.iter().filter(|&&l| tree.disk[l as usize]).count();
        assert!(disks * 4 >= tree.leaves.len() * 3, "{disks} of {} leaves are disks", tree.leaves.len());
    }
}
