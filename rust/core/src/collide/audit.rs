//! Penetration audit of a skin against colliders at their current positions,
//! independent of any solver bookkeeping:
//!
//! * vertices inside a **closed** collider deeper than a tolerance: exact ray
//!   parity along +z (see [`ray_up_crosses`]) through the collider's BVH, then
//!   "deeper than the tolerance" = no collider triangle within that distance;
//! * mesh edges (with the diagonals of its fan-triangulated polygons)
//!   properly crossing a collider triangle;
//! * collider edges properly crossing a mesh polygon (fan-triangulated).
//!
//! Thickness is ignored: the audit counts real interpenetrations.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::bvh::{BoxTree, Bounds};
use super::collider::Collider;
use super::geometry::{point_triangle_distance_squared, ray_up_crosses, segment_crosses_triangle};
use crate::mesh::MeshInput;
use crate::{Error, Result};

/// Settings of [`audit`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AuditParams {
    /// Vertices inside a collider but closer than this to its surface are not
    /// counted.
    pub depth_tolerance: f32,
}

impl Default for AuditParams {
    fn default() -> Self {
        AuditParams { depth_tolerance: 1e-4 }
    }
}

/// What [`audit`] found.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AuditReport {
    /// Skin vertices inside some closed collider, deeper than the tolerance.
    pub vertices_inside: Vec<u32>,
    /// Skin edges `[a, b]` (a < b) crossing a collider triangle.
    pub edges_crossing: Vec<[u32; 2]>,
    /// `(collider, edge)` pairs: collider edges crossing a skin polygon; the
    /// edge index refers to [`Collider::edges`].
    pub collider_edges_crossing: Vec<(u32, u32)>,
    /// Colliders that are not closed, for which the inside test was skipped.
    pub open_colliders: Vec<u32>,
}

fn d(v: Vec3) -> DVec3 {
    v.as_dvec3()
}

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

/// Fan triangulation of every polygon.
pub fn fan_triangles(corner_verts: &[i32], offsets: &[u32]) -> Vec<[u32; 3]> {
    let mut tris = Vec::with_capacity(corner_verts.len());
    for w in offsets.windows(2) {
        let poly = &corner_verts[w[0] as usize..w[1] as usize];
        for k in 1..poly.len() - 1 {
            tris.push([poly[0] as u32, poly[k] as u32, poly[k + 1] as u32]);
        }
    }
    tris
}

/// Whether `p` is inside closed collider `c` (current positions) by more
/// than `tolerance`.
pub fn is_inside(c: &Collider, p: Vec3, tolerance: f32) -> bool {
    let tree = c.tree();
    let top = tree.bounds();
    if !top.contains(p) {
        return false;
    }
    let ray = Bounds { min: p, max: Vec3::new(p.x, p.y, top.max.z) };
    let pos = c.current();
    let mut crossings = 0u32;
    tree.query(&ray, |t| {
        let [a, b, cc] = c.triangles()[t].map(|v| pos[v as usize].to_array());
        crossings += ray_up_crosses(p.to_array(), a, b, cc) as u32;
        true
    });
    if crossings % 2 == 0 {
        return false;
    }
    let tol = tolerance.max(0.0) as f64;
    let near = Bounds { min: p, max: p }.inflated(tolerance.max(0.0));
    let mut shallow = false;
    tree.query(&near, |t| {
        let [a, b, cc] = c.triangles()[t].map(|v| d(pos[v as usize]));
        if point_triangle_distance_squared(d(p), a, b, cc) < tol * tol {
            shallow = true;
            return false;
        }
        true
    });
    !shallow
}

/// Audits `mesh` against `colliders` at their current positions.
pub fn audit(mesh: MeshInput<'_>, colliders: &[&Collider], params: &AuditParams) -> Result<AuditReport> {
    if !params.depth_tolerance.is_finite() || params.depth_tolerance < 0.0 {
        return Err(Error::invalid(format!(
            "audit depth tolerance must be finite and ≥ 0, got {}",
            params.depth_tolerance
        )));
    }
    let offsets = mesh.validate()?;
    let positions = mesh.positions;
    let mut report = AuditReport::default();
    report.open_colliders =
        colliders.iter().enumerate().filter(|(_, c)| !c.is_closed()).map(|(i, _)| i as u32).collect();

    // 1. Vertices inside closed colliders.
    report.vertices_inside = (0..positions.len() as u32)
        .into_par_iter()
        .filter(|&v| {
            colliders
                .iter()
                .any(|c| c.is_closed() && is_inside(c, positions[v as usize], params.depth_tolerance))
        })
        .collect();

    // 2. Skin edges (the polygons' and their triangulation's diagonals)
    // crossing collider triangles.
    let tris = fan_triangles(mesh.corner_verts, &offsets);
    let edges = triangle_edges(&tris);
    report.edges_crossing = edges
        .par_iter()
        .copied()
        .filter(|&[a, b]| {
            let (pa, pb) = (positions[a as usize], positions[b as usize]);
            let query = Bounds::of_points(&[pa, pb]);
            colliders.iter().any(|c| {
                let pos = c.current();
                let mut crossing = false;
                c.tree().query(&query, |t| {
                    let [x, y, z] = c.triangles()[t].map(|v| d(pos[v as usize]));
                    crossing = segment_crosses_triangle(d(pa), d(pb), x, y, z);
                    !crossing
                });
                crossing
            })
        })
        .collect();

    // 3. Collider edges crossing skin polygons (fan-triangulated).
    let boxes: Vec<Bounds> = tris
        .par_iter()
        .map(|t| Bounds::of_points(&t.map(|v| positions[v as usize])))
        .collect();
    let skin_tree = BoxTree::build(&boxes)?;
    for (ci, c) in colliders.iter().enumerate() {
        let pos = c.current();
        let crossing: Vec<(u32, u32)> = (0..c.edges().len() as u32)
            .into_par_iter()
            .filter(|&e| {
                let [a, b] = c.edges()[e as usize].map(|v| pos[v as usize]);
                let mut crossing = false;
                skin_tree.query(&Bounds::of_points(&[a, b]), |t| {
                    let [x, y, z] = tris[t].map(|v| d(positions[v as usize]));
                    crossing = segment_crosses_triangle(d(a), d(b), x, y, z);
                    !crossing
                });
                crossing
            })
            .map(|e| (ci as u32, e))
            .collect();
        report.collider_edges_crossing.extend(crossing);
    }
    Ok(report)
}
