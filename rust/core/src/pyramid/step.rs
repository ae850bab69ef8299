//! Frame-to-frame stepping with collisions: seed 000, Algorithm 2.
//!
//! [`PyramidDeformer::step`] keeps its last output, which is free of
//! collisions, and for each new frame
//!
//! 1. moves every vertex from that output towards this frame's input along
//!    a straight path while the colliders move from their previous to their
//!    current positions, stopping and projecting at contacts, with friction
//!    (first pass, [`ResolveParams::first_pass`]);
//! 2. runs the projective solve from there, and after every iteration
//!    detects and resolves contacts along each vertex's move during that
//!    iteration against the colliders at rest (second pass,
//!    [`ResolveParams::in_loop`]).
//!
//! Vertices squeezed between colliders so that no projection frees them are
//! *pinched*: they are counted, kept within a bounded distance of where the
//! solver wanted them, and never NaN (see [`crate::collide::response`]).

use glam::Vec3;

use super::deformer::{Closeness, PyramidDeformer};
use crate::collide::audit::is_inside;
use crate::collide::{Collider, ColliderSet, ContactStats, ResolveParams};
use crate::mesh::validate_positions;
use crate::{Error, Result};

/// What one [`PyramidDeformer::step`] did about contacts.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StepReport {
    /// The first pass (last output → this frame's input, colliders sweeping).
    pub first_pass: ContactStats,
    /// Contacts resolved by the in-loop passes, over all iterations.
    pub in_loop_contacts: usize,
    /// Vertices any pass of this frame left pinched (ascending).
    pub pinched: Vec<u32>,
    /// Largest correction one in-loop pass applied to one vertex.
    pub max_in_loop_correction: f32,
}

impl PyramidDeformer {
    /// Solves the next frame of a sequence against `colliders` (already
    /// updated to this frame) and remembers the result as the start of the
    /// next one. The first call, and the first after [`Self::reset`], starts
    /// from `input` itself, which should then be free of collisions.
    pub fn step(
        &mut self,
        input: &[Vec3],
        colliders: &[&Collider],
        iterations: usize,
        closeness: Closeness<'_>,
    ) -> Result<(Vec<Vec3>, StepReport)> {
        let n = self.vertex_count();
        if input.len() != n {
            return Err(Error::invalid(format!("input: {} vertices given, the deformer has {n}", input.len())));
        }
        validate_positions("input", input)?;
        let set = ColliderSet::new(colliders.iter().copied());
        let mut report = StepReport::default();
        let mut x = input.to_vec();
        if !colliders.is_empty() {
            let start = self.history.as_deref().unwrap_or(input);
            report.first_pass = set.resolve_path(start, &mut x, &self.skin, &ResolveParams::first_pass())?;
            report.pinched = report.first_pass.pinched.clone();
        }
        // A vertex one pass leaves pinched inside a collider starts the next
        // pass inside, where no contact is seen again: keep the suspects and
        // look at where they end.
        let mut suspects: Vec<u32> = report.first_pass.pinched.clone();
        let mut last_pinched: Vec<u32> = report.first_pass.pinched.clone();
        // The hook borrows the skin while the solve borrows the deformer.
        let skin = std::mem::take(&mut self.skin);
        let mut in_loop = |_iteration: usize, before: &[Vec3], after: &mut [Vec3]| -> Result<()> {
            let stats = set.resolve_path(before, after, &skin, &ResolveParams::in_loop())?;
            report.in_loop_contacts += stats.vertex_contacts + stats.edge_contacts + stats.collider_vertex_contacts;
            report.max_in_loop_correction = report.max_in_loop_correction.max(stats.max_correction);
            suspects.extend_from_slice(&stats.pinched);
            last_pinched = stats.pinched;
            Ok(())
        };
        let hook: Option<&mut dyn crate::solve::IterationHook> =
            if colliders.is_empty() { None } else { Some(&mut in_loop) };
        let solved = self.solve_into(input, &mut x, iterations, closeness, hook);
        self.skin = skin;
        solved?;
        report.pinched = still_pinched(&x, colliders, suspects, last_pinched);
        self.history = Some(x.clone());
        Ok((x, report))
    }

}

/// The last pass's pinched vertices, and the earlier ones that ended inside a
/// closed collider (ascending).
fn still_pinched(x: &[Vec3], colliders: &[&Collider], suspects: Vec<u32>, mut pinched: Vec<u32>) -> Vec<u32> {
    let depth = |c: &Collider| 0.5 * c.settings().thickness;
    pinched.extend(suspects.into_iter().filter(|&v| {
        colliders.iter().any(|c| c.is_closed() && is_inside(c, x[v as usize], depth(c)))
    }));
    pinched.sort_unstable();
    pinched.dedup();
    pinched
}

impl PyramidDeformer {
    /// Forgets the last output: the next [`Self::step`] starts from its input.
    pub fn reset(&mut self) {
        self.history = None;
    }

    /// Makes `positions` the last output, as if a step had produced them:
    /// a bake resuming after frames already cached starts from the last of
    /// them. They must be free of collisions for the next step's guarantee.
    pub fn set_history(&mut self, positions: &[Vec3]) -> Result<()> {
        let n = self.vertex_count();
        if positions.len() != n {
            return Err(Error::invalid(format!("history: {} vertices given, the deformer has {n}", positions.len())));
        }
        validate_positions("history", positions)?;
        self.history = Some(positions.to_vec());
        Ok(())
    }

    /// The last output of [`Self::step`], if any.
    pub fn history(&self) -> Option<&[Vec3]> {
        self.history.as_deref()
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::collide::{audit, AuditParams, ColliderSettings};
    use crate::mesh::shapes::{grid, quad_sphere, PolyMesh};
    use crate::pyramid::DeformerOptions;

    struct Scene {
        skin: PolyMesh,
        deformer: PyramidDeformer,
        sphere: PolyMesh,
        triangles: Vec<[u32; 3]>,
    }

    fn scene() -> Scene {
        let skin = grid(40, 40, 2.0);
        let deformer = PyramidDeformer::bind(skin.input(), DeformerOptions::default()).unwrap();
        let sphere = quad_sphere(8, 0.3);
        let offsets: Vec<u32> = std::iter::once(0)
            .chain(sphere.polygon_sizes.iter().scan(0u32, |acc, &s| {
                *acc += s as u32;
                Some(*acc)
            }))
            .collect();
        let triangles = crate::collide::audit::fan_triangles(&sphere.corner_verts, &offsets);
        Scene { skin, deformer, sphere, triangles }
    }

    fn moved(points: &[Vec3], by: Vec3) -> Vec<Vec3> {
        points.iter().map(|&p| p + by).collect()
    }

    /// Steps the flat skin through the sphere centres `path`, auditing every
    /// frame; returns the last output and the most pinched vertices of a frame.
    fn run(scene: &mut Scene, colliders: &mut [Collider], paths: &[Vec<Vec3>], closeness: f32) -> (Vec<Vec3>, usize) {
        let mut out = Vec::new();
        let mut most_pinched = 0;
        // Once skin is pinched its history is no longer collision-free, and
        // nothing can be promised about later frames but bounds.
        for k in 0..paths[0].len() {
            for (c, path) in colliders.iter_mut().zip(paths) {
                c.update(&moved(&scene.sphere.positions, path[k])).unwrap();
            }
            let refs: Vec<&Collider> = colliders.iter().collect();
            let (x, report) = scene.deformer.step(&scene.skin.positions, &refs, 10, Closeness::Uniform(closeness)).unwrap();
            assert!(x.iter().all(|p| p.is_finite()), "frame {k}: non-finite output");
            most_pinched = most_pinched.max(report.pinched.len());
            if most_pinched == 0 {
                let found = audit(
                    crate::mesh::MeshInput { positions: &x, ..scene.skin.input() },
                    &refs,
                    &AuditParams::default(),
                )
                .unwrap();
                assert_eq!(found.vertices_inside.len(), 0, "frame {k}: vertices inside");
                assert_eq!(found.edges_crossing.len(), 0, "frame {k}: edges crossing");
                assert_eq!(found.collider_edges_crossing.len(), 0, "frame {k}: collider edges crossing");
            }
            out = x;
        }
        (out, most_pinched)
    }

    fn sphere_collider(scene: &Scene, at: Vec3, friction: f32) -> Collider {
        let settings = ColliderSettings { thickness: 0.01, static_friction: friction, kinetic_friction: friction };
        Collider::new(&moved(&scene.sphere.positions, at), &scene.triangles, settings).unwrap()
    }

    /// The sphere rises into the skin, then slides along +x; returns the
    /// mean x drift of the skin vertices over the sphere's top.
    fn push_and_slide(friction: f32) -> f32 {
        let mut scene = scene();
        let start = Vec3::new(-0.2, 0.0, -0.32);
        let mut path: Vec<Vec3> = (0..=6).map(|k| start + Vec3::Z * (0.025 * k as f32)).collect();
        let top = *path.last().unwrap();
        path.extend((1..=6).map(|k| top + Vec3::X * (0.03 * k as f32)));
        let end = *path.last().unwrap();
        let mut colliders = [sphere_collider(&scene, start, friction)];
        let (out, pinched) = run(&mut scene, &mut colliders, &[path], 0.02);
        assert_eq!(pinched, 0);
        let over: Vec<usize> = (0..out.len())
            .filter(|&i| (out[i] - (end + Vec3::Z * 0.3)).truncate().length() < 0.1 && out[i].z > 0.0)
            .collect();
        assert!(!over.is_empty(), "the sphere raised no skin");
        over.iter().map(|&i| out[i].x - scene.skin.positions[i].x).sum::<f32>() / over.len() as f32
    }

    #[test]
    fn sphere_pushed_in_and_slid_drags_skin_only_with_friction() {
        let dragged = push_and_slide(1.0);
        let slid = push_and_slide(0.0);
        assert!(dragged > 0.05, "high friction should drag the skin along: mean drift {dragged}");
        assert!(slid.abs() < 0.4 * dragged, "zero friction should let it slide: drift {slid} vs {dragged}");
    }

    #[test]
    fn a_collider_crossing_the_skin_within_one_frame_does_not_tunnel() {
        let mut scene = scene();
        // From well below to well above the skin in a single frame.
        let path = vec![Vec3::new(0.0, 0.0, -0.5), Vec3::new(0.0, 0.0, 0.5)];
        let mut colliders = [sphere_collider(&scene, path[0], 0.0)];
        let (out, pinched) = run(&mut scene, &mut colliders, &[path], 0.02);
        assert_eq!(pinched, 0);
        // The skin rides on the sphere's top rather than staying behind.
        let centre = out.iter().copied().min_by(|a, b| a.truncate().length().total_cmp(&b.truncate().length())).unwrap();
        assert!(centre.z > 0.5 + 0.3 - 0.05, "skin left behind at z = {}", centre.z);
    }

    #[test]
    fn skin_squeezed_between_two_colliders_is_pinched_not_exploded() {
        let mut scene = scene();
        let below: Vec<Vec3> = (0..=8).map(|k| Vec3::new(0.0, 0.0, -0.35 + 0.04 * k as f32)).collect();
        let above: Vec<Vec3> = below.iter().map(|p| -*p).collect();
        let mut colliders = [sphere_collider(&scene, below[0], 0.0), sphere_collider(&scene, above[0], 0.0)];
        let (out, pinched) = run(&mut scene, &mut colliders, &[below, above], 0.02);
        assert!(pinched > 0, "the spheres overlap through the skin: someone must be pinched");
        let worst = out.iter().zip(&scene.skin.positions).map(|(a, b)| (*a - *b).length()).fold(0.0, f32::max);
        assert!(worst < 1.0, "pinched skin moved {worst}");
    }

    #[test]
    fn without_colliders_step_is_the_solve_and_reset_forgets() {
        let mut scene = scene();
        let input: Vec<Vec3> = scene.skin.positions.iter().map(|p| *p + Vec3::new(0.0, 0.0, p.x * p.x)).collect();
        let solved = scene.deformer.solve(&input, 10, Closeness::Default).unwrap();
        let (stepped, report) = scene.deformer.step(&input, &[], 10, Closeness::Default).unwrap();
        assert_eq!(solved, stepped);
        assert_eq!(report, StepReport::default());
        assert_eq!(scene.deformer.history(), Some(&stepped[..]));
        scene.deformer.reset();
        assert!(scene.deformer.history().is_none());
        assert!(scene.deformer.step(&input[1..], &[], 10, Closeness::Default).is_err());
    }
}

#[cfg(test)]
mod uv_sphere_tests {
    use glam::Vec3;

    use super::*;
    use crate::collide::{audit, AuditParams, ColliderSettings};
    use crate::mesh::shapes::grid;
    use crate::pyramid::DeformerOptions;

    /// Blender's UV sphere: poles, `segments` around, `rings` bands.
    fn uv_sphere(segments: usize, rings: usize, radius: f32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let mut points = vec![Vec3::new(0.0, 0.0, radius)];
        for i in 1..rings {
            let theta = std::f32::consts::PI * i as f32 / rings as f32;
            for j in 0..segments {
                let phi = 2.0 * std::f32::consts::PI * j as f32 / segments as f32;
                points.push(radius * Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()));
            }
        }
        points.push(Vec3::new(0.0, 0.0, -radius));
        let (top, bottom) = (0u32, points.len() as u32 - 1);
        let ring = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
        let mut tris = Vec::new();
        for j in 0..segments {
            tris.push([top, ring(1, j), ring(1, j + 1)]);
            tris.push([bottom, ring(rings - 1, j + 1), ring(rings - 1, j)]);
        }
        for i in 1..rings - 1 {
            for j in 0..segments {
                let (a, b, c, d) = (ring(i, j), ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j));
                tris.push([a, d, c]);
                tris.push([a, c, b]);
            }
        }
        (points, tris)
    }

    #[test]
    fn a_uv_sphere_crossing_the_skin_in_one_frame_does_not_tunnel() {
        let skin = grid(40, 40, 2.0);
        let mut deformer = PyramidDeformer::bind(skin.input(), DeformerOptions::default()).unwrap();
        let (sphere, tris) = uv_sphere(32, 16, 0.3);
        let at = |z: f32| sphere.iter().map(|p| *p + Vec3::Z * z).collect::<Vec<_>>();
        let settings = ColliderSettings { thickness: 0.01, static_friction: 0.0, kinetic_friction: 0.0 };
        let mut collider = Collider::new(&at(-0.5), &tris, settings).unwrap();
        for z in [-0.5, 0.5, 0.5] {
            collider.update(&at(z)).unwrap();
            let (x, report) = deformer.step(&skin.positions, &[&collider], 10, Closeness::Uniform(0.02)).unwrap();
            assert!(report.pinched.is_empty());
            let found = audit(crate::mesh::MeshInput { positions: &x, ..skin.input() }, &[&collider], &AuditParams::default()).unwrap();
            assert_eq!(
                (found.vertices_inside.len(), found.edges_crossing.len(), found.collider_edges_crossing.len()),
                (0, 0, 0),
                "sphere at z = {z}"
            );
        }
    }
}

#[cfg(test)]
mod open_collider_tests {
    use glam::Vec3;

    use super::*;
    use crate::collide::{audit, AuditParams, ColliderSettings};
    use crate::mesh::shapes::grid;
    use crate::pyramid::DeformerOptions;

    #[test]
    #[ignore = "known defect: the rim edges of an open collider rising through the skin in one frame \
                can end up through 4 skin triangles (no pinched vertices reported); see issue 5's notes"]
    fn an_open_board_rising_through_the_skin_in_one_frame_carries_it() {
        let skin = grid(40, 40, 2.0);
        let mut deformer = PyramidDeformer::bind(skin.input(), DeformerOptions::default()).unwrap();
        let board = grid(8, 8, 0.8);
        let offsets: Vec<u32> = (0..=board.polygon_sizes.len() as u32).map(|k| 4 * k).collect();
        let tris = crate::collide::audit::fan_triangles(&board.corner_verts, &offsets);
        let at = |z: f32| board.positions.iter().map(|p| *p + Vec3::Z * z).collect::<Vec<_>>();
        let settings = ColliderSettings { thickness: 0.01, static_friction: 0.3, kinetic_friction: 0.2 };
        let mut collider = Collider::new(&at(-0.3), &tris, settings).unwrap();
        for z in [-0.3, 0.3, 0.3] {
            collider.update(&at(z)).unwrap();
            let (x, report) = deformer.step(&skin.positions, &[&collider], 10, Closeness::Uniform(0.05)).unwrap();
            let found = audit(crate::mesh::MeshInput { positions: &x, ..skin.input() }, &[&collider], &AuditParams::default()).unwrap();
            assert_eq!(
                (found.edges_crossing.len(), found.collider_edges_crossing.len(), report.pinched.len()),
                (0, 0, 0),
                "board at z = {z}: {:?}",
                found.collider_edges_crossing
            );
        }
    }
}
