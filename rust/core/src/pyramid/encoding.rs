//! What the bind stores: the pyramid coordinates of a mesh ([`Encoding`]) and
//! why a vertex has none ([`PinReason`]). Built by [`super::encode`], read by
//! the projection ([`super::project`]), the kernels and the constraints.

/// Why a vertex is not encoded. Pinned vertices get no pyramid constraint and
/// follow their input (closeness 1); neighbours still see them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PinReason {
    /// On an open border, with a one-ring too small or too narrow to close
    /// (fewer than 3 neighbours, or all of them nearly on one line).
    Boundary,
    /// Its polygons do not form one fan (non-manifold edge, bow-tie, flipped face).
    NonManifold,
    /// No polygon uses it.
    Isolated,
    /// Fewer than 3 neighbours.
    LowValence,
    /// More than [`super::encode::MAX_VALENCE`] neighbours.
    HighValence,
    /// The ring polygon has (next to) no area, so no normal.
    ZeroArea,
    /// The projected vertex is not strictly inside the kernel of its projected
    /// ring, or (nearly) coincides with a neighbour (see
    /// [`super::encode::MIN_RELATIVE_NEIGHBOUR_DISTANCE`]): mean-value weights
    /// are unreliable.
    NotStarShaped,
    /// The ring is folded at rest (a sharp crease or step): some edge rises
    /// steeper than [`super::encode::MAX_REST_ELEVATION`] over the ring's
    /// plane, where pyramid coordinates are ill-conditioned.
    Folded,
    /// The encoding does not reproduce the rest position in f32 (safety net,
    /// like StretchMesh's bind-time self-test).
    Inexact,
}

impl PinReason {
    /// Every reason, in declaration order.
    pub const ALL: [PinReason; 9] = [
        PinReason::Boundary,
        PinReason::NonManifold,
        PinReason::Isolated,
        PinReason::LowValence,
        PinReason::HighValence,
        PinReason::ZeroArea,
        PinReason::NotStarShaped,
        PinReason::Folded,
        PinReason::Inexact,
    ];

    /// A stable identifier (snake case) for scripts and reports; [`Self::describe`] is the prose.
    pub fn name(self) -> &'static str {
        match self {
            PinReason::Boundary => "boundary",
            PinReason::NonManifold => "non_manifold",
            PinReason::Isolated => "isolated",
            PinReason::LowValence => "low_valence",
            PinReason::HighValence => "high_valence",
            PinReason::ZeroArea => "zero_area",
            PinReason::NotStarShaped => "not_star_shaped",
            PinReason::Folded => "folded",
            PinReason::Inexact => "inexact",
        }
    }

    pub fn describe(self) -> &'static str {
        match self {
            PinReason::Boundary => "boundary corner without a usable one-ring",
            PinReason::NonManifold => "non-manifold",
            PinReason::Isolated => "isolated",
            PinReason::LowValence => "fewer than 3 neighbours",
            PinReason::HighValence => "too many neighbours",
            PinReason::ZeroArea => "one-ring without area",
            PinReason::NotStarShaped => "one-ring not star-shaped around the vertex",
            PinReason::Folded => "one-ring folded at rest (sharp crease or step)",
            PinReason::Inexact => "encoding not reproducible in single precision",
        }
    }
}

/// The pyramid coordinates of a mesh.
#[derive(Debug, Clone)]
pub struct Encoding {
    vertex_count: usize,
    scale_safe: bool,
    /// Encoded vertices, ascending.
    vertices: Vec<u32>,
    /// Per encoded vertex: its neighbours at `ring_offsets[e]..ring_offsets[e+1]`.
    ring_offsets: Vec<u32>,
    ring: Vec<u32>,
    /// Mean-value weight of each neighbour (sum 1 per vertex).
    weights: Vec<f32>,
    /// Scale-safe: elevation tangent of each edge `v − v_j` over the plane.
    tangents: Vec<f32>,
    /// Plain: signed height of the vertex over its ring's plane.
    heights: Vec<f32>,
    pinned: Vec<(u32, PinReason)>,
    mean_edge_length: f32,
}

impl Encoding {
    /// No vertex encoded or pinned yet.
    pub(super) fn empty(vertex_count: usize, scale_safe: bool, mean_edge_length: f32) -> Self {
        Encoding {
            vertex_count,
            scale_safe,
            vertices: Vec::new(),
            ring_offsets: vec![0],
            ring: Vec::new(),
            weights: Vec::new(),
            tangents: Vec::new(),
            heights: Vec::new(),
            pinned: Vec::new(),
            mean_edge_length,
        }
    }

    /// Appends encoded vertex `v` (vertices come ascending).
    pub(super) fn push(&mut self, v: u32, ring: &[u32], weights: &[f32], tangents: &[f32], height: f32) {
        self.vertices.push(v);
        self.ring.extend_from_slice(ring);
        self.ring_offsets.push(self.ring.len() as u32);
        self.weights.extend_from_slice(weights);
        self.tangents.extend_from_slice(tangents);
        self.heights.push(height);
    }

    /// Records that `v` could not be encoded, and why.
    pub(super) fn pin(&mut self, v: u32, reason: PinReason) {
        self.pinned.push((v, reason));
    }

    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }

    pub fn scale_safe(&self) -> bool {
        self.scale_safe
    }

    /// Encoded vertices, ascending.
    pub fn vertices(&self) -> &[u32] {
        &self.vertices
    }

    /// Number of encoded vertices.
    pub fn len(&self) -> usize {
        self.vertices.len()
    }

    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }

    /// Neighbours of encoded vertex `e`, counter-clockwise.
    #[inline]
    pub fn ring(&self, e: usize) -> &[u32] {
        &self.ring[self.ring_range(e)]
    }

    /// Mean-value weights of encoded vertex `e`, in ring order.
    #[inline]
    pub fn weights(&self, e: usize) -> &[f32] {
        &self.weights[self.ring_range(e)]
    }

    /// Scale-safe elevation tangents of encoded vertex `e` (empty in plain mode).
    #[inline]
    pub fn tangents(&self, e: usize) -> &[f32] {
        if self.scale_safe {
            &self.tangents[self.ring_range(e)]
        } else {
            &[]
        }
    }

    /// Plain height of encoded vertex `e` over its ring's plane.
    #[inline]
    pub fn height(&self, e: usize) -> f32 {
        self.heights[e]
    }

    #[inline]
    fn ring_range(&self, e: usize) -> std::ops::Range<usize> {
        self.ring_offsets[e] as usize..self.ring_offsets[e + 1] as usize
    }

    /// Pinned vertices with the reason, ascending.
    pub fn pinned(&self) -> &[(u32, PinReason)] {
        &self.pinned
    }

    /// Pinned vertex indices, ascending.
    pub fn pinned_vertices(&self) -> Vec<u32> {
        self.pinned.iter().map(|p| p.0).collect()
    }

    /// Mean rest edge length: the unit of [`crate::pyramid::PyramidDeformer::residual`].
    pub fn mean_edge_length(&self) -> f32 {
        self.mean_edge_length
    }

    /// Total stored neighbour entries (for bandwidth estimates).
    pub fn ring_entries(&self) -> usize {
        self.ring.len()
    }

    /// A copy with the listed vertices moved to the pinned list as `Inexact`.
    pub(super) fn without(&self, drop: &[u32]) -> Encoding {
        let mut out = Encoding {
            pinned: self.pinned.clone(),
            ..Encoding::empty(self.vertex_count, self.scale_safe, self.mean_edge_length)
        };
        for e in 0..self.vertices.len() {
            let v = self.vertices[e];
            if drop.binary_search(&v).is_ok() {
                out.pinned.push((v, PinReason::Inexact));
                continue;
            }
            out.vertices.push(v);
            out.ring.extend_from_slice(self.ring(e));
            out.ring_offsets.push(out.ring.len() as u32);
            out.weights.extend_from_slice(self.weights(e));
            out.tangents.extend_from_slice(self.tangents(e));
            out.heights.push(self.heights[e]);
        }
        out.pinned.sort_unstable_by_key(|p| p.0);
        out
    }
}
