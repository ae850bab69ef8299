//! Compliant colliders inside the step (seed 002 §1).
//!
//! A compliant collider vertex is an unknown pulled to its animated position
//! (its *goal*) by a spring of stiffness density `k` that already contains
//! the 1/h² factor, without momentum. Where a collider's goal shape overlaps
//! where the skin is heading, the skin's own stiffness and the collider's
//! springs compete, and both give way:
//!
//! * **The skin** gets one target row per vertex whose target (the input, or
//!   with dynamics the inertial prediction) lies inside a closed compliant
//!   collider's goal shape: towards the closest point of the goal surface
//!   (plus the thickness), weighted `(1 − c)·k/K` with `k` interpolated at
//!   that point and `K` the stiffness density of the skin's own weights
//!   ([`STIFFNESS_DENSITY`]). The rows are constant within a solve, like the
//!   inertia term, so where the skin settles is a fixed point of the solve
//!   and does not depend on how many iterations or substeps reach it. A
//!   closeness of 1 keeps the skin on its input; the collider then yields
//!   entirely.
//! * **The collider** recedes: each compliant vertex heads for its goal and
//!   stops at the skin ([`recede_from`]), before the first pass and after
//!   every solver iteration. During the contact passes it stands still, so
//!   the skin never passes through it.
//!
//! Kinematic vertices of a compliant collider (stiffness 0) follow their
//! goals exactly and act as an ordinary collider. An open compliant collider
//! has no inside: it only recedes where the skin stops it.

use glam::Vec3;
use rayon::prelude::*;

use super::dynamics::STIFFNESS_DENSITY;
use crate::collide::is_inside;
use crate::collide::{Clearance, Collider, ColliderMotion, ColliderSet, ColliderSettings, Envelope, ResolveParams, Skin};
use crate::solve::Iteration;
use crate::Result;

/// Distance a receded vertex keeps from the skin, in thicknesses. Contacts
/// are detected at one thickness, between vertices and triangles and between
/// edges; receded vertices held at that distance leave the collider's edges
/// between them inside it wherever the skin curves, and resolving those
/// contacts shoves the vertices sideways by amounts that depend on the path
/// (1 and 4 substeps then differ by 10% of the motion). At two thicknesses
/// they agree within 1% (`sequence::tests::compliance`).
const CLEARANCE: f32 = 2.0;

/// How far, in thicknesses, the skin's boxes as a collider reach beyond the
/// thickness ([`Collider::rest_at`]): a vertex that moved less than half of
/// that since its boxes were made keeps them. Between two iterations most
/// of the skin moves by rounding only: on the flesh benchmark (thickness
/// 0.005) about 5,600 of 100,000 vertices move farther than a twentieth of
/// the thickness per iteration. Fatter boxes would keep more of them but
/// let more candidates through every query.
const SKIN_SLACK: f32 = 0.1;

/// Target rows that make the skin give way to compliant colliders: per skin
/// vertex a target and a weight (0 where no compliant collider claims the
/// vertex). `None` when no vertex is claimed.
///
/// `heading` is where each skin vertex heads this substep, `closeness` its
/// closeness weight, `goals[c]` the goal positions of compliant collider `c`
/// (`None` for kinematic colliders).
pub(super) fn contact_targets(
    heading: &[Vec3],
    closeness: &[f32],
    colliders: &[&mut Collider],
    goals: &[Option<Vec<Vec3>>],
) -> Result<Option<(Vec<Vec3>, Vec<f32>)>> {
    let mut shapes: Vec<(Collider, &[f32])> = Vec::new();
    for (collider, goal) in colliders.iter().zip(goals) {
        let (Some(goal), Some(compliance)) = (goal, collider.compliance()) else { continue };
        if collider.is_closed() {
            // The collider's own trees refitted to the goals: building new
            // ones (and the edge lists) cost more than the rows themselves.
            let mut shape = (**collider).clone();
            shape.set_positions(goal, goal)?;
            shapes.push((shape, &compliance.stiffness));
        }
    }
    if shapes.is_empty() {
        return Ok(None);
    }
    let rows: Vec<(Vec3, f32)> = heading
        .par_iter()
        .zip(closeness)
        .map(|(&p, &c)| {
            let free = 1.0 - c.min(1.0);
            let (mut sum, mut weight) = (Vec3::ZERO, 0.0f32);
            if free > 0.0 {
                for (shape, stiffness) in &shapes {
                    if !is_inside(shape, p, 0.0) {
                        continue;
                    }
                    let Some(closest) = shape.closest_point(p) else { continue };
                    let [a, b, d] = shape.triangles()[closest.triangle as usize].map(|v| stiffness[v as usize]);
                    let k = Vec3::new(a, b, d).dot(closest.barycentric).max(0.0);
                    if k > 0.0 {
                        let outward = (closest.point - p).normalize_or_zero();
                        let w = free * k / STIFFNESS_DENSITY;
                        sum += (closest.point + outward * shape.settings().thickness) * w;
                        weight += w;
                    }
                }
            }
            if weight > 0.0 {
                (sum / weight, weight)
            } else {
                (p, 0.0)
            }
        })
        .collect();
    if rows.iter().all(|&(_, w)| w == 0.0) {
        return Ok(None);
    }
    Ok(Some(rows.into_iter().unzip()))
}

/// In-loop recessions of compliant colliders run after every third
/// iteration, counted back from the one that ends the solve (issue 29: one
/// after every iteration cost the compliant flesh bench ~3.3–4.2× a
/// collisions-only step; every other one saved about a quarter of that, and
/// every third saves another ~8 % of the step by instruction count).
///
/// Why skipping one is safe: the colliders' pass still runs after every
/// iteration against every collider where it stands, compliant ones
/// included, so no iteration leaves the skin inside a collider; a recession
/// only moves compliant vertices towards their goals and stops them at the
/// skin, so a skipped one leaves the collider where the last one put it, a
/// position the contact pass then holds the skin against. What skipping
/// costs is how closely the collider follows the skin: it lags the skin by
/// at most two iterations. Measured on the flesh bench's sliding frames
/// (`docs/performance.md`): every other iteration ended 0.75 % (RMS) and
/// 1.4 % (at most) of the skin's displacement away from receding after
/// every iteration, every third 1.2 % and 3.4 % (RMS within Converge's own
/// 2 % tolerance); only in the last three iterations, where the skin slides under
/// the collider, the collider lagged the whole solve and frames ended up to
/// 14 % away. The iteration that ends the solve always recedes: it decides
/// where the collider rests. Counted from the end, as
/// [`Iteration::remaining`] tells it, that holds where Converge's stopping
/// rule ends the solve too: the hook's closing iteration
/// ([`RECESSION_CLOSING_ITERATIONS`]) follows once the rule is met.
pub(super) fn recedes_after(iteration: Iteration) -> bool {
    match iteration.remaining {
        Some(remaining) => remaining % RECESSION_EVERY == 0,
        None => iteration.index % RECESSION_EVERY == RECESSION_EVERY - 1,
    }
}

/// In-loop recessions run after one iteration in this many ([`recedes_after`]).
pub(super) const RECESSION_EVERY: usize = 3;

/// Iterations the solve runs after Converge's stopping rule is met where
/// compliant colliders recede: the last, which must know it is the last.
pub(super) const RECESSION_CLOSING_ITERATIONS: usize = 1;

/// Compliant vertices move from the collider's current positions towards
/// `goal` while the skin stays at `x`; contacts with the skin stop them (the
/// collider recedes). Kinematic vertices go to their goals. The collider is
/// left at rest at the result.
///
/// `fresh`: the first recession of a substep, which tests every compliant
/// vertex and element against the skin (the later ones test only what
/// moves). Either way the skin standing in as a collider has its boxes made
/// again only where it moved since the last recession: a substep starts
/// where the last one's solve, whose last iteration receded, left the skin.
pub(super) fn recede_from(
    skin_collider: &mut Option<Collider>,
    skin: &Skin,
    collider: &mut Collider,
    own: &Skin,
    x: &[Vec3],
    goal: &[Vec3],
    fresh: bool,
) -> Result<Recession> {
    let refit_started = std::time::Instant::now();
    let settings = ColliderSettings { thickness: collider.settings().thickness, static_friction: 0.0, kinetic_friction: 0.0 };
    // After every iteration the skin moves much only near the contacts: its
    // boxes are made again only where it moved (see `SKIN_SLACK`).
    let slack = settings.thickness * SKIN_SLACK;
    let (obstacle, refitted) = match skin_collider {
        Some(c) => {
            c.set_settings(settings)?;
            let refitted = c.rest_at(x, slack, false)?;
            (c, refitted)
        }
        None => {
            let c = skin_collider.insert(Collider::new(x, skin.triangles(), settings)?);
            let refitted = c.rest_at(x, slack, true)?;
            (c, refitted)
        }
    };
    // In the loop the skin's own pass has just cleared the skin of the
    // collider where it stands: only what moves now needs testing. The first
    // recession of a substep starts from last substep's state and tests all.
    // Most moving vertices rest at twice the thickness from the skin, which
    // is smooth under them: one slab proves each one's star apart.
    let params = ResolveParams { motion: ColliderMotion::AtCurrent, friction: false, moving_only: !fresh, star_slabs: true, ..ResolveParams::in_loop() };
    let set = ColliderSet::new([&*obstacle]);
    // Where a goal lies behind the skin (or within the thickness of it), the
    // vertex recedes along its own normal (the direction its region pushes
    // into the skin) to the skin's offset surface on the side it is on;
    // elsewhere it heads for its goal. Where it ends depends on the goal and
    // the skin only, not on the path (the path only tells which side of the
    // skin the vertex is on), so the result does not depend on substeps or
    // iterations. (The point of the skin nearest the goal would minimise the
    // spring exactly, but for a goal deep behind a curved skin it moves much
    // further than the skin does: 1 and 4 substeps then differ by 6% of the
    // motion.) The move is still checked by continuous collision detection,
    // which stops what the heading did not foresee.
    let clearance = settings.thickness * CLEARANCE + 1e-6;
    let refit_ms = ms_since(refit_started);
    let started = std::time::Instant::now();
    let start = collider.current().to_vec();
    let stiffness = collider.compliance().map(|k| k.stiffness.clone()).unwrap_or_default();
    let normals = vertex_normals(goal, collider.triangles());
    let heading: Vec<Vec3> = (0..goal.len())
        .into_par_iter()
        .map(|v| {
            let g = goal[v];
            if stiffness.get(v).is_none_or(|&k| k == 0.0) {
                return g;
            }
            // A goal clear of the skin and reachable in a straight line needs no
            // search for the skin's closest point (which is slow far from it).
            // A vertex already at its goal casts no ray: a segment of no
            // length meets no triangle (`first_hit` finds none). On the
            // compliant flesh bench that is 324k of the 484k rays a run (most
            // of the collider rests at its goals), each a call, an
            // allocation and a box test for nothing.
            let hit = if start[v] == g { None } else { obstacle.first_hit(start[v], g) };
            if hit.is_none() && !obstacle.is_within(g, clearance) {
                return g;
            }
            let face_normal = |t: u32| {
                let [a, b, c] = obstacle.triangles()[t as usize].map(|k| x[k as usize]);
                (b - a).cross(c - a).normalize_or_zero()
            };
            // The point of the skin nearest the goal: no farther than where
            // the straight line met the skin, or than the clearance the goal
            // is within (the search need not look farther; slightly more, for
            // the rounding of the fraction).
            let within = match hit {
                Some((t, _)) => (1.0 - t) * (g - start[v]).length(),
                None => clearance,
            };
            let nearest = || obstacle.closest_point_within(g, within as f64 * (1.0 + 1e-4) + 1e-6);
            let outward = |triangle: u32, at: Vec3| {
                let normal = face_normal(triangle);
                if normal.dot(start[v] - at) >= 0.0 { normal } else { -normal }
            };
            let n = normals[v];
            let Some((t, _)) = hit else {
                // The goal is within the clearance of the skin, in reach.
                let Some(near) = nearest() else { return g };
                let side = outward(near.triangle, near.point);
                if side.dot(g - near.point) >= clearance {
                    return g;
                }
                let dir = if n.dot(side) >= 0.0 { n } else { -n };
                if dir.dot(side) < 0.3 {
                    return near.point + side * clearance; // the normal runs along the skin: no well-defined crossing
                }
                let reach = 4.0 * ((g - near.point).length() + clearance);
                return match obstacle.first_hit(g, g + dir * reach) {
                    Some((t, tri)) => {
                        let m = face_normal(tri);
                        let m = if m.dot(dir) >= 0.0 { m } else { -m };
                        g + dir * (t * reach + clearance / m.dot(dir).max(0.3))
                    }
                    None => near.point + side * clearance,
                };
            };
            // The goal is behind the skin as seen from the vertex (a resting
            // vertex pressed into it, most of the work of a frame): the vertex
            // heads for where its own normal through the goal comes out of the
            // skin, offset by the clearance. That crossing's triangle says
            // whether the normal runs along the skin, so the point nearest the
            // goal (a search through all the skin within the goal's depth
            // behind it) is needed only where it does, or where the normal
            // finds no crossing: the offset surface over it then, which like
            // the crossing depends on the goal and the skin only.
            let fallback = || match nearest() {
                Some(near) => near.point + outward(near.triangle, near.point) * clearance,
                None => g,
            };
            let dir = if n.dot(start[v] - g) >= 0.0 { n } else { -n };
            let reach = 4.0 * ((1.0 - t) * (g - start[v]).length() + clearance);
            match obstacle.first_hit(g, g + dir * reach) {
                Some((t, tri)) => {
                    let m = face_normal(tri);
                    let m = if m.dot(dir) >= 0.0 { m } else { -m };
                    if m.dot(dir) < 0.3 {
                        return fallback(); // the normal runs along the skin: no well-defined crossing
                    }
                    g + dir * (t * reach + clearance / m.dot(dir))
                }
                None => fallback(),
            }
        })
        .collect();
    let heading_ms = ms_since(started);
    let mut end = heading;
    let started = std::time::Instant::now();
    let stats = set.resolve_path(&start, &mut end, own, &params)?;
    // A move that cannot be made free of contacts is not made: the collider
    // stays where it was, which is collision-free.
    let start = if stats.pinched.is_empty() { end } else { start };
    collider.set_positions(&start, &start)?;
    Ok(Recession {
        contacts: stats.vertex_contacts + stats.edge_contacts + stats.collider_vertex_contacts,
        refitted,
        heading_ms,
        contacts_ms: refit_ms + ms_since(started),
    })
}

/// Wall-clock milliseconds since `started` (for [`super::ContactWork`]).
pub(super) fn ms_since(started: std::time::Instant) -> f64 {
    started.elapsed().as_secs_f64() * 1e3
}

/// What one [`recede_from`] did.
pub(super) struct Recession {
    /// Contacts that stopped compliant vertices at the skin.
    pub contacts: usize,
    /// Skin vertices whose boxes as a collider were made again.
    pub refitted: usize,
    /// Wall-clock time spent choosing where each vertex heads.
    pub heading_ms: f64,
    /// Wall-clock time of the contact pass that stops them at the skin.
    pub contacts_ms: f64,
}

/// The clearance of the skin at `positions` for a substep's in-loop passes
/// (see [`Clearance`]), measured against the kinematic colliders where they
/// stand and with their supporting planes. A compliant collider recedes
/// after every pass, between where it stands and its goal and a little
/// sideways as the skin under it moves: it is measured by its [`Envelope`],
/// each vertex's box around both grown by the clearance's radius, and
/// without planes. The clearance is valid for as long as every compliant
/// collider stays inside its envelope; the step measures again when one
/// leaves (`StepReport::clearance_measurements`).
///
/// A compliant collider gets no supporting planes from its goal shape: it
/// can rest outside that shape (a ball jumping into a closed skin stops at
/// the skin, short of its goal), so such planes would not bound it, and
/// where it stays inside they prove only the contact's rim (issue 29,
/// `docs/performance.md`, "supporting planes from the goal shape").
pub(super) fn in_loop_clearance(colliders: &[&Collider], goals: &[Option<Vec<Vec3>>], skin: &Skin, positions: &[Vec3]) -> Result<Clearance> {
    let radius = Clearance::default_radius(colliders, skin, positions);
    if colliders.iter().all(|c| !c.is_compliant()) {
        return Clearance::new(colliders, skin, positions, radius)?.with_planes(colliders);
    }
    let envelopes = colliders
        .iter()
        .zip(goals)
        .map(|(c, goal)| match goal {
            Some(goal) if c.is_compliant() => Envelope::new(c, goal, radius).map(Some),
            _ => Ok(None),
        })
        .collect::<Result<Vec<_>>>()?;
    Clearance::with_envelopes(colliders, envelopes, skin, positions, radius)
}

/// A compliant collider as a moving mesh: its edges and triangles, inverse
/// mass 1 where compliant and 0 where kinematic.
pub(super) fn compliant_skin(collider: &Collider, stiffness: &[f32]) -> Result<Skin> {
    let inverse_mass = stiffness.iter().map(|&k| if k > 0.0 { 1.0 } else { 0.0 }).collect();
    Skin::new(collider.vertex_count(), collider.edges().to_vec(), collider.triangles().to_vec())?.with_inverse_mass(inverse_mass)
}

/// Area-weighted vertex normals (unit, or zero where undefined).
fn vertex_normals(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut normals = vec![Vec3::ZERO; positions.len()];
    for tri in triangles {
        let [a, b, c] = tri.map(|v| positions[v as usize]);
        let n = (b - a).cross(c - a);
        for &v in tri {
            normals[v as usize] += n;
        }
    }
    normals.iter().map(|n| n.normalize_or_zero()).collect()
}
