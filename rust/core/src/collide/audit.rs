//! Penetration audit of a skin against colliders at their current positions,
//! independent of the solver: it shares none of the solver's geometry
//! (triangulation, containment, crossing tests, collider trees), so that a
//! bug there shows up here instead of hiding from its own checker.
//!
//! * vertices inside a **closed** collider deeper than a tolerance: ray
//!   parity along −z ([`crosses_below`]), then "deeper than the tolerance" =
//!   no collider triangle within that distance;
//! * mesh edges (with the diagonals of its fan-triangulated polygons)
//!   properly crossing a collider triangle;
//! * collider edges properly crossing a mesh polygon (fan-triangulated).
//!
//! Thickness is ignored: the audit counts real interpenetrations. Each
//! collider gets its own box tree over its current triangles, built per audit.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::bvh::{BoxTree, Bounds};
use super::collider::Collider;
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
    let surfaces: Vec<Surface> = colliders.iter().map(|c| Surface::new(c)).collect::<Result<_>>()?;

    // 1. Vertices inside closed colliders.
    report.vertices_inside = (0..positions.len() as u32)
        .into_par_iter()
        .filter(|&v| {
            surfaces.iter().any(|s| s.closed && s.contains(positions[v as usize], params.depth_tolerance))
        })
        .collect();

    // 2. Skin edges (the polygons' and their fan diagonals) crossing collider
    // triangles.
    let (tris, edges) = skin_elements(mesh.corner_verts, &offsets);
    report.edges_crossing = edges
        .par_iter()
        .copied()
        .filter(|&[a, b]| {
            let (pa, pb) = (positions[a as usize], positions[b as usize]);
            surfaces.iter().any(|s| s.crossed_by(pa, pb))
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
                    let [x, y, z] = tris[t].map(|v| positions[v as usize].as_dvec3());
                    crossing = segment_through_triangle(a.as_dvec3(), b.as_dvec3(), x, y, z);
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

/// A collider's current surface as the audit sees it: f64 corners and a box
/// tree of its own.
struct Surface<'a> {
    positions: Vec<DVec3>,
    triangles: &'a [[u32; 3]],
    tree: BoxTree,
    closed: bool,
}

impl<'a> Surface<'a> {
    fn new(c: &'a Collider) -> Result<Self> {
        let current = c.current();
        let boxes: Vec<Bounds> = c.triangles().iter().map(|t| Bounds::of_points(&t.map(|v| current[v as usize]))).collect();
        Ok(Surface {
            positions: current.iter().map(|p| p.as_dvec3()).collect(),
            triangles: c.triangles(),
            tree: BoxTree::build(&boxes)?,
            closed: c.is_closed(),
        })
    }

    fn corners(&self, t: usize) -> [DVec3; 3] {
        self.triangles[t].map(|v| self.positions[v as usize])
    }

    /// Whether `p` is inside this (closed) surface by more than `tolerance`.
    fn contains(&self, p: Vec3, tolerance: f32) -> bool {
        if self.tree.is_empty() {
            return false;
        }
        let top = self.tree.bounds();
        if !top.contains(p) {
            return false;
        }
        let ray = Bounds { min: Vec3::new(p.x, p.y, top.min.z), max: p };
        let q = p.as_dvec3();
        let mut below = 0u32;
        self.tree.query(&ray, |t| {
            let [a, b, c] = self.corners(t);
            below += crosses_below(q, a, b, c) as u32;
            true
        });
        if below % 2 == 0 {
            return false;
        }
        let tol = tolerance.max(0.0) as f64;
        let near = Bounds { min: p, max: p }.inflated(tolerance.max(0.0));
        let mut shallow = false;
        self.tree.query(&near, |t| {
            let [a, b, c] = self.corners(t);
            shallow = distance_to_triangle(q, a, b, c) < tol;
            !shallow
        });
        !shallow
    }

    /// Whether segment `a b` properly crosses one of the triangles.
    fn crossed_by(&self, a: Vec3, b: Vec3) -> bool {
        let mut crossing = false;
        self.tree.query(&Bounds::of_points(&[a, b]), |t| {
            let [x, y, z] = self.corners(t);
            crossing = segment_through_triangle(a.as_dvec3(), b.as_dvec3(), x, y, z);
            !crossing
        });
        crossing
    }
}

/// The skin's fan triangles (from each polygon's first corner) and their
/// unique edges `[min, max]`, sorted: the polygons' sides and the fans'
/// diagonals, where a folded polygon first meets a collider.
fn skin_elements(corner_verts: &[i32], offsets: &[u32]) -> (Vec<[u32; 3]>, Vec<[u32; 2]>) {
    let mut tris = Vec::with_capacity(corner_verts.len());
    let mut edges = Vec::with_capacity(2 * corner_verts.len());
    let mut edge = |a: u32, b: u32| {
        if a != b {
            edges.push([a.min(b), a.max(b)]);
        }
    };
    for w in offsets.windows(2) {
        let polygon = &corner_verts[w[0] as usize..w[1] as usize];
        let corner = |i: usize| polygon[i] as u32;
        let k = polygon.len();
        for i in 0..k {
            edge(corner(i), corner((i + 1) % k));
        }
        for i in 2..k.saturating_sub(1) {
            edge(corner(0), corner(i));
        }
        tris.extend((1..k.saturating_sub(1)).map(|i| [corner(0), corner(i), corner(i + 1)]));
    }
    edges.par_sort_unstable();
    edges.dedup();
    (tris, edges)
}

/// Twice the signed area of `(u, v, p)` in the xy plane, with `p` moved by
/// `(ε², ε)` for infinitesimal ε so that it is never 0 for distinct `u`, `v`
/// (simulation of simplicity): a ray through a shared edge or vertex then
/// counts exactly once over a closed surface. Differences of f32 coordinates
/// and their products are exact in f64.
fn side(u: DVec3, v: DVec3, p: DVec3) -> f64 {
    let area = (u.x - p.x) * (v.y - p.y) - (u.y - p.y) * (v.x - p.x);
    if area != 0.0 {
        return area;
    }
    // The ε term (from p.y), then the ε² term (from p.x).
    let by_y = v.x - u.x;
    if by_y != 0.0 {
        return by_y;
    }
    u.y - v.y
}

/// Whether the ray from `p` towards −z crosses triangle `a b c`.
fn crosses_below(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> bool {
    let (wa, wb, wc) = (side(b, c, p), side(c, a, p), side(a, b, p));
    let inside = (wa > 0.0 && wb > 0.0 && wc > 0.0) || (wa < 0.0 && wb < 0.0 && wc < 0.0);
    if !inside {
        return false;
    }
    // Height of the triangle at p's (x, y), from its projected barycentrics.
    let total = wa + wb + wc;
    if total == 0.0 {
        return false;
    }
    let z = (wa * a.z + wb * b.z + wc * c.z) / total;
    z < p.z
}

/// Distance from `p` to triangle `a b c`: to its plane where the foot falls
/// inside, otherwise to the nearest side (also for degenerate triangles).
fn distance_to_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let n = (b - a).cross(c - a);
    let area2 = n.length_squared();
    if area2 > 0.0 {
        let height = (p - a).dot(n) / area2;
        let foot = p - n * height;
        let inside = [(a, b), (b, c), (c, a)].iter().all(|&(u, v)| (v - u).cross(foot - u).dot(n) >= 0.0);
        if inside {
            return (p - foot).length();
        }
    }
    [(a, b), (b, c), (c, a)].iter().map(|&(u, v)| distance_to_segment(p, u, v)).fold(f64::INFINITY, f64::min)
}

fn distance_to_segment(p: DVec3, u: DVec3, v: DVec3) -> f64 {
    let d = v - u;
    let len2 = d.length_squared();
    let t = if len2 > 0.0 { ((p - u).dot(d) / len2).clamp(0.0, 1.0) } else { 0.0 };
    (p - (u + d * t)).length()
}

/// Whether segment `p q` properly crosses triangle `a b c`: `p` and `q`
/// strictly on opposite sides of its plane, and the line through them
/// strictly inside its three sides (signs of the Plücker products of the line
/// with each side all equal and non-zero). Touching does not count.
pub(super) fn segment_through_triangle(p: DVec3, q: DVec3, a: DVec3, b: DVec3, c: DVec3) -> bool {
    let n = (b - a).cross(c - a);
    let (hp, hq) = (n.dot(p - a), n.dot(q - a));
    if !(hp > 0.0 && hq < 0.0 || hp < 0.0 && hq > 0.0) {
        return false;
    }
    // Line L = (direction d, moment m); side(L, u→v) = d·(u×v) + (v−u)·m.
    let (d, m) = (q - p, p.cross(q));
    let plucker = |u: DVec3, v: DVec3| d.dot(u.cross(v)) + (v - u).dot(m);
    let (s1, s2, s3) = (plucker(a, b), plucker(b, c), plucker(c, a));
    (s1 > 0.0 && s2 > 0.0 && s3 > 0.0) || (s1 < 0.0 && s2 < 0.0 && s3 < 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ray_through_a_shared_edge_or_vertex_counts_once() {
        // A square split along its diagonal, below the points.
        let (a, b, c, d) = (DVec3::new(0.0, 0.0, -1.0), DVec3::new(1.0, 0.0, -1.0), DVec3::new(1.0, 1.0, -1.0), DVec3::new(0.0, 1.0, -1.0));
        for p in [[0.5, 0.5], [0.0, 0.0], [0.25, 0.75], [1.0, 0.5], [0.5, 0.0]] {
            let p = DVec3::new(p[0], p[1], 0.0);
            assert!(crosses_below(p, a, b, c) as u32 + crosses_below(p, a, c, d) as u32 <= 1, "{p:?}");
        }
        let centre = DVec3::new(0.5, 0.5, 0.0);
        assert_eq!(crosses_below(centre, a, b, c) as u32 + crosses_below(centre, a, c, d) as u32, 1);
        let under = DVec3::new(0.5, 0.5, -2.0);
        assert!(!crosses_below(under, a, b, c) && !crosses_below(under, a, c, d));
    }

    #[test]
    fn crossing_and_touching_segments() {
        let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        let through = |p: [f64; 3], q: [f64; 3]| segment_through_triangle(DVec3::from(p), DVec3::from(q), a, b, c);
        assert!(through([0.2, 0.2, 1.0], [0.2, 0.2, -1.0]));
        assert!(!through([0.8, 0.8, 1.0], [0.8, 0.8, -1.0]), "outside the triangle");
        assert!(!through([0.2, 0.2, 1.0], [0.2, 0.2, 0.0]), "ends on it");
        assert!(!through([0.0, 0.0, 1.0], [0.0, 0.0, 2.0]), "above it");
        assert!(!through([0.5, 0.0, 1.0], [0.5, 0.0, -1.0]), "through a side");
    }

    #[test]
    fn distances_inside_beside_and_to_a_degenerate_triangle() {
        let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        assert!((distance_to_triangle(DVec3::new(0.2, 0.2, 2.0), a, b, c) - 2.0).abs() < 1e-12);
        assert!((distance_to_triangle(DVec3::new(-1.0, 0.0, 0.0), a, b, c) - 1.0).abs() < 1e-12);
        assert!((distance_to_triangle(DVec3::new(1.0, 1.0, 0.0), a, b, c) - 0.5f64.sqrt()).abs() < 1e-12);
        assert!((distance_to_triangle(DVec3::new(0.5, 1.0, 0.0), a, b, b) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn skin_elements_are_the_fans_and_their_sorted_edges() {
        let (tris, edges) = skin_elements(&[0, 1, 2, 3, 1, 4, 2], &[0, 4, 7]);
        assert_eq!(tris, vec![[0, 1, 2], [0, 2, 3], [1, 4, 2]]);
        assert_eq!(edges, vec![[0, 1], [0, 2], [0, 3], [1, 2], [1, 4], [2, 3], [2, 4]]);
    }
}
