//! [`Sequence::step`]: one frame, split into substeps (see the module
//! documentation of [`super`]).

use glam::Vec3;

use super::compliance::{compliant_skin, contact_targets, in_loop_clearance, ms_since, recede_from, recedes_after, RECESSION_CLOSING_ITERATIONS};
use super::dynamics::{kinetic_energy, Dynamics, MAX_SUBSTEPS};
use super::options::{accumulate, StepOptions, StepReport, StrainMode};
use super::self_pass::{self, SelfPass};
use super::strain_pass::{limit_strain_with_contacts, HOLDS, POST_STRAIN_SWEEPS, STRAIN_EARLY_ITERATIONS, STRAIN_ROUNDS, STRAIN_ROUNDS_EARLY, STRAIN_TOLERANCE};
use super::Sequence;
use crate::collide::is_inside;
use crate::collide::planes::LocalPlanes;
use crate::collide::{Anchors, Clearance, Collider, ColliderSet, ColliderSettings, ResolveParams, Skin};
use crate::mesh::validate_positions;
use crate::pyramid::MAX_ITERATIONS;
use crate::pyramid::PyramidDeformer;
use crate::solve::{ConstraintId, Iteration, IterationHook, Sliding, SlidingHook, Targets};
use crate::strain::{EdgeLimits, Hierarchy};
use crate::{Error, Result};

impl Sequence {
    /// [`Self::step`] in welded vertices (see [`super::seams`]).
    pub(super) fn step_welded(
        &mut self,
        input: &[Vec3],
        colliders: &mut [&mut Collider],
        options: &StepOptions<'_>,
    ) -> Result<(Vec<Vec3>, StepReport)> {
        let n = self.deformer.vertex_count();
        if input.len() != n {
            return Err(Error::invalid(format!("input: {} vertices given, the deformer has {n}", input.len())));
        }
        validate_positions("input", input)?;
        if !(1..=MAX_SUBSTEPS).contains(&options.substeps) {
            return Err(Error::invalid(format!("substeps is {}; it must be between 1 and {MAX_SUBSTEPS}", options.substeps)));
        }
        if let Some(dynamics) = &options.dynamics {
            dynamics.validate()?;
        }
        if options.iterations > MAX_ITERATIONS {
            return Err(Error::invalid(format!(
                "iterations is {}; at most {} are allowed",
                options.iterations,
                MAX_ITERATIONS
            )));
        }
        self.deformer.set_closeness(options.closeness)?;
        let limits = match options.strain {
            Some(strain) => {
                if self.rest.is_empty() {
                    return Err(Error::invalid("strain limits need a deformer bound to a mesh (its edges and rest lengths)".to_string()));
                }
                Some((EdgeLimits::new(&self.mesh_edges, &self.rest, strain.max_stretch)?, strain.mode))
            }
            None => None,
        };

        let substeps = options.substeps;
        let start = self.history.clone().unwrap_or_else(|| input.to_vec());
        let last_moves = self.self_moves.take();
        let mut self_pass = self.begin_self(options.self_collision.as_ref(), &start, last_moves)?;
        // Copies only where substeps interpolate or compliant colliders move:
        // the plain frame (one substep, kinematic colliders) allocates nothing here.
        let last_input = match (&self.last_input, substeps > 1) {
            (Some(last), true) => last.clone(),
            _ => Vec::new(),
        };
        // Where each collider is at the ends of the frame; compliant ones start
        // from where they were solved last frame (their `previous`).
        let frame_ends: Vec<(Vec<Vec3>, Vec<Vec3>)> = colliders
            .iter()
            .map(|c| {
                if substeps > 1 || c.is_compliant() {
                    (c.previous().to_vec(), c.current().to_vec())
                } else {
                    (Vec::new(), Vec::new())
                }
            })
            .collect();
        for (c, (previous, _)) in colliders.iter_mut().zip(&frame_ends) {
            if c.is_compliant() {
                c.set_positions(previous, previous)?;
            }
        }
        let mut report = StepReport::default();
        let mut x = start;
        let result = (|| -> Result<()> {
            for s in 1..=substeps {
                let (f0, f1) = ((s - 1) as f32 / substeps as f32, s as f32 / substeps as f32);
                let input_s = if substeps == 1 || last_input.is_empty() { input.to_vec() } else { lerp(&last_input, input, f1) };
                let mut goals: Vec<Option<Vec<Vec3>>> = Vec::with_capacity(colliders.len());
                for (c, (previous, current)) in colliders.iter_mut().zip(&frame_ends) {
                    match c.compliance() {
                        Some(compliance) => {
                            goals.push(Some(if substeps == 1 {
                                compliance.goals.clone()
                            } else {
                                lerp(&compliance.previous_goals, &compliance.goals, f1)
                            }));
                        }
                        None => {
                            if substeps > 1 {
                                c.set_positions(&lerp(previous, current, f0), &lerp(previous, current, f1))?;
                            }
                            goals.push(None);
                        }
                    }
                }
                let h = options.dynamics.map_or(0.0, |d| d.frame_time / substeps as f32);
                x = self.substep(&x, &input_s, colliders, &goals, options, limits.as_ref(), h, self_pass.as_mut(), &mut report)?;
            }
            Ok(())
        })();
        // Kinematic colliders back to the whole frame; compliant ones keep
        // the frame's motion from where they were to where they are solved.
        for (c, (previous, current)) in colliders.iter_mut().zip(&frame_ends) {
            if c.is_compliant() {
                let solved = c.current().to_vec();
                c.set_positions(previous, &solved)?;
            } else if substeps > 1 {
                c.set_positions(previous, current)?;
            }
        }
        result?;

        report.max_recession = colliders
            .iter()
            .filter_map(|c| c.compliance().map(|k| (c.current(), &k.goals)))
            .flat_map(|(solved, goals)| solved.iter().zip(goals.iter()).map(|(a, b)| (*a - *b).length()))
            .fold(0.0, f32::max);
        if let Some((limits, _)) = &limits {
            report.worst_stretch = limits.worst_stretch(&x);
        }
        if let (Some(dynamics), Some(v)) = (&options.dynamics, &self.velocity) {
            report.kinetic_energy = kinetic_energy(v, &self.vertex_area, dynamics.mass);
        }
        if options.dynamics.is_none() {
            self.velocity = None;
        }
        report.pinched.sort_unstable();
        report.pinched.dedup();
        if let Some(pass) = self_pass {
            self.finish_self(pass, &x, &mut report)?;
        }
        self.history = Some(x.clone());
        self.last_input = Some(input.to_vec());
        Ok((x, report))
    }

    /// One substep from the collision-free `x_n` towards `input` (see the
    /// module documentation). `goals[c]` holds the compliant colliders'
    /// animated positions at the end of the substep; `h` is its length in
    /// seconds (dynamics only).
    #[allow(clippy::too_many_arguments)]
    fn substep(
        &mut self,
        x_n: &[Vec3],
        input: &[Vec3],
        colliders: &mut [&mut Collider],
        goals: &[Option<Vec<Vec3>>],
        options: &StepOptions<'_>,
        limits: Option<&(EdgeLimits, StrainMode)>,
        h: f32,
        mut self_pass: Option<&mut SelfPass>,
        report: &mut StepReport,
    ) -> Result<Vec<Vec3>> {
        let n = x_n.len();
        // Where the skin heads: the input, or with dynamics where inertia carries it.
        let target: Vec<Vec3> = match &options.dynamics {
            Some(dynamics) => {
                let prediction = self.predict(x_n, dynamics, h);
                self.set_inertia(Some((dynamics, h, &prediction)))?;
                prediction
            }
            None => {
                self.set_inertia(None)?;
                input.to_vec()
            }
        };
        // Where compliant colliders' goals overlap that, the skin gives way.
        let started = std::time::Instant::now();
        let contacts = contact_targets(&target, self.deformer.closeness_weights(), colliders, goals)?;
        if contacts.is_some() {
            report.contact_work.compliant_targets_ms += ms_since(started);
        }
        report.compliant_skin_vertices = report.compliant_skin_vertices.max(contacts.as_ref().map_or(0, |(_, w)| w.iter().filter(|&&w| w > 0.0).count()));
        self.set_contact_targets(contacts)?;
        // A warm start unless the path from the last output to the target
        // means something else: with colliders the first pass's path from
        // there to the input is where friction holds the skin against them,
        // and with dynamics the target is already the inertial prediction.
        // With self-collision the warm start is that path too: the last
        // output carried by the input's own motion, the skin's path over the
        // frame where its offset from the input holds; the input alone
        // would sweep it back through the contacts the last solve held it
        // at, and make every iteration of the solve move it beyond the
        // first pass's margins (issue 30, seventeenth round); but only
        // where that does not change the result (`SelfPass::starts_warm`).
        let converges = self.deformer.accelerated() && self.deformer.tolerance().is_some();
        let warm_self = self_pass.as_deref().is_none_or(|pass| pass.starts_warm(converges));
        let warm = if colliders.is_empty() && options.dynamics.is_none() && warm_self { self.warm_start(&target) } else { None };
        let started_warm = warm.is_some();
        let mut x = warm.unwrap_or(target);
        // A vertex one pass leaves pinched inside a collider starts the next
        // pass inside, where no contact is seen again: keep the suspects and
        // look at where they end.
        let mut suspects: Vec<u32> = Vec::new();
        let compliant: Vec<usize> = (0..colliders.len()).filter(|&c| colliders[c].is_compliant()).collect();
        let compliant_skins: Vec<Option<Skin>> = colliders
            .iter()
            .map(|c| c.compliance().map(|k| compliant_skin(c, &k.stiffness)).transpose())
            .collect::<Result<_>>()?;

        if !colliders.is_empty() {
            // 1. Compliant vertices towards their goals, stopping at the skin.
            let started = std::time::Instant::now();
            for &c in &compliant {
                let goal = goals[c].as_deref().expect("compliant colliders have goals");
                let own = compliant_skins[c].as_ref().expect("compliant");
                let moved = recede_from(&mut self.skin_collider, &self.skin, colliders[c], own, x_n, goal, true)?;
                report.compliant_contacts += moved.contacts;
            }
            report.contact_work.first_recession_ms += ms_since(started);
            // 2. The skin towards its target while the colliders sweep.
            let started = std::time::Instant::now();
            let refs: Vec<&Collider> = colliders.iter().map(|c| &**c).collect();
            let carried = self.carried_planes.take().filter(|k| k.fits(colliders)).map(|k| k.planes);
            let first = ColliderSet::new(refs).resolve_path_carrying(x_n, &mut x, &self.skin, &ResolveParams::first_pass(), carried.as_ref())?;
            accumulate(&mut report.first_pass, &first);
            report.held += first.held.len();
            suspects.extend_from_slice(&first.pinched);
            for &c in &compliant {
                colliders[c].hold()?;
            }
            report.contact_work.first_pass_ms += ms_since(started);
        }
        // 2b. The skin against itself along the same paths (with the colliders again where it moved skin).
        if let (Some(pass), Some(collision)) = (self_pass.as_deref_mut(), self.self_collision.as_ref()) {
            let refs: Vec<&Collider> = colliders.iter().map(|c| &**c).collect();
            self_pass::first_pass(collision, pass, x_n, &mut x, &refs, &self.skin, started_warm, converges, report)?;
        }

        // 3. The solve, with the in-loop passes after every iteration.
        // Strain projections move a vertex in proportion to how free it is.
        let inverse_mass: Vec<f32> = match limits {
            Some(_) => self.deformer.closeness_weights().iter().map(|&c| 1.0 - c.min(1.0)).collect(),
            None => Vec::new(),
        };
        let mut last_pinched: Vec<u32> = suspects.clone();
        let skin = &self.skin;
        let skin_collider = &mut self.skin_collider;
        let self_collision = self.self_collision.as_ref().filter(|_| self_pass.is_some());
        let unified = limits.filter(|(_, mode)| *mode == StrainMode::Unified).map(|(l, _)| l);
        if let Some(limits) = unified {
            if !self.strain_levels.as_ref().is_some_and(|levels| levels.fits(limits)) {
                self.strain_levels = Some(Hierarchy::new(limits, &self.rest));
            }
        }
        let levels = self.strain_levels.as_ref().filter(|_| unified.is_some());
        let any_colliders = !colliders.is_empty();
        // Where the skin is, at the start of the in-loop passes, relative to
        // the colliders: the passes skip what cannot have reached them since,
        // and lift what the solve pulls back in along the colliders' planes.
        // Receding compliant colliders are measured by their envelopes, and
        // again if one leaves its envelope (see `in_loop_clearance`).
        let mut clearance: Option<Clearance> = None;
        // Only where the colliders' pass is the only one that moves the skin
        // does its account of which vertices slide hold for the iteration.
        let report_sliding = unified.is_none() && compliant.is_empty() && self_collision.is_none();
        // Where static friction holds the skin, from one in-loop pass to the
        // next: the colliders stand still through the solve (the first pass
        // has carried the skin along with their motion), unless compliant
        // ones recede in it.
        let mut anchors = compliant.is_empty().then(Anchors::new);
        let mut in_loop = SlidingHook::new(|iteration: Iteration, before: &[Vec3], after: &mut [Vec3], sliding: &mut Vec<Sliding>| -> Result<()> {
            if any_colliders {
                let started = std::time::Instant::now();
                // Compliant colliders stand still here; they recede below.
                let refs: Vec<&Collider> = colliders.iter().map(|c| &**c).collect();
                if !clearance.as_ref().is_some_and(|c| c.is_valid_for(&refs, before.len())) {
                    clearance = Some(in_loop_clearance(&refs, goals, skin, before)?);
                    report.clearance_measurements += 1;
                }
                let set = ColliderSet::new(refs);
                let stats = set.resolve_path_with(before, after, skin, &ResolveParams::in_loop(), clearance.as_ref(), anchors.as_mut())?;
                report.in_loop_contacts += stats.vertex_contacts + stats.edge_contacts + stats.collider_vertex_contacts;
                report.in_loop_tested += stats.tested;
                report.max_in_loop_correction = report.max_in_loop_correction.max(stats.max_correction);
                if report_sliding {
                    sliding.extend(stats.sliding.iter().map(|&(vertex, slide)| Sliding { vertex, normal: slide.normal, friction: slide.friction }));
                }
                report.held += stats.held.len();
                suspects.extend_from_slice(&stats.pinched);
                last_pinched = stats.pinched;
                report.contact_work.in_loop_pass_ms += ms_since(started);
            }
            // Strain rounds in the iteration that ends the solve and the
            // `STRAIN_EARLY_ITERATIONS` before it only: the earlier ones' are
            // undone by the solve iterations after them. The multilevel
            // projection only where the rounds have room to settle its large
            // moves against the contacts: the last iteration.
            let strain_rounds = match iteration.remaining {
                Some(0) => Some((STRAIN_ROUNDS, levels)),
                Some(remaining) if remaining <= STRAIN_EARLY_ITERATIONS => Some((STRAIN_ROUNDS_EARLY, None)),
                _ => None,
            };
            if let (Some(limits), Some((rounds, levels))) = (unified, strain_rounds) {
                let started = std::time::Instant::now();
                // Strain limits cap static friction: a vertex whose anchor
                // holds one of its edges past the limit is let go, so the
                // rounds below slide it and the next pass holds it where they
                // left it instead of putting it back at its anchor (issue 29:
                // on the 100k flesh bench ~3,100 such put-backs a pass undid
                // the rounds' slide, and frame 5 took 17 rounds, not 8).
                if let Some(anchors) = anchors.as_mut() {
                    anchors.release(|v| limits.past_limit_at(after, v, HOLDS));
                }
                let pass = limit_strain_with_contacts(limits, levels, colliders, after, skin, &inverse_mass, rounds, clearance.as_ref())?;
                suspects.extend_from_slice(&pass.pinched);
                last_pinched.extend(pass.pinched);
                report.contact_work.strain_rounds += pass.rounds;
                report.contact_work.strain_cycles += pass.cycles;
                report.contact_work.strain_ms += ms_since(started);
            }
            // Compliant colliders recede after every third iteration,
            // counted back from the last (why that is safe: `recedes_after`).
            let recede = recedes_after(iteration);
            for &c in compliant.iter().filter(|_| recede) {
                let goal = goals[c].as_deref().expect("compliant colliders have goals");
                let moved = recede_from(skin_collider, skin, colliders[c], compliant_skins[c].as_ref().expect("compliant"), after, goal, false)?;
                report.in_loop_recessions += 1;
                report.compliant_contacts += moved.contacts;
                report.in_loop_skin_refits += moved.refitted;
                report.contact_work.recession_heading_ms += moved.heading_ms;
                report.contact_work.recession_contacts_ms += moved.contacts_ms;
            }
            if let (Some(pass), Some(collision)) = (self_pass.as_deref_mut(), self_collision) {
                let refs: Vec<&Collider> = colliders.iter().map(|c| &**c).collect();
                self_pass::in_loop(collision, pass, before, after, &refs, skin, clearance.as_ref(), report)?;
            }
            Ok(())
        })
        // Where Converge's stopping rule ends the solve, the strain rounds'
        // iterations (measured by the rule, the rounds, undone by the next
        // iteration, would keep it from being met) and the last recession's
        // follow once it is met.
        .closing(closing_iterations(unified.is_some(), !compliant.is_empty()));
        let hook: Option<&mut dyn IterationHook> =
            if any_colliders || unified.is_some() || self_collision.is_some() { Some(&mut in_loop) } else { None };
        self.deformer.solver_mut().solve(input, &mut x, options.iterations, hook)?;
        self.carried_planes = clearance.and_then(Clearance::into_planes).map(|planes| CarriedPlanes {
            planes,
            colliders: colliders.iter().map(|c| (c.current().to_vec(), c.triangles().to_vec(), c.settings())).collect(),
        });
        if let Some((limits, StrainMode::Post)) = limits {
            limits.project(&mut x, &inverse_mass, POST_STRAIN_SWEEPS, STRAIN_TOLERANCE);
        }
        let refs: Vec<&Collider> = colliders.iter().map(|c| &**c).collect();
        report.pinched.extend(still_pinched(&x, &refs, suspects, last_pinched));

        if let Some(dynamics) = &options.dynamics {
            let decay = (-dynamics.damping * h).exp();
            let velocity: Vec<Vec3> = x.iter().zip(x_n).map(|(a, b)| (*a - *b) * (decay / h)).collect();
            self.velocity = Some(velocity);
        }
        debug_assert_eq!(x.len(), n);
        Ok(x)
    }

    /// Where a solve that follows the input starts, without colliders or
    /// dynamics: the input plus the offset
    /// from its input that the last frame's solve ended with, so that a bake
    /// frame starts near its solution (a warm start, issue 28); None on a
    /// first frame (it starts at the input). With substeps every substep carries the last
    /// frame's offset. Only the start changes: the solve converges to the
    /// same solution from either.
    fn warm_start(&self, input: &[Vec3]) -> Option<Vec<Vec3>> {
        match (&self.history, &self.last_input) {
            (Some(solved), Some(last)) if solved.len() == input.len() && last.len() == input.len() => {
                Some(input.iter().zip(solved).zip(last).map(|((i, s), l)| *i + (*s - *l)).collect())
            }
            _ => None,
        }
    }

    /// Inertial prediction `x_n + h·v_n + h²·g` (velocities zero when unknown).
    fn predict(&self, x_n: &[Vec3], dynamics: &Dynamics, h: f32) -> Vec<Vec3> {
        let gravity = dynamics.gravity * (h * h);
        match &self.velocity {
            Some(v) => x_n.iter().zip(v).map(|(x, v)| *x + *v * h + gravity).collect(),
            None => x_n.iter().map(|x| *x + gravity).collect(),
        }
    }

    /// Turns the inertia term on (targets = the prediction, weights from the
    /// closeness and `h`) or off (weights 0).
    fn set_inertia(&mut self, on: Option<(&Dynamics, f32, &[Vec3])>) -> Result<()> {
        let rows = on.map(|(dynamics, h, prediction)| {
            let scale = dynamics.inertia_scale(h);
            let weights: Vec<f32> = self.deformer.closeness_weights().iter().map(|&c| (1.0 - c.min(1.0)) * scale).collect();
            (prediction, weights)
        });
        let rows = rows.as_ref().map(|(targets, weights)| (*targets, &weights[..]));
        set_target_rows(&mut self.deformer, &mut self.inertia, "inertia", rows)
    }

    /// Sets the rows that make the skin give way to compliant colliders
    /// ([`contact_targets`]), or turns them off.
    fn set_contact_targets(&mut self, rows: Option<(Vec<Vec3>, Vec<f32>)>) -> Result<()> {
        let rows = rows.as_ref().map(|(targets, weights)| (&targets[..], &weights[..]));
        set_target_rows(&mut self.deformer, &mut self.contact_targets, "compliant contacts", rows)
    }
}

/// Gives the per-vertex target rows in `slot` these targets and weights,
/// adding them to the solver the first time, or turns them off (weights 0,
/// written only if some are not already 0, so that the factorisation stays).
fn set_target_rows(
    deformer: &mut PyramidDeformer,
    slot: &mut Option<ConstraintId>,
    name: &str,
    rows: Option<(&[Vec3], &[f32])>,
) -> Result<()> {
    let n = deformer.vertex_count();
    let solver = deformer.solver_mut();
    match rows {
        Some((targets, weights)) => {
            let id = match *slot {
                Some(id) => id,
                None => {
                    let all: Vec<u32> = (0..n as u32).collect();
                    let id = solver.add(Box::new(Targets::new(name, &all)), vec![0.0; all.len()])?;
                    *slot = Some(id);
                    id
                }
            };
            solver.set_weights(id, weights)?;
            solver.set_targets(id, targets)
        }
        None => match *slot {
            Some(id) if solver.weights(id)?.iter().any(|&w| w != 0.0) => solver.set_weights(id, &vec![0.0; n]),
            _ => Ok(()),
        },
    }
}

fn lerp(a: &[Vec3], b: &[Vec3], t: f32) -> Vec<Vec3> {
    a.iter().zip(b).map(|(a, b)| a.lerp(*b, t)).collect()
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

/// A substep's in-loop supporting planes, kept for the next substep's first
/// pass, which moves them along with the colliders
/// ([`LocalPlanes::drifting`]); with the colliders' positions, triangles
/// and settings they were measured against.
#[derive(Debug, Clone)]
pub(super) struct CarriedPlanes {
    planes: LocalPlanes,
    /// Per collider: positions, triangles (a plane's promise holds only for
    /// the triangles there were) and settings.
    colliders: Vec<(Vec<Vec3>, Vec<[u32; 3]>, ColliderSettings)>,
}

impl CarriedPlanes {
    /// Whether the colliders start this step where, and as, the planes met
    /// them: the same positions, triangles and settings.
    pub(super) fn fits(&self, colliders: &[&mut Collider]) -> bool {
        self.colliders.len() == colliders.len()
            && self.colliders.iter().zip(colliders).all(|((positions, triangles, settings), c)| {
                c.settings() == *settings && c.previous() == &positions[..] && c.triangles() == &triangles[..]
            })
    }
}

/// The iterations a solve runs after Converge's stopping rule is met
/// ([`IterationHook::closing_iterations`]): those whose strain rounds and
/// compliant recessions count, the most either needs.
fn closing_iterations(strain_limits: bool, compliant: bool) -> usize {
    let strain = if strain_limits { STRAIN_EARLY_ITERATIONS + 1 } else { 0 };
    let recessions = if compliant { RECESSION_CLOSING_ITERATIONS } else { 0 };
    strain.max(recessions)
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::collide::{audit, AuditParams, ColliderSettings};
    use crate::mesh::shapes::{grid, quad_sphere, PolyMesh};
    use crate::pyramid::{Closeness, DeformerOptions};

    struct Scene {
        skin: PolyMesh,
        deformer: Sequence,
        sphere: PolyMesh,
        triangles: Vec<[u32; 3]>,
    }

    fn scene() -> Scene {
        let skin = grid(40, 40, 2.0);
        let deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        let sphere = quad_sphere(8, 0.3);
        let offsets: Vec<u32> = std::iter::once(0)
            .chain(sphere.polygon_sizes.iter().scan(0u32, |acc, &s| {
                *acc += s as u32;
                Some(*acc)
            }))
            .collect();
        let triangles = crate::mesh::fan_triangles(&sphere.corner_verts, &offsets);
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
            let mut refs: Vec<&mut Collider> = colliders.iter_mut().collect();
            let (x, report) = scene.deformer.step(&scene.skin.positions, &mut refs, &StepOptions::new(10, Closeness::Uniform(closeness))).unwrap();
            let refs: Vec<&Collider> = colliders.iter().collect();
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
        let solved = scene.deformer.solve(&input, StepOptions::default().iterations, Closeness::Default).unwrap();
        let (stepped, report) = scene.deformer.step(&input, &mut [], &StepOptions::default()).unwrap();
        assert_eq!(solved, stepped);
        assert_eq!(report, StepReport::default());
        assert_eq!(scene.deformer.history(), Some(stepped.clone()));
        scene.deformer.reset();
        assert!(scene.deformer.history().is_none());
        // The first step after a reset starts cold again, like the first of all.
        let (again, _) = scene.deformer.step(&input, &mut [], &StepOptions::default()).unwrap();
        assert_eq!(again, solved);
        assert!(scene.deformer.step(&input[1..], &mut [], &StepOptions::default()).is_err());
    }
}

#[cfg(test)]
mod uv_sphere_tests {
    use glam::Vec3;

    use super::*;
    use crate::collide::{audit, AuditParams, ColliderSettings};
    use crate::mesh::shapes::{grid, uv_sphere_triangles};
    use crate::pyramid::{Closeness, DeformerOptions};

    #[test]
    fn a_uv_sphere_crossing_the_skin_in_one_frame_does_not_tunnel() {
        let skin = grid(40, 40, 2.0);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        let (sphere, tris) = uv_sphere_triangles(32, 16, 0.3);
        let at = |z: f32| sphere.iter().map(|p| *p + Vec3::Z * z).collect::<Vec<_>>();
        let settings = ColliderSettings { thickness: 0.01, static_friction: 0.0, kinetic_friction: 0.0 };
        let mut collider = Collider::new(&at(-0.5), &tris, settings).unwrap();
        for z in [-0.5, 0.5, 0.5] {
            collider.update(&at(z)).unwrap();
            let (x, report) = deformer.step(&skin.positions, &mut [&mut collider], &StepOptions::new(10, Closeness::Uniform(0.02))).unwrap();
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
    use crate::pyramid::{Closeness, DeformerOptions};

    /// The rim of a board rising through the skin meets the draped skin along
    /// the diagonals of its quads: the collision skin must test them.
    #[test]
    fn an_open_board_rising_through_the_skin_in_one_frame_carries_it() {
        let skin = grid(40, 40, 2.0);
        let mut deformer = Sequence::bind(skin.input(), DeformerOptions::default()).unwrap();
        let board = grid(8, 8, 0.8);
        let offsets: Vec<u32> = (0..=board.polygon_sizes.len() as u32).map(|k| 4 * k).collect();
        let tris = crate::mesh::fan_triangles(&board.corner_verts, &offsets);
        let at = |z: f32| board.positions.iter().map(|p| *p + Vec3::Z * z).collect::<Vec<_>>();
        let settings = ColliderSettings { thickness: 0.01, static_friction: 0.3, kinetic_friction: 0.2 };
        let mut collider = Collider::new(&at(-0.3), &tris, settings).unwrap();
        for z in [-0.3, 0.3, 0.3] {
            collider.update(&at(z)).unwrap();
            let (x, report) = deformer.step(&skin.positions, &mut [&mut collider], &StepOptions::new(10, Closeness::Uniform(0.05))).unwrap();
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

