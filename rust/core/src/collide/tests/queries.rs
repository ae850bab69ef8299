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

#[test]
fn closest_point_is_the_nearest_triangle_inside_and_outside_a_closed_collider() {
    // Points deep inside a sphere, near its surface and far outside, against
    // every triangle measured (the best-first search measures a handful).
    let (positions, tris) = crate::mesh::shapes::uv_sphere_triangles(24, 12, 0.5);
    let c = Collider::new(&positions, &tris, ColliderSettings::new(0.01, 0.0)).unwrap();
    let distance = |p: Vec3, t: &[u32; 3]| {
        let [a, b, d] = t.map(|v| positions[v as usize].as_dvec3());
        let (v, w) = crate::collide::geometry::closest_on_triangle(p.as_dvec3(), a, b, d);
        (p.as_dvec3() - (a + v * (b - a) + w * (d - a))).length()
    };
    for k in 0..200 {
        let f = k as f32;
        let direction = Vec3::new((f * 0.37).sin(), (f * 0.71).cos(), (f * 0.13).sin() * 0.9).normalize();
        let p = direction * (0.05 + 0.006 * f) + Vec3::new(0.01, -0.02, 0.03);
        let brute = tris.iter().map(|t| distance(p, t)).fold(f64::INFINITY, f64::min);
        let near = c.closest_point(p).unwrap();
        let found = distance(p, &tris[near.triangle as usize]);
        assert!((found - brute).abs() < 1e-9, "{p}: triangle {} at {found}, nearest at {brute}", near.triangle);
        assert!(((near.point - p).length() as f64 - brute).abs() < 1e-5);
        // Bounded by anything beyond the nearest distance, the same point
        // and triangle; bounded short of it, none.
        assert_eq!(c.closest_point_within(p, brute * 1.001 + 1e-9), Some(near), "{p}");
        assert_eq!(c.closest_point_within(p, brute * 0.999), None, "{p}");
    }
}

#[test]
fn first_hit_is_the_nearest_crossing_of_every_triangle() {
    // Segments of every length and direction through a closed sphere, some
    // along an axis (zero components of the direction), some missing it,
    // against every triangle tested.
    let (positions, tris) = crate::mesh::shapes::uv_sphere_triangles(24, 12, 0.5);
    let c = Collider::new(&positions, &tris, ColliderSettings::new(0.01, 0.0)).unwrap();
    let crossing = |p: Vec3, q: Vec3, t: &[u32; 3]| -> Option<f64> {
        let [a, b, d] = t.map(|v| positions[v as usize].as_dvec3());
        let (o, dir) = (p.as_dvec3(), q.as_dvec3() - p.as_dvec3());
        let (e1, e2) = (b - a, d - a);
        let h = dir.cross(e2);
        let det = e1.dot(h);
        if det.abs() < 1e-300 {
            return None;
        }
        let s = o - a;
        let (u, qv) = (s.dot(h) / det, s.cross(e1));
        let (v, along) = (dir.dot(qv) / det, e2.dot(qv) / det);
        ((0.0..=1.0).contains(&u) && v >= 0.0 && u + v <= 1.0 && (0.0..=1.0).contains(&along)).then_some(along)
    };
    let mut hits = 0;
    for k in 0..300 {
        let f = k as f32;
        let p = Vec3::new((f * 0.31).sin(), (f * 0.57).cos(), (f * 0.11).sin()) * (0.2 + 0.004 * f);
        let direction = match k % 3 {
            0 => Vec3::new(0.0, 0.0, 1.0),
            _ => Vec3::new((f * 0.73).cos(), (f * 0.29).sin(), (f * 0.91).cos()),
        };
        let q = p + direction * (0.05 + 0.01 * f);
        let brute = tris.iter().enumerate().filter_map(|(t, tri)| crossing(p, q, tri).map(|a| (t, a))).min_by(|a, b| a.1.total_cmp(&b.1));
        let found = c.first_hit(p, q);
        assert_eq!(found.map(|(t, _)| t as f64), brute.map(|(_, a)| a as f32 as f64), "{p} → {q}: {found:?} against {brute:?}");
        hits += found.is_some() as usize;
    }
    assert!(hits > 50, "only {hits} segments hit: the test says little");
}

#[test]
fn queries_of_a_collider_thicker_than_its_triangles_do_not_depend_on_the_thickness() {
    // The searches measure from the boxes less the thickness (a skin standing
    // in as a collider has triangles smaller than it): the same answers as
    // without one, on a bent sheet where a thick box reaches far past its
    // triangle's neighbours. (Where the closest point or the crossing is on
    // an edge, either triangle of the edge may be named.)
    let mesh = grid(12, 12, 2.0);
    let positions: Vec<Vec3> = mesh.positions.iter().map(|p| Vec3::new(p.x, p.y, 0.3 * (2.0 * p.x).sin() * p.y.cos())).collect();
    let offsets: Vec<u32> = (0..=mesh.polygon_sizes.len() as u32).map(|k| 4 * k).collect();
    let tris = crate::mesh::fan_triangles(&mesh.corner_verts, &offsets);
    let thin = Collider::new(&positions, &tris, ColliderSettings::new(0.0, 0.0)).unwrap();
    let thick = Collider::new(&positions, &tris, ColliderSettings::new(0.6, 0.0)).unwrap();
    let mut hits = 0;
    for k in 0..300 {
        let f = k as f32;
        let p = Vec3::new((f * 0.37).sin(), (f * 0.71).cos(), 0.8 * (f * 0.13).sin());
        let (a, b) = (thick.closest_point(p).unwrap(), thin.closest_point(p).unwrap());
        assert!((a.point - b.point).length() < 1e-6, "{p}: {a:?} against {b:?}");
        let q = p + Vec3::new((f * 0.29).cos(), (f * 0.53).sin(), -(f * 0.17).cos()) * (0.3 + 0.005 * f);
        let along = |c: &Collider| c.first_hit(p, q).map(|(t, _)| t);
        assert_eq!(along(&thick), along(&thin), "{p} → {q}");
        hits += thin.first_hit(p, q).is_some() as usize;
    }
    assert!(hits > 50, "only {hits} segments hit: the test says little");
}
