//! Frame-to-frame stepping with collisions: seed 000, Algorithm 2, with the
//! additions of seed 002 (compliant colliders, strain limits) and seed 000 §4
//! (dynamics).
//!
//! [`Sequence::step`] keeps its last output, which is free of
//! collisions, and splits each new frame into substeps (input and colliders
//! interpolated linearly). Each substep
//!
//! 1. moves the compliant colliders' vertices from where they are towards
//!    their animated positions, stopping at the skin (they recede on contact),
//!    and gives the skin target rows where it heads into their animated
//!    shapes, so that it gives way in proportion to their stiffness
//!    ([`compliance`]);
//! 2. moves every skin vertex from the last output towards this substep's
//!    input (or, with dynamics, its inertial prediction) while the colliders
//!    sweep over the substep, stopping and projecting at contacts, with
//!    friction (first pass, [`crate::collide::ResolveParams::first_pass`]);
//! 3. runs the projective solve from there, and after every iteration
//!    * detects and resolves contacts along each vertex's move during that
//!      iteration (second pass,
//!      [`crate::collide::ResolveParams::in_loop`]), compliant
//!      colliders standing still;
//!    * with strain limits in [`StrainMode::Unified`], alternates edge
//!      shortening and contact resolution until both hold;
//!    * lets the compliant vertices move back towards their goals, stopping
//!      at the skin again.
//!
//! Every move in this sequence is checked by continuous collision detection
//! from a collision-free start, which is what keeps the result free of
//! penetrations. Vertices squeezed between colliders so that no projection
//! frees them are *pinched*: they are counted, kept within a bounded distance
//! of where the solver wanted them, and never NaN (see
//! [`crate::collide::response`]).
//!
//! A [`Sequence`] owns the bound [`PyramidDeformer`] and the state of one
//! bake: the last output, velocities, the last input, the solver rows it adds
//! (inertia, compliant contacts), the skin as a collider and the planes
//! carried from one substep to the next. It is the one module that drives
//! both [`crate::collide`] and [`crate::solve`]; [`crate::pyramid`] only says
//! which constraints the solver holds.
//!
//! Vertices that coincide at rest (split seams) are welded at bind: the
//! solver and the passes work on the welded mesh, and [`seams`] is the public
//! boundary that takes and returns the mesh's own vertices.
//!
//! Files: [`seams`] (the public boundary, in the mesh's vertices), [`step`]
//! (the frame and its substeps), [`options`] (what a step is asked and
//! reports), [`dynamics`], [`compliance`], [`strain_pass`], [`self_pass`]
//! (the skin's contact with itself, with the colliders).

pub mod compliance;
pub mod dynamics;
pub mod options;
mod seams;
mod self_pass;
mod step;
mod strain_pass;

use glam::Vec3;

use crate::collide::{Collider, SelfCollision, Skin};
use crate::mesh::{polygon_edges, MeshInput, Weld, SLIVER_RATIO, WELD_TOLERANCE};
use crate::pyramid::{DeformerOptions, PyramidDeformer};
use crate::solve::ConstraintId;
use crate::strain::Hierarchy;
use crate::Result;

pub use dynamics::{Dynamics, MAX_SUBSTEPS, STIFFNESS_DENSITY};
pub use options::{ContactWork, SelfOptions, SelfWork, StepOptions, StepReport, StrainMode, StrainOptions};

use self_pass::KeptTangles;
use step::CarriedPlanes;

/// A bound mesh and the state of the sequence of frames being solved.
pub struct Sequence {
    /// The mesh's vertices → the welded ones everything below works on (the
    /// identity for a mesh without split seams).
    weld: Weld,
    /// Bound on the welded mesh.
    deformer: PyramidDeformer,
    // Bind-time data of the collision and strain passes.
    /// Edges and triangles for the collision passes (vertices only when
    /// built from a bare deformer: [`Sequence::step`] then handles vertex
    /// contacts only).
    skin: Skin,
    /// Rest positions (strain limits measure against them).
    rest: Vec<Vec3>,
    /// The mesh's own edges, which strain limits hold (the collision skin's
    /// edges also include the diagonals of triangulated polygons).
    mesh_edges: Vec<[u32; 2]>,
    /// The welded mesh's polygons (corners, sizes): self-collision splits
    /// them on its own, each quad both ways.
    polygons: (Vec<i32>, Vec<i32>),
    /// Area around each vertex at rest (a third of its triangles'): masses.
    vertex_area: Vec<f32>,
    // Per-bake state.
    /// Last output of [`Sequence::step`]: collision-free, where the next
    /// frame's first pass starts from.
    history: Option<Vec<Vec3>>,
    /// Dynamics state: velocities at the end of the last step.
    velocity: Option<Vec<Vec3>>,
    /// The last step's input: substeps interpolate from it.
    last_input: Option<Vec<Vec3>>,
    /// The inertia term, added to the deformer's solver on the first
    /// dynamic step.
    inertia: Option<ConstraintId>,
    /// Target rows of skin giving way to compliant colliders, added on the
    /// first step that needs them.
    contact_targets: Option<ConstraintId>,
    /// The skin as a collider, for compliant colliders' vertices to meet.
    skin_collider: Option<Collider>,
    /// The last substep's in-loop supporting planes, for the next first pass.
    carried_planes: Option<CarriedPlanes>,
    /// The multilevel blocks of the unified strain pass, built on the first
    /// step that needs them and kept while the limits stay the same.
    strain_levels: Option<Hierarchy>,
    /// Self-collision's bind, made on the first step that asks for it.
    self_collision: Option<SelfCollision>,
    /// The last output's self-intersections: the next frame's tangles.
    self_tangles: Option<KeptTangles>,
    /// How far the last step's solves moved each vertex from where their
    /// first self-collision passes left it, if every substep of it had
    /// self-collision and started warm: the next warm first pass's margins.
    self_moves: Option<Vec<f32>>,
}

impl Sequence {
    /// Welds the vertices of `mesh` that coincide at rest (within
    /// [`WELD_TOLERANCE`] of its size) and the ends of sliver edges (shorter
    /// than [`SLIVER_RATIO`] of their neighbours), binds the welded mesh
    /// ([`PyramidDeformer::bind`]) and builds the skin, edges and areas the
    /// collision, strain and dynamics passes need.
    pub fn bind(mesh: MeshInput<'_>, options: DeformerOptions) -> Result<Self> {
        let offsets = mesh.validate()?; // before welding: finite positions, indices in range
        let weld = Weld::by_distance_and_slivers(mesh.positions, mesh.corner_verts, &offsets, WELD_TOLERANCE, SLIVER_RATIO);
        let (positions, corner_verts);
        let welded = if weld.is_identity() {
            mesh
        } else {
            positions = weld.gather(mesh.positions);
            corner_verts = weld.corners(mesh.corner_verts);
            MeshInput { positions: &positions, corner_verts: &corner_verts, polygon_sizes: mesh.polygon_sizes }
        };
        let deformer = PyramidDeformer::bind(welded, options)?;
        let skin = Skin::from_mesh(welded)?;
        let mut sequence = Self::new(deformer);
        sequence.rest = welded.positions.to_vec();
        sequence.mesh_edges = polygon_edges(welded.corner_verts, &welded.validate()?);
        sequence.polygons = (welded.corner_verts.to_vec(), welded.polygon_sizes.to_vec());
        sequence.vertex_area = vertex_areas(welded.positions, skin.triangles());
        sequence.skin = skin;
        sequence.weld = weld;
        Ok(sequence)
    }

    /// A sequence over a deformer built without a mesh (e.g. from a bare
    /// encoding): vertex contacts only, unit masses, no strain limits.
    pub fn new(deformer: PyramidDeformer) -> Self {
        let n = deformer.vertex_count();
        Sequence {
            weld: Weld::identity(n),
            deformer,
            skin: Skin::vertices_only(n),
            rest: Vec::new(),
            mesh_edges: Vec::new(),
            polygons: (Vec::new(), Vec::new()),
            vertex_area: vec![1.0; n],
            history: None,
            velocity: None,
            last_input: None,
            inertia: None,
            contact_targets: None,
            skin_collider: None,
            carried_planes: None,
            strain_levels: None,
            self_collision: None,
            self_tangles: None,
            self_moves: None,
        }
    }

    /// The deformer of the welded mesh: its vertices are
    /// [`Self::weld`]'s welded ones.
    pub fn deformer(&self) -> &PyramidDeformer {
        &self.deformer
    }

    /// The deformer of the welded mesh, e.g. for solver settings.
    pub fn deformer_mut(&mut self) -> &mut PyramidDeformer {
        &mut self.deformer
    }
}

impl Sequence {
    /// Forgets the last output and the dynamics state: the next
    /// [`Self::step`] starts from its input, at rest.
    pub fn reset(&mut self) {
        self.history = None;
        self.velocity = None;
        self.last_input = None;
        self.self_tangles = None;
        self.self_moves = None;
    }
}

/// A third of the area of the triangles around each vertex (1 for a vertex
/// without triangles, so that it still has a mass).
fn vertex_areas(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<f32> {
    let mut area = vec![0.0f32; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        let third = (b - a).cross(c - a).length() / 6.0;
        for &v in t {
            area[v as usize] += third;
        }
    }
    for a in &mut area {
        if !(*a > 0.0) {
            *a = 1.0;
        }
    }
    area
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod seam_tests;
#[cfg(test)]
mod irregular_tests;
#[cfg(test)]
mod self_tests;
#[cfg(test)]
mod contact_convergence_tests;
