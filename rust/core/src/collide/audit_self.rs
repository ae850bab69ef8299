//! The audit's count of a mesh's self-intersections, independent of the
//! self-collision passes: its own triangulation per polygon, its own box
//! tree, and the audit's Plücker crossing test
//! ([`super::audit`]), nothing of [`super::self_contact`].
//!
//! Two polygons intersect when they do under *some* split of their quads
//! (a renderer, Blender's BVHTree or an exporter may draw either
//! diagonal): a side or diagonal of one (a quad's two, an ngon's fan
//! diagonals) properly crosses a triangle of the other (a quad's four, of
//! both splits; an ngon's fan). Polygons sharing a vertex are not counted
//! (they touch by construction), as in Blender's own check
//! (`BVHTree.overlap` of a mesh with itself, pairs sharing no vertex).

use glam::Vec3;
use rayon::prelude::*;

use super::audit::segment_through_triangle;
use super::bvh::{BoxTree, Bounds};
use crate::mesh::MeshInput;
use crate::Result;

/// Pairs of polygons `[a, b]` (`a < b`, ascending) that intersect and share no vertex.
pub fn self_intersections(mesh: MeshInput<'_>) -> Result<Vec<[u32; 2]>> {
    let offsets = mesh.validate()?;
    let positions = mesh.positions;
    let polygon = |p: usize| &mesh.corner_verts[offsets[p] as usize..offsets[p + 1] as usize];
    // Each quad's triangles of both splits, other polygons' fans, each with its polygon.
    let mut triangles: Vec<([u32; 3], u32)> = Vec::with_capacity(2 * mesh.corner_verts.len());
    for p in 0..offsets.len() - 1 {
        let c: Vec<u32> = polygon(p).iter().map(|&v| v as u32).collect();
        if c.len() == 4 {
            for t in [[c[0], c[1], c[2]], [c[0], c[2], c[3]], [c[0], c[1], c[3]], [c[1], c[2], c[3]]] {
                triangles.push((t, p as u32));
            }
            continue;
        }
        for k in 1..c.len().saturating_sub(1) {
            triangles.push(([c[0], c[k], c[k + 1]], p as u32));
        }
    }
    let boxes: Vec<Bounds> = triangles.par_iter().map(|(t, _)| Bounds::of_points(&t.map(|v| positions[v as usize]))).collect();
    let tree = BoxTree::build(&boxes)?;
    let shares = |a: &[i32], b: &[i32]| a.iter().any(|v| b.contains(v));
    let mut pairs: Vec<[u32; 2]> = (0..offsets.len() - 1)
        .into_par_iter()
        .flat_map_iter(|p| {
            let corners = polygon(p);
            let k = corners.len();
            // The sides, and the fan diagonals from the first corner (a
            // quad's both diagonals).
            let other_diagonal = (k == 4).then(|| (corners[1], corners[3]));
            let segments = (0..k)
                .map(move |i| (corners[i], corners[(i + 1) % k]))
                .chain((2..k.saturating_sub(1)).map(move |i| (corners[0], corners[i])))
                .chain(other_diagonal);
            let mut found: Vec<[u32; 2]> = Vec::new();
            for (a, b) in segments {
                let (pa, pb): (Vec3, Vec3) = (positions[a as usize], positions[b as usize]);
                tree.query(&Bounds::of_points(&[pa, pb]), |t| {
                    let (tri, q) = triangles[t];
                    if q as usize != p && !shares(corners, polygon(q as usize)) {
                        let [x, y, z] = tri.map(|v| positions[v as usize].as_dvec3());
                        if segment_through_triangle(pa.as_dvec3(), pb.as_dvec3(), x, y, z) {
                            found.push([p.min(q as usize) as u32, p.max(q as usize) as u32]);
                        }
                    }
                    true
                });
            }
            found
        })
        .collect();
    pairs.par_sort_unstable();
    pairs.dedup();
    Ok(pairs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::shapes::{grid, PolyMesh};

    #[test]
    fn two_crossing_sheets_intersect_a_flat_one_does_not() {
        let flat = grid(4, 4, 1.0);
        assert!(self_intersections(flat.input()).unwrap().is_empty());
        // A second sheet standing upright through the first one's middle.
        let mut mesh = flat.clone();
        let base = mesh.positions.len();
        for j in 0..2 {
            for i in 0..2 {
                mesh.positions.push(Vec3::new(-0.1 + 0.2 * i as f32, 0.05, -0.3 + 0.6 * j as f32));
            }
        }
        mesh.push_polygon(&[base, base + 1, base + 3, base + 2]);
        let found = self_intersections(mesh.input()).unwrap();
        assert!(!found.is_empty());
        assert!(found.iter().all(|&[a, b]| a < b && b == 16), "{found:?}");
        let empty = PolyMesh::default();
        assert!(self_intersections(empty.input()).unwrap().is_empty());
    }

    #[test]
    fn a_pair_crossing_under_either_split_of_a_quad_counts() {
        let mesh = crate::mesh::fixtures::creased_quad_and_a_needle(0.4, 0.0);
        assert_eq!(self_intersections(mesh.input()).unwrap(), vec![[0, 1]]);
    }
}
