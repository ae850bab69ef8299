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
    let frames = slide_path().len();
    let (x, its) = slide_frames(friction, frames, &|_| (iterations, accelerated, tolerance));
    let x = x.last().unwrap().clone();
    let drift = drift_over(&x, *slide_path().last().unwrap());
    (x, drift, its)
}

/// The mean x drift from rest of the skin over the top of the sphere centred at `centre`.
fn drift_over(x: &[Vec3], centre: Vec3) -> f32 {
    let skin = grid(40, 40, 2.0);
    let over: Vec<usize> = (0..x.len()).filter(|&v| (x[v].truncate() - centre.truncate()).length() < 0.1 && x[v].z > 0.0).collect();
    over.iter().map(|&v| x[v].x - skin.positions[v].x).sum::<f32>() / over.len().max(1) as f32
}

/// Solver settings of a frame: iterations, accelerated, tolerance.
type FrameSettings<'a> = dyn Fn(usize) -> (usize, bool, Option<f32>) + 'a;

/// The first `frames` frames of the slide, each solved with `settings(frame)`;
/// every frame's result and iterations.
fn slide_frames(friction: f32, frames: usize, settings: &FrameSettings<'_>) -> (Vec<Vec<Vec3>>, Vec<usize>) {
    let skin = grid(40, 40, 2.0);
    let mut sequence = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
    let (ball, tris) = sphere(0.3);
    let path = slide_path();
    let mut collider = Collider::new(&moved(&ball.positions, path[0]), &tris, ColliderSettings::new(0.01, friction)).unwrap();
    let (mut results, mut its) = (Vec::new(), Vec::new());
    for (frame, &at) in path.iter().enumerate().take(frames) {
        let (iterations, accelerated, tolerance) = settings(frame);
        sequence.deformer_mut().set_accelerated(accelerated);
        sequence.deformer_mut().set_tolerance(tolerance).unwrap();
        collider.update(&moved(&ball.positions, at)).unwrap();
        let options = StepOptions::new(iterations, Closeness::Uniform(0.02));
        results.push(sequence.step(&skin.positions, &mut [&mut collider], &options).unwrap().0);
        its.push(sequence.deformer_mut().last_iterations());
    }
    (results, its)
}

/// Iterations of the reference solve ([`converge_errors`]).
const REFERENCE_ITERATIONS: usize = 1000;

/// Issue 28's convergence error of every frame of Converge's slide, with x_∞
/// defined for a scene with contacts: frame `f`'s result against the same
/// solve continued, i.e. the bake run with Converge up to frame `f − 1` (the
/// same start: warm from Converge's own frames, friction's resting
/// references included) and frame `f` solved by the same accelerated solver
/// from that start without a tolerance for [`REFERENCE_ITERATIONS`]. With
/// static friction the converged shape depends on the path (plain 1,000 and
/// accelerated 400 iterations differ 6.2 %): this is the fixed point of the
/// path Converge itself takes. With contacts the issue's "until positions
/// change by less than 1e-7 of the mesh size per iteration" is not reached,
/// by plain or accelerated iterations: a few vertices at the contact's rim
/// keep flickering in and out (largest step per iteration 1e-4–2e-3 of the
/// mesh size after 1,000 iterations) while the RMS shape is settled (the
/// 500th and 1,000th iterates differ by 0.04–0.2 % of the displacement,
/// frames 6 and 12, friction 0). Returns the errors, Converge's iterations,
/// per frame the reference's largest last step (a fraction of the mesh size;
/// measured only if `with_last_steps`, else 0), the reference's RMS
/// displacement and its drift over the sphere's top (how far static friction
/// dragged the skin).
fn converge_errors(friction: f32, frames: usize, with_last_steps: bool) -> (Vec<f64>, Vec<usize>, Vec<f64>, Vec<f64>, Vec<f32>) {
    let skin = grid(40, 40, 2.0);
    let size = 2.0;
    let converge = |_: usize| (ACCELERATED_ITERATIONS, true, Some(CONVERGE_TOLERANCE));
    let (results, its) = slide_frames(friction, frames, &converge);
    let (mut errors, mut last_steps, mut offsets, mut drifts) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for f in 0..frames {
        let continued = |n: usize| {
            let settings = move |frame: usize| if frame == f { (n, true, None) } else { converge(frame) };
            slide_frames(friction, f + 1, &settings).0.pop().unwrap()
        };
        let reference = continued(REFERENCE_ITERATIONS);
        let last_step = match with_last_steps {
            true => continued(REFERENCE_ITERATIONS + 1).iter().zip(&reference).map(|(p, q)| (*p - *q).length()).fold(0.0f32, f32::max) as f64 / size,
            false => 0.0,
        };
        let offset = rms(&reference, &skin.positions);
        drifts.push(drift_over(&reference, slide_path()[f]));
        errors.push(rms(&results[f], &reference) / offset);
        last_steps.push(last_step);
        offsets.push(offset);
    }
    (errors, its, last_steps, offsets, drifts)
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
/// (issue 28's definition). A measurement, not a check (Converge with a
/// rough sliding contact does not meet 5 % yet):
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

/// Converge's convergence error on every frame of the slide, cold (the
/// first frame) and warm, by issue 28's definition ([`converge_errors`]):
/// `cargo test --release -p tegument-core --lib measure_converge_errors_on_the_slide -- --ignored --nocapture`.
#[test]
#[ignore]
fn measure_converge_errors_on_the_slide() {
    for friction in [0.0, 1.0] {
        let frames = slide_path().len();
        let (errors, its, last_steps, offsets, drifts) = converge_errors(friction, frames, true);
        let drifts: Vec<String> = drifts.iter().map(|d| format!("{d:.4}")).collect();
        println!("friction {friction}: the reference's drift over the sphere per frame {drifts:?}");
        let offsets: Vec<String> = offsets.iter().map(|o| format!("{o:.4}")).collect();
        println!("friction {friction}: RMS displacement per frame {offsets:?}");
        let percent: Vec<String> = errors.iter().map(|e| format!("{:.1}", 100.0 * e)).collect();
        let steps: Vec<String> = last_steps.iter().map(|s| format!("{s:.0e}")).collect();
        println!("friction {friction}: error % per frame {percent:?}, iterations {its:?}, reference's last step {steps:?}");
    }
}



/// Converge on the frictionless slide: every frame in contact within issue
/// 28's 5 % of converged ([`converge_errors`]). The contact patch slides
/// along the sphere, and the correction moves it there: the hook reports the
/// vertices it left sliding and the correction moves them along the surface
/// instead of holding them fixed (before, frames 1, 7, 8, 10 and 12 ended
/// 5.4–6.4 % away).
/// The first frame does not touch the sphere (its displacement is ~0, so
/// its ratio means nothing); frames from the first contact on count.
#[test]
fn converge_keeps_a_frictionless_sliding_contact_within_five_percent_of_converged() {
    let frames = slide_path().len();
    let (errors, its, _, offsets, _) = converge_errors(0.0, frames, false);
    let in_contact: Vec<(usize, f64)> = (0..frames).filter(|&f| offsets[f] > 1e-4).map(|f| (f, errors[f])).collect();
    assert!(in_contact.len() >= frames - 1, "frames in contact: {in_contact:?}, displacements {offsets:?}");
    for &(frame, error) in &in_contact {
        assert!(error <= 0.05, "frame {frame}: {:.1} % from converged (all: {in_contact:?}, iterations {its:?})", 100.0 * error);
    }
}

/// Converge on the rough (friction 1) slide, at its hardest frames: the
/// first contact (frame 1) and the last two of the slide along the sphere
/// (11 and 12), each within issue 28's 5 % of converged, measured as
/// [`converge_errors`] does (against the same path continued to
/// [`REFERENCE_ITERATIONS`] on that frame) but on those frames only, so that
/// it runs in the core suite (the whole slide is
/// `measure_converge_errors_on_the_slide`, ignored).
#[test]
fn converge_keeps_the_rough_slide_within_five_percent_at_its_hardest_frames() {
    let friction = 1.0;
    let skin = grid(40, 40, 2.0);
    let converge = |_: usize| (ACCELERATED_ITERATIONS, true, Some(CONVERGE_TOLERANCE));
    let (results, its) = slide_frames(friction, slide_path().len(), &converge);
    for f in [1, 11, 12] {
        let reference_settings = move |frame: usize| if frame == f { (REFERENCE_ITERATIONS, true, None) } else { converge(frame) };
        let reference = slide_frames(friction, f + 1, &reference_settings).0.pop().unwrap();
        let error = rms(&results[f], &reference) / rms(&reference, &skin.positions);
        assert!(error <= 0.05, "frame {f}: {:.1} % from converged (iterations {its:?})", 100.0 * error);
    }
}
