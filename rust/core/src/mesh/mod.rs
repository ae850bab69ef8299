//! Polygon mesh topology in Blender's own layout.
//!
//! A mesh arrives as Blender stores it: vertex positions, the vertex index of
//! every face corner ("corner verts", Blender's `loops`), and the corner count
//! of every polygon. [`validate`] checks those arrays; [`Topology`] derives
//! what the deformers need: unique edges, one-rings ordered with the face
//! orientation, boundaries, and everything that is not a clean 2-manifold;
//! [`Weld`] joins the vertices an importer split at seams.

mod aggregate;
mod elements;
pub mod fixtures;
pub mod shapes;
mod topology;
mod transform;
mod validate;
mod weld;

pub use aggregate::{aggregate_edges, aggregate_once, group_members};
pub use elements::{either_split_triangles, fan_triangles, polygon_edges, triangle_edges, vertex_incidence};
pub use topology::{Topology, TopologyReport};
pub use transform::transform_points;
pub use validate::{all_finite, as_vec3, validate_positions, MeshInput};
pub use weld::{Weld, SLIVER_RATIO, WELD_TOLERANCE};

#[cfg(test)]
mod tests;
