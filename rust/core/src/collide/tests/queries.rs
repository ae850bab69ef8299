//! Surface queries of a collider: closest point, first hit, proximity.

use glam::Vec3;

use crate::collide::{Collider, ColliderSettings};
use crate::mesh::shapes::grid;

/// A 2 × 2 grid in the plane z = 0, as a collider.
fn plane() -> Collider {
    let mesh = grid(8, 8, 2.0);
    let offsets: Vec<u32> = (0..=mesh.polygon_sizes.len() as u32).map(|k| 4 * k).collect();
    let tris = crate::mesh::fan_triangles(&mesh.corner_verts, &offsets);
    Collider::new(&mesh.positions, &tris, ColliderSettings::new(0.0, 0.0)).unwrap()
}

#[test]
fn closest_point_hit_and_proximity_on_a_plane() {
    let c = plane();
    for p in [Vec3::new(0.3, -0.2, 0.7), Vec3::new(-0.9, 0.9, -0.05), Vec3::new(0.0, 0.0, 5.0)] {
        let near = c.closest_point(p).unwrap();
        assert!((near.point - Vec3::new(p.x, p.y, 0.0)).length() < 1e-5, "{p}: {}", near.point);
        assert!((near.barycentric.element_sum() - 1.0).abs() < 1e-5);
    }
    // Beyond the border, the closest point is on the border.
    let near = c.closest_point(Vec3::new(3.0, 0.0, 1.0)).unwrap();
    assert!((near.point - Vec3::new(1.0, 0.0, 0.0)).length() < 1e-5);
    let (t, _) = c.first_hit(Vec3::new(0.1, 0.1, 1.0), Vec3::new(0.1, 0.1, -3.0)).unwrap();
    assert!((t - 0.25).abs() < 1e-6);
    assert!(c.first_hit(Vec3::new(0.1, 0.1, 1.0), Vec3::new(0.1, 0.1, 0.5)).is_none());
    assert!(c.is_within(Vec3::new(0.5, 0.5, 0.009), 0.01));
    assert!(!c.is_within(Vec3::new(0.5, 0.5, 0.011), 0.01));
}
