//! Dynamics, compliant colliders and strain limits through
//! [`Sequence::step`] (seed 000 §4, seed 002).

use glam::Vec3;

use super::{Dynamics, Sequence, StepOptions, StepReport, StrainMode, StrainOptions};
use crate::pyramid::{Closeness, DeformerOptions};
use crate::collide::{audit, AuditParams, Collider, ColliderSettings};
use crate::mesh::shapes::{grid, quad_sphere, PolyMesh};
use crate::mesh::MeshInput;
use crate::strain::MaxStretch;

pub(super) fn moved(points: &[Vec3], by: Vec3) -> Vec<Vec3> {
    points.iter().map(|&p| p + by).collect()
}

fn centroid(points: &[Vec3]) -> Vec3 {
    points.iter().copied().sum::<Vec3>() / points.len() as f32
}

/// A closed quad sphere of `radius` at the origin and its triangles.
pub(super) fn sphere(radius: f32) -> (PolyMesh, Vec<[u32; 3]>) {
    let mesh = quad_sphere(8, radius);
    let offsets: Vec<u32> = std::iter::once(0)
        .chain(mesh.polygon_sizes.iter().scan(0u32, |acc, &s| {
            *acc += s as u32;
            Some(*acc)
        }))
        .collect();
    let triangles = crate::mesh::fan_triangles(&mesh.corner_verts, &offsets);
    (mesh, triangles)
}

fn penetrations(skin: &PolyMesh, x: &[Vec3], colliders: &[&Collider]) -> (usize, usize, usize) {
    let found = audit(MeshInput { positions: x, ..skin.input() }, colliders, &AuditParams::default()).unwrap();
    (found.vertices_inside.len(), found.edges_crossing.len(), found.collider_edges_crossing.len())
}

mod dynamics {
    use super::*;

    fn dynamic(substeps: usize, closeness: f32) -> StepOptions<'static> {
        StepOptions {
            substeps,
            dynamics: Some(Dynamics { frame_time: 1.0 / 24.0, mass: 1.0, damping: 1.0, gravity: Vec3::ZERO }),
            ..StepOptions::new(10, Closeness::Uniform(closeness))
        }
    }

    /// The input slides 0.5 along x over 6 frames and stops; returns the
    /// output centroid's x per frame and the last output.
    fn translate_and_stop(options: &StepOptions<'_>, frames: usize) -> (Vec<f32>, Vec<Vec3>, Vec<StepReport>) {
        let skin = grid(12, 12, 1.0);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        let (mut xs, mut out, mut reports) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..frames {
            let shift = 0.5 * (k.min(6) as f32 / 6.0);
            let input = moved(&skin.positions, Vec3::X * shift);
            let (x, report) = deformer.step(&input, &mut [], options).unwrap();
            assert!(x.iter().all(|p| p.is_finite()));
            xs.push(centroid(&x).x);
            out = x;
            reports.push(report);
        }
        (xs, out, reports)
    }

    #[test]
    fn translated_input_that_stops_is_overshot_then_settles() {
        let (xs, _, _) = translate_and_stop(&dynamic(1, 0.1), 120);
        let peak = xs.iter().copied().fold(f32::MIN, f32::max);
        assert!(peak > 0.5 + 0.02, "no overshoot: peak {peak}");
        // Lags behind while the input moves.
        assert!(xs[3] < 0.5 * 3.0 / 6.0 - 0.01, "no lag: {}", xs[3]);
        let last = *xs.last().unwrap();
        assert!((last - 0.5).abs() < 0.005, "not settled: {last}");
    }

    #[test]
    fn closeness_one_follows_the_input_exactly() {
        let skin = grid(8, 8, 1.0);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        for k in 0..10 {
            let input: Vec<Vec3> = skin.positions.iter().map(|p| *p + Vec3::new(0.1 * k as f32, 0.0, (p.x * k as f32).sin() * 0.1)).collect();
            let (x, _) = deformer.step(&input, &mut [], &dynamic(2, 1.0)).unwrap();
            for (a, b) in x.iter().zip(&input) {
                assert!((*a - *b).length() < 1e-5, "frame {k}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn the_settled_result_does_not_depend_on_substeps() {
        let (_, one, _) = translate_and_stop(&dynamic(1, 0.1), 150);
        let (_, four, _) = translate_and_stop(&dynamic(4, 0.1), 150);
        let worst = one.iter().zip(&four).map(|(a, b)| (*a - *b).length()).fold(0.0, f32::max);
        assert!(worst < 0.01 * 0.5, "1 vs 4 substeps differ by {worst} (motion 0.5)");
    }

    #[test]
    fn without_input_motion_kinetic_energy_does_not_grow() {
        // At rest it stays at rest.
        let skin = grid(8, 8, 1.0);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        for _ in 0..50 {
            let (_, report) = deformer.step(&skin.positions, &mut [], &dynamic(1, 0.1)).unwrap();
            assert!(report.kinetic_energy < 1e-12, "energy from nothing: {}", report.kinetic_energy);
        }
        // Kicked, then still: each swing carries less energy than the last.
        let (_, _, reports) = translate_and_stop(&dynamic(1, 0.1), 120);
        let energy: Vec<f64> = reports.iter().map(|r| r.kinetic_energy).collect();
        let peaks: Vec<f64> =
            (7..energy.len() - 1).filter(|&k| energy[k] > energy[k - 1] && energy[k] >= energy[k + 1]).map(|k| energy[k]).collect();
        assert!(peaks.len() >= 2, "expected oscillation, energies {energy:?}");
        for w in peaks.windows(2) {
            assert!(w[1] <= w[0], "kinetic energy grew from one swing to the next: {peaks:?}");
        }
    }

    #[test]
    fn bad_dynamics_are_named() {
        let skin = grid(4, 4, 1.0);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        let mut options = dynamic(1, 0.1);
        options.dynamics.as_mut().unwrap().mass = 0.0;
        let err = deformer.step(&skin.positions, &mut [], &options).unwrap_err().to_string();
        assert!(err.contains("mass"), "{err}");
        let options = StepOptions { substeps: 0, ..dynamic(1, 0.1) };
        let err = deformer.step(&skin.positions, &mut [], &options).unwrap_err().to_string();
        assert!(err.contains("substeps"), "{err}");
    }
}

mod compliance {
    use super::*;

    struct Result {
        pinched: usize,
        audit: (usize, usize, usize),
        recession: f32,
        skin: Vec<Vec3>,
        arm: Vec<Vec3>,
    }

    /// A flat skin resting on a kinematic "torso" sphere; an "arm" sphere
    /// comes down into it, deeper than the skin over the torso allows.
    fn impossible_collision(stiffness: Option<f32>, substeps: usize) -> Result {
        let skin = grid(30, 30, 1.6);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        let (ball, tris) = sphere(0.3);
        let settings = ColliderSettings::new(0.01, 0.0);
        let mut torso = Collider::new(&moved(&ball.positions, Vec3::new(0.0, 0.0, -0.32)), &tris, settings).unwrap();
        let arm_at = |z: f32| moved(&ball.positions, Vec3::new(0.0, 0.0, z));
        let mut arm = Collider::new(&arm_at(0.5), &tris, settings).unwrap();
        if let Some(k) = stiffness {
            arm.set_compliance(Some(&vec![k; ball.positions.len()])).unwrap();
        }
        let mut pinched = 0;
        let mut x = Vec::new();
        let options = StepOptions { substeps, ..StepOptions::new(10, Closeness::Uniform(0.2)) };
        // Down over 8 frames, then held for 3 (the comparisons are of the settled result).
        for k in 0..=11 {
            let z = 0.5 - 0.05 * k.min(8) as f32;
            arm.update(&arm_at(z)).unwrap();
            let (out, report) = deformer.step(&skin.positions, &mut [&mut torso, &mut arm], &options).unwrap();
            assert!(out.iter().all(|p| p.is_finite()));
            pinched = pinched.max(report.pinched.len());
            x = out;
        }
        let audit = penetrations(&skin, &x, &[&torso, &arm]);
        let recession = arm.current().iter().zip(arm_at(0.1)).map(|(a, b)| (*a - b).length()).fold(0.0, f32::max);
        Result { pinched, audit, recession, skin: x, arm: arm.current().to_vec() }
    }

    #[test]
    fn without_compliance_the_skin_is_pinched() {
        let r = impossible_collision(None, 1);
        assert!(r.pinched > 0, "the arm goes 0.2 into skin held by the torso: someone must be pinched");
    }

    #[test]
    fn a_compliant_arm_recedes_and_leaves_no_penetration() {
        let r = impossible_collision(Some(100.0), 1);
        assert_eq!(r.audit, (0, 0, 0), "penetrations left");
        assert_eq!(r.pinched, 0);
        assert!(r.recession > 0.1, "the arm should have receded by about 0.2: {}", r.recession);
        // A gap on both sides: the arm's lowest point is above the skin over the torso.
        let arm_bottom = r.arm.iter().map(|p| p.z).fold(f32::MAX, f32::min);
        let skin_centre = r.skin.iter().filter(|p| p.truncate().length() < 0.05).map(|p| p.z).fold(f32::MIN, f32::max);
        assert!(arm_bottom > skin_centre, "arm bottom {arm_bottom} below the skin {skin_centre}");
    }

    #[test]
    fn one_and_four_substeps_agree() {
        let one = impossible_collision(Some(100.0), 1);
        let four = impossible_collision(Some(100.0), 4);
        assert_eq!(four.audit, (0, 0, 0));
        let motion = 0.4;
        let skin = one.skin.iter().zip(&four.skin).map(|(a, b)| (*a - *b).length()).fold(0.0, f32::max);
        let arm = one.arm.iter().zip(&four.arm).map(|(a, b)| (*a - *b).length()).fold(0.0, f32::max);
        assert!(skin < 0.01 * motion && arm < 0.01 * motion, "1 vs 4 substeps: skin {skin}, arm {arm}");
    }

    /// A compliant ball pressed 0.1 into a free skin (no torso behind it):
    /// how far the skin's centre gives way and how far the ball recedes.
    fn press_free_skin(stiffness: f32) -> (f32, f32) {
        let skin = grid(30, 30, 1.6);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        let (ball, tris) = sphere(0.3);
        let at = |z: f32| moved(&ball.positions, Vec3::new(0.0, 0.0, z));
        let mut arm = Collider::new(&at(0.5), &tris, ColliderSettings::new(0.01, 0.0)).unwrap();
        arm.set_compliance(Some(&vec![stiffness; ball.positions.len()])).unwrap();
        let mut x = Vec::new();
        for k in 0..=5 {
            arm.update(&at(0.5 - 0.06 * k as f32)).unwrap();
            let options = StepOptions::new(30, Closeness::Uniform(0.2));
            x = deformer.step(&skin.positions, &mut [&mut arm], &options).unwrap().0;
            assert_eq!(penetrations(&skin, &x, &[&arm]), (0, 0, 0), "frame {k}");
        }
        let dent = -x.iter().filter(|p| p.truncate().length() < 0.05).map(|p| p.z).fold(f32::MAX, f32::min);
        let recession = arm.current().iter().zip(at(0.2)).map(|(a, b)| (*a - b).length()).fold(0.0, f32::max);
        (dent, recession)
    }

    #[test]
    fn the_stiffer_collider_dents_the_skin_more_and_recedes_less() {
        let (soft_dent, soft_recession) = press_free_skin(20.0);
        let (stiff_dent, stiff_recession) = press_free_skin(2000.0);
        assert!(soft_dent > 0.0 && soft_recession > 0.0, "both give way: dent {soft_dent}, recession {soft_recession}");
        assert!(stiff_dent > 1.5 * soft_dent, "stiffer should dent more: {stiff_dent} vs {soft_dent}");
        assert!(stiff_recession < soft_recession, "stiffer should recede less: {stiff_recession} vs {soft_recession}");
    }

    /// The same compliant ball pressed into skins of the same spacing, one
    /// four times the other's area: the in-loop passes test the skin near
    /// the ball only, measure their clearance once a frame (the ball stays
    /// inside its envelope), the skin it recedes from is refitted where it
    /// moved, and the larger skin costs them no more of either.
    #[test]
    fn compliant_passes_test_the_contact_region_not_the_whole_skin() {
        let tested = |cells: usize, size: f32| {
            let skin = grid(cells, cells, size);
            let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
            let (ball, tris) = sphere(0.3);
            let at = |z: f32| moved(&ball.positions, Vec3::new(0.0, 0.0, z));
            let mut arm = Collider::new(&at(0.5), &tris, ColliderSettings::new(0.01, 0.0)).unwrap();
            arm.set_compliance(Some(&vec![100.0; ball.positions.len()])).unwrap();
            let (mut tested, mut measurements, mut recession, mut refits) = (0, 0, 0.0f32, 0);
            for k in 0..=5 {
                arm.update(&at(0.5 - 0.06 * k as f32)).unwrap();
                let (x, report) = deformer.step(&skin.positions, &mut [&mut arm], &StepOptions::new(10, Closeness::Uniform(0.2))).unwrap();
                assert_eq!(penetrations(&skin, &x, &[&arm]), (0, 0, 0), "{cells}² skin, frame {k}");
                assert!(report.pinched.is_empty());
                tested += report.in_loop_tested;
                refits += report.in_loop_skin_refits;
                measurements += report.clearance_measurements;
                recession = report.max_recession;
            }
            (skin.positions.len(), tested, measurements, recession, refits)
        };
        let (small_n, small, small_measured, small_recession, small_refits) = tested(30, 1.6);
        let (large_n, large, large_measured, large_recession, large_refits) = tested(60, 3.2);
        assert!(large_n > 3 * small_n);
        assert!(small_recession > 0.01 && (large_recession - small_recession).abs() < 0.1 * small_recession, "recession {small_recession} / {large_recession}");
        assert!(small > 0, "the passes tested nothing near the ball");
        assert!(large as f64 <= 1.25 * small as f64, "in-loop tests grew with the skin: {small} on {small_n} vertices, {large} on {large_n}");
        // 6 frames of 10 passes: on average under a tenth of the skin a pass.
        let passes = 60;
        assert!(large < passes * large_n / 10, "the in-loop passes tested most of the skin: {large} tests over {passes} passes, {large_n} vertices");
        assert!(small_measured <= 12 && large_measured <= 12, "clearances measured: {small_measured} / {large_measured} over 6 frames");
        // The skin the ball recedes from is refitted where it moved only.
        assert!(small_refits > 0, "the skin never moved under the ball");
        assert!(large_refits as f64 <= 1.25 * small_refits as f64, "skin refits grew with the skin: {small_refits} on {small_n} vertices, {large_refits} on {large_n}");
        assert!(large_refits < passes * large_n / 10, "most of the skin was refitted after each iteration: {large_refits} refits over {passes} passes, {large_n} vertices");
    }

    /// One frame of [`skin_sliding_under_a_resting_ball`]: the step's
    /// report and the iterations its solve ran.
    struct SlideFrame {
        report: StepReport,
        ran: usize,
    }

    /// A compliant ball comes to rest in a free skin, whose input then rises
    /// into it (frames 5–9, by 0.1) and slides under it (from frame 6, by
    /// up to 0.15) while the ball's animation holds still; with a count of
    /// `iterations`, or that as Converge's limit. Asserts in every frame: no
    /// penetration (by the audit, which shares no geometry with the
    /// passes), nothing pinched.
    fn skin_sliding_under_a_resting_ball(iterations: usize, converge: bool) -> Vec<SlideFrame> {
        let skin = grid(30, 30, 1.6);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        deformer.deformer_mut().set_accelerated(converge);
        deformer.deformer_mut().set_tolerance(converge.then_some(crate::pyramid::CONVERGE_TOLERANCE)).unwrap();
        let (ball, tris) = sphere(0.3);
        let at = |z: f32| moved(&ball.positions, Vec3::new(0.0, 0.0, z));
        let mut arm = Collider::new(&at(0.5), &tris, ColliderSettings::new(0.01, 0.3)).unwrap();
        arm.set_compliance(Some(&vec![100.0; ball.positions.len()])).unwrap();
        let options = StepOptions::new(iterations, Closeness::Uniform(0.3));
        let mut frames = Vec::new();
        for k in 0..=10usize {
            arm.update(&at(0.5 - 0.06 * k.min(4) as f32)).unwrap();
            let lift = 0.02 * k.saturating_sub(4).min(5) as f32;
            let slide = 0.03 * k.saturating_sub(5) as f32;
            let input = moved(&skin.positions, Vec3::new(slide, 0.0, lift));
            let (x, report) = deformer.step(&input, &mut [&mut arm], &options).unwrap();
            assert!(x.iter().all(|p| p.is_finite()), "frame {k}");
            assert_eq!(penetrations(&skin, &x, &[&arm]), (0, 0, 0), "frame {k} (converge: {converge})");
            assert!(report.pinched.is_empty(), "frame {k}: {} pinched (converge: {converge})", report.pinched.len());
            frames.push(SlideFrame { report, ran: deformer.deformer().last_iterations() });
        }
        frames
    }

    /// A compliant ball pressed into a free skin rests on it; then the
    /// skin's input rises into the ball and slides sideways under it while
    /// the ball's animation holds still. Every third iteration the ball's
    /// resting vertices recede from where the skin has moved: the skin is never
    /// passed through (by the audit, which shares no geometry with the
    /// passes), the ball keeps receding as the skin comes up, and nothing
    /// is pinched.
    #[test]
    fn a_skin_moving_under_a_resting_compliant_ball_is_never_passed_through() {
        let frames = skin_sliding_under_a_resting_ball(10, false);
        let recessions: Vec<f32> = frames.iter().map(|f| f.report.max_recession).collect();
        assert!(recessions[4] > 0.01, "the ball rests in the skin: recession {}", recessions[4]);
        assert!(recessions[9] > recessions[4] + 0.02, "the skin came up 0.1 into the ball, which should recede: {recessions:?}");
    }

    /// Issue 29: compliant colliders recede in the solve after every third
    /// iteration, counted back from the last, which always recedes (the
    /// contact pass still runs after every one, so no iteration leaves the
    /// skin inside): with a count of 10, 4 recessions a frame, after
    /// iterations 1, 4, 7 and 10 (10 when they receded after every
    /// iteration, 5 after every other). With Converge the stopping rule ends
    /// the solve and the last iteration's recession runs in the closing
    /// iteration that follows it: at most one more than a third of the
    /// iterations the solve ran.
    #[test]
    fn compliant_colliders_recede_after_every_third_iteration() {
        let counted = skin_sliding_under_a_resting_ball(10, false);
        let recessions: Vec<usize> = counted.iter().map(|f| f.report.in_loop_recessions).collect();
        assert!(recessions.iter().all(|&r| r == 4), "recessions per frame with 10 iterations: {recessions:?}");
        assert!(counted[9].report.max_recession > counted[4].report.max_recession + 0.02, "the skin came up 0.1 into the ball, which should recede");

        let converged = skin_sliding_under_a_resting_ball(40, true);
        let ran: Vec<usize> = converged.iter().map(|f| f.ran).collect();
        let recessions: Vec<usize> = converged.iter().map(|f| f.report.in_loop_recessions).collect();
        println!("Converge: iterations per frame {ran:?}, recessions {recessions:?}");
        assert!(ran.iter().any(|&r| r + 3 < 40), "no solve stopped before its limit, so this tests nothing: {ran:?}");
        for (f, frame) in converged.iter().enumerate() {
            let r = frame.report.in_loop_recessions;
            assert!(r >= 1 && r <= frame.ran / 3 + 1, "frame {f}: {r} recessions in {} iterations (all: {recessions:?}, iterations {ran:?})", frame.ran);
        }
        assert!(converged[9].report.max_recession > converged[4].report.max_recession + 0.02, "the skin came up 0.1 into the ball, which should recede");
    }

    #[test]
    fn bad_stiffness_is_named() {
        let (ball, tris) = sphere(0.3);
        let mut arm = Collider::new(&ball.positions, &tris, ColliderSettings::new(0.0, 0.0)).unwrap();
        let mut k = vec![1.0; ball.positions.len()];
        k[3] = f32::NAN;
        let err = arm.set_compliance(Some(&k)).unwrap_err().to_string();
        assert!(err.contains("vertex 3"), "{err}");
        let err = arm.set_compliance(Some(&[1.0])).unwrap_err().to_string();
        assert!(err.contains("values"), "{err}");
    }
}

mod strain {
    use super::*;

    /// A sphere pressed into the skin with high friction, then dragged
    /// sideways: the skin it holds stretches the edges around it.
    fn drag(strain: Option<StrainOptions<'_>>) -> (StepReport, (usize, usize, usize), f32) {
        drag_frames(strain, 10).pop().expect("the drag has frames")
    }

    /// [`drag`] with this many solve iterations, every frame's report, audit
    /// and worst stretch.
    fn drag_frames(strain: Option<StrainOptions<'_>>, iterations: usize) -> Vec<(StepReport, (usize, usize, usize), f32)> {
        drag_frames_solved(strain, iterations, false).into_iter().map(|(frame, _)| frame).collect()
    }

    /// [`drag_frames`] with Converge (the accelerated solver with its
    /// stopping rule) or plain iterations, and the iterations each frame ran.
    fn drag_frames_solved(
        strain: Option<StrainOptions<'_>>,
        iterations: usize,
        converge: bool,
    ) -> Vec<((StepReport, (usize, usize, usize), f32), usize)> {
        let skin = grid(40, 40, 2.0);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        deformer.deformer_mut().set_accelerated(converge);
        deformer.deformer_mut().set_tolerance(converge.then_some(crate::pyramid::CONVERGE_TOLERANCE)).unwrap();
        let (ball, tris) = sphere(0.3);
        let settings = ColliderSettings::new(0.01, 2.0);
        let start = Vec3::new(-0.3, 0.0, -0.32);
        let mut path: Vec<Vec3> = (0..=5).map(|k| start + Vec3::Z * (0.03 * k as f32)).collect();
        let top = *path.last().unwrap();
        path.extend((1..=8).map(|k| top + Vec3::X * (0.05 * k as f32)));
        let mut ball_collider = Collider::new(&moved(&ball.positions, start), &tris, settings).unwrap();
        let options = StepOptions { strain, ..StepOptions::new(iterations, Closeness::Uniform(0.5)) };
        let mut frames = Vec::new();
        let limits = crate::strain::EdgeLimits::new(&polygon_edges(&skin), &skin.positions, MaxStretch::Uniform(0.0)).unwrap();
        for at in path {
            ball_collider.update(&moved(&ball.positions, at)).unwrap();
            let (x, report) = deformer.step(&skin.positions, &mut [&mut ball_collider], &options).unwrap();
            let audit = penetrations(&skin, &x, &[&ball_collider]);
            let stretch = limits.worst_stretch(&x);
            if strain.is_some_and(|s| s.mode == StrainMode::Unified) {
                assert_eq!(audit, (0, 0, 0), "unified strain limiting left penetrations");
            }
            frames.push(((report, audit, stretch), deformer.deformer().last_iterations()));
        }
        frames
    }

    pub(super) fn polygon_edges(skin: &PolyMesh) -> Vec<[u32; 2]> {
        let offsets: Vec<u32> = (0..=skin.polygon_sizes.len() as u32).map(|k| 4 * k).collect();
        crate::mesh::polygon_edges(&skin.corner_verts, &offsets)
    }

    const EPS: f32 = 0.1;

    #[test]
    fn the_drag_stretches_edges_past_the_limit_without_one() {
        let (_, audit, stretch) = drag(None);
        assert_eq!(audit, (0, 0, 0));
        assert!(stretch > 1.0 + EPS * 1.5, "the scenario should stretch edges: {stretch}");
    }

    #[test]
    fn unified_strain_limits_hold_with_no_penetration() {
        let strain = StrainOptions { max_stretch: MaxStretch::Uniform(EPS), mode: StrainMode::Unified };
        let (report, audit, stretch) = drag(Some(strain));
        assert_eq!(audit, (0, 0, 0));
        assert!(stretch <= (1.0 + EPS) * 1.01, "edge stretched to {stretch}");
        assert!((report.worst_stretch - stretch).abs() < 1e-5);
    }

    /// Issue 29: early strain rounds run only in the few iterations just
    /// before the last; an earlier iteration's would be undone by the solve
    /// iterations after it, which pull the skin back over its limits. So
    /// with 30 iterations a frame runs no more rounds than with 10 may (with
    /// 2 in each of the 29 earlier iterations this drag ran up to 60), and
    /// every frame still holds the limits.
    #[test]
    fn only_the_iterations_before_the_last_run_early_strain_rounds() {
        use super::super::strain_pass::{STRAIN_ROUNDS, STRAIN_ROUNDS_EARLY};
        let strain = StrainOptions { max_stretch: MaxStretch::Uniform(EPS), mode: StrainMode::Unified };
        let frames = drag_frames(Some(strain), 30);
        let rounds: Vec<usize> = frames.iter().map(|(report, _, _)| report.contact_work.strain_rounds).collect();
        assert!(rounds.iter().any(|&r| r > 0), "the drag should need strain rounds: {rounds:?}");
        // The last iteration's rounds and those of the two before it.
        let most = STRAIN_ROUNDS + 2 * STRAIN_ROUNDS_EARLY;
        assert!(rounds.iter().all(|&r| r <= most), "strain rounds per frame: {rounds:?}");
        let worst: Vec<f32> = frames.iter().map(|&(_, _, stretch)| stretch).collect();
        assert!(worst.iter().all(|&w| w <= (1.0 + EPS) * 1.01), "worst stretch per frame: {worst:?}");
    }

    /// The drag limited to `EPS` with Converge and a count of `iterations`:
    /// per frame the iterations the solve ran, the strain rounds and the
    /// worst stretch.
    fn converge_drag(iterations: usize) -> (Vec<usize>, Vec<usize>, Vec<f32>) {
        let strain = StrainOptions { max_stretch: MaxStretch::Uniform(EPS), mode: StrainMode::Unified };
        let frames = drag_frames_solved(Some(strain), iterations, true);
        let ran = frames.iter().map(|&(_, ran)| ran).collect();
        let rounds = frames.iter().map(|((report, _, _), _)| report.contact_work.strain_rounds).collect();
        let worst = frames.iter().map(|&((_, _, stretch), _)| stretch).collect();
        (ran, rounds, worst)
    }

    /// With Converge a solve stops by its rule, before or after its
    /// iteration count (the count is a limit counted in work on small
    /// meshes: 24 here); the strain rounds run where it stops (the solver
    /// tells the hook, `solve::Iteration`). Frames ran 2, 4, 11, 24, 16, 16,
    /// 24 … iterations when the rounds were tied to the count; the two tests
    /// below catch what that broke.
    #[test]
    fn unified_strain_limits_hold_when_converge_stops_the_solve_early() {
        let iterations = crate::pyramid::ACCELERATED_ITERATIONS;
        let (ran, _, worst) = converge_drag(iterations);
        assert!(ran.iter().any(|&r| r < iterations), "no frame stopped early, so this tests nothing: {ran:?}");
        assert!(worst.iter().all(|&w| w <= (1.0 + EPS) * 1.01), "worst stretch per frame: {worst:?} (iterations {ran:?})");
    }

    /// Issue 29: with Converge the stopping rule, not the iteration count,
    /// ends the solve, and the strain rounds must run in the iterations that
    /// end it. With a count of 40, rounds tied to the count ran in none of
    /// the frames whose solves stopped after 25, 20 and 5 iterations, which
    /// left edges at 1.35–1.46× their rest length (limit 1.1). Since the
    /// rounds' iterations follow where the rule is met: every frame within
    /// 1.108, 4–6 rounds a frame.
    #[test]
    fn unified_strain_limits_hold_when_converge_stops_long_before_the_count() {
        let iterations = 40;
        let (ran, rounds, worst) = converge_drag(iterations);
        println!("iterations per frame {ran:?}, strain rounds {rounds:?}, worst stretch {worst:?}");
        assert!(ran.iter().any(|&r| r + 3 < iterations), "no solve stopped before the count's last iterations, so this tests nothing: {ran:?}");
        assert!(worst.iter().all(|&w| w <= (1.0 + EPS) * 1.01), "worst stretch per frame: {worst:?} (iterations {ran:?})");
    }

    /// Issue 29: with Converge on a small mesh the count is a limit in work
    /// (24 iterations here for a count of 12), so a solve may run past the
    /// count. The full strain rounds belong to the iteration that ends the
    /// solve, not to every iteration past the count: a frame runs at most
    /// the last iteration's rounds and the early rounds of the two before it.
    /// With them tied to the count, frames that ran 24 iterations ran 23–30
    /// rounds; since, 4–6.
    #[test]
    fn a_converge_solve_past_its_count_runs_the_full_strain_rounds_once() {
        use super::super::strain_pass::{STRAIN_EARLY_ITERATIONS, STRAIN_ROUNDS, STRAIN_ROUNDS_EARLY};
        let iterations = crate::pyramid::ACCELERATED_ITERATIONS;
        let (ran, rounds, worst) = converge_drag(iterations);
        println!("iterations per frame {ran:?}, strain rounds {rounds:?}, worst stretch {worst:?}");
        assert!(ran.iter().any(|&r| r > iterations), "no solve ran past its count, so this tests nothing: {ran:?}");
        let most = STRAIN_ROUNDS + STRAIN_EARLY_ITERATIONS * STRAIN_ROUNDS_EARLY;
        assert!(rounds.iter().all(|&r| r <= most), "strain rounds per frame: {rounds:?} (iterations {ran:?}; at most {most})");
        assert!(worst.iter().all(|&w| w <= (1.0 + EPS) * 1.01), "worst stretch per frame: {worst:?} (iterations {ran:?})");
    }

    #[test]
    fn post_strain_limits_hold_but_leave_penetrations() {
        let strain = StrainOptions { max_stretch: MaxStretch::Uniform(EPS), mode: StrainMode::Post };
        let (_, audit, stretch) = drag(Some(strain));
        assert!(stretch <= (1.0 + EPS) * 1.01, "edge stretched to {stretch}");
        assert!(audit.0 + audit.1 + audit.2 > 0, "post-collision limiting left no penetration: {audit:?}");
    }
}

/// Issue 29: a strain-limited skin under a rough collider must slide
/// rather than stretch. A 61 × 61 sheet held at its border (closeness 1), a
/// friction-1 sphere pressed 0.15 into it and dragged 0.6 sideways, edges
/// limited to 1.1 × their rest length (`UNIFIED`): every frame within
/// `(1 + ε)·1.01` and without penetration, and the skin that touched the
/// sphere when the drag began stays behind it: the sphere slides over it.
///
/// Measured (16 sweeps a strain round, the rounds stopping once every edge
/// is within 0.9 % of its limit): the worst edge is 1.1000–1.1095 × its
/// rest length in the frames of the press and the drag (1.1003–1.1017 while
/// the rounds ran on towards 0.1 %; 1.25 before the strain rounds resolved
/// their moves without friction and against contact planes), with no
/// penetration; the skin under the sphere at the start of the drag moves at
/// most 0.028 along the drag (mean; 0.008 at the end) while the sphere moves
/// 0.6.
#[test]
fn a_held_sheet_dragged_by_a_rough_sphere_slides_within_its_strain_limit() {
    let skin = grid(60, 60, 2.0);
    let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
    let border: Vec<f32> = skin.positions.iter().map(|p| if p.x.abs() > 0.999 || p.y.abs() > 0.999 { 1.0 } else { 0.05 }).collect();
    let (ball, tris) = sphere(0.3);
    let pressed = 5;
    let path: Vec<Vec3> = (0..=pressed)
        .map(|k| Vec3::new(-0.3, 0.0, 0.5 - 0.07 * k as f32))
        .chain((1..=12).map(|k| Vec3::new(-0.3 + 0.05 * k as f32, 0.0, 0.15)))
        .collect();
    let mut collider = Collider::new(&moved(&ball.positions, path[0]), &tris, ColliderSettings::new(0.01, 1.0)).unwrap();
    const EPS: f32 = 0.1;
    let options = StepOptions {
        strain: Some(StrainOptions { max_stretch: MaxStretch::Uniform(EPS), mode: StrainMode::Unified }),
        ..StepOptions::new(10, Closeness::PerVertex(&border))
    };
    let limits = crate::strain::EdgeLimits::new(&strain::polygon_edges(&skin), &skin.positions, MaxStretch::Uniform(0.0)).unwrap();
    let mut worst = Vec::new();
    // The skin touching the sphere when the drag begins, and where it was.
    let mut touching: Vec<(usize, Vec3)> = Vec::new();
    let mut drift = Vec::new();
    for (frame, at) in path.iter().enumerate() {
        collider.update(&moved(&ball.positions, *at)).unwrap();
        let (x, _) = deformer.step(&skin.positions, &mut [&mut collider], &options).unwrap();
        assert_eq!(penetrations(&skin, &x, &[&collider]), (0, 0, 0), "frame {frame}");
        worst.push(limits.worst_stretch(&x));
        if frame == pressed {
            touching = (0..x.len()).filter(|&i| (x[i] - *at).length() < 0.3 + 0.03).map(|i| (i, x[i])).collect();
        } else if frame > pressed {
            let mean = touching.iter().map(|&(i, p)| x[i].x - p.x).sum::<f32>() / touching.len() as f32;
            drift.push((mean, at.x - path[pressed].x));
        }
    }
    assert!(worst.iter().all(|&w| w <= (1.0 + EPS) * 1.01), "worst stretch per frame: {worst:?}");
    assert!(touching.len() > 20, "the sphere touched only {} vertices", touching.len());
    // The skin it pressed lags behind the sphere in every frame, and at the
    // end has gone a small fraction of the way.
    assert!(
        drift.iter().all(|&(skin, sphere)| skin.abs() < 0.5 * sphere),
        "mean drift of the pressed skin against the sphere's, per frame of the drag: {drift:?}"
    );
    let (last, sphere) = *drift.last().unwrap();
    assert!(last.abs() < 0.05 * sphere, "the pressed skin went {last} of the sphere's {sphere}");
}

/// Issue 29: strain limits cap static friction. The flesh benchmark's scene
/// at a quarter of its vertices (a 160 × 160 sheet of side 1 at closeness
/// 0.1, the benchmark's cell size; a sphere of radius 0.15 rising into it
/// and sliding sideways, static friction 0.4, kinetic 0.3; edges limited to
/// 1.1 × their rest length, `UNIFIED`). A vertex static friction holds is
/// anchored where it stuck; where its anchor holds an edge past the limit it
/// is let go before the strain rounds, which slide it, and the next pass
/// holds it where they left it. Without that, each pass put such vertices
/// back at their anchors, undoing the rounds' slide: frame 10 ran out of
/// rounds (20, every round of the last iteration and the two before it) and
/// ended at 1.121 × the rest length, past the promise (1.111). With it, every
/// frame is within 1.109 in at most 13 rounds. A weak guard: without the cap
/// this scene fails only in frame 10, and a path one bit different (`-0.32`
/// for `-0.3 - 0.02`) held the promise without the cap too; the benchmark's
/// 100k-vertex scene shows the cap's effect in every run (docs/performance.md).
#[test]
fn static_friction_holds_the_skin_only_as_far_as_its_strain_limits_allow() {
    use super::strain_pass::{STRAIN_EARLY_ITERATIONS, STRAIN_ROUNDS, STRAIN_ROUNDS_EARLY};
    let skin = grid(160, 160, 1.0);
    let ball = quad_sphere(20, 0.15);
    let tris = crate::mesh::fan_triangles(&ball.corner_verts, &ball.input().validate().unwrap());
    // The benchmark's path, at half the size, written as the benchmark
    // writes it: the outcome without the cap hangs on the last bit (with
    // `-0.32` for `-0.3 - 0.02` it held the promise even without the cap).
    let centre = |k: usize| {
        let k = k as f32;
        0.5 * Vec3::new(-0.3 + 0.04 * (k - 6.0).max(0.0), 0.05, -0.3 - 0.02 + 0.03 * k.min(6.0))
    };
    let settings = ColliderSettings { thickness: 0.0025, static_friction: 0.4, kinetic_friction: 0.3 };
    let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
    let mut collider = Collider::new(&moved(&ball.positions, centre(0)), &tris, settings).unwrap();
    const EPS: f32 = 0.1;
    let options = StepOptions {
        strain: Some(StrainOptions { max_stretch: MaxStretch::Uniform(EPS), mode: StrainMode::Unified }),
        ..StepOptions::new(10, Closeness::Uniform(0.1))
    };
    let limits = crate::strain::EdgeLimits::new(&strain::polygon_edges(&skin), &skin.positions, MaxStretch::Uniform(0.0)).unwrap();
    let (mut rounds, mut worst) = (Vec::new(), Vec::new());
    for k in 1..=10 {
        collider.update(&moved(&ball.positions, centre(k))).unwrap();
        let (x, report) = deformer.step(&skin.positions, &mut [&mut collider], &options).unwrap();
        assert_eq!(penetrations(&skin, &x, &[&collider]), (0, 0, 0), "frame {k}");
        rounds.push(report.contact_work.strain_rounds);
        worst.push(limits.worst_stretch(&x));
    }
    assert!(worst.iter().all(|&w| w <= (1.0 + EPS) * 1.01), "worst stretch per frame: {worst:?} (strain rounds {rounds:?})");
    // No frame runs out of rounds: each ends its last pass with the limits held.
    let all = STRAIN_ROUNDS + STRAIN_EARLY_ITERATIONS * STRAIN_ROUNDS_EARLY;
    assert!(rounds.iter().all(|&r| r < all), "strain rounds per frame: {rounds:?} (all of them: {all})");
}

mod carried_planes {
    use super::*;

    /// A sphere rising into the skin carries it along. Each frame's first
    /// pass moves the last frame's in-loop planes along with the sphere, but
    /// only while the sphere starts where, and as, they met it: a thicker
    /// collider, one put back elsewhere, or other triangles at the same
    /// positions get fresh ones. The skin never gets inside.
    #[test]
    fn last_frames_planes_are_carried_only_while_the_colliders_start_where_they_met_them() {
        let skin = grid(30, 30, 2.0);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        let (ball, tris) = sphere(0.3);
        let at = |k: usize| moved(&ball.positions, Vec3::new(0.0, 0.0, -0.32 + 0.03 * k as f32));
        let mut c = Collider::new(&at(0), &tris, ColliderSettings::new(0.01, 0.3)).unwrap();
        let options = StepOptions::new(10, Closeness::Uniform(0.05));
        let step = |deformer: &mut Sequence, c: &mut Collider| {
            let (x, report) = deformer.step(&skin.positions, &mut [c], &options).unwrap();
            assert_eq!(penetrations(&skin, &x, &[c]), (0, 0, 0));
            report
        };
        for k in 1..=5 {
            c.update(&at(k)).unwrap();
            let carried = deformer.carried_planes.as_ref().is_some_and(|p| p.fits(&[&mut c]));
            assert_eq!(carried, k > 1, "frame {k}");
            let report = step(&mut deformer, &mut c);
            if k > 2 {
                assert!(report.first_pass.plane_lifts > 0, "frame {k}: the first pass lifted nothing along planes");
            }
        }
        c.set_settings(ColliderSettings::new(0.02, 0.3)).unwrap();
        c.update(&at(6)).unwrap();
        assert!(!deformer.carried_planes.as_ref().unwrap().fits(&[&mut c]), "a thicker collider");
        step(&mut deformer, &mut c);
        c.set_positions(&at(4), &at(5)).unwrap();
        assert!(!deformer.carried_planes.as_ref().unwrap().fits(&[&mut c]), "a collider put back");
        step(&mut deformer, &mut c);
        // Where the sphere stands now, as a new collider: the same one fits,
        // one with other triangles (here half of them) does not.
        let settings = c.settings();
        let mut same = Collider::new(&at(5), &tris, settings).unwrap();
        let mut half = Collider::new(&at(5), &tris[..tris.len() / 2], settings).unwrap();
        same.update(&at(6)).unwrap();
        half.update(&at(6)).unwrap();
        let carried = deformer.carried_planes.as_ref().unwrap();
        assert!(carried.fits(&[&mut same]), "the same collider");
        assert!(!carried.fits(&[&mut half]), "other triangles at the same positions");
    }
}

/// Issue 29, "pinched means pinched": a ball that jumps into a closed skin
/// within one frame and rests there. The skin wraps a pocket around it and
/// keeps it: where the in-loop rounds cannot clear a vertex of the resting
/// ball, it goes back to where the pass started (clear of it) instead of
/// being left pinched, soft, to slip through.
mod resting_pocket {
    use super::*;

    #[test]
    fn a_ball_resting_inside_a_closed_skin_keeps_its_pocket_and_pinches_nothing() {
        let skin = quad_sphere(24, 1.0);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        let (ball, tris) = sphere(0.35);
        let at = |x: f32| moved(&ball.positions, Vec3::new(x, 0.0, 0.0));
        let mut collider = Collider::new(&at(1.8), &tris, ColliderSettings::new(0.005, 0.3)).unwrap();
        let options = StepOptions::new(10, Closeness::Uniform(0.05));
        let mut held = 0;
        for frame in 0..24 {
            collider.update(&at(if frame < 2 { 1.8 } else { 0.45 })).unwrap();
            let (x, report) = deformer.step(&skin.positions, &mut [&mut collider], &options).unwrap();
            assert_eq!(report.pinched, Vec::<u32>::new(), "frame {frame}: nothing pinches the skin");
            assert_eq!(penetrations(&skin, &x, &[&collider]), (0, 0, 0), "frame {frame}");
            if frame >= 2 {
                // The ball's centre is inside the rest sphere: the skin keeps it out of its volume.
                let nearest = x.iter().map(|p| p.length()).fold(f32::MAX, f32::min);
                assert!(nearest < 0.45, "frame {frame}: no pocket (nearest vertex {nearest} from the centre)");
            }
            held += report.held;
        }
        assert!(held > 0, "the scene must exercise holding back (else it tests nothing new)");
    }
}

/// Issue 28 through the stepper: a bake with the accelerated solver and the
/// add-on's Converge settings (its tolerance, its iteration limit) delivers
/// the converged look from its first frame on, and more iterations change it
/// by little.
mod convergence {
    use super::*;
    use crate::mesh::shapes::cylinder;
    use crate::pyramid::{PyramidDeformer, ACCELERATED_ITERATIONS, CONVERGE_TOLERANCE};

    fn rms(a: &[Vec3], b: &[Vec3]) -> f64 {
        (a.iter().zip(b).map(|(p, q)| (*p - *q).as_dvec3().length_squared()).sum::<f64>() / a.len() as f64).sqrt()
    }

    /// The upper half of a tube bent about x by `angle`, blended over its middle.
    fn bent(mesh: &PolyMesh, angle: f32) -> Vec<Vec3> {
        let turn = glam::Mat3::from_rotation_x(angle) * glam::Mat3::from_rotation_z(angle * 0.5);
        let pivot = Vec3::new(0.0, 0.0, 2.0);
        mesh.positions
            .iter()
            .map(|&p| {
                let t = ((p.z - 1.6) / 0.8).clamp(0.0, 1.0);
                let w = t * t * (3.0 - 2.0 * t);
                p * (1.0 - w) + (turn * (p - pivot) + pivot) * w
            })
            .collect()
    }

    /// Frames of a bend growing to 100°, baked at `iterations` (with the
    /// Converge tolerance: at most that many), and the iterations each took.
    fn bake(mesh: &PolyMesh, frames: &[Vec<Vec3>], iterations: usize, closeness: f32, tolerance: Option<f32>) -> (Vec<Vec<Vec3>>, Vec<usize>) {
        let mut sequence = Sequence::bind(mesh.input(), DeformerOptions::default()).unwrap();
        sequence.deformer_mut().set_accelerated(true);
        sequence.deformer_mut().set_tolerance(tolerance).unwrap();
        let options = StepOptions::new(iterations, Closeness::Uniform(closeness));
        frames
            .iter()
            .map(|input| (sequence.step(input, &mut [], &options).unwrap().0, sequence.deformer_mut().last_iterations()))
            .unzip()
    }

    fn frames(mesh: &PolyMesh) -> Vec<Vec<Vec3>> {
        (1..=6).map(|k| bent(mesh, (100.0 * k as f32 / 6.0).to_radians())).collect()
    }

    #[test]
    fn an_accelerated_bake_is_within_five_percent_of_the_converged_solve_in_every_frame() {
        let mesh = cylinder(48, 60, 0.5, 4.0);
        let frames = frames(&mesh);
        let default = ACCELERATED_ITERATIONS;
        for closeness in [0.05, 0.01] {
            let (baked, iterations) = bake(&mesh, &frames, default, closeness, Some(CONVERGE_TOLERANCE));
            let mut reference = PyramidDeformer::bind(mesh.input(), DeformerOptions::default()).unwrap();
            for (k, (input, x)) in frames.iter().zip(&baked).enumerate() {
                let converged = reference.solve(input, 1000, Closeness::Uniform(closeness)).unwrap();
                let error = rms(x, &converged) / rms(&converged, input);
                println!("closeness {closeness} frame {k}: {error:.4} in {} iterations", iterations[k]);
                // Frame 0 is cold (from the input), the others warm.
                assert!(error <= 0.05, "closeness {closeness}, frame {k}: convergence error {error:.4} after {} iterations", iterations[k]);
            }
            // The tolerance stopped the warm frames early: that is what makes Converge affordable.
            assert!(iterations[1..].iter().all(|&k| k < default), "closeness {closeness}: iterations {iterations:?}");
        }
    }

    #[test]
    fn accelerated_bakes_beyond_their_iteration_count_differ_by_at_most_five_percent() {
        let mesh = cylinder(48, 60, 0.5, 4.0);
        let frames = frames(&mesh);
        let default = ACCELERATED_ITERATIONS;
        for closeness in [0.05, 0.01] {
            let (baked, _) = bake(&mesh, &frames, default, closeness, Some(CONVERGE_TOLERANCE));
            // More iterations, run to their count.
            for more in [2 * default, 4 * default, 10 * default] {
                let (other, _) = bake(&mesh, &frames, more, closeness, None);
                for (k, ((a, b), input)) in baked.iter().zip(&other).zip(&frames).enumerate() {
                    let difference = rms(a, b) / rms(b, input);
                    assert!(difference <= 0.05, "closeness {closeness}, frame {k}: {default} and {more} iterations differ by {difference:.4}");
                }
            }
        }
    }

    #[test]
    fn warm_frames_start_from_the_last_solution() {
        // A still input baked twice: the second frame starts where the first
        // ended, so one iteration leaves it (almost) where it was.
        let mesh = cylinder(48, 60, 0.5, 4.0);
        let input = bent(&mesh, 1.2);
        let mut sequence = Sequence::bind(mesh.input(), DeformerOptions::default()).unwrap();
        let (first, _) = sequence.step(&input, &mut [], &StepOptions::new(200, Closeness::Default)).unwrap();
        let (second, _) = sequence.step(&input, &mut [], &StepOptions::new(1, Closeness::Default)).unwrap();
        let scale = rms(&first, &input);
        assert!(rms(&second, &first) < 1e-3 * scale, "the warm frame moved {} of the displacement", rms(&second, &first) / scale);
        // After a reset the frame starts cold again.
        sequence.reset();
        let (cold, _) = sequence.step(&input, &mut [], &StepOptions::new(1, Closeness::Default)).unwrap();
        assert!(rms(&cold, &first) > 0.1 * scale);
    }
}
