//! Contact resolution by projection, with position-based friction.
//!
//! [`ColliderSet::resolve_path`] takes every skin vertex's motion over a
//! step, `start[i] → end[i]`, while the colliders move from their previous to
//! their current positions ([`ColliderMotion::Swept`], the first pass) or stay
//! at their current positions ([`ColliderMotion::AtCurrent`], the in-loop
//! pass), and changes `end` so that the motion is collision-free:
//!
//! 1. **Vertex–triangle**: conservative CCD (with the collider's thickness as
//!    minimum separation) gives each vertex its earliest contact. The contact
//!    point (barycentric `u, v` on the triangle) is followed to the end of the
//!    step and the vertex is projected onto the collision-free side of that
//!    triangle's plane, offset by the thickness. The side is the outside for
//!    closed colliders (outward winding detected from the signed volume) and,
//!    for open ones, the side the vertex was on just before contact.
//! 2. **Friction** (Bender, Müller, Macklin 2015): the tangential slip
//!    relative to the collider since contact, Δx⊥, is removed entirely if
//!    |Δx⊥| < μs·d (static friction; d = projection depth), otherwise reduced
//!    by μk·d (kinetic). Colliders are kinematic (inverse mass 0), so the whole
//!    correction goes to the skin.
//! 3. **Edge–edge** and **collider vertex–skin triangle**: each skin edge
//!    against the collider edges, each skin triangle against the collider
//!    vertices (sharp collider corners). The correction moves the skin's
//!    contact point out along the contact normal, split between the skin
//!    vertices by their barycentric weights (the minimum-norm change).
//!    Several contacts on a vertex are averaged (Jacobi). With these and 1,
//!    every way two triangle meshes can start to intersect is covered.
//! 4. Repeat detection on the vertices that moved, up to
//!    [`ResolveParams::max_rounds`] rounds; an edge or triangle is checked
//!    again only once a corner has moved since its last check (a vertex
//!    projected in step 1 has its elements checked in the same round).
//!    Vertices still in violation after the last round are **pinched**
//!    (e.g. squeezed between two colliders): they are reported, their
//!    displacement is bounded, never NaN.
//!
//! # Use in the two passes (seed 000, Algorithm 2)
//!
//! ```text
//! // once per bind
//! let skin = Skin::from_mesh(mesh)?;
//! // once per frame
//! for c in &mut colliders { c.update(&collider_positions_this_frame)?; }
//! let set = ColliderSet::new(colliders.iter());
//! // pass 1: from last frame's collision-free output towards this frame's input
//! let mut x = input.clone();
//! let stats = set.resolve_path(&last_output, &mut x, &skin, &ResolveParams::first_pass())?;
//! // pass 2: inside the solver loop; the clearance lets every pass skip the
//! // skin that cannot have reached a collider since it was measured, and its
//! // planes prove resting contacts apart and lift the skin the solve pulls in
//! let radius = Clearance::default_radius(set.colliders(), &skin, &x);
//! let clearance = Clearance::new(set.colliders(), &skin, &x, radius)?.with_planes(set.colliders())?;
//! for _ in 0..iterations {
//!     let before = x.clone();
//!     solver.iterate(&mut x);                         // global + local step
//!     let s = set.resolve_path_with(&before, &mut x, &skin, &ResolveParams::in_loop(), Some(&clearance))?;
//!     // s.pinched → soft constraints / report
//! }
//! ```
//!
//! The start positions must be collision-free (they are the output of the
//! previous call); the result then is too, up to pinched vertices.

use std::cell::RefCell;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::thread::LocalKey;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::audit::{fan_triangles, triangle_edges};
use super::bvh::{BoxTree, Bounds};
use super::ccd::{self, CcdParams};
use super::clearance::{ascending_unique, Clearance, PLANE_REACH};
use super::collider::Collider;
use super::geometry::{triangle_normal, unit};
use super::planes::{Lift, LocalPlanes, VertexStep};
use super::proximity;
use super::slab::{Patch, SLICES};
use crate::mesh::{validate_positions, MeshInput};
use crate::{Error, Result};

/// How the colliders move during the step being resolved.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColliderMotion {
    /// From their previous to their current positions (first pass).
    Swept,
    /// Still, at their current positions (in-loop pass).
    AtCurrent,
}

/// Settings of [`ColliderSet::resolve_path`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResolveParams {
    pub motion: ColliderMotion,
    /// Detection–projection rounds before remaining violations count as pinched.
    pub max_rounds: usize,
    /// Test skin edges against collider edges.
    pub edge_edge: bool,
    /// Test collider vertices against skin triangles.
    pub collider_vertices: bool,
    /// Apply friction (off for passes where it would double count).
    pub friction: bool,
}

impl ResolveParams {
    /// Pass 1: colliders sweep over the frame, friction on.
    pub fn first_pass() -> Self {
        ResolveParams { motion: ColliderMotion::Swept, max_rounds: 12, edge_edge: true, collider_vertices: true, friction: true }
    }
    /// Pass 2: colliders at their current positions, friction on.
    pub fn in_loop() -> Self {
        ResolveParams { motion: ColliderMotion::AtCurrent, max_rounds: 12, edge_edge: true, collider_vertices: true, friction: true }
    }
}

/// What [`ColliderSet::resolve_path`] did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ContactStats {
    /// Vertex–triangle projections applied (over all rounds).
    pub vertex_contacts: usize,
    /// Edge–edge projections applied (over all rounds).
    pub edge_contacts: usize,
    /// Collider-vertex–skin-triangle projections applied (over all rounds).
    pub collider_vertex_contacts: usize,
    /// Of the vertex–triangle projections, those made along a supporting
    /// plane without a lookup: the clearance's ([`Clearance::with_planes`])
    /// or the sweeping colliders' ([`LocalPlanes::drifting`]).
    pub plane_lifts: usize,
    /// Vertices whose end position changed, ascending.
    pub moved: Vec<u32>,
    /// Vertices still in violation after the last round, ascending.
    pub pinched: Vec<u32>,
    /// Detection rounds run.
    pub rounds: usize,
    /// Largest displacement applied to one vertex.
    pub max_correction: f32,
}

/// The skin's connectivity as the collision passes need it. Build it once
/// (per bind) and pass it to every [`ColliderSet::resolve_path`] call.
#[derive(Debug, Clone, Default)]
pub struct Skin {
    vertex_count: usize,
    edges: Vec<[u32; 2]>,
    triangles: Vec<[u32; 3]>,
    vertex_edges: (Vec<u32>, Vec<u32>),
    vertex_triangles: (Vec<u32>, Vec<u32>),
    /// Inverse mass per vertex (all 1 when `None`): 0 marks a vertex whose
    /// motion is imposed, which contacts never move (the kinematic part of a
    /// compliant collider when the collider is the moving mesh).
    inverse_mass: Option<Vec<f32>>,
}

impl Skin {
    /// A skin of `vertex_count` vertices with the given edges (tested against
    /// collider edges) and triangles (tested against collider vertices).
    pub fn new(vertex_count: usize, edges: Vec<[u32; 2]>, triangles: Vec<[u32; 3]>) -> Result<Self> {
        if let Some((i, e)) = edges.iter().enumerate().find(|(_, e)| e.iter().any(|&v| v as usize >= vertex_count)) {
            return Err(Error::invalid(format!(
                "edge {i} refers to vertex {}, but the skin has {vertex_count} vertices",
                e[0].max(e[1])
            )));
        }
        if let Some((i, t)) = triangles.iter().enumerate().find(|(_, t)| t.iter().any(|&v| v as usize >= vertex_count)) {
            return Err(Error::invalid(format!(
                "triangle {i} refers to vertex {}, but the skin has {vertex_count} vertices",
                t.iter().max().copied().unwrap_or(0)
            )));
        }
        let vertex_edges = incidence(vertex_count, edges.iter().map(|e| &e[..]));
        let vertex_triangles = incidence(vertex_count, triangles.iter().map(|t| &t[..]));
        Ok(Skin { vertex_count, edges, triangles, vertex_edges, vertex_triangles, inverse_mass: None })
    }

    /// The same skin with one inverse mass per vertex (finite, ≥ 0).
    pub fn with_inverse_mass(mut self, inverse_mass: Vec<f32>) -> Result<Self> {
        if inverse_mass.len() != self.vertex_count {
            return Err(Error::invalid(format!(
                "{} inverse masses given for {} vertices",
                inverse_mass.len(),
                self.vertex_count
            )));
        }
        if let Some(v) = inverse_mass.iter().position(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::invalid(format!("inverse mass of vertex {v} is {}; it must be finite and ≥ 0", inverse_mass[v])));
        }
        self.inverse_mass = Some(inverse_mass);
        Ok(self)
    }

    fn inverse_mass(&self, v: u32) -> f64 {
        self.inverse_mass.as_ref().map_or(1.0, |w| w[v as usize] as f64)
    }

    /// Fan-triangulated polygons of a polygon mesh and their edges, the
    /// diagonals included (see [`triangle_edges`]).
    pub fn from_mesh(mesh: MeshInput<'_>) -> Result<Self> {
        let offsets = mesh.validate()?;
        let triangles = fan_triangles(mesh.corner_verts, &offsets);
        Skin::new(mesh.positions.len(), triangle_edges(&triangles), triangles)
    }

    /// Vertices only: no edge–edge or collider-vertex tests.
    pub fn vertices_only(vertex_count: usize) -> Self {
        Skin { vertex_count, vertex_edges: (vec![0; vertex_count + 1], Vec::new()), vertex_triangles: (vec![0; vertex_count + 1], Vec::new()), ..Default::default() }
    }

    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// The edges around vertex `v`.
    pub(super) fn edges_of(&self, v: u32) -> &[u32] {
        let (offsets, list) = &self.vertex_edges;
        &list[offsets[v as usize] as usize..offsets[v as usize + 1] as usize]
    }

    /// The triangles around vertex `v`.
    pub(super) fn triangles_of(&self, v: u32) -> &[u32] {
        let (offsets, list) = &self.vertex_triangles;
        &list[offsets[v as usize] as usize..offsets[v as usize + 1] as usize]
    }

    /// Edges and triangles touching any of `vertices`, together with the
    /// given ones (`also`), each once, ascending.
    fn touching(&self, vertices: &[u32], also: (&[u32], &[u32])) -> (Vec<u32>, Vec<u32>) {
        (
            ascending_unique(also.0.iter().copied().chain(vertices.iter().flat_map(|&v| self.edges_of(v).iter().copied())), self.edges.len()),
            ascending_unique(also.1.iter().copied().chain(vertices.iter().flat_map(|&v| self.triangles_of(v).iter().copied())), self.triangles.len()),
        )
    }
}

/// CSR lists of the elements around each of `n` vertices.
fn incidence<'e>(n: usize, elements: impl Iterator<Item = &'e [u32]> + Clone) -> (Vec<u32>, Vec<u32>) {
    let mut offsets = vec![0u32; n + 1];
    for el in elements.clone() {
        for &v in el {
            offsets[v as usize + 1] += 1;
        }
    }
    for i in 0..n {
        offsets[i + 1] += offsets[i];
    }
    let mut fill = offsets.clone();
    let mut list = vec![0u32; offsets[n] as usize];
    for (k, el) in elements.enumerate() {
        for &v in el {
            list[fill[v as usize] as usize] = k as u32;
            fill[v as usize] += 1;
        }
    }
    (offsets, list)
}

thread_local! {
    /// Per-thread lists of an element's candidate triangles (or collider
    /// vertices) and of the collider edges already tested, reused from one
    /// skin element to the next: allocating and growing them per element
    /// took about a tenth of an in-loop pass.
    static CANDIDATES: RefCell<Vec<u32>> = const { RefCell::new(Vec::new()) };
    static SEEN: RefCell<Vec<u32>> = const { RefCell::new(Vec::new()) };
}

/// A thread's buffer, lent empty for one element's tests and handed back
/// when dropped. (Taken out of its cell rather than borrowed in place, so a
/// nested use on the same thread just gets a fresh list.)
struct Scratch {
    list: Vec<u32>,
    home: &'static LocalKey<RefCell<Vec<u32>>>,
}

impl Scratch {
    fn lend(home: &'static LocalKey<RefCell<Vec<u32>>>) -> Self {
        let mut list = home.with(|cell| std::mem::take(&mut *cell.borrow_mut()));
        list.clear();
        Scratch { list, home }
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let list = std::mem::take(&mut self.list);
        let _ = self.home.try_with(|cell| *cell.borrow_mut() = list);
    }
}

impl std::ops::Deref for Scratch {
    type Target = Vec<u32>;
    fn deref(&self) -> &Vec<u32> {
        &self.list
    }
}

impl std::ops::DerefMut for Scratch {
    fn deref_mut(&mut self) -> &mut Vec<u32> {
        &mut self.list
    }
}

/// The colliders one skin collides with, borrowed for a step.
pub struct ColliderSet<'a> {
    colliders: Vec<&'a Collider>,
    /// Per collider, a motion that overrides [`ResolveParams::motion`]: a
    /// compliant collider sweeps within an in-loop pass while the
    /// kinematic ones stay at rest.
    motions: Vec<Option<ColliderMotion>>,
    /// Outward orientation sign per collider (+1 / −1), 0 for open ones.
    outward: Vec<f64>,
    /// Largest absolute collider coordinate: sets rounding-aware tolerances.
    scale: f64,
}

/// A vertex–triangle contact found for one vertex.
#[derive(Clone, Copy)]
struct VertexHit {
    collider: usize,
    triangle: usize,
    hit: ccd::CcdHit,
}

fn d(v: Vec3) -> DVec3 {
    v.as_dvec3()
}

impl<'a> ColliderSet<'a> {
    pub fn new(colliders: impl IntoIterator<Item = &'a Collider>) -> Self {
        let colliders: Vec<&Collider> = colliders.into_iter().collect();
        let outward = colliders.iter().map(|c| c.outward_sign()).collect();
        let scale = colliders.iter().map(|c| c.extent() as f64).fold(1e-3, f64::max);
        let motions = vec![None; colliders.len()];
        ColliderSet { colliders, motions, outward, scale }
    }

    /// Collider `c` moves as `motion` whatever the pass's parameters say.
    pub fn set_motion(&mut self, c: usize, motion: Option<ColliderMotion>) {
        self.motions[c] = motion;
    }

    pub fn colliders(&self) -> &[&'a Collider] {
        &self.colliders
    }

    /// How collider `c` moves in a pass of `motion`.
    fn motion(&self, c: usize, motion: ColliderMotion) -> ColliderMotion {
        self.motions[c].unwrap_or(motion)
    }

    /// Collider `c`'s triangle tree for a pass of `motion`: its boxes over
    /// the sweep (in the collider's drifting frame) or where it stands.
    fn triangle_tree(&self, c: usize, motion: ColliderMotion) -> &'a BoxTree {
        let col = self.colliders[c];
        match self.motion(c, motion) {
            ColliderMotion::Swept => col.swept_tree(),
            ColliderMotion::AtCurrent => col.tree(),
        }
    }

    /// The same for collider `c`'s vertices.
    fn vertex_tree(&self, c: usize, motion: ColliderMotion) -> &'a BoxTree {
        let col = self.colliders[c];
        match self.motion(c, motion) {
            ColliderMotion::Swept => col.swept_vertex_tree(),
            ColliderMotion::AtCurrent => col.vertex_tree(),
        }
    }

    /// The box to look up in collider `c`'s trees for a skin element whose
    /// corners lie in `from` at the start of the step and in `to` at its end.
    fn query_box(&self, c: usize, motion: ColliderMotion, from: Bounds, to: Bounds) -> Bounds {
        match self.motion(c, motion) {
            ColliderMotion::Swept => self.colliders[c].swept_query(from, to),
            ColliderMotion::AtCurrent => from.union(to),
        }
    }

    /// A skin point's path `s → e`, where collider `c`'s trees see it.
    fn tree_path(&self, c: usize, motion: ColliderMotion, s: DVec3, e: DVec3) -> (DVec3, DVec3) {
        match self.motion(c, motion) {
            ColliderMotion::Swept => (s, e - self.colliders[c].drift().as_dvec3()),
            ColliderMotion::AtCurrent => (s, e),
        }
    }

    /// Distance added beyond the thickness when projecting. It keeps f32
    /// rounding from putting a result back inside, and it is the margin by
    /// which a resting contact clears the CCD's minimum separation: the
    /// interval search must shrink its boxes below this margin to prove a
    /// resting pair apart, so a margin of a tenth of the thickness (or 1e-5
    /// of the scene scale) keeps resting contacts cheap.
    fn slack(&self, thickness: f64) -> f64 {
        0.1 * thickness + 1e-5 * self.scale
    }

    /// CCD settings for the response. The iteration cap keeps near-degenerate
    /// resting pairs (parallel edges at the separation) bounded in cost; a
    /// capped query reports its earliest unresolved time, which is still
    /// conservative, and the projection then decides whether anything is
    /// violated at the end of the step.
    fn ccd_params(&self, thickness: f64) -> CcdParams {
        CcdParams { min_separation: thickness, tolerance: (1e-6 * self.scale).max(0.25 * self.slack(thickness)), max_iterations: 400, t_max: 1.0 }
    }

    /// Triangle corners of collider `c` at the start and end of the step.
    fn triangle_ends(&self, c: usize, t: usize, motion: ColliderMotion) -> ([DVec3; 3], [DVec3; 3]) {
        let motion = self.motion(c, motion);
        let col = self.colliders[c];
        let tri = col.triangles()[t];
        let end = tri.map(|v| d(col.current()[v as usize]));
        let start = match motion {
            ColliderMotion::Swept => tri.map(|v| d(col.previous()[v as usize])),
            ColliderMotion::AtCurrent => end,
        };
        (start, end)
    }

    fn edge_ends(&self, c: usize, e: usize, motion: ColliderMotion) -> ([DVec3; 2], [DVec3; 2]) {
        let motion = self.motion(c, motion);
        let col = self.colliders[c];
        let edge = col.edges()[e];
        let end = edge.map(|v| d(col.current()[v as usize]));
        let start = match motion {
            ColliderMotion::Swept => edge.map(|v| d(col.previous()[v as usize])),
            ColliderMotion::AtCurrent => end,
        };
        (start, end)
    }

    /// The projected end of the first vertex–triangle contact of `s → e`
    /// that needs one. Not simply the earliest contact: one reported within
    /// the tolerance may need no correction, and the next one then decides.
    ///
    /// Candidates are tried in the order the path enters their leaf boxes
    /// (their boxes over the frame, grown by the thickness and here by the
    /// CCD's tolerance, so no contact of a triangle is reported before its
    /// entry): once a contact that needs a correction is found, a candidate
    /// entered later cannot come before it. A path that misses a leaf box
    /// cannot touch its triangle at all. A vertex pulled deep into a collider
    /// has a column of candidates but meets the nearest first.
    fn vertex_correction(&self, s: Vec3, e: Vec3, params: &ResolveParams) -> Option<Vec3> {
        let motion = params.motion;
        let (from, to) = (Bounds::of_points(&[s]), Bounds::of_points(&[e]));
        let (s64, e64) = (d(s), d(e));
        let mut candidates = Scratch::lend(&CANDIDATES);
        let mut order: Vec<(f64, u32, u32)> = Vec::new();
        for (c, col) in self.colliders.iter().enumerate() {
            let ccd = self.ccd_params(col.settings().thickness as f64);
            self.candidate_triangles(c, motion, from, to, &mut candidates);
            if self.slab_apart(c, &candidates, &[s64], &[e64], motion, ccd.min_separation, false) {
                continue;
            }
            // Entry times in the trees' frame: distances, and so contacts,
            // are the same there at every instant.
            let grow = 4.0 * ccd.tolerance + 1e-6 * self.scale;
            let (ps, pe) = self.tree_path(c, motion, s64, e64);
            let tree = self.triangle_tree(c, motion);
            for &t in candidates.iter() {
                if let Some(entry) = entry_time(ps, pe, &tree.primitive_bounds(t as usize), grow) {
                    order.push((entry, c as u32, t));
                }
            }
        }
        order.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut best: Option<(f64, Vec3)> = None;
        for (entry, c, t) in order {
            if best.is_some_and(|(toi, _)| entry > toi) {
                break;
            }
            let (c, t) = (c as usize, t as usize);
            let Some(hit) = self.vertex_triangle_hit(s64, e64, c, t, motion) else { continue };
            if best.is_some_and(|(toi, _)| hit.toi >= toi) {
                continue;
            }
            if let Some(p) = self.project_vertex(s, e, &VertexHit { collider: c, triangle: t, hit }, params) {
                best = Some((hit.toi, p));
            }
        }
        best.map(|(_, p)| p)
    }

    /// The first contact of the path `s64 → e64` with triangle `t` of
    /// collider `c`, if any.
    fn vertex_triangle_hit(&self, s64: DVec3, e64: DVec3, c: usize, t: usize, motion: ColliderMotion) -> Option<ccd::CcdHit> {
        let params = self.ccd_params(self.colliders[c].settings().thickness as f64);
        let ([a0, b0, c0], [a1, b1, c1]) = self.triangle_ends(c, t, motion);
        // A still or rigidly translating triangle has a closed-form
        // first contact, cheaper than sampling distances to prove
        // the pair apart; its deviation from a translation is added
        // to the separation so the answer stays conservative.
        let shift = a1 - a0;
        let deviation = (b1 - b0 - shift).length().max((c1 - c0 - shift).length());
        let translating = deviation <= params.tolerance;
        let apart = if translating { proximity::vertex_triangle_apart_by_plane } else { proximity::vertex_triangle_apart };
        if apart(s64, [a0, b0, c0], e64, [a1, b1, c1], params.min_separation) {
            return None;
        }
        if translating {
            let separation = params.min_separation + params.tolerance + deviation;
            ccd::vertex_triangle_translating(s64, e64, [a0, b0, c0], shift, separation, params.t_max)
        } else {
            proximity::vertex_triangle_advance(s64, [a0, b0, c0], e64, [a1, b1, c1], params.min_separation, params.tolerance, params.t_max)
                .filter(|hit| hit.converged)
                .or_else(|| ccd::vertex_triangle(s64, a0, b0, c0, e64, a1, b1, c1, &params))
        }
    }

    /// Collider `c`'s triangles whose boxes (grown by the thickness) meet
    /// a skin element's, into `out`: the only ones the element can reach
    /// while its corners move from `from` to `to` (see [`Self::query_box`]).
    fn candidate_triangles(&self, c: usize, motion: ColliderMotion, from: Bounds, to: Bounds, out: &mut Vec<u32>) {
        out.clear();
        self.triangle_tree(c, motion).query(&self.query_box(c, motion, from, to), |t| {
            out.push(t as u32);
            true
        });
    }

    /// Whether a skin element (corners `start → end`, at most 3) provably
    /// stays farther than `separation` from all of collider `c`'s `triangles`
    /// over the step, by slabs (see [`Patch::apart`]; `sliced` allows a slab
    /// per part of the step when the collider sweeps).
    #[allow(clippy::too_many_arguments)]
    fn slab_apart(&self, c: usize, triangles: &[u32], start: &[DVec3], end: &[DVec3], motion: ColliderMotion, separation: f64, sliced: bool) -> bool {
        if triangles.is_empty() {
            return true;
        }
        let swept = self.motion(c, motion) == ColliderMotion::Swept;
        Patch::with(|patch| {
            patch.gather(self.colliders[c], triangles, swept);
            patch.apart(start, end, separation, sliced)
        })
    }

    /// The projected end position for a vertex–triangle contact, or `None`
    /// if the end already satisfies it.
    fn project_vertex(&self, s: Vec3, e: Vec3, h: &VertexHit, params: &ResolveParams) -> Option<Vec3> {
        let col = self.colliders[h.collider];
        let settings = col.settings();
        let sep = settings.thickness as f64;
        let ([a0, b0, c0], [a1, b1, c1]) = self.triangle_ends(h.collider, h.triangle, params.motion);
        let (t, u, v) = (h.hit.toi, h.hit.u, h.hit.v);
        let lerp = |p0: DVec3, p1: DVec3| p0 + t * (p1 - p0);
        let (at, bt, ct) = (lerp(a0, a1), lerp(b0, b1), lerp(c0, c1));
        let (s, e) = (d(s), d(e));
        let xt = lerp(s, e);
        let qt = at + u * (bt - at) + v * (ct - at);
        let q0 = a0 + u * (b0 - a0) + v * (c0 - a0);
        let q1 = a1 + u * (b1 - a1) + v * (c1 - a1);
        let n1 = triangle_normal(a1, b1, c1).or_else(|| triangle_normal(at, bt, ct))?;
        let side = match self.outward[h.collider] {
            o if o != 0.0 => o,
            _ => open_side(s, e, xt, qt, q0, q1, triangle_normal(at, bt, ct), triangle_normal(a0, b0, c0), n1, sep),
        };
        let n = side * n1;
        let dist = (e - q1).dot(n);
        if dist >= sep {
            return None;
        }
        let depth = sep + self.slack(sep) - dist;
        let mut out = e + depth * n;
        if params.friction && (settings.static_friction > 0.0 || settings.kinetic_friction > 0.0) {
            let slip = (out - xt) - (q1 - qt);
            let tangential = slip - slip.dot(n) * n;
            let len = tangential.length();
            if len > 0.0 {
                if len < settings.static_friction as f64 * depth {
                    out -= tangential;
                } else {
                    out -= tangential * (settings.kinetic_friction as f64 * depth / len).min(1.0);
                }
            }
        }
        let out = out.as_vec3();
        out.is_finite().then_some(out)
    }

    /// Earliest contact of skin edge `(ia, ib)` against collider edges, and
    /// the corrections of its two end positions.
    fn edge_correction(
        &self,
        start: &[Vec3],
        end: &[Vec3],
        edge: [u32; 2],
        masses: [f64; 2],
        params: &ResolveParams,
    ) -> Option<(DVec3, DVec3)> {
        let [ia, ib] = edge.map(|v| v as usize);
        let (sa, sb, ea, eb) = (d(start[ia]), d(start[ib]), d(end[ia]), d(end[ib]));
        let (from, to) = (Bounds::of_points(&[start[ia], start[ib]]), Bounds::of_points(&[end[ia], end[ib]]));
        let mut hits: Vec<(usize, usize, ccd::CcdHit)> = Vec::new();
        let mut seen = Scratch::lend(&SEEN);
        let mut candidates = Scratch::lend(&CANDIDATES);
        for (c, col) in self.colliders.iter().enumerate() {
            let ccd_params = self.ccd_params(col.settings().thickness as f64);
            self.candidate_triangles(c, params.motion, from, to, &mut candidates);
            if self.slab_apart(c, &candidates, &[sa, sb], &[ea, eb], params.motion, ccd_params.min_separation, true) {
                continue;
            }
            seen.clear();
            for &t in candidates.iter() {
                let t = t as usize;
                let (tri0, tri1) = self.triangle_ends(c, t, params.motion);
                if proximity::beyond_triangle_plane(tri0, tri1, &[sa, sb], &[ea, eb], ccd_params.min_separation) {
                    // Apart from the triangle's plane, so from its three edges.
                    for &e in &col.triangle_edges()[t] {
                        if !seen.contains(&e) {
                            seen.push(e);
                        }
                    }
                    continue;
                }
                for &e in &col.triangle_edges()[t] {
                    if seen.contains(&e) {
                        continue;
                    }
                    seen.push(e);
                    let ([c0, c1], [c0e, c1e]) = self.edge_ends(c, e as usize, params.motion);
                    if proximity::edge_edge_apart([sa, sb], [c0, c1], [ea, eb], [c0e, c1e], ccd_params.min_separation) {
                        continue;
                    }
                    let advanced = proximity::edge_edge_advance([sa, sb], [c0, c1], [ea, eb], [c0e, c1e], ccd_params.min_separation, ccd_params.tolerance, ccd_params.t_max);
                    // Advancement that ran out of steps is only a lower bound on the
                    // time; the interval search then finds where the contact is.
                    let found = match advanced {
                        Some(hit) if !hit.converged => ccd::edge_edge(sa, sb, c0, c1, ea, eb, c0e, c1e, &ccd_params),
                        other => other,
                    };
                    if let Some(hit) = found {
                        hits.push((c, e as usize, hit));
                    }
                }
            }
        }
        hits.sort_by(|a, b| a.2.toi.total_cmp(&b.2.toi));
        hits.into_iter().find_map(|(c, e, hit)| self.edge_contact_correction(sa, sb, ea, eb, c, e, hit, masses, params))
    }

    /// Corrections of a skin edge's two ends for one edge–edge contact, or
    /// `None` if its end positions already keep the separation.
    #[allow(clippy::too_many_arguments)]
    fn edge_contact_correction(
        &self,
        sa: DVec3,
        sb: DVec3,
        ea: DVec3,
        eb: DVec3,
        c: usize,
        e: usize,
        hit: ccd::CcdHit,
        [ma, mb]: [f64; 2],
        params: &ResolveParams,
    ) -> Option<(DVec3, DVec3)> {
        let col = self.colliders[c];
        let sep = col.settings().thickness as f64;
        let ([c0, c1], [c0e, c1e]) = self.edge_ends(c, e, params.motion);
        let (t, u, v) = (hit.toi, hit.u, hit.v);
        let lerp = |p0: DVec3, p1: DVec3| p0 + t * (p1 - p0);
        let pt = lerp(sa, ea) + u * (lerp(sb, eb) - lerp(sa, ea));
        let rt = lerp(c0, c0e) + v * (lerp(c1, c1e) - lerp(c0, c0e));
        let p1 = ea + u * (eb - ea);
        let r1 = c0e + v * (c1e - c0e);
        let p0 = sa + u * (sb - sa);
        let r0 = c0 + v * (c1 - c0);
        let cross1 = unit((eb - ea).cross(c1e - c0e));
        let n = if self.outward[c] != 0.0 {
            // Closed collider: the outside is known from the adjacent faces.
            let out = self.edge_outward(c, e)?;
            match cross1 {
                Some(n) if n.dot(out).abs() > 0.2 => n * n.dot(out).signum(),
                _ => out,
            }
        } else {
            let n1 = cross1.or_else(|| unit(p1 - r1))?;
            let side = open_side_generic((pt - rt).dot(n1), (p0 - r0).dot(n1), ((p1 - p0) - (r1 - r0)).dot(n1), sep);
            side * n1
        };
        let dist = (p1 - r1).dot(n);
        if dist >= sep {
            return None;
        }
        let depth = sep + self.slack(sep) - dist;
        // The minimum-norm change under the inverse masses (PBD).
        let (wa, wb) = (1.0 - u, u);
        let denominator = ma * wa * wa + mb * wb * wb;
        if !(denominator > 1e-12) {
            return None;
        }
        let lambda = depth / denominator;
        let (da, db) = (ma * wa * lambda * n, mb * wb * lambda * n);
        (da.is_finite() && db.is_finite()).then_some((da, db))
    }

    /// Outward direction at collider edge `e`: the normalised sum of its
    /// faces' outward normals at the current positions.
    fn edge_outward(&self, c: usize, e: usize) -> Option<DVec3> {
        self.mean_outward(c, self.colliders[c].edge_triangles(e))
    }

    /// Unit mean of the current normals of collider `c`'s `triangles`,
    /// turned to face out of the collider.
    fn mean_outward(&self, c: usize, triangles: &[u32]) -> Option<DVec3> {
        let col = self.colliders[c];
        let mut sum = DVec3::ZERO;
        for &t in triangles {
            let [a, b, cc] = col.triangles()[t as usize].map(|v| d(col.current()[v as usize]));
            if let Some(n) = triangle_normal(a, b, cc) {
                sum += n;
            }
        }
        unit(sum * self.outward[c])
    }

    /// Earliest contact of a collider vertex with skin triangle `tri`, and
    /// the corrections of the triangle's three end positions.
    fn face_correction(
        &self,
        start: &[Vec3],
        end: &[Vec3],
        tri: [u32; 3],
        masses: [f64; 3],
        params: &ResolveParams,
    ) -> Option<[DVec3; 3]> {
        let [i0, i1, i2] = tri.map(|v| v as usize);
        let (s0, s1, s2) = (d(start[i0]), d(start[i1]), d(start[i2]));
        let (e0, e1, e2) = (d(end[i0]), d(end[i1]), d(end[i2]));
        let (from, to) = (Bounds::of_points(&[start[i0], start[i1], start[i2]]), Bounds::of_points(&[end[i0], end[i1], end[i2]]));
        let mut hits: Vec<(usize, usize, ccd::CcdHit)> = Vec::new();
        let mut candidates = Scratch::lend(&CANDIDATES);
        // A skin triangle resting on a collider faces it: its own normal is
        // the direction of a slab that proves all nearby collider vertices
        // apart at once. Over a part `t0..t1` of the step, the normal is the
        // triangle's halfway through it, and the frame moves with the first
        // candidate vertex.
        let skin_at = |t: f64| [s0 + t * (e0 - s0), s1 + t * (e1 - s1), s2 + t * (e2 - s2)];
        let slab = |c: usize, candidates: &[u32], t0: f64, t1: f64| {
            let [m0, m1, m2] = skin_at(0.5 * (t0 + t1));
            let Some(n) = triangle_normal(m0, m1, m2) else { return false };
            let vertex_at = |v: u32| {
                let (r0, r1) = self.vertex_ends(c, v as usize, params.motion);
                (r0 + t0 * (r1 - r0), r0 + t1 * (r1 - r0))
            };
            let (r0, r1) = vertex_at(candidates[0]);
            proximity::separated_along(n, r1 - r0, &skin_at(t0), &skin_at(t1), candidates.iter().map(|&v| vertex_at(v)), self.colliders[c].settings().thickness as f64)
        };
        for (c, col) in self.colliders.iter().enumerate() {
            let ccd_params = self.ccd_params(col.settings().thickness as f64);
            candidates.clear();
            self.vertex_tree(c, params.motion).query(&self.query_box(c, params.motion, from, to), |v| {
                candidates.push(v as u32);
                true
            });
            if candidates.is_empty() {
                continue;
            }
            let swept = self.motion(c, params.motion) == ColliderMotion::Swept;
            if slab(c, &candidates, 0.0, 1.0)
                || (swept && (0..SLICES).all(|k| slab(c, &candidates, k as f64 / SLICES as f64, (k + 1) as f64 / SLICES as f64)))
            {
                continue;
            }
            for &v in candidates.iter() {
                let v = v as usize;
                let (r0, r1) = self.vertex_ends(c, v, params.motion);
                if proximity::vertex_triangle_apart(r0, [s0, s1, s2], r1, [e0, e1, e2], ccd_params.min_separation) {
                    continue;
                }
                let advanced = proximity::vertex_triangle_advance(r0, [s0, s1, s2], r1, [e0, e1, e2], ccd_params.min_separation, ccd_params.tolerance, ccd_params.t_max);
                let found = match advanced {
                    Some(hit) if !hit.converged => ccd::vertex_triangle(r0, s0, s1, s2, r1, e0, e1, e2, &ccd_params),
                    other => other,
                };
                if let Some(hit) = found {
                    hits.push((c, v, hit));
                }
            }
        }
        hits.sort_by(|a, b| a.2.toi.total_cmp(&b.2.toi));
        let ends = ([s0, s1, s2], [e0, e1, e2]);
        hits.into_iter().find_map(|(c, v, hit)| self.face_contact_correction(ends, c, v, hit, masses, params))
    }

    /// Corrections of a skin triangle's corners for one collider-vertex
    /// contact, or `None` if its end positions already keep the separation.
    fn face_contact_correction(
        &self,
        ([s0, s1, s2], [e0, e1, e2]): ([DVec3; 3], [DVec3; 3]),
        c: usize,
        v: usize,
        hit: ccd::CcdHit,
        masses: [f64; 3],
        params: &ResolveParams,
    ) -> Option<[DVec3; 3]> {
        let sep = self.colliders[c].settings().thickness as f64;
        let (r0, r1) = self.vertex_ends(c, v, params.motion);
        let (t, u, w) = (hit.toi, hit.u, hit.v);
        let weights = [1.0 - u - w, u, w];
        let at = |a: DVec3, b: DVec3, c: DVec3| weights[0] * a + weights[1] * b + weights[2] * c;
        let lerp = |p0: DVec3, p1: DVec3| p0 + t * (p1 - p0);
        let (p0, p1) = (at(s0, s1, s2), at(e0, e1, e2));
        let pt = at(lerp(s0, e0), lerp(s1, e1), lerp(s2, e2));
        let rt = lerp(r0, r1);
        let n1 = triangle_normal(e0, e1, e2).or_else(|| triangle_normal(lerp(s0, e0), lerp(s1, e1), lerp(s2, e2)));
        let n = if self.outward[c] != 0.0 {
            let out = self.vertex_outward(c, v)?;
            match n1 {
                Some(n) if n.dot(out).abs() > 0.2 => n * n.dot(out).signum(),
                _ => out,
            }
        } else {
            let n1 = n1.or_else(|| unit(p1 - r1))?;
            let side = open_side_generic((pt - rt).dot(n1), (p0 - r0).dot(n1), ((p1 - p0) - (r1 - r0)).dot(n1), sep);
            side * n1
        };
        let dist = (p1 - r1).dot(n);
        if dist >= sep {
            return None;
        }
        let depth = sep + self.slack(sep) - dist;
        let denominator: f64 = weights.iter().zip(&masses).map(|(w, m)| m * w * w).sum();
        if !(denominator > 1e-12) {
            return None;
        }
        let lambda = depth / denominator;
        let mut out = [DVec3::ZERO; 3];
        for k in 0..3 {
            out[k] = masses[k] * weights[k] * lambda * n;
        }
        out.iter().all(|x| x.is_finite()).then_some(out)
    }

    fn vertex_ends(&self, c: usize, v: usize, motion: ColliderMotion) -> (DVec3, DVec3) {
        let motion = self.motion(c, motion);
        let col = self.colliders[c];
        let end = d(col.current()[v]);
        match motion {
            ColliderMotion::Swept => (d(col.previous()[v]), end),
            ColliderMotion::AtCurrent => (end, end),
        }
    }

    /// Outward direction at collider vertex `v` (sum of its faces' normals).
    fn vertex_outward(&self, c: usize, v: usize) -> Option<DVec3> {
        self.mean_outward(c, self.colliders[c].vertex_triangles(v))
    }

    /// Edge–edge and collider-vertex–skin-triangle corrections of one round,
    /// averaged per vertex. Returns the number of contacts and the changes.
    #[allow(clippy::too_many_arguments)]
    fn shared_corrections(
        &self,
        start: &[Vec3],
        end: &[Vec3],
        skin: &Skin,
        edges: &[u32],
        triangles: &[u32],
        params: &ResolveParams,
        planes: Option<(&LocalPlanes, &[Vec3])>,
    ) -> (usize, usize, Vec<(u32, Vec3)>) {
        let cleared = |corners: &[u32]| planes.is_some_and(|(p, from)| p.clears(corners, from, end));
        let from_edges: Vec<(u32, [DVec3; 2])> = if params.edge_edge {
            edges
                .par_iter()
                .filter_map(|&k| {
                    let edge = skin.edges[k as usize];
                    if cleared(&edge) {
                        return None;
                    }
                    self.edge_correction(start, end, edge, edge.map(|v| skin.inverse_mass(v)), params).map(|(a, b)| (k, [a, b]))
                })
                .collect()
        } else {
            Vec::new()
        };
        let from_faces: Vec<(u32, [DVec3; 3])> = if params.collider_vertices {
            triangles
                .par_iter()
                .filter_map(|&k| {
                    let tri = skin.triangles[k as usize];
                    if cleared(&tri) {
                        return None;
                    }
                    self.face_correction(start, end, tri, tri.map(|v| skin.inverse_mass(v)), params).map(|c| (k, c))
                })
                .collect()
        } else {
            Vec::new()
        };
        let mut sum: std::collections::BTreeMap<u32, (DVec3, u32)> = Default::default();
        let mut add = |v: u32, delta: DVec3| {
            let slot = sum.entry(v).or_insert((DVec3::ZERO, 0));
            slot.0 += delta;
            slot.1 += 1;
        };
        for (k, deltas) in &from_edges {
            for (&v, &delta) in skin.edges[*k as usize].iter().zip(deltas) {
                add(v, delta);
            }
        }
        for (k, deltas) in &from_faces {
            for (&v, &delta) in skin.triangles[*k as usize].iter().zip(deltas) {
                add(v, delta);
            }
        }
        let changes = sum
            .into_iter()
            .filter_map(|(v, (delta, count))| {
                let p = (d(end[v as usize]) + delta / count as f64).as_vec3();
                p.is_finite().then_some((v, p))
            })
            .collect();
        (from_edges.len(), from_faces.len(), changes)
    }

    /// Makes the motion `start → end` collision-free against the colliders by
    /// changing `end` (see the module documentation).
    pub fn resolve_path(&self, start: &[Vec3], end: &mut [Vec3], skin: &Skin, params: &ResolveParams) -> Result<ContactStats> {
        self.resolve_path_with(start, end, skin, params, None)
    }

    /// [`resolve_path`](Self::resolve_path), skipping the skin elements that
    /// `clearance` proves apart from the colliders (if it was measured
    /// against them in their present state and they stand still in this
    /// pass; otherwise it is not used).
    /// The in-loop passes of a frame share one clearance.
    pub fn resolve_path_with(
        &self,
        start: &[Vec3],
        end: &mut [Vec3],
        skin: &Skin,
        params: &ResolveParams,
        clearance: Option<&Clearance>,
    ) -> Result<ContactStats> {
        self.resolve(start, end, skin, params, clearance, None)
    }

    /// [`resolve_path`](Self::resolve_path) for colliders that sweep, with the
    /// supporting planes of the last frame's in-loop passes to carry along
    /// with them where they still hold (see [`LocalPlanes::drifting`] for
    /// what `carried` must have been measured against).
    pub fn resolve_path_carrying(&self, start: &[Vec3], end: &mut [Vec3], skin: &Skin, params: &ResolveParams, carried: Option<&LocalPlanes>) -> Result<ContactStats> {
        self.resolve(start, end, skin, params, None, carried)
    }

    fn resolve(
        &self,
        start: &[Vec3],
        end: &mut [Vec3],
        skin: &Skin,
        params: &ResolveParams,
        clearance: Option<&Clearance>,
        carried: Option<&LocalPlanes>,
    ) -> Result<ContactStats> {
        let n = start.len();
        if end.len() != n || skin.vertex_count != n {
            return Err(Error::invalid(format!(
                "start has {n} positions, end has {} and the skin has {} vertices; all three must agree",
                end.len(),
                skin.vertex_count
            )));
        }
        validate_positions("start positions", start)?;
        validate_positions("end positions", end)?;
        let mut stats = ContactStats::default();
        if self.colliders.is_empty() || n == 0 {
            return Ok(stats);
        }
        // Where the vertices the pass moves were asked to go, recorded when
        // first moved (most of a skin is not).
        let mut requested: Vec<(u32, Vec3)> = Vec::new();
        let mut moved = vec![false; n];
        // The clearance and its planes hold for colliders standing still.
        let still = (0..self.colliders.len()).all(|c| self.motion(c, params.motion) == ColliderMotion::AtCurrent);
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
            Some(clearance) => {
                let unproven = clearance.unproven(skin, start, end);
                (unproven.vertices, unproven.edges, unproven.triangles)
            }
            // Without one, those whose step misses every collider's whole box.
            None => {
                let mut reach_vertices = vec![false; n];
                let mut reach_edges = vec![false; skin.edges.len()];
                let mut reach_triangles = vec![false; skin.triangles.len()];
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
                    mark(&mut reach_edges, skin.edges.as_flattened(), 2);
                    mark(&mut reach_triangles, skin.triangles.as_flattened(), 3);
                }
                let listed = |flags: &[bool]| -> Vec<u32> { (0..flags.len() as u32).into_par_iter().with_min_len(4096).filter(|&k| flags[k as usize]).collect() };
                (listed(&reach_vertices), listed(&reach_edges), listed(&reach_triangles))
            }
        };
        // Vertices with inverse mass 0 move as imposed: never corrected.
        if skin.inverse_mass.is_some() {
            active.retain(|&i| skin.inverse_mass(i) > 0.0);
        }
        // Supporting planes: the clearance's for still colliders; for sweeping
        // ones, planes around the active vertices in the frame drifting with
        // the colliders, if they translate together (carried along from the
        // last frame where they hold). Each comes with the step starts in its
        // frame.
        let all_swept = (0..self.colliders.len()).all(|c| self.motion(c, params.motion) == ColliderMotion::Swept);
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
        let mut converged = false;
        for _ in 0..params.max_rounds.max(1) {
            stats.rounds += 1;
            // Skin vertices against collider triangles.
            let updates: Vec<(u32, Vec3)> = active
                .par_iter()
                .filter_map(|&i| {
                    let (s, e) = (start[i as usize], end[i as usize]);
                    match planes.map_or(VertexStep::Unknown, |(p, from)| p.vertex_step(i, from[i as usize], e, lift)) {
                        VertexStep::Clear => None,
                        VertexStep::Lifted(p) => {
                            lifted.fetch_add(1, Ordering::Relaxed);
                            Some((i, p))
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
            for (i, p) in updates {
                apply(i, p, end);
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
            for (i, p) in shared {
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
                .filter(|&i| {
                    let (s, e) = (start[i as usize], end[i as usize]);
                    match planes.map_or(VertexStep::Unknown, |(p, from)| p.vertex_step(i, from[i as usize], e, lift)) {
                        VertexStep::Clear => false,
                        VertexStep::Lifted(_) => true,
                        VertexStep::Unknown => self.vertex_correction(s, e, params).is_some(),
                    }
                })
                .collect();
            let (_, _, shared) = self.shared_corrections(start, end, skin, &active_edges, &active_triangles, params, planes);
            pinched.extend(shared.iter().map(|(v, _)| *v));
            pinched.sort_unstable();
            pinched.dedup();
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
        requested.sort_unstable_by_key(|&(i, _)| i);
        for (i, asked) in requested {
            stats.moved.push(i);
            stats.max_correction = stats.max_correction.max((end[i as usize] - asked).length());
        }
        Ok(stats)
    }
}

/// When the path `s → e` (parameter 0..1) first enters `bounds` grown by
/// `grow`, or `None` if it misses it.
fn entry_time(s: DVec3, e: DVec3, bounds: &Bounds, grow: f64) -> Option<f64> {
    let (lo, hi) = (bounds.min.as_dvec3() - DVec3::splat(grow), bounds.max.as_dvec3() + DVec3::splat(grow));
    let direction = e - s;
    let (mut enter, mut leave) = (0.0f64, 1.0f64);
    for k in 0..3 {
        if direction[k] == 0.0 {
            if s[k] < lo[k] || s[k] > hi[k] {
                return None;
            }
            continue;
        }
        let (a, b) = ((lo[k] - s[k]) / direction[k], (hi[k] - s[k]) / direction[k]);
        enter = enter.max(a.min(b));
        leave = leave.min(a.max(b));
    }
    // Rounding of the divisions: a path grazing a face may come out just
    // outside; the growth is far larger than that, so the order still holds.
    (enter <= leave).then_some(enter)
}


/// Side (+1/−1 along the triangle normal) an open collider's contact is
/// resolved to: where the vertex was just before contact, else at the start,
/// else opposite to the relative motion, else the normal's side.
#[allow(clippy::too_many_arguments)]
fn open_side(
    s: DVec3,
    e: DVec3,
    xt: DVec3,
    qt: DVec3,
    q0: DVec3,
    q1: DVec3,
    nt: Option<DVec3>,
    n0: Option<DVec3>,
    n1: DVec3,
    sep: f64,
) -> f64 {
    let at_contact = nt.map_or(0.0, |n| (xt - qt).dot(n) * n.dot(n1).signum());
    let at_start = n0.map_or(0.0, |n| (s - q0).dot(n) * n.dot(n1).signum());
    open_side_generic(at_contact, at_start, ((e - s) - (q1 - q0)).dot(n1), sep)
}

fn open_side_generic(at_contact: f64, at_start: f64, relative_motion: f64, sep: f64) -> f64 {
    let tiny = 1e-12;
    if at_contact.abs() > (0.25 * sep).max(tiny) {
        at_contact.signum()
    } else if at_start.abs() > tiny {
        at_start.signum()
    } else if relative_motion.abs() > tiny {
        -relative_motion.signum()
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn point() -> impl Strategy<Value = DVec3> {
        (-2.0f64..2.0, -2.0f64..2.0, -2.0f64..2.0).prop_map(|(x, y, z)| DVec3::new(x, y, z))
    }

    proptest! {
        /// No point of the path before its entry time lies in the (grown)
        /// box, and a path said to miss it has no point in it at all.
        #[test]
        fn a_path_is_never_in_a_box_before_it_enters_it(s in point(), e in point(), a in point(), b in point(), axis_aligned in any::<bool>()) {
            let e = if axis_aligned { DVec3::new(s.x, s.y, e.z) } else { e };
            let bounds = Bounds::of_points(&[a.as_vec3(), b.as_vec3()]);
            let grow = 0.01;
            let (lo, hi) = (bounds.min.as_dvec3() - grow, bounds.max.as_dvec3() + grow);
            let inside = |p: DVec3| p.cmpge(lo).all() && p.cmple(hi).all();
            let entry = entry_time(s, e, &bounds, grow);
            for k in 0..=400 {
                let t = k as f64 / 400.0;
                if inside(s.lerp(e, t)) {
                    prop_assert!(entry.is_some_and(|entry| entry <= t + 1e-12), "in the box at {t}, entry {entry:?}");
                }
            }
        }
    }

    #[test]
    fn entry_times_of_simple_paths() {
        let unit = Bounds { min: Vec3::ZERO, max: Vec3::ONE };
        let at = |s: [f64; 3], e: [f64; 3]| entry_time(DVec3::from(s), DVec3::from(e), &unit, 0.0);
        assert_eq!(at([-1.0, 0.5, 0.5], [3.0, 0.5, 0.5]), Some(0.25));
        assert_eq!(at([0.5, 0.5, 0.5], [3.0, 0.5, 0.5]), Some(0.0), "starting inside");
        assert_eq!(at([-1.0, 2.0, 0.5], [3.0, 2.0, 0.5]), None, "passing beside");
        assert_eq!(at([-3.0, 0.5, 0.5], [-2.0, 0.5, 0.5]), None, "stopping short");
    }
}
