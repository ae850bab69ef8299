//! Contacts and convergence (issue 28): the scene of
//! `blender_tests/test_collisions.py`'s sliding sphere (a 2 × 2 grid, a
//! sphere of radius 0.3 pushed 0.15 into it, then slid 0.18 along x).

use glam::Vec3;

use super::{Sequence, StepOptions};
use crate::collide::{Collider, ColliderSettings};
use super::tests::{moved, sphere};
use crate::mesh::shapes::grid;
use crate::pyramid::{Closeness, DeformerOptions, ACCELERATED_ITERATIONS, CONVERGE_TOLERANCE};

fn slide_path() -> Vec<Vec3> {
    let rise: Vec<Vec3> = (0..7).map(|k| Vec3::new(-0.2, 0.0, -0.32 + 0.025 * k as f32)).collect();
    let top = *rise.last().unwrap();
    rise.iter().copied().chain((1..7).map(|k| top + Vec3::X * (0.03 * k as f32))).collect()
}

/// The last frame, the mean x drift of the skin over the sphere's top, and
/// the iterations each frame ran.
fn slide(friction: f32, iterations: usize, accelerated: bool, tolerance: Option<f32>) -> (Vec<Vec3>, f32, Vec<usize>) {
    let skin = grid(40, 40, 2.0);
    let mut sequence = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
    sequence.deformer_mut().set_accelerated(accelerated);
    sequence.deformer_mut().set_tolerance(tolerance).unwrap();
    let (ball, tris) = sphere(0.3);
    let path = slide_path();
    let mut collider = Collider::new(&moved(&ball.positions, path[0]), &tris, ColliderSettings::new(0.01, friction)).unwrap();
    let options = StepOptions::new(iterations, Closeness::Uniform(0.02));
    let mut x = Vec::new();
    let mut its = Vec::new();
    for &at in &path {
        collider.update(&moved(&ball.positions, at)).unwrap();
        x = sequence.step(&skin.positions, &mut [&mut collider], &options).unwrap().0;
        its.push(sequence.deformer_mut().last_iterations());
    }
    let top = *path.last().unwrap();
    let over: Vec<usize> = (0..x.len()).filter(|&v| (x[v].truncate() - top.truncate()).length() < 0.1 && x[v].z > 0.0).collect();
    let drift = over.iter().map(|&v| x[v].x - skin.positions[v].x).sum::<f32>() / over.len().max(1) as f32;
    (x, drift, its)
}

fn rms(a: &[Vec3], b: &[Vec3]) -> f64 {
    (a.iter().zip(b).map(|(p, q)| (*p - *q).as_dvec3().length_squared()).sum::<f64>() / a.len() as f64).sqrt()
}

/// Static friction keeps its drag however many iterations run: a resting
/// contact is held where it rests, not where each iteration's pull crosses
/// the surface (measured from there, plain iterations dragged the skin 0.087
/// after 10, 0.010 after 100 and 0.004 after 1,000: converging lost the drag).
#[test]
fn a_rough_sphere_drags_the_skin_as_far_after_many_iterations_as_after_some() {
    let (_, rough_100, _) = slide(1.0, 100, false, None);
    let (_, rough_300, _) = slide(1.0, 300, false, None);
    let (_, smooth_300, _) = slide(0.0, 300, false, None);
    assert!(rough_100 > 0.02 && rough_300 > 0.02, "drag after 100 iterations {rough_100}, after 300 {rough_300}");
    assert!((rough_100 - rough_300).abs() < 0.2 * rough_300, "drag after 100 iterations {rough_100}, after 300 {rough_300}");
    assert!(smooth_300.abs() < 0.1 * rough_300, "without friction {smooth_300}, with {rough_300}");
}

/// Convergence error of the add-on's Converge with a rough and a smooth
/// sliding sphere, against the same accelerated solve run 400 iterations
/// (issue 28's definition). A measurement, not a check (Converge with
/// contacts does not meet 5 % yet):
/// `cargo test --release -p tegument-core --lib converge_with_a_sliding_sphere -- --ignored --nocapture`.
#[test]
#[ignore]
fn measure_converge_with_a_sliding_sphere() {
    let skin = grid(40, 40, 2.0);
    for friction in [1.0, 0.0] {
        let (reference, reference_drift, _) = slide(friction, 400, true, None);
        for (name, iterations, accelerated, tolerance) in [
            ("plain 10", 10, false, None),
            ("plain 100", 100, false, None),
            ("plain 1000", 1000, false, None),
            ("Converge", ACCELERATED_ITERATIONS, true, Some(CONVERGE_TOLERANCE)),
            ("accelerated 50", 50, true, None),
        ] {
            let (x, drift, its) = slide(friction, iterations, accelerated, tolerance);
            let error = rms(&x, &reference) / rms(&reference, &skin.positions);
            println!("friction {friction} {name}: drift {drift:.4} (accelerated 400: {reference_drift:.4}), error {error:.4}, iterations {its:?}");
        }
    }
}
