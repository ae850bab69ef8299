//! Edges, ordered one-rings and the mesh's defects, derived once per bind.

use glam::Vec3;
use rayon::prelude::*;

use super::validate::MeshInput;
use crate::Result;

/// Relative size below which a polygon counts as having no area: its vector
/// area is compared with the square of the mesh's bounding-box diagonal.
const ZERO_AREA_RELATIVE: f32 = 1e-12;

/// Per-vertex facts, packed as bits.
mod flag {
    pub const BOUNDARY: u8 = 1;
    pub const NON_MANIFOLD: u8 = 2;
    pub const ISOLATED: u8 = 4;
}

/// What is unusual about a mesh: the lists behind `check_mesh` and the
/// deformers' rules for vertices they cannot encode.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TopologyReport {
    pub vertex_count: usize,
    pub edge_count: usize,
    pub polygon_count: usize,
    /// Edges used by exactly one polygon.
    pub boundary_edges: Vec<[u32; 2]>,
    /// Vertices on a boundary edge.
    pub boundary_vertices: Vec<u32>,
    /// Edges used by more than two polygons.
    pub non_manifold_edges: Vec<[u32; 2]>,
    /// Edges used by two polygons that walk it in the same direction: one of
    /// the two is flipped.
    pub flipped_edges: Vec<[u32; 2]>,
    /// Vertices whose polygons do not form a single fan (bow-ties, or the
    /// ends of non-manifold or flipped edges).
    pub non_manifold_vertices: Vec<u32>,
    /// Polygons with a repeated vertex or (next to) no area.
    pub degenerate_polygons: Vec<u32>,
    /// Vertices no polygon uses.
    pub isolated_vertices: Vec<u32>,
}

impl TopologyReport {
    /// True for a closed, consistently oriented 2-manifold without defects.
    pub fn is_closed_manifold(&self) -> bool {
        self.boundary_edges.is_empty() && self.is_clean()
    }

    /// True when nothing but boundaries is reported.
    pub fn is_clean(&self) -> bool {
        self.non_manifold_edges.is_empty()
            && self.flipped_edges.is_empty()
            && self.non_manifold_vertices.is_empty()
            && self.degenerate_polygons.is_empty()
            && self.isolated_vertices.is_empty()
    }
}

/// The connectivity of a validated mesh.
///
/// One-rings are stored in compressed rows: the neighbours of vertex `v` are
/// `ring_verts[ring_offsets[v]..ring_offsets[v + 1]]`, ordered counter-clockwise
/// around the polygons' normal. An open ring (boundary vertex) starts and ends
/// at the boundary neighbours; a closed ring does not repeat its first vertex.
#[derive(Debug, Clone)]
pub struct Topology {
    vertex_count: usize,
    polygon_offsets: Vec<u32>,
    corner_verts: Vec<u32>,
    edges: Vec<[u32; 2]>,
    ring_offsets: Vec<u32>,
    ring_verts: Vec<u32>,
    vertex_flags: Vec<u8>,
    report: TopologyReport,
}

/// One polygon corner seen from its vertex: the polygon spans, counter-clockwise
/// around the vertex, from `next` to `prev`.
#[derive(Debug, Clone, Copy)]
struct Wedge {
    next: u32,
    prev: u32,
}

impl Topology {
    /// Validates the arrays and derives the topology.
    pub fn build(input: MeshInput<'_>) -> Result<Self> {
        let polygon_offsets = input.validate()?;
        let vertex_count = input.positions.len();
        let corner_verts: Vec<u32> = input.corner_verts.iter().map(|&v| v as u32).collect();
        let polygon_count = polygon_offsets.len() - 1;
        let polygon = |p: usize| &corner_verts[polygon_offsets[p] as usize..polygon_offsets[p + 1] as usize];

        let diagonal_sq = bounding_box_diagonal(input.positions).powi(2);
        let (has_repeat, degenerate): (Vec<bool>, Vec<bool>) = (0..polygon_count)
            .into_par_iter()
            .map(|p| {
                let corners = polygon(p);
                let repeat = has_repeated_vertex(corners);
                let area = vector_area(input.positions, corners).length();
                (repeat, repeat || area <= ZERO_AREA_RELATIVE * diagonal_sq)
            })
            .unzip();
        let degenerate_polygons: Vec<u32> = (0..polygon_count as u32).filter(|&p| degenerate[p as usize]).collect();

        // Polygons with a repeated vertex have no well-defined corners; they are
        // reported and left out of edges and rings. Polygons that merely have no
        // area are still connected and stay in.
        let usable = |p: usize| !has_repeat[p];

        // Half-edges keyed by their undirected edge, sorted so that the
        // polygons sharing an edge sit next to each other.
        let mut half_edges: Vec<(u64, bool)> = Vec::with_capacity(corner_verts.len());
        for p in (0..polygon_count).filter(|&p| usable(p)) {
            let corners = polygon(p);
            for (i, &a) in corners.iter().enumerate() {
                let b = corners[(i + 1) % corners.len()];
                let (lo, hi, forward) = if a < b { (a, b, true) } else { (b, a, false) };
                half_edges.push(((lo as u64) << 32 | hi as u64, forward));
            }
        }
        half_edges.par_sort_unstable();

        let mut edges = Vec::with_capacity(half_edges.len() / 2 + 1);
        let mut boundary_edges = Vec::new();
        let mut non_manifold_edges = Vec::new();
        let mut flipped_edges = Vec::new();
        for group in half_edges.chunk_by(|a, b| a.0 == b.0) {
            let edge = [(group[0].0 >> 32) as u32, group[0].0 as u32];
            edges.push(edge);
            match group {
                [_] => boundary_edges.push(edge),
                [a, b] if a.1 == b.1 => flipped_edges.push(edge),
                [_, _] => {}
                _ => non_manifold_edges.push(edge),
            }
        }

        // Wedges grouped by vertex (counting sort), then chained into fans.
        let mut wedge_offsets = vec![0u32; vertex_count + 1];
        for p in (0..polygon_count).filter(|&p| usable(p)) {
            for &v in polygon(p) {
                wedge_offsets[v as usize + 1] += 1;
            }
        }
        for v in 0..vertex_count {
            wedge_offsets[v + 1] += wedge_offsets[v];
        }
        let mut fill = wedge_offsets.clone();
        let mut wedges = vec![Wedge { next: 0, prev: 0 }; corner_verts.len()];
        for p in (0..polygon_count).filter(|&p| usable(p)) {
            let corners = polygon(p);
            let k = corners.len();
            for i in 0..k {
                let v = corners[i] as usize;
                wedges[fill[v] as usize] = Wedge { next: corners[(i + 1) % k], prev: corners[(i + k - 1) % k] };
                fill[v] += 1;
            }
        }

        let rings: Vec<(Vec<u32>, u8)> = (0..vertex_count)
            .into_par_iter()
            .map(|v| order_fan(&wedges[wedge_offsets[v] as usize..wedge_offsets[v + 1] as usize]))
            .collect();
        let mut ring_offsets = Vec::with_capacity(vertex_count + 1);
        let mut ring_verts = Vec::with_capacity(corner_verts.len());
        let mut vertex_flags = Vec::with_capacity(vertex_count);
        ring_offsets.push(0);
        for (ring, flags) in rings {
            ring_verts.extend_from_slice(&ring);
            ring_offsets.push(ring_verts.len() as u32);
            vertex_flags.push(flags);
        }
        // An edge shared by three polygons leaves every fan around its ends
        // ambiguous, even where the local walk happened to succeed.
        for edge in non_manifold_edges.iter().chain(&flipped_edges) {
            for &v in edge {
                vertex_flags[v as usize] |= flag::NON_MANIFOLD;
            }
        }

        let with_flag = |bit: u8| -> Vec<u32> {
            (0..vertex_count as u32).filter(|&v| vertex_flags[v as usize] & bit != 0).collect()
        };
        let report = TopologyReport {
            vertex_count,
            edge_count: edges.len(),
            polygon_count,
            boundary_vertices: with_flag(flag::BOUNDARY),
            non_manifold_vertices: with_flag(flag::NON_MANIFOLD),
            isolated_vertices: with_flag(flag::ISOLATED),
            boundary_edges,
            non_manifold_edges,
            flipped_edges,
            degenerate_polygons,
        };
        Ok(Topology { vertex_count, polygon_offsets, corner_verts, edges, ring_offsets, ring_verts, vertex_flags, report })
    }

    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }

    pub fn polygon_count(&self) -> usize {
        self.polygon_offsets.len() - 1
    }

    /// The vertex indices of polygon `p`, in winding order.
    pub fn polygon(&self, p: usize) -> &[u32] {
        &self.corner_verts[self.polygon_offsets[p] as usize..self.polygon_offsets[p + 1] as usize]
    }

    /// Offsets of each polygon's first corner, with the corner count appended.
    pub fn polygon_offsets(&self) -> &[u32] {
        &self.polygon_offsets
    }

    /// Every polygon's corners, polygon after polygon.
    pub fn corner_verts(&self) -> &[u32] {
        &self.corner_verts
    }

    /// Unique undirected edges, `[low, high]`, sorted.
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }

    /// The neighbours of `v`, counter-clockwise around the surface normal.
    pub fn one_ring(&self, v: usize) -> &[u32] {
        &self.ring_verts[self.ring_offsets[v] as usize..self.ring_offsets[v + 1] as usize]
    }

    /// Row offsets of the one-rings (`vertex_count + 1` entries).
    pub fn ring_offsets(&self) -> &[u32] {
        &self.ring_offsets
    }

    /// All one-rings, concatenated in vertex order.
    pub fn ring_verts(&self) -> &[u32] {
        &self.ring_verts
    }

    /// True when `v` sits on a boundary: its one-ring is open.
    pub fn is_boundary(&self, v: usize) -> bool {
        self.vertex_flags[v] & flag::BOUNDARY != 0
    }

    /// True when the polygons around `v` do not form one consistent fan; its
    /// one-ring is then the concatenation of its fans and has no geometric meaning.
    pub fn is_non_manifold(&self, v: usize) -> bool {
        self.vertex_flags[v] & flag::NON_MANIFOLD != 0
    }

    pub fn is_isolated(&self, v: usize) -> bool {
        self.vertex_flags[v] & flag::ISOLATED != 0
    }

    pub fn report(&self) -> &TopologyReport {
        &self.report
    }

    /// Vertices an artist should look at: ends of non-manifold and flipped
    /// edges, bow-ties, corners of degenerate polygons and isolated vertices.
    pub fn problem_vertices(&self) -> Vec<u32> {
        let mut marked = vec![false; self.vertex_count];
        for &p in &self.report.degenerate_polygons {
            for &v in self.polygon(p as usize) {
                marked[v as usize] = true;
            }
        }
        for v in self.report.non_manifold_vertices.iter().chain(&self.report.isolated_vertices) {
            marked[*v as usize] = true;
        }
        (0..self.vertex_count as u32).filter(|&v| marked[v as usize]).collect()
    }
}

/// Chains the wedges around one vertex into its ordered ring.
///
/// Each wedge's `prev` is the next wedge's `next`. A manifold vertex has one
/// chain: closed (interior) or open with one start (boundary). Anything else
/// is flagged non-manifold and its fans are concatenated.
fn order_fan(wedges: &[Wedge]) -> (Vec<u32>, u8) {
    if wedges.is_empty() {
        return (Vec::new(), flag::ISOLATED);
    }
    let k = wedges.len();
    let mut flags = 0u8;
    // A neighbour reached twice as `next` (or twice as `prev`) means an edge
    // with more than two polygons or with a flipped polygon around this vertex.
    for i in 0..k {
        for j in i + 1..k {
            if wedges[i].next == wedges[j].next || wedges[i].prev == wedges[j].prev {
                flags |= flag::NON_MANIFOLD;
            }
        }
    }
    let successor = |w: usize| (0..k).find(|&u| u != w && wedges[u].next == wedges[w].prev);
    let has_predecessor = |w: usize| (0..k).any(|u| u != w && wedges[u].prev == wedges[w].next);

    let mut used = vec![false; k];
    let mut ring = Vec::with_capacity(k + 1);
    let mut fans = 0;
    let mut open_fans = 0;
    // Open fans first (they have a definite start), then closed cycles.
    let starts: Vec<usize> = (0..k).filter(|&w| !has_predecessor(w)).chain(0..k).collect();
    for start in starts {
        if used[start] {
            continue;
        }
        fans += 1;
        let mut w = start;
        ring.push(wedges[w].next);
        loop {
            used[w] = true;
            match successor(w) {
                Some(u) if !used[u] => {
                    ring.push(wedges[u].next);
                    w = u;
                }
                Some(_) => break, // closed the cycle
                None => {
                    open_fans += 1;
                    ring.push(wedges[w].prev);
                    break;
                }
            }
        }
    }
    if open_fans > 0 {
        flags |= flag::BOUNDARY;
    }
    if fans > 1 {
        flags |= flag::NON_MANIFOLD;
    }
    (ring, flags)
}

fn has_repeated_vertex(corners: &[u32]) -> bool {
    (0..corners.len()).any(|i| corners[i + 1..].contains(&corners[i]))
}

/// Twice the area vector of a (possibly non-planar) polygon: Newell's sum.
pub(crate) fn vector_area(positions: &[Vec3], corners: &[u32]) -> Vec3 {
    let mut sum = Vec3::ZERO;
    for (i, &a) in corners.iter().enumerate() {
        let b = corners[(i + 1) % corners.len()];
        sum += positions[a as usize].cross(positions[b as usize]);
    }
    sum * 0.5
}

fn bounding_box_diagonal(positions: &[Vec3]) -> f32 {
    if positions.is_empty() {
        return 0.0;
    }
    let (lo, hi) = positions
        .iter()
        .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), &p| (lo.min(p), hi.max(p)));
    (hi - lo).length()
}

