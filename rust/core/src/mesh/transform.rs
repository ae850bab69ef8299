//! Object matrices applied to whole point arrays: Blender gives positions in
//! object space, and the deformer solves in world space.

use glam::{DMat4, Vec3};
use rayon::prelude::*;

/// Points per task: large enough that a task outweighs its scheduling.
const CHUNK: usize = 8192;

/// `out[i] = matrix · (points[i], 1)`, the affine part of `matrix` (its last
/// row is not used). Evaluated in f64 and rounded once, so that a world matrix
/// with a large translation costs no more precision than the f32 result has.
pub fn transform_points(matrix: &DMat4, points: &[Vec3], out: &mut [Vec3]) {
    assert_eq!(points.len(), out.len(), "one output per point");
    out.par_chunks_mut(CHUNK).zip(points.par_chunks(CHUNK)).for_each(|(out, points)| {
        for (o, p) in out.iter_mut().zip(points) {
            *o = matrix.transform_point3(p.as_dvec3()).as_vec3();
        }
    });
}

#[cfg(test)]
mod tests {
    use glam::{DQuat, DVec3};

    use super::*;

    #[test]
    fn points_are_moved_by_the_affine_part_in_double_precision() {
        let matrix = DMat4::from_scale_rotation_translation(
            DVec3::new(1.0, 2.0, 0.5),
            DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.8),
            DVec3::new(1.0e5, -3.0, 2.5),
        );
        // More points than one task, so that the chunks meet.
        let points: Vec<Vec3> = (0..20_000).map(|i| Vec3::new(i as f32 * 1e-3, (i % 7) as f32, -(i as f32).sqrt())).collect();
        let mut out = vec![Vec3::NAN; points.len()];
        transform_points(&matrix, &points, &mut out);
        for (p, o) in points.iter().zip(&out) {
            let exact = matrix.transform_point3(p.as_dvec3());
            assert_eq!(*o, exact.as_vec3(), "{p}: rounded once from the double-precision product");
        }
        // The inverse brings them back to within the f32 rounding of the world positions.
        let mut back = vec![Vec3::NAN; points.len()];
        transform_points(&matrix.inverse(), &out, &mut back);
        for (p, b) in points.iter().zip(&back) {
            assert!((*p - *b).length() < 0.05, "{p} came back as {b}");
        }
    }

    #[test]
    fn identity_and_empty_input() {
        let points = [Vec3::new(1.0, -2.0, 3.5), Vec3::new(f32::MAX, f32::MIN_POSITIVE, 0.0)];
        let mut out = [Vec3::ZERO; 2];
        transform_points(&DMat4::IDENTITY, &points, &mut out);
        assert_eq!(out, points);
        transform_points(&DMat4::IDENTITY, &[], &mut []);
    }
}
