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
//!    correction goes to the skin. On still colliders (the in-loop pass) a
//!    vertex that starts the step resting on the surface measures its slip
//!    from where it rests ([`super::planes::resting_reference`]): static
//!    friction then holds it over any number of solver iterations.
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
//!     let s = set.resolve_path_with(&before, &mut x, &skin, &ResolveParams::in_loop(), Some(&clearance), None)?;
//!     // s.pinched → soft constraints / report
//! }
//! ```
//!
//! The start positions must be collision-free (they are the output of the
//! previous call); the result then is too, up to pinched vertices.

//!
//! Files: this one holds the set, its parameters and the public entry
//! points; `resolve.rs` runs the rounds, vertex–triangle
//! contacts are in `vertex.rs`, edge–edge in `edge.rs`, collider vertex–skin
//! triangle in `face.rs`, the side and entry-time helpers in `contact.rs`,
//! the per-thread candidate lists in `scratch.rs`, whole stars proven apart
//! by one slab in `star.rs`, and `verify.rs` checks given vertices' steps
//! again after a caller changed them.

mod contact;
mod edge;
mod face;
mod resolve;
mod scratch;
mod star;
mod verify;
mod vertex;

use glam::{DVec3, Vec3};

use super::bvh::{BoxTree, Bounds};
use super::ccd::{self, CcdParams};
use super::collider::Collider;
use super::planes::LocalPlanes;
use super::clearance::Clearance;
use super::friction::{Anchors, Slide};
use super::skin::Skin;
use crate::Result;

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
    /// Test only the vertices that move (start ≠ end) and the edges and
    /// triangles with such a corner. Sound only for a pass whose start the
    /// caller knows to be clear of colliders that all stand still: an element
    /// whose corners all stay where they were then stays clear. Used for a
    /// compliant collider receding from the skin after an in-loop pass, which
    /// has just cleared the skin of it: most of the collider stands still
    /// (at its goal, or resting where it was), and only the rest costs.
    pub moving_only: bool,
    /// Before the first round, prove each tested vertex's whole star (the
    /// vertex, its edges and its triangles) apart from the colliders by one
    /// slab, and leave the elements of proven stars out of the pairwise
    /// tests. Only where the colliders stand still ([`ColliderMotion::AtCurrent`]).
    /// Pays where most moving vertices rest a little beyond the thickness
    /// over a smooth collider, each element otherwise proven apart on its own:
    /// a compliant collider receding from the skin it rests on.
    pub star_slabs: bool,
}

impl ResolveParams {
    /// Pass 1: colliders sweep over the frame, friction on.
    pub fn first_pass() -> Self {
        ResolveParams { motion: ColliderMotion::Swept, max_rounds: 12, edge_edge: true, collider_vertices: true, friction: true, moving_only: false, star_slabs: false }
    }
    /// Pass 2: colliders at their current positions, friction on.
    pub fn in_loop() -> Self {
        ResolveParams { motion: ColliderMotion::AtCurrent, max_rounds: 12, edge_edge: true, collider_vertices: true, friction: true, moving_only: false, star_slabs: false }
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
    /// Skin vertices tested against the colliders: those neither the
    /// clearance (nor a wider one, [`ColliderSet::resolve_path_within`]) nor
    /// the colliders' whole boxes ruled out.
    pub tested: usize,
    /// Vertices whose end position changed, ascending.
    pub moved: Vec<u32>,
    /// Vertices still in violation after the last round, ascending.
    pub pinched: Vec<u32>,
    /// Vertices the rounds could not clear of colliders standing still, put
    /// back at their (clear) start positions instead, ascending.
    pub held: Vec<u32>,
    /// Of the moved vertices, those whose last move was a vertex–triangle
    /// projection that left them sliding along the collider (kinetic
    /// friction or none), ascending, with its normal and friction; the
    /// others were held by static friction, pushed by an edge or a collider
    /// corner, put back, or pinched.
    pub sliding: Vec<(u32, Slide)>,
    /// Detection rounds run.
    pub rounds: usize,
    /// Largest displacement applied to one vertex.
    pub max_correction: f32,
}

/// The colliders one skin collides with, borrowed for a step.
pub struct ColliderSet<'a> {
    colliders: Vec<&'a Collider>,
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
        ColliderSet { colliders, outward, scale }
    }

    pub fn colliders(&self) -> &[&'a Collider] {
        &self.colliders
    }

    /// Collider `c`'s triangle tree for a pass of `motion`: its boxes over
    /// the sweep (in the collider's drifting frame) or where it stands.
    fn triangle_tree(&self, c: usize, motion: ColliderMotion) -> &'a BoxTree {
        let col = self.colliders[c];
        match motion {
            ColliderMotion::Swept => col.swept_tree(),
            ColliderMotion::AtCurrent => col.tree(),
        }
    }

    /// The same for collider `c`'s vertices.
    fn vertex_tree(&self, c: usize, motion: ColliderMotion) -> &'a BoxTree {
        let col = self.colliders[c];
        match motion {
            ColliderMotion::Swept => col.swept_vertex_tree(),
            ColliderMotion::AtCurrent => col.vertex_tree(),
        }
    }

    /// The box to look up in collider `c`'s trees for a skin element whose
    /// corners lie in `from` at the start of the step and in `to` at its end.
    fn query_box(&self, c: usize, motion: ColliderMotion, from: Bounds, to: Bounds) -> Bounds {
        match motion {
            ColliderMotion::Swept => self.colliders[c].swept_query(from, to),
            ColliderMotion::AtCurrent => from.union(to),
        }
    }

    /// A skin point's path `s → e`, where collider `c`'s trees see it.
    fn tree_path(&self, c: usize, motion: ColliderMotion, s: DVec3, e: DVec3) -> (DVec3, DVec3) {
        match motion {
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
        let col = self.colliders[c];
        let edge = col.edges()[e];
        let end = edge.map(|v| d(col.current()[v as usize]));
        let start = match motion {
            ColliderMotion::Swept => edge.map(|v| d(col.previous()[v as usize])),
            ColliderMotion::AtCurrent => end,
        };
        (start, end)
    }

    /// Makes the motion `start → end` collision-free against the colliders by
    /// changing `end` (see the module documentation).
    pub fn resolve_path(&self, start: &[Vec3], end: &mut [Vec3], skin: &Skin, params: &ResolveParams) -> Result<ContactStats> {
        self.resolve_path_with(start, end, skin, params, None, None)
    }

    /// [`resolve_path`](Self::resolve_path), skipping the skin elements that
    /// `clearance` proves apart from the colliders (if it was measured
    /// against them in their present state and they stand still in this
    /// pass; otherwise it is not used). The in-loop passes of a frame share
    /// one clearance, and, where the colliders stand still through the
    /// solve, their `anchors`: the vertices static friction holds stay at
    /// their anchors while the pull stays inside the static cone (see
    /// [`super::Anchor`]); the pass updates `anchors` for the next one.
    pub fn resolve_path_with(
        &self,
        start: &[Vec3],
        end: &mut [Vec3],
        skin: &Skin,
        params: &ResolveParams,
        clearance: Option<&Clearance>,
        anchors: Option<&mut Anchors>,
    ) -> Result<ContactStats> {
        self.resolve(start, end, skin, params, clearance, None, None, anchors)
    }

    /// [`resolve_path_with`](Self::resolve_path_with) without anchors, where
    /// `wider`, a clearance with a wider reach measured since `clearance`
    /// against the same colliders (both used only while the colliders stand
    /// as measured), also proves apart what moved beyond `clearance`'s
    /// radius ([`Clearance::unproven_with`]): the same result from fewer tests.
    /// `clearance`'s planes still decide where they apply, so a vertex with
    /// a plane is tested as before.
    pub fn resolve_path_within(
        &self,
        start: &[Vec3],
        end: &mut [Vec3],
        skin: &Skin,
        params: &ResolveParams,
        clearance: Option<&Clearance>,
        wider: Option<&Clearance>,
    ) -> Result<ContactStats> {
        self.resolve(start, end, skin, params, clearance, wider, None, None)
    }

    /// [`resolve_path`](Self::resolve_path) for colliders that sweep, with the
    /// supporting planes of the last frame's in-loop passes to carry along
    /// with them where they still hold (see [`LocalPlanes::drifting`] for
    /// what `carried` must have been measured against).
    pub fn resolve_path_carrying(&self, start: &[Vec3], end: &mut [Vec3], skin: &Skin, params: &ResolveParams, carried: Option<&LocalPlanes>) -> Result<ContactStats> {
        self.resolve(start, end, skin, params, None, None, carried, None)
    }
}
