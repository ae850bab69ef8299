//! The skin as the collision passes see it: vertices, the edges tested
//! against collider edges, the triangles tested against collider vertices,
//! and which of them touch each vertex.

use crate::mesh::{fan_triangles, triangle_edges, vertex_incidence, MeshInput};
use crate::{Error, Result};

/// The skin's connectivity as the collision passes need it. Build it once
/// (per bind) and pass it to every [`ColliderSet::resolve_path`] call.
#[derive(Debug, Clone, Default)]
pub struct Skin {
    vertex_count: usize,
    edges: Vec<[u32; 2]>,
    triangles: Vec<[u32; 3]>,
    vertex_edges: (Vec<u32>, Vec<u32>),
    vertex_triangles: (Vec<u32>, Vec<u32>),
    /// Inverse mass per vertex (all 1 when `None`): 0 marks a vertex whose
    /// motion is imposed, which contacts never move (the kinematic part of a
    /// compliant collider when the collider is the moving mesh).
    inverse_mass: Option<Vec<f32>>,
}

impl Skin {
    /// A skin of `vertex_count` vertices with the given edges (tested against
    /// collider edges) and triangles (tested against collider vertices).
    pub fn new(vertex_count: usize, edges: Vec<[u32; 2]>, triangles: Vec<[u32; 3]>) -> Result<Self> {
        if let Some((i, e)) = edges.iter().enumerate().find(|(_, e)| e.iter().any(|&v| v as usize >= vertex_count)) {
            return Err(Error::invalid(format!(
                "edge {i} refers to vertex {}, but the skin has {vertex_count} vertices",
                e[0].max(e[1])
            )));
        }
        if let Some((i, t)) = triangles.iter().enumerate().find(|(_, t)| t.iter().any(|&v| v as usize >= vertex_count)) {
            return Err(Error::invalid(format!(
                "triangle {i} refers to vertex {}, but the skin has {vertex_count} vertices",
                t.iter().max().copied().unwrap_or(0)
            )));
        }
        let vertex_edges = vertex_incidence(vertex_count, edges.iter().map(|e| &e[..]));
        let vertex_triangles = vertex_incidence(vertex_count, triangles.iter().map(|t| &t[..]));
        Ok(Skin { vertex_count, edges, triangles, vertex_edges, vertex_triangles, inverse_mass: None })
    }

    /// The same skin with one inverse mass per vertex (finite, ≥ 0).
    pub fn with_inverse_mass(mut self, inverse_mass: Vec<f32>) -> Result<Self> {
        if inverse_mass.len() != self.vertex_count {
            return Err(Error::invalid(format!(
                "{} inverse masses given for {} vertices",
                inverse_mass.len(),
                self.vertex_count
            )));
        }
        if let Some(v) = inverse_mass.iter().position(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::invalid(format!("inverse mass of vertex {v} is {}; it must be finite and ≥ 0", inverse_mass[v])));
        }
        self.inverse_mass = Some(inverse_mass);
        Ok(self)
    }

    /// Whether some vertices have an inverse mass other than 1.
    pub(super) fn has_inverse_mass(&self) -> bool {
        self.inverse_mass.is_some()
    }

    pub(super) fn inverse_mass(&self, v: u32) -> f64 {
        self.inverse_mass.as_ref().map_or(1.0, |w| w[v as usize] as f64)
    }

    /// Fan-triangulated polygons of a polygon mesh and their edges, the
    /// diagonals included (see [`triangle_edges`]).
    pub fn from_mesh(mesh: MeshInput<'_>) -> Result<Self> {
        let offsets = mesh.validate()?;
        let triangles = fan_triangles(mesh.corner_verts, &offsets);
        Skin::new(mesh.positions.len(), triangle_edges(&triangles), triangles)
    }

    /// Vertices only: no edge–edge or collider-vertex tests.
    pub fn vertices_only(vertex_count: usize) -> Self {
        Skin { vertex_count, vertex_edges: (vec![0; vertex_count + 1], Vec::new()), vertex_triangles: (vec![0; vertex_count + 1], Vec::new()), ..Default::default() }
    }

    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// The edges around vertex `v`.
    pub(super) fn edges_of(&self, v: u32) -> &[u32] {
        let (offsets, list) = &self.vertex_edges;
        &list[offsets[v as usize] as usize..offsets[v as usize + 1] as usize]
    }

    /// The triangles around vertex `v`.
    pub(super) fn triangles_of(&self, v: u32) -> &[u32] {
        let (offsets, list) = &self.vertex_triangles;
        &list[offsets[v as usize] as usize..offsets[v as usize + 1] as usize]
    }

    /// Edges and triangles touching any of `vertices`, together with the
    /// given ones (`also`), each once, ascending.
    pub(super) fn touching(&self, vertices: &[u32], also: (&[u32], &[u32])) -> (Vec<u32>, Vec<u32>) {
        (
            ascending_unique(also.0.iter().copied().chain(vertices.iter().flat_map(|&v| self.edges_of(v).iter().copied())), self.edges.len()),
            ascending_unique(also.1.iter().copied().chain(vertices.iter().flat_map(|&v| self.triangles_of(v).iter().copied())), self.triangles.len()),
        )
    }
}

/// `indices` (each below `count`) ascending, each once: a bit per index
/// instead of sorting the tens of thousands an element list gathers.
pub(crate) fn ascending_unique(indices: impl Iterator<Item = u32>, count: usize) -> Vec<u32> {
    let mut bits = vec![0u64; count.div_ceil(64)];
    for k in indices {
        bits[k as usize / 64] |= 1 << (k % 64);
    }
    let mut out = Vec::with_capacity(bits.iter().map(|w| w.count_ones() as usize).sum());
    for (w, &word) in bits.iter().enumerate() {
        let mut word = word;
        while word != 0 {
            out.push((w * 64) as u32 + word.trailing_zeros());
            word &= word - 1;
        }
    }
    out
}
