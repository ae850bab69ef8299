//! Elements derived from a polygon mesh in Blender's layout: its edges, a fan
//! triangulation and the triangulation's edges. The solver's collision skin
//! and strain limits use these; the penetration audit
//! ([`crate::collide::audit`]) deliberately triangulates on its own.

use rayon::prelude::*;

/// Unique edges `[min, max]` of a polygon mesh, sorted.
pub fn polygon_edges(corner_verts: &[i32], offsets: &[u32]) -> Vec<[u32; 2]> {
    let mut edges = Vec::with_capacity(corner_verts.len());
    for w in offsets.windows(2) {
        let poly = &corner_verts[w[0] as usize..w[1] as usize];
        for k in 0..poly.len() {
            let (a, b) = (poly[k] as u32, poly[(k + 1) % poly.len()] as u32);
            if a != b {
                edges.push([a.min(b), a.max(b)]);
            }
        }
    }
    edges.par_sort_unstable();
    edges.dedup();
    edges
}

/// Unique edges `[min, max]` of triangles, sorted: a fan-triangulated
/// polygon's edges *and* its diagonals. Collision tests and the audit need the
/// diagonals: two triangulated surfaces meet where an edge of one crosses a
/// triangle of the other, and a folded quad first meets a collider edge along
/// its diagonal.
pub fn triangle_edges(triangles: &[[u32; 3]]) -> Vec<[u32; 2]> {
    let mut edges: Vec<[u32; 2]> = triangles
        .iter()
        .flat_map(|&[a, b, c]| [[a, b], [b, c], [c, a]])
        .filter(|[a, b]| a != b)
        .map(|[a, b]| [a.min(b), a.max(b)])
        .collect();
    edges.par_sort_unstable();
    edges.dedup();
    edges
}

/// Fan triangulation of every polygon (triangles with two equal corners left out).
pub fn fan_triangles(corner_verts: &[i32], offsets: &[u32]) -> Vec<[u32; 3]> {
    let mut tris = Vec::with_capacity(corner_verts.len());
    for w in offsets.windows(2) {
        let poly = &corner_verts[w[0] as usize..w[1] as usize];
        for k in 1..poly.len() - 1 {
            let t = [poly[0] as u32, poly[k] as u32, poly[k + 1] as u32];
            // Two equal corners (a polygon welded onto itself) cover nothing.
            if t[0] != t[1] && t[1] != t[2] && t[2] != t[0] {
                tris.push(t);
            }
        }
    }
    tris
}

/// A triangle and the polygon it comes from.
pub type PolygonTriangle = ([u32; 3], u32);

/// The triangles of every way a renderer may split each polygon, each with
/// its polygon: a quad with four distinct corners `a b c d` gives both
/// splits' four triangles (`abc`, `acd` and `abd`, `bcd`: the faces of the
/// tetrahedron of its corners), any other polygon its fan. Also the quads
/// (their corners in order), whose two diagonals cross by construction.
/// Self-collision and its audit use these: Blender's BVHTree, a Subdivision
/// Surface or an exporter may draw either diagonal of a quad, and a creased
/// quad is not planar, so a guarantee given for one split only is not one.
pub fn either_split_triangles(corner_verts: &[i32], offsets: &[u32]) -> (Vec<PolygonTriangle>, Vec<[u32; 4]>) {
    let mut triangles = Vec::with_capacity(corner_verts.len() * 2);
    let mut quads = Vec::new();
    for (polygon, w) in offsets.windows(2).enumerate() {
        let poly = &corner_verts[w[0] as usize..w[1] as usize];
        let corner = |k: usize| poly[k] as u32;
        let distinct = |t: &[u32]| (0..t.len()).all(|i| (i + 1..t.len()).all(|j| t[i] != t[j]));
        if poly.len() == 4 && distinct(&[corner(0), corner(1), corner(2), corner(3)]) {
            let [a, b, c, d] = [corner(0), corner(1), corner(2), corner(3)];
            for t in [[a, b, c], [a, c, d], [a, b, d], [b, c, d]] {
                triangles.push((t, polygon as u32));
            }
            quads.push([a, b, c, d]);
            continue;
        }
        for k in 1..poly.len().saturating_sub(1) {
            let t = [corner(0), corner(k), corner(k + 1)];
            if distinct(&t) {
                triangles.push((t, polygon as u32));
            }
        }
    }
    (triangles, quads)
}

/// Compressed rows of the elements (edges, triangles) around each of `n`
/// vertices: `(offsets, element indices)`, each vertex's ascending.
pub fn vertex_incidence<'e>(n: usize, elements: impl Iterator<Item = &'e [u32]> + Clone) -> (Vec<u32>, Vec<u32>) {
    let mut offsets = vec![0u32; n + 1];
    for el in elements.clone() {
        for &v in el {
            offsets[v as usize + 1] += 1;
        }
    }
    for i in 0..n {
        offsets[i + 1] += offsets[i];
    }
    let mut fill = offsets.clone();
    let mut list = vec![0u32; offsets[n] as usize];
    for (k, el) in elements.enumerate() {
        for &v in el {
            list[fill[v as usize] as usize] = k as u32;
            fill[v as usize] += 1;
        }
    }
    (offsets, list)
}
