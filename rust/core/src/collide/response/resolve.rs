//! The rounds of a resolution: detection on what moved, corrections
//! averaged per vertex, pinched vertices bounded.

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::{d, ColliderMotion, ColliderSet, ContactStats, ResolveParams};
use crate::collide::bvh::Bounds;
use crate::collide::clearance::{Clearance, PLANE_REACH};
use crate::collide::friction::{Anchor, Anchors, Cone, Hold, Slide};
use crate::collide::geometry::unit;
use crate::collide::planes::{Lift, LocalPlanes, VertexStep};
use crate::collide::skin::Skin;
use crate::mesh::validate_positions;
use crate::{Error, Result};

/// One move a pass made of a vertex.
#[derive(Clone, Copy)]
pub(super) enum Move {
    /// A vertex–triangle projection (or a lift along a plane), or pushes
    /// that static friction held.
    Projected(Hold),
    /// A push out along edge–edge or collider corner contacts' normals, by
    /// this change, slowed by this kinetic friction (0: none).
    Pushed(Vec3, f32),
    /// Put back where its step started (`hold_back`).
    HeldBack,
}

/// Whether a vertex moved by `moves` (in order) is left sliding, and along
/// what: a projection decides; a push slides along its own direction, or
/// keeps a slide along a normal it follows (within about 8°); anything else,
/// a hold-back included, leaves it stuck.
fn sliding_after(moves: impl Iterator<Item = Move>) -> Option<Slide> {
    let mut state: Option<Slide> = None;
    let mut first = true;
    for m in moves {
        state = match (m, state) {
            (Move::Projected(Hold::Sliding(slide)), _) => Some(slide),
            (Move::Projected(Hold::Stuck(_)), _) | (Move::HeldBack, _) => None,
            (Move::Pushed(delta, _), Some(slide)) if delta.dot(slide.normal) > 0.99 * delta.length() => Some(slide),
            (Move::Pushed(delta, friction), None) if first => delta.try_normalize().map(|normal| Slide { normal, friction }),
            (Move::Pushed(..), _) => None,
        };
        first = false;
    }
    state
}

/// The anchors as one pass reads them: an anchored vertex's first contact
/// in the pass decides, from where the solve pulled it, whether it stays
/// stuck ([`Anchor::holds`]); if so, every contact of it in the pass ends
/// at its anchor ([`Anchor::lift`]).
struct AnchorPass<'x> {
    anchors: Option<&'x Anchors>,
    held: HashMap<u32, bool>,
}

impl AnchorPass<'_> {
    /// Vertex `i`'s anchor if it holds the vertex in this pass; `pulled` is
    /// where the vertex is before this contact moves it.
    fn held(&mut self, i: u32, pulled: Vec3) -> Option<Anchor> {
        let anchor = *self.anchors?.get(i)?;
        self.held.entry(i).or_insert_with(|| anchor.holds(pulled)).then_some(anchor)
    }

    /// The anchored vertices no contact of this round touches although the
    /// solve pulled them into their anchor's surface within its static cone,
    /// ascending, with their anchors: they are held there. A contact puts a
    /// vertex a slack beyond the collider's thickness, and a pull back into
    /// that slack meets no contact: without this, such a vertex lost its
    /// anchor, sank below the thickness in the next iteration and was
    /// anchored again elsewhere, a cycle of four iterations that kept the
    /// slide's first frame in contact 5 % from converged (issue 28,
    /// `docs/performance.md`). Marks them held for the pass. A vertex of
    /// inverse mass 0 is never corrected, so it is never held either.
    fn pressed_without_contact(&mut self, contacts: &[u32], end: &[Vec3], skin: &Skin) -> Vec<(u32, Anchor)> {
        let Some(anchors) = self.anchors else { return Vec::new() };
        let mut pressed: Vec<(u32, Anchor)> = anchors
            .iter()
            .filter(|(i, _)| contacts.binary_search(i).is_err() && skin.inverse_mass(*i) > 0.0)
            .filter(|(i, anchor)| anchor.holds(end[*i as usize]))
            .collect();
        pressed.sort_unstable_by_key(|&(i, _)| i);
        for &(i, _) in &pressed {
            self.held.insert(i, true);
        }
        pressed
    }

    /// Vertex `i` leaves its anchor for the rest of the pass.
    fn release(&mut self, i: u32) {
        self.held.insert(i, false);
    }

    /// Vertex `i`'s anchor if a contact in this pass found it held.
    fn kept(&self, i: u32) -> Option<Anchor> {
        self.held.get(&i).copied().unwrap_or(false).then(|| self.anchors.and_then(|a| a.get(i).copied())).flatten()
    }
}

/// The pushes of one round on one vertex: their changes, how many, and how
/// friction left their contact points.
#[derive(Default)]
struct Pushes {
    delta: DVec3,
    count: u32,
    /// Sum of the normals of the contacts static friction held, and the
    /// cone of the first of them.
    stuck_normals: DVec3,
    stuck: Option<Cone>,
    stuck_count: u32,
    /// Largest kinetic friction of the contacts that slid.
    kinetic_friction: f32,
}

impl Pushes {
    fn add(&mut self, delta: DVec3, hold: Hold) {
        self.delta += delta;
        self.count += 1;
        match hold {
            Hold::Stuck(cone) => {
                self.stuck_normals += cone.normal.as_dvec3();
                self.stuck.get_or_insert(cone);
                self.stuck_count += 1;
            }
            Hold::Sliding(slide) => self.kinetic_friction = self.kinetic_friction.max(slide.friction),
        }
    }

    /// Stuck (in the cone of the contacts' mean normal) if static friction
    /// held every contact, else pushed by `delta`.
    fn outcome(&self, delta: Vec3) -> Move {
        match (self.stuck, unit(self.stuck_normals)) {
            (Some(cone), Some(normal)) if self.stuck_count == self.count => Move::Projected(Hold::Stuck(Cone { normal: normal.as_vec3(), ..cone })),
            _ => Move::Pushed(delta, self.kinetic_friction),
        }
    }
}

impl<'a> ColliderSet<'a> {
    /// Edge–edge and collider-vertex–skin-triangle corrections of one round,
    /// averaged per vertex. Returns the number of contacts and per vertex its
    /// new end and how the contacts left it: stuck if static friction held
    /// every one of them (in their mean normal's cone), else pushed.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn shared_corrections(
        &self,
        start: &[Vec3],
        end: &[Vec3],
        skin: &Skin,
        edges: &[u32],
        triangles: &[u32],
        params: &ResolveParams,
        planes: Option<(&LocalPlanes, &[Vec3])>,
    ) -> (usize, usize, Vec<(u32, Vec3, Move)>) {
        let cleared = |corners: &[u32]| planes.is_some_and(|(p, from)| p.clears(corners, from, end));
        let from_edges: Vec<(u32, [DVec3; 2], Hold)> = if params.edge_edge {
            edges
                .par_iter()
                .filter_map(|&k| {
                    let edge = skin.edges()[k as usize];
                    if cleared(&edge) {
                        return None;
                    }
                    self.edge_correction(start, end, edge, edge.map(|v| skin.inverse_mass(v)), params).map(|((a, b), hold)| (k, [a, b], hold))
                })
                .collect()
        } else {
            Vec::new()
        };
        let from_faces: Vec<(u32, [DVec3; 3], Hold)> = if params.collider_vertices {
            triangles
                .par_iter()
                .filter_map(|&k| {
                    let tri = skin.triangles()[k as usize];
                    if cleared(&tri) {
                        return None;
                    }
                    self.face_correction(start, end, tri, tri.map(|v| skin.inverse_mass(v)), params).map(|(c, hold)| (k, c, hold))
                })
                .collect()
        } else {
            Vec::new()
        };
        let mut sum: std::collections::BTreeMap<u32, Pushes> = Default::default();
        let mut add = |v: u32, delta: DVec3, hold: Hold| sum.entry(v).or_default().add(delta, hold);
        for (k, deltas, hold) in &from_edges {
            for (&v, &delta) in skin.edges()[*k as usize].iter().zip(deltas) {
                add(v, delta, *hold);
            }
        }
        for (k, deltas, hold) in &from_faces {
            for (&v, &delta) in skin.triangles()[*k as usize].iter().zip(deltas) {
                add(v, delta, *hold);
            }
        }
        let changes = sum
            .into_iter()
            .filter_map(|(v, pushes)| {
                let delta = pushes.delta / pushes.count as f64;
                let p = (d(end[v as usize]) + delta).as_vec3();
                p.is_finite().then(|| (v, p, pushes.outcome(delta.as_vec3())))
            })
            .collect();
        (from_edges.len(), from_faces.len(), changes)
    }

    /// True when no collider moves during a pass of `motion`: still in-loop
    /// passes, and sweeps of colliders that stayed where they were.
    fn stand_still(&self, motion: ColliderMotion) -> bool {
        match motion {
            ColliderMotion::AtCurrent => true,
            ColliderMotion::Swept => self.colliders.iter().all(|col| {
                bytemuck::cast_slice::<Vec3, u32>(col.previous()) == bytemuck::cast_slice::<Vec3, u32>(col.current())
            }),
        }
    }

    /// Whether vertex `i`'s step from `start` to `end` still meets a collider:
    /// the supporting planes decide where they can, the lookup otherwise.
    fn step_collides(
        &self,
        i: u32,
        start: &[Vec3],
        end: &[Vec3],
        params: &ResolveParams,
        planes: Option<(&LocalPlanes, &[Vec3])>,
        lift: impl Fn(usize) -> Lift,
    ) -> bool {
        let (s, e) = (start[i as usize], end[i as usize]);
        match planes.map_or(VertexStep::Unknown, |(p, from)| p.vertex_step(i, from[i as usize], e, lift)) {
            VertexStep::Clear => false,
            VertexStep::Lifted(..) => true,
            VertexStep::Unknown => self.vertex_correction(s, e, params).is_some(),
        }
    }

    /// Puts `first` back at their start positions, then every vertex whose
    /// step the reverted ones make collide again, until none does: the start
    /// is clear of still colliders, so this ends with every vertex either on
    /// a checked path or back where it started. Returns the vertices held.
    #[allow(clippy::too_many_arguments)]
    fn hold_back(
        &self,
        start: &[Vec3],
        end: &mut [Vec3],
        skin: &Skin,
        params: &ResolveParams,
        first: Vec<u32>,
        active: &[u32],
        planes: Option<(&LocalPlanes, &[Vec3])>,
        lift: impl Fn(usize) -> Lift + Sync,
    ) -> Vec<u32> {
        let mut held = vec![false; start.len()];
        let mut newly = first;
        let mut all = Vec::new();
        while !newly.is_empty() {
            for &v in &newly {
                held[v as usize] = true;
                end[v as usize] = start[v as usize];
            }
            all.extend_from_slice(&newly);
            // The elements around the vertices just held move differently now;
            // the last round's vertices had their corrections applied unverified.
            let (edges, triangles) = skin.touching(&newly, (&[], &[]));
            let mut again: Vec<u32> = active
                .par_iter()
                .copied()
                .filter(|&i| !held[i as usize] && self.step_collides(i, start, end, params, planes, &lift))
                .collect();
            let (_, _, shared) = self.shared_corrections(start, end, skin, &edges, &triangles, params, planes);
            again.extend(shared.iter().map(|(v, ..)| *v).filter(|&v| !held[v as usize]));
            again.sort_unstable();
            again.dedup();
            newly = again;
        }
        all.sort_unstable();
        all
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn resolve(
        &self,
        start: &[Vec3],
        end: &mut [Vec3],
        skin: &Skin,
        params: &ResolveParams,
        clearance: Option<&Clearance>,
        wider: Option<&Clearance>,
        carried: Option<&LocalPlanes>,
        anchors: Option<&mut Anchors>,
    ) -> Result<ContactStats> {
        let n = start.len();
        if end.len() != n || skin.vertex_count() != n {
            return Err(Error::invalid(format!(
                "start has {n} positions, end has {} and the skin has {} vertices; all three must agree",
                end.len(),
                skin.vertex_count()
            )));
        }
        validate_positions("start positions", start)?;
        validate_positions("end positions", end)?;
        if let Some(v) = anchors.as_ref().and_then(|a| a.iter().map(|(v, _)| v).find(|&v| v as usize >= n)) {
            return Err(Error::invalid(format!(
                "an anchor names vertex {v} but the skin has {n} vertices: anchors belong to the skin they were made on"
            )));
        }
        let mut stats = ContactStats::default();
        if self.colliders.is_empty() || n == 0 {
            return Ok(stats);
        }
        // Where the vertices the pass moves were asked to go, recorded when
        // first moved (most of a skin is not).
        let mut requested: Vec<(u32, Vec3)> = Vec::new();
        let mut moved = vec![false; n];
        // How each move left its vertex, in the order of the moves: a vertex
        // slides if the last move of it was a projection that let it slide.
        let mut holds: Vec<(u32, Move)> = Vec::new();
        // The clearance and its planes hold for colliders standing still.
        let still = params.motion == ColliderMotion::AtCurrent;
        let clearance = clearance.filter(|c| still && c.is_valid_for(&self.colliders, n));
        let lift = |c: usize| {
            let settings = self.colliders[c].settings();
            let friction = |mu: f32| if params.friction { mu as f64 } else { 0.0 };
            Lift {
                slack: self.slack(settings.thickness as f64),
                static_friction: friction(settings.static_friction),
                kinetic_friction: friction(settings.kinetic_friction),
            }
        };
        let (mut active, mut active_edges, mut active_triangles) = match clearance {
            // Elements the clearance proves apart are left out from the start.
            // With a wider one too, what neither proves apart.
            Some(clearance) => {
                let unproven = match wider.filter(|w| still && w.is_valid_for(&self.colliders, n)) {
                    Some(wider) => clearance.unproven_with(wider, skin, start, end),
                    None => clearance.unproven(skin, start, end),
                };
                (unproven.vertices, unproven.edges, unproven.triangles)
            }
            // Without one, those whose step misses every collider's whole box.
            None => {
                let mut reach_vertices = vec![false; n];
                let mut reach_edges = vec![false; skin.edges().len()];
                let mut reach_triangles = vec![false; skin.triangles().len()];
                for c in 0..self.colliders.len() {
                    // Each vertex's box over the step where the collider's
                    // trees see it, once; an element's is its corners' union.
                    let root = self.triangle_tree(c, params.motion).bounds();
                    let boxes: Vec<Bounds> = (0..n)
                        .into_par_iter()
                        .with_min_len(4096)
                        .map(|i| self.query_box(c, params.motion, Bounds::of_points(&[start[i]]), Bounds::of_points(&[end[i]])))
                        .collect();
                    let mark = |flags: &mut [bool], elements: &[u32], size: usize| {
                        flags.par_chunks_mut(4096).enumerate().for_each(|(chunk, out)| {
                            for (k, flag) in out.iter_mut().enumerate() {
                                let first = (chunk * 4096 + k) * size;
                                let union = elements[first..first + size].iter().fold(Bounds::EMPTY, |u, &v| u.union(boxes[v as usize]));
                                *flag |= root.overlaps(&union);
                            }
                        })
                    };
                    reach_vertices.par_iter_mut().zip(&boxes).with_min_len(4096).for_each(|(flag, b)| *flag |= root.overlaps(b));
                    mark(&mut reach_edges, skin.edges().as_flattened(), 2);
                    mark(&mut reach_triangles, skin.triangles().as_flattened(), 3);
                }
                let listed = |flags: &[bool]| -> Vec<u32> { (0..flags.len() as u32).into_par_iter().with_min_len(4096).filter(|&k| flags[k as usize]).collect() };
                (listed(&reach_vertices), listed(&reach_edges), listed(&reach_triangles))
            }
        };
        // Elements that stand still where the caller knows them clear of
        // colliders that stand still stay clear (`ResolveParams::moving_only`).
        if params.moving_only && still {
            let moves = |v: u32| start[v as usize] != end[v as usize];
            active.retain(|&i| moves(i));
            active_edges.retain(|&e| skin.edges()[e as usize].iter().any(|&v| moves(v)));
            active_triangles.retain(|&t| skin.triangles()[t as usize].iter().any(|&v| moves(v)));
        }
        // Vertices with inverse mass 0 move as imposed: never corrected.
        if skin.has_inverse_mass() {
            active.retain(|&i| skin.inverse_mass(i) > 0.0);
        }
        // A vertex whose whole star one slab proves apart needs no test, nor
        // do its edges and triangles (`ResolveParams::star_slabs`). Only in
        // the first round: what a round moves is tested again in the next.
        if params.star_slabs && still {
            let apart = self.stars_apart(start, end, skin, &active, params);
            active.retain(|&i| !apart[i as usize]);
            active_edges.retain(|&e| !skin.edges()[e as usize].iter().any(|&v| apart[v as usize]));
            active_triangles.retain(|&t| !skin.triangles()[t as usize].iter().any(|&v| apart[v as usize]));
        }
        stats.tested = active.len();
        // Supporting planes: the clearance's for still colliders; for sweeping
        // ones, planes around the active vertices in the frame drifting with
        // the colliders, if they translate together (carried along from the
        // last frame where they hold). Each comes with the step starts in its
        // frame.
        let all_swept = params.motion == ColliderMotion::Swept;
        let drifting = match clearance {
            None if all_swept => {
                let radius = PLANE_REACH * Clearance::default_radius(&self.colliders, skin, start);
                LocalPlanes::drifting(&self.colliders, &self.outward, start, &active, radius, carried)
            }
            _ => None,
        };
        let planes: Option<(&LocalPlanes, &[Vec3])> = match &drifting {
            Some((planes, from)) => Some((planes, from)),
            None => clearance.and_then(|c| c.planes()).map(|planes| (planes, start)),
        };
        let lifted = AtomicUsize::new(0);
        // Anchors hold where the colliders stand still.
        let anchors = anchors.filter(|_| still);
        let mut anchored = AnchorPass { anchors: anchors.as_deref(), held: HashMap::new() };
        let mut converged = false;
        for _ in 0..params.max_rounds.max(1) {
            stats.rounds += 1;
            // Skin vertices against collider triangles.
            let updates: Vec<(u32, (Vec3, Hold))> = active
                .par_iter()
                .filter_map(|&i| {
                    let (s, e) = (start[i as usize], end[i as usize]);
                    match planes.map_or(VertexStep::Unknown, |(p, from)| p.vertex_step(i, from[i as usize], e, lift)) {
                        VertexStep::Clear => None,
                        VertexStep::Lifted(p, hold) => {
                            lifted.fetch_add(1, Ordering::Relaxed);
                            Some((i, (p, hold)))
                        }
                        VertexStep::Unknown => self.vertex_correction(s, e, params).map(|p| (i, p)),
                    }
                })
                .collect();
            stats.vertex_contacts += updates.len();
            stats.plane_lifts += lifted.swap(0, Ordering::Relaxed);
            let mut apply = |i: u32, p: Vec3, end: &mut [Vec3]| {
                if !moved[i as usize] {
                    moved[i as usize] = true;
                    requested.push((i, end[i as usize]));
                }
                end[i as usize] = p;
            };
            let mut lifted_now: Vec<u32> = Vec::with_capacity(updates.len());
            if stats.rounds == 1 {
                let mut contacts: Vec<u32> = updates.iter().map(|&(i, _)| i).collect();
                contacts.sort_unstable();
                for (i, anchor) in anchored.pressed_without_contact(&contacts, end, skin) {
                    apply(i, anchor.point, end);
                    holds.push((i, Move::Projected(Hold::Stuck(anchor.cone))));
                    lifted_now.push(i);
                }
            }
            for (i, (p, hold)) in updates {
                let (p, hold) = match anchored.held(i, end[i as usize]) {
                    Some(anchor) => (anchor.lift(p, hold.normal()), Hold::Stuck(anchor.cone)),
                    None => (p, hold),
                };
                apply(i, p, end);
                holds.push((i, Move::Projected(hold)));
                lifted_now.push(i);
            }
            // Skin edges against collider edges, skin triangles against
            // collider vertices: those still to be checked, and those around
            // the vertices just moved, at their new ends. An element checked
            // here stays checked until one of its corners moves again.
            (active_edges, active_triangles) = skin.touching(&lifted_now, (&active_edges, &active_triangles));
            let (ee, fv, shared) = self.shared_corrections(start, end, skin, &active_edges, &active_triangles, params, planes);
            stats.edge_contacts += ee;
            stats.collider_vertex_contacts += fv;
            let mut pushed: Vec<u32> = Vec::with_capacity(shared.len());
            for (i, p, how) in shared {
                anchored.release(i);
                let how = match how {
                    Move::Pushed(_, friction) => Move::Pushed(p - end[i as usize], friction),
                    how => how,
                };
                holds.push((i, how));
                apply(i, p, end);
                pushed.push(i);
            }
            // Every vertex moved in this round is checked again in the next;
            // the elements around those the shared corrections pushed are
            // checked after the next round's vertex corrections.
            let mut next: Vec<u32> = lifted_now.iter().chain(&pushed).copied().collect();
            next.sort_unstable();
            next.dedup();
            next.retain(|&i| skin.inverse_mass(i) > 0.0);
            if next.is_empty() {
                converged = true;
                break;
            }
            (active_edges, active_triangles) = skin.touching(&pushed, (&[], &[]));
            active = next;
        }
        if !converged {
            // Verify the last round's changes; what is still in violation is pinched.
            let mut pinched: Vec<u32> = active
                .par_iter()
                .copied()
                .filter(|&i| self.step_collides(i, start, end, params, planes, lift))
                .collect();
            let (_, _, shared) = self.shared_corrections(start, end, skin, &active_edges, &active_triangles, params, planes);
            pinched.extend(shared.iter().map(|(v, ..)| *v));
            pinched.sort_unstable();
            pinched.dedup();
            if self.stand_still(params.motion) {
                // Against colliders that stand still, the pass's start was clear of
                // them (the step keeps it so): what the rounds cannot clear goes back
                // there, so a contact that held keeps holding while nothing moves the
                // colliders, and nothing is pinched that has room (issue 29).
                let held = self.hold_back(start, end, skin, params, pinched, &active, planes, lift);
                holds.extend(held.iter().map(|&v| (v, Move::HeldBack)));
                stats.held = held;
                pinched = Vec::new();
            }
            // Bound the displacement of pinched vertices: no farther from the
            // requested end than the step length plus twice the largest thickness.
            let max_thickness =
                self.colliders.iter().map(|c| c.settings().thickness as f64).fold(0.0, f64::max);
            requested.sort_unstable_by_key(|&(i, _)| i);
            for &i in &pinched {
                let Ok(k) = requested.binary_search_by_key(&i, |&(j, _)| j) else { continue };
                let (i, asked) = (i as usize, d(requested[k].1));
                let limit = (asked - d(start[i])).length() + 2.0 * max_thickness + self.slack(max_thickness);
                let offset = d(end[i]) - asked;
                if offset.length() > limit {
                    end[i] = (asked + offset * (limit / offset.length())).as_vec3();
                }
            }
            stats.pinched = pinched;
        }
        // Stable: each vertex's moves stay in order, its last one decides.
        holds.sort_by_key(|&(i, _)| i);
        stats.sliding = holds
            .chunk_by(|a, b| a.0 == b.0)
            .filter(|moves| stats.pinched.binary_search(&moves[0].0).is_err())
            .filter_map(|moves| Some((moves[0].0, sliding_after(moves.iter().map(|m| m.1))?)))
            .collect();
        // A vertex the pass left stuck is anchored where it ends, unless an
        // anchor held it already (which stays where it was): the anchors of
        // the next pass. Those the pass released, left sliding or pinched,
        // or no longer touched (lifted off the surface) have none.
        if anchors.is_some() {
            let mut next = HashMap::new();
            for moves in holds.chunk_by(|a, b| a.0 == b.0) {
                let i = moves[0].0;
                if stats.pinched.binary_search(&i).is_ok() {
                    continue;
                }
                let anchor = match moves.last().map(|m| m.1) {
                    Some(Move::Projected(Hold::Stuck(cone))) => Some(anchored.kept(i).unwrap_or(Anchor { point: end[i as usize], cone })),
                    Some(Move::HeldBack) => anchored.kept(i),
                    _ => None,
                };
                if let Some(anchor) = anchor {
                    next.insert(i, anchor);
                }
            }
            if let Some(anchors) = anchors {
                anchors.replace(next);
            }
        }
        requested.sort_unstable_by_key(|&(i, _)| i);
        for (i, asked) in requested {
            stats.moved.push(i);
            stats.max_correction = stats.max_correction.max((end[i as usize] - asked).length());
        }
        Ok(stats)
    }
}
