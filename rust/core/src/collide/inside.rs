//! Whether a point is inside a closed collider: the solver's test (compliant
//! colliders' goal shapes, vertices left pinched). The penetration audit has
//! its own ([`super::audit`]), so that a bug here cannot hide from it.

use glam::{DVec3, Vec3};

use super::bvh::Bounds;
use super::collider::Collider;
use super::geometry::{point_triangle_distance_squared, ray_up_crosses};

fn d(v: Vec3) -> DVec3 {
    v.as_dvec3()
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

