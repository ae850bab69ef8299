//! Checks of raw mesh arrays, with messages that say where the problem is.

use glam::Vec3;

use crate::error::{check_allocation, memory_limit};
use crate::{Error, Result};

/// Peak working memory per vertex and per face corner of the heaviest
/// consumer of a mesh (a pyramid bind and solve: topology, encoding, the
/// factorised system), measured at about 390 bytes per vertex on a quad grid
/// (4 corners per vertex), with some headroom.
const BYTES_PER_VERTEX: u64 = 192;
const BYTES_PER_CORNER: u64 = 64;

/// Reinterprets a flat `[x0, y0, z0, x1, ...]` slice as vectors without copying.
pub fn as_vec3(flat: &[f32]) -> Result<&[Vec3]> {
    if flat.len() % 3 != 0 {
        return Err(Error::invalid(format!(
            "positions hold {} floats, which is not a multiple of 3 (x, y, z per vertex)",
            flat.len()
        )));
    }
    Ok(bytemuck::cast_slice(flat))
}

/// Whether no value is NaN or infinite: a branch-free scan (exponent bits all
/// ones) that the compiler vectorises, split across threads for large arrays.
/// Checking every frame's positions with a per-vertex early exit cost about
/// as much as one solver iteration's worth of bookkeeping at 100k vertices.
pub fn all_finite(values: &[f32]) -> bool {
    use rayon::prelude::*;
    const EXPONENT: u32 = 0x7f80_0000;
    let clean = |chunk: &[f32]| chunk.iter().fold(0u32, |bad, v| bad | u32::from(v.to_bits() & EXPONENT == EXPONENT)) == 0;
    values.par_chunks(1 << 16).all(clean)
}

/// Fails on the first coordinate that is NaN or infinite, naming the vertex.
pub fn validate_positions(what: &str, positions: &[Vec3]) -> Result<()> {
    if all_finite(bytemuck::cast_slice(positions)) {
        return Ok(());
    }
    match positions.iter().position(|p| !p.is_finite()) {
        None => Ok(()),
        Some(vertex) => Err(Error::invalid(format!(
            "{what}: vertex {vertex} is not finite ({:?})",
            positions[vertex].to_array()
        ))),
    }
}

/// A mesh as Blender stores it, borrowed from the caller.
#[derive(Debug, Clone, Copy)]
pub struct MeshInput<'a> {
    /// One position per vertex.
    pub positions: &'a [Vec3],
    /// The vertex index of every face corner, polygon after polygon.
    pub corner_verts: &'a [i32],
    /// The number of corners of every polygon.
    pub polygon_sizes: &'a [i32],
}

impl<'a> MeshInput<'a> {
    /// Checks every index and size and returns the offset of each polygon's
    /// first corner (with the corner count appended).
    pub fn validate(&self) -> Result<Vec<u32>> {
        validate_positions("positions", self.positions)?;
        let vertex_count = self.positions.len();
        if vertex_count > u32::MAX as usize - 1 {
            return Err(Error::invalid(format!("{vertex_count} vertices is more than Tegument supports")));
        }
        let corners = self.corner_verts.len() as u64;
        check_allocation::<u8>(
            &format!("a mesh of {vertex_count} vertices and {corners} face corners"),
            (vertex_count as u64).saturating_mul(BYTES_PER_VERTEX).saturating_add(corners.saturating_mul(BYTES_PER_CORNER)),
            memory_limit(),
        )?;
        let mut offsets = Vec::with_capacity(self.polygon_sizes.len() + 1);
        let mut total: u64 = 0;
        offsets.push(0u32);
        for (polygon, &size) in self.polygon_sizes.iter().enumerate() {
            if size < 3 {
                return Err(Error::invalid(format!(
                    "polygon {polygon} has {size} corners; a polygon needs at least 3"
                )));
            }
            total += size as u64;
            if total > self.corner_verts.len() as u64 {
                return Err(Error::invalid(format!(
                    "polygon sizes add up to more corners than the {} given (already {total} at polygon {polygon})",
                    self.corner_verts.len()
                )));
            }
            offsets.push(total as u32);
        }
        if total != self.corner_verts.len() as u64 {
            return Err(Error::invalid(format!(
                "polygon sizes add up to {total} corners but {} corner vertex indices were given",
                self.corner_verts.len()
            )));
        }
        if let Some(corner) = self
            .corner_verts
            .iter()
            .position(|&v| v < 0 || v as usize >= vertex_count)
        {
            return Err(Error::invalid(format!(
                "corner {corner} refers to vertex {}, but the mesh has {vertex_count} vertices",
                self.corner_verts[corner]
            )));
        }
        Ok(offsets)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_finite_finds_any_non_finite_value_in_any_chunk() {
        let mut values = vec![1.0f32; 3 * 100_000];
        values[7] = f32::MAX;
        values[8] = f32::MIN_POSITIVE / 2.0; // subnormal: finite
        values[9] = -0.0;
        assert!(all_finite(&values));
        for at in [0, 65_535, 65_536, values.len() - 1] {
            for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -f32::NAN] {
                let mut v = values.clone();
                v[at] = bad;
                assert!(!all_finite(&v), "{bad} at {at}");
            }
        }
        assert!(all_finite(&[]));
    }

    #[test]
    fn validate_positions_names_the_first_bad_vertex() {
        let mut p = vec![Vec3::ONE; 70_000];
        p[66_000].y = f32::NAN;
        p[69_000].x = f32::INFINITY;
        let message = validate_positions("input", &p).unwrap_err().to_string();
        assert!(message.contains("vertex 66000"), "{message}");
    }
}
