//! A kinematic collider: a triangle mesh with last-frame and this-frame world
//! positions (same topology), a thickness, static and kinetic friction, and
//! BVHs over its triangle and vertex bounds: over the frame's sweep (for the
//! first pass) and where they stand now (for the in-loop passes, the
//! clearance and the audit).

use glam::Vec3;

use super::bvh::{BoxTree, Bounds, UpdateReport};
use super::geometry::closest_on_triangle;
use crate::mesh::{validate_positions, vertex_incidence};
use crate::{Error, Result};

/// Thickness and friction of a collider.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColliderSettings {
    /// Minimum distance kept between the skin and the collider's surface.
    pub thickness: f32,
    /// Static friction coefficient μs (Bender et al. 2015): a contact with
    /// tangential slip below μs · penetration depth sticks.
    pub static_friction: f32,
    /// Kinetic friction coefficient μk: otherwise the slip is reduced by
    /// μk · penetration depth.
    pub kinetic_friction: f32,
}

/// What an artist gets before touching anything, in the add-on and the wheel
/// alike: skin kept 5 mm (in metres) off the surface, and the friction of skin
/// on skin or cloth, sticking a little and sliding a little less.
impl Default for ColliderSettings {
    fn default() -> Self {
        ColliderSettings { thickness: 0.005, static_friction: 0.3, kinetic_friction: 0.2 }
    }
}

impl ColliderSettings {
    /// Same coefficient for static and kinetic friction.
    pub fn new(thickness: f32, friction: f32) -> Self {
        ColliderSettings { thickness, static_friction: friction, kinetic_friction: friction }
    }

    fn validate(&self) -> Result<()> {
        for (name, value) in [
            ("thickness", self.thickness),
            ("static friction", self.static_friction),
            ("kinetic friction", self.kinetic_friction),
        ] {
            if !value.is_finite() || value < 0.0 {
                return Err(Error::invalid(format!("collider {name} must be finite and ≥ 0, got {value}")));
            }
        }
        Ok(())
    }
}

/// A triangle mesh moving from `previous` to `current` over the frame.
#[derive(Debug, Clone)]
pub struct Collider {
    triangles: Vec<[u32; 3]>,
    /// Unique undirected edges, `[min, max]`, sorted.
    edges: Vec<[u32; 2]>,
    /// The three edge ids of every triangle (edges of corners 0-1, 1-2, 2-0).
    triangle_edges: Vec<[u32; 3]>,
    /// Up to two triangles of every edge (`u32::MAX` where there is none).
    edge_faces: Vec<[u32; 2]>,
    /// Every edge is shared by exactly two triangles (the inside test applies).
    closed: bool,
    previous: Vec<Vec3>,
    current: Vec<Vec3>,
    settings: ColliderSettings,
    /// The collider's translation over the frame, as one vector: the middle
    /// of its vertices' displacements, per axis. The swept trees hold their
    /// boxes in a frame moving with it (see [`Collider::drift`]).
    drift: Vec3,
    /// How far any vertex's displacement over the frame is from the drift
    /// (Euclidean): how far the collider moves within the drifting frame.
    drift_spread: f64,
    /// Thickened boxes of the triangles over the frame, in the drifting frame.
    swept_tree: BoxTree,
    /// Thickened boxes of the vertices over the frame, in the drifting frame
    /// (collider vertices against skin triangles).
    swept_vertex_tree: BoxTree,
    /// Thickened boxes of the triangles at the current positions.
    tree: BoxTree,
    /// Thickened boxes of the vertices at the current positions.
    vertex_tree: BoxTree,
    /// Previous = current: the swept trees would hold the still trees'
    /// boxes, so they are neither refitted nor used.
    at_rest: bool,
    /// CSR lists of the triangles around every vertex.
    vertex_triangle_offsets: Vec<u32>,
    vertex_triangle_list: Vec<u32>,
    last_update: Option<UpdateReport>,
    /// Compliant vertices (seed 002 §1), if any were painted.
    compliance: Option<Compliance>,
    /// Identifies the state of the positions and settings: see [`Collider::generation`].
    generation: u64,
    shape: Shape,
    /// Set by [`Collider::rest_at`]: the still boxes are grown by `slack`
    /// beyond the thickness, around `boxed_at` (per vertex, where its boxes
    /// were made; empty otherwise: around the current positions), and every
    /// vertex is within `slack` of it.
    slack: f32,
    boxed_at: Vec<Vec3>,
    /// Vertices whose boxes [`Collider::rest_at`] made again one by one
    /// since the trees were last refitted whole.
    remade_since_refit: usize,
}

/// How far the f32 rounding of `p − drift` may move a point of box `b`
/// (zero when there is no drift): boxes in the drifting frame are grown by
/// it so that the exact shifted positions stay inside.
fn drift_rounding(drift: Vec3, b: &Bounds) -> f32 {
    if drift == Vec3::ZERO {
        return 0.0;
    }
    f32::EPSILON * b.min.abs().max(b.max.abs()).max_element()
}

/// Source of [`Collider::generation`] values, unique within the process.
static GENERATIONS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

fn next_generation() -> u64 {
    GENERATIONS.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

/// A point on a collider's surface: where, on which triangle, and its
/// barycentric weights there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    pub point: Vec3,
    pub triangle: u32,
    pub barycentric: Vec3,
}

/// The compliant part of a collider: its vertices are unknowns of the step,
/// pulled to their animated positions (the *goals*) by springs of stiffness
/// density `stiffness` (which already contains the 1/h² factor, so it does
/// not depend on substeps), without momentum. On contact they recede. The
/// collider's `current` positions are then the solved ones, which is what
/// the next frame starts from.
/// Whole-collider figures the contact passes need, kept with the positions.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Shape {
    outward: f64,
    extent: f32,
}

#[derive(Debug, Clone)]
pub struct Compliance {
    /// Per vertex; 0 = kinematic (follows its goal exactly).
    pub stiffness: Vec<f32>,
    /// This frame's animated positions.
    pub goals: Vec<Vec3>,
    /// Last frame's animated positions (substeps interpolate from them).
    pub previous_goals: Vec<Vec3>,
}

impl Collider {
    /// A collider at rest at `positions` (previous = current).
    pub fn new(positions: &[Vec3], triangles: &[[u32; 3]], settings: ColliderSettings) -> Result<Self> {
        settings.validate()?;
        validate_positions("collider positions", positions)?;
        if positions.len() >= u32::MAX as usize {
            return Err(Error::invalid(format!("a collider with {} vertices is too large", positions.len())));
        }
        for (t, tri) in triangles.iter().enumerate() {
            if let Some(&v) = tri.iter().find(|&&v| v as usize >= positions.len()) {
                return Err(Error::invalid(format!(
                    "collider triangle {t} refers to vertex {v}, but the collider has {} vertices",
                    positions.len()
                )));
            }
        }
        let (edges, triangle_edges, closed) = edges_of(triangles);
        let mut edge_faces = vec![[u32::MAX; 2]; edges.len()];
        for (t, ids) in triangle_edges.iter().enumerate() {
            for &e in ids {
                let slot = &mut edge_faces[e as usize];
                if slot[0] == u32::MAX {
                    slot[0] = t as u32;
                } else if slot[1] == u32::MAX {
                    slot[1] = t as u32;
                }
            }
        }
        let (vertex_triangle_offsets, vertex_triangle_list) = vertex_incidence(positions.len(), triangles.iter().map(|t| &t[..]));
        let mut collider = Collider {
            triangles: triangles.to_vec(),
            edges,
            triangle_edges,
            edge_faces,
            closed,
            previous: positions.to_vec(),
            current: positions.to_vec(),
            settings,
            drift: Vec3::ZERO,
            drift_spread: 0.0,
            swept_tree: BoxTree::build(&[])?,
            swept_vertex_tree: BoxTree::build(&[])?,
            tree: BoxTree::build(&[])?,
            vertex_tree: BoxTree::build(&[])?,
            at_rest: true,
            vertex_triangle_offsets,
            vertex_triangle_list,
            last_update: None,
            compliance: None,
            generation: next_generation(),
            shape: Shape::default(),
            slack: 0.0,
            boxed_at: Vec::new(),
            remade_since_refit: 0,
        };
        collider.shape = collider.measure_shape();
        collider.swept_tree = BoxTree::build(&collider.swept_boxes())?;
        collider.swept_vertex_tree = BoxTree::build(&collider.swept_vertex_boxes())?;
        collider.tree = BoxTree::build(&collider.still_boxes())?;
        collider.vertex_tree = BoxTree::build(&collider.still_vertex_boxes())?;
        Ok(collider)
    }

    /// Next frame: the current positions become the previous ones, `positions`
    /// the current ones; the BVHs are refitted (and rebuilt if degraded). The
    /// report is the triangle tree's at the current positions.
    pub fn update(&mut self, positions: &[Vec3]) -> Result<UpdateReport> {
        self.check_count(positions.len())?;
        validate_positions("collider positions", positions)?;
        std::mem::swap(&mut self.previous, &mut self.current);
        self.current.copy_from_slice(positions);
        if let Some(c) = &mut self.compliance {
            std::mem::swap(&mut c.previous_goals, &mut c.goals);
            c.goals.copy_from_slice(positions);
        }
        self.refresh()
    }

    /// Paints compliance: one stiffness density per vertex (finite, ≥ 0; 0 =
    /// kinematic). All zeros, or `None`, makes the collider fully kinematic.
    /// The goals start at the current positions.
    pub fn set_compliance(&mut self, stiffness: Option<&[f32]>) -> Result<()> {
        let Some(stiffness) = stiffness else {
            self.compliance = None;
            return Ok(());
        };
        if stiffness.len() != self.current.len() {
            return Err(Error::invalid(format!(
                "collider stiffness has {} values but the collider has {} vertices",
                stiffness.len(),
                self.current.len()
            )));
        }
        if let Some(v) = stiffness.iter().position(|k| !(k.is_finite() && *k >= 0.0)) {
            return Err(Error::invalid(format!(
                "collider stiffness of vertex {v} is {}; it must be finite and ≥ 0",
                stiffness[v]
            )));
        }
        self.compliance = stiffness.iter().any(|&k| k > 0.0).then(|| Compliance {
            stiffness: stiffness.to_vec(),
            goals: self.current.clone(),
            previous_goals: self.previous.clone(),
        });
        Ok(())
    }

    /// The compliant part, if any vertex is compliant.
    pub fn compliance(&self) -> Option<&Compliance> {
        self.compliance.as_ref()
    }

    /// Whether any vertex is compliant.
    pub fn is_compliant(&self) -> bool {
        self.compliance.is_some()
    }

    /// Sets both ends of the frame explicitly (e.g. after a jump in time).
    pub fn set_positions(&mut self, previous: &[Vec3], current: &[Vec3]) -> Result<UpdateReport> {
        self.check_count(previous.len())?;
        self.check_count(current.len())?;
        validate_positions("collider previous positions", previous)?;
        validate_positions("collider positions", current)?;
        self.previous.copy_from_slice(previous);
        self.current.copy_from_slice(current);
        self.refresh()
    }

    /// At rest at `positions` (previous = current), for a mesh standing in
    /// as a collider that moves a little everywhere and much only in places
    /// (the skin, after every solver iteration, for compliant colliders to
    /// stop at): the still boxes are grown by `slack` beyond the thickness,
    /// and only those of vertices that moved more than half of it since
    /// their boxes were made are made again, with their leaves' and the
    /// leaves' ancestors' boxes. Each box still holds its element grown by
    /// the thickness, so every query finds what it would with tight boxes
    /// (a few more candidates, tested exactly). `fresh` (or another slack,
    /// or positions that were set otherwise since, or as many boxes remade
    /// one by one since the last such refit as there are vertices) refits
    /// everything, and rebuilds degraded trees. Returns how many vertices'
    /// boxes were made again (all of them when refitted whole).
    pub fn rest_at(&mut self, positions: &[Vec3], slack: f32, fresh: bool) -> Result<usize> {
        use rayon::prelude::*;
        self.check_count(positions.len())?;
        validate_positions("collider positions", positions)?;
        if !(slack.is_finite() && slack >= 0.0) {
            return Err(Error::invalid(format!("collider slack is {slack}; it must be finite and ≥ 0")));
        }
        self.previous.copy_from_slice(positions);
        self.current.copy_from_slice(positions);
        // Boxes remade one by one leave the trees as they were built; once as
        // many have been remade as there are vertices, everything is refitted
        // (rebuilding a degraded tree), so that cost, in proportion to the
        // mesh, is paid in proportion to the motion.
        let incremental = !fresh
            && self.at_rest
            && self.slack == slack
            && self.boxed_at.len() == positions.len()
            && self.remade_since_refit < positions.len();
        if !incremental {
            self.refresh_with_slack(slack, positions.to_vec())?;
            self.remade_since_refit = 0;
            return Ok(positions.len());
        }
        let reach = 0.5 * slack;
        let moved: Vec<u32> = (0..positions.len() as u32)
            .into_par_iter()
            .with_min_len(4096)
            .filter(|&v| positions[v as usize].distance(self.boxed_at[v as usize]) > reach)
            .collect();
        for &v in &moved {
            self.boxed_at[v as usize] = positions[v as usize];
        }
        self.remade_since_refit += moved.len();
        let mut triangles: Vec<u32> = moved.iter().flat_map(|&v| self.vertex_triangles(v as usize).iter().copied()).collect();
        triangles.sort_unstable();
        triangles.dedup();
        let r = self.settings.thickness + slack;
        let at = &self.boxed_at;
        let triangle_boxes: Vec<(u32, Bounds)> =
            triangles.par_iter().map(|&t| (t, Bounds::of_points(&self.triangles[t as usize].map(|v| at[v as usize])).inflated(r))).collect();
        let vertex_boxes: Vec<(u32, Bounds)> = moved.par_iter().map(|&v| (v, Bounds { min: at[v as usize], max: at[v as usize] }.inflated(r))).collect();
        self.generation = next_generation();
        self.shape = self.measure_shape();
        let (still, vertices) = rayon::join(|| self.tree.update_some(&triangle_boxes), || self.vertex_tree.update_some(&vertex_boxes));
        still?;
        vertices?;
        Ok(moved.len())
    }

    /// [`Self::refresh`] with the still boxes grown by `slack` around `boxed_at`.
    fn refresh_with_slack(&mut self, slack: f32, boxed_at: Vec<Vec3>) -> Result<UpdateReport> {
        self.slack = slack;
        self.boxed_at = boxed_at;
        self.refresh_keeping_slack()
    }

    /// Forgets the motion: previous = current (a teleport, or the first frame).
    pub fn hold(&mut self) -> Result<UpdateReport> {
        self.previous.copy_from_slice(&self.current);
        self.refresh()
    }

    pub fn set_settings(&mut self, settings: ColliderSettings) -> Result<()> {
        settings.validate()?;
        if settings == self.settings {
            return Ok(());
        }
        self.settings = settings;
        self.refresh().map(|_| ())
    }

    fn check_count(&self, given: usize) -> Result<()> {
        if given != self.current.len() {
            return Err(Error::Topology(format!(
                "collider had {} vertices, update gave {given}",
                self.current.len()
            )));
        }
        Ok(())
    }

    /// A number that changes whenever the positions or the settings do (and
    /// is never reused by another state within the process), so that what was
    /// computed from this state — a [`super::clearance::Clearance`] — can tell
    /// whether it still applies. A clone shares it until either changes.
    pub fn generation(&self) -> u64 {
        self.generation
    }

    fn refresh(&mut self) -> Result<UpdateReport> {
        self.slack = 0.0;
        self.boxed_at = Vec::new();
        self.refresh_keeping_slack()
    }

    fn refresh_keeping_slack(&mut self) -> Result<UpdateReport> {
        self.generation = next_generation();
        self.shape = self.measure_shape();
        self.drift = self.measure_drift();
        self.drift_spread = self.measure_drift_spread();
        // A collider at rest (a skin standing in as one, each pass) sweeps
        // nowhere: its still trees serve for both.
        self.at_rest = self.previous == self.current;
        let (still_boxes, still_vertex_boxes) = (self.still_boxes(), self.still_vertex_boxes());
        if self.at_rest {
            let (still, vertices) = rayon::join(|| self.tree.update(&still_boxes), || self.vertex_tree.update(&still_vertex_boxes));
            let report = still?;
            vertices?;
            self.last_update = Some(report);
            return Ok(report);
        }
        // The four trees are independent: refitted side by side.
        let (swept_boxes, swept_vertex_boxes) = (self.swept_boxes(), self.swept_vertex_boxes());
        let (swept, still) = rayon::join(
            || rayon::join(|| self.swept_tree.update(&swept_boxes), || self.swept_vertex_tree.update(&swept_vertex_boxes)),
            || rayon::join(|| self.tree.update(&still_boxes), || self.vertex_tree.update(&still_vertex_boxes)),
        );
        swept.0?;
        swept.1?;
        let report = still.0?;
        still.1?;
        self.last_update = Some(report);
        Ok(report)
    }

    /// The middle of the range of the vertices' displacements, per axis: the
    /// translation that leaves the smallest residual motion in the swept
    /// boxes. Zero for a collider at rest.
    fn measure_drift(&self) -> Vec3 {
        use rayon::prelude::*;
        let (lo, hi) = (self.previous.par_iter(), self.current.par_iter())
            .into_par_iter()
            .map(|(&a, &b)| (b - a, b - a))
            .reduce(|| (Vec3::INFINITY, Vec3::NEG_INFINITY), |x, y| (x.0.min(y.0), x.1.max(y.1)));
        if lo.cmpgt(hi).any() {
            return Vec3::ZERO;
        }
        0.5 * (lo + hi)
    }

    /// The largest distance of a vertex's displacement from the drift, in
    /// f64 from the f32 positions, rounded up.
    fn measure_drift_spread(&self) -> f64 {
        use rayon::prelude::*;
        let drift = self.drift.as_dvec3();
        let largest = (self.previous.par_iter(), self.current.par_iter())
            .into_par_iter()
            .with_min_len(4096)
            .map(|(&a, &b)| (b.as_dvec3() - a.as_dvec3() - drift).length())
            .reduce(|| 0.0, f64::max);
        largest * (1.0 + 1e-12) + f64::EPSILON * drift.abs().max_element()
    }

    /// Box of triangle `t` over the whole frame in the frame drifting with
    /// [`Collider::drift`], grown by the thickness (and by the rounding of
    /// the shift).
    pub fn swept_box(&self, t: usize) -> Bounds {
        let [a, b, c] = self.triangles[t].map(|v| v as usize);
        let drift = self.drift;
        let (ca, cb, cc) = (self.current[a] - drift, self.current[b] - drift, self.current[c] - drift);
        let corners = [self.previous[a], self.previous[b], self.previous[c], ca, cb, cc];
        let b = Bounds::of_points(&corners);
        b.inflated(self.settings.thickness + drift_rounding(drift, &b))
    }

    fn swept_vertex_boxes(&self) -> Vec<Bounds> {
        use rayon::prelude::*;
        let (r, drift) = (self.settings.thickness, self.drift);
        (self.previous.par_iter(), self.current.par_iter())
            .into_par_iter()
            .map(|(&a, &b)| {
                let b = Bounds::of_points(&[a, b - drift]);
                b.inflated(r + drift_rounding(drift, &b))
            })
            .collect()
    }

    fn swept_boxes(&self) -> Vec<Bounds> {
        use rayon::prelude::*;
        (0..self.triangles.len()).into_par_iter().map(|t| self.swept_box(t)).collect()
    }

    fn still_boxes(&self) -> Vec<Bounds> {
        use rayon::prelude::*;
        let (r, at) = (self.settings.thickness + self.slack, self.boxed_at());
        self.triangles.par_iter().map(|t| Bounds::of_points(&t.map(|v| at[v as usize])).inflated(r)).collect()
    }

    fn still_vertex_boxes(&self) -> Vec<Bounds> {
        use rayon::prelude::*;
        let r = self.settings.thickness + self.slack;
        self.boxed_at().par_iter().map(|&p| Bounds { min: p, max: p }.inflated(r)).collect()
    }

    /// Where the still boxes are made around (see [`Self::rest_at`]).
    fn boxed_at(&self) -> &[Vec3] {
        if self.boxed_at.is_empty() { &self.current } else { &self.boxed_at }
    }

    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }
    pub fn triangle_edges(&self) -> &[[u32; 3]] {
        &self.triangle_edges
    }
    /// The (up to two) triangles of edge `e`.
    pub fn edge_triangles(&self, e: usize) -> &[u32] {
        let faces = &self.edge_faces[e];
        let count = faces.iter().take_while(|&&f| f != u32::MAX).count();
        &faces[..count]
    }
    pub fn previous(&self) -> &[Vec3] {
        &self.previous
    }
    pub fn current(&self) -> &[Vec3] {
        &self.current
    }
    pub fn vertex_count(&self) -> usize {
        self.current.len()
    }
    pub fn settings(&self) -> ColliderSettings {
        self.settings
    }
    /// Whether every edge has exactly two triangles (a closed surface).
    /// +1 if a closed collider's triangles wind outward (positive volume at
    /// the current positions), −1 if inward, 0 for open colliders.
    pub fn outward_sign(&self) -> f64 {
        self.shape.outward
    }

    /// The largest absolute coordinate of the previous and current
    /// positions: the scale of rounding-aware tolerances.
    pub fn extent(&self) -> f32 {
        self.shape.extent
    }

    /// What every contact pass reads from the whole collider, once per state.
    fn measure_shape(&self) -> Shape {
        use rayon::prelude::*;
        let extent = self.current.par_iter().chain(self.previous.par_iter()).map(|p| p.abs().max_element()).reduce(|| 0.0, f32::max);
        if !self.closed {
            return Shape { outward: 0.0, extent };
        }
        let p = &self.current;
        let volume: f64 = self
            .triangles
            .par_iter()
            .map(|t| {
                let [a, b, c] = t.map(|v| p[v as usize].as_dvec3());
                a.dot(b.cross(c))
            })
            .sum();
        let outward = if volume > 0.0 {
            1.0
        } else if volume < 0.0 {
            -1.0
        } else {
            0.0
        };
        Shape { outward, extent }
    }

    pub fn is_closed(&self) -> bool {
        self.closed
    }
    /// The BVH over the thickened triangle boxes at the current positions.
    pub fn tree(&self) -> &BoxTree {
        &self.tree
    }
    /// The BVH over the thickened vertex boxes at the current positions.
    pub fn vertex_tree(&self) -> &BoxTree {
        &self.vertex_tree
    }

    /// The translation of the frame in which [`Collider::swept_tree`] and
    /// [`Collider::swept_vertex_tree`] hold their boxes: a point at `p` at
    /// time `t` of the step (0 = previous, 1 = current) sits at
    /// `p − t·drift` in it. Distances are the same in both frames at every
    /// instant, so a contact search may take its candidates there; what
    /// moves with the collider barely moves in that frame, and its boxes
    /// stay small (a rigidly translating collider's are its boxes at rest).
    pub fn drift(&self) -> Vec3 {
        self.drift
    }
    /// How far any point of the collider moves over the step within the
    /// frame drifting with [`Collider::drift`]: zero for a rigid translation,
    /// up to rounding.
    pub fn drift_spread(&self) -> f64 {
        self.drift_spread
    }
    /// The BVH over thickened triangle boxes over the frame, in the frame
    /// moving with [`Collider::drift`]; query it with [`Collider::swept_query`].
    pub fn swept_tree(&self) -> &BoxTree {
        if self.at_rest { &self.tree } else { &self.swept_tree }
    }
    /// The same for vertex boxes.
    pub fn swept_vertex_tree(&self) -> &BoxTree {
        if self.at_rest { &self.vertex_tree } else { &self.swept_vertex_tree }
    }
    /// The box, in the drifting frame, of a skin element whose corners lie
    /// in `start` at the start of the step and in `end` at its end.
    pub fn swept_query(&self, start: Bounds, end: Bounds) -> Bounds {
        let drift = self.drift;
        if drift == Vec3::ZERO {
            return start.union(end);
        }
        let shifted = Bounds { min: end.min - drift, max: end.max - drift };
        let b = start.union(shifted);
        b.inflated(drift_rounding(drift, &b))
    }
    /// The triangles around vertex `v`.
    pub fn vertex_triangles(&self, v: usize) -> &[u32] {
        let (a, b) = (self.vertex_triangle_offsets[v] as usize, self.vertex_triangle_offsets[v + 1] as usize);
        &self.vertex_triangle_list[a..b]
    }
    /// The point of the surface (at the current positions) closest to `p`,
    /// or `None` for a collider without triangles.
    pub fn closest_point(&self, p: Vec3) -> Option<SurfacePoint> {
        self.closest_point_within(p, f64::INFINITY)
    }

    /// [`Self::closest_point`] when it is nearer than `limit`, else `None`.
    /// A caller that knows a point of the surface within `limit` gets the
    /// same answer sooner: the search skips every subtree farther than that
    /// from the start, where the unbounded one descends to the nearest leaf
    /// first and prunes only from there.
    pub fn closest_point_within(&self, p: Vec3, limit: f64) -> Option<SurfacePoint> {
        if self.triangles.is_empty() {
            return None;
        }
        let pd = p.as_dvec3();
        // The search measures each candidate once; its surface point is kept here.
        let mut found = None;
        self.tree.nearest(p, limit, self.settings.thickness as f64, |t| {
            let [a, b, c] = self.triangles[t].map(|v| self.current[v as usize].as_dvec3());
            let (v, w) = closest_on_triangle(pd, a, b, c);
            let q = a + v * (b - a) + w * (c - a);
            let d = (pd - q).length();
            if found.as_ref().is_none_or(|(best, _)| d < *best) {
                let barycentric = Vec3::new((1.0 - v - w) as f32, v as f32, w as f32);
                found = Some((d, SurfacePoint { point: q.as_vec3(), triangle: t as u32, barycentric }));
            }
            d
        })?;
        found.map(|(_, point)| point)
    }

    /// Whether any triangle (at the current positions) is within `distance` of `p`.
    pub fn is_within(&self, p: Vec3, distance: f32) -> bool {
        let pd = p.as_dvec3();
        let limit = (distance as f64) * (distance as f64);
        let mut found = false;
        self.tree.query(&Bounds { min: p, max: p }.inflated(distance), |t| {
            let [a, b, c] = self.triangles[t].map(|v| self.current[v as usize].as_dvec3());
            let (v, w) = closest_on_triangle(pd, a, b, c);
            found = (pd - (a + v * (b - a) + w * (c - a))).length_squared() <= limit;
            !found
        });
        found
    }

    /// Where segment `p → q` first meets the surface (at the current
    /// positions): the fraction along it and the triangle, or `None`.
    pub fn first_hit(&self, p: Vec3, q: Vec3) -> Option<(f32, u32)> {
        let (pd, qd) = (p.as_dvec3(), q.as_dvec3());
        let dir = qd - pd;
        let (t, along) = self.tree.first_along(p, q, self.settings.thickness as f64, |t| {
            let [a, b, c] = self.triangles[t].map(|v| self.current[v as usize].as_dvec3());
            // Möller–Trumbore, in f64.
            let (e1, e2) = (b - a, c - a);
            let h = dir.cross(e2);
            let det = e1.dot(h);
            if det.abs() < 1e-300 {
                return None;
            }
            let s = pd - a;
            let u = s.dot(h) / det;
            let qv = s.cross(e1);
            let v = dir.dot(qv) / det;
            let along = e2.dot(qv) / det;
            ((0.0..=1.0).contains(&u) && v >= 0.0 && u + v <= 1.0 && (0.0..=1.0).contains(&along)).then_some(along)
        })?;
        Some((along as f32, t as u32))
    }

    /// What the last update of the BVH did.
    pub fn last_update(&self) -> Option<UpdateReport> {
        self.last_update
    }
}

/// Unique edges, the edge ids of every triangle, and whether every edge has
/// exactly two triangles.
fn edges_of(triangles: &[[u32; 3]]) -> (Vec<[u32; 2]>, Vec<[u32; 3]>, bool) {
    let mut keyed: Vec<([u32; 2], u32)> = Vec::with_capacity(triangles.len() * 3);
    for (t, tri) in triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            keyed.push(([a.min(b), a.max(b)], (t * 3 + k) as u32));
        }
    }
    keyed.sort_unstable();
    let mut edges = Vec::new();
    let mut triangle_edges = vec![[0u32; 3]; triangles.len()];
    let mut closed = !triangles.is_empty();
    let mut i = 0;
    while i < keyed.len() {
        let mut j = i;
        while j < keyed.len() && keyed[j].0 == keyed[i].0 {
            let slot = keyed[j].1 as usize;
            triangle_edges[slot / 3][slot % 3] = edges.len() as u32;
            j += 1;
        }
        if j - i != 2 || keyed[i].0[0] == keyed[i].0[1] {
            closed = false;
        }
        edges.push(keyed[i].0);
        i = j;
    }
    (edges, triangle_edges, closed)
}

/// Triangles of a flat `[a0, b0, c0, a1, …]` index array, checked.
pub fn triangles_from_flat(indices: &[i32]) -> Result<Vec<[u32; 3]>> {
    if indices.len() % 3 != 0 {
        return Err(Error::invalid(format!(
            "triangle indices hold {} values, which is not a multiple of 3",
            indices.len()
        )));
    }
    indices
        .chunks_exact(3)
        .enumerate()
        .map(|(t, c)| {
            if let Some(&v) = c.iter().find(|&&v| v < 0) {
                return Err(Error::invalid(format!("triangle {t} has a negative vertex index {v}")));
            }
            Ok([c[0] as u32, c[1] as u32, c[2] as u32])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collide::geometry::point_triangle_distance_squared;
    use proptest::prelude::*;

    fn point(range: f32) -> impl Strategy<Value = Vec3> {
        (-range..range, -range..range, -range..range).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }


    /// A collider kept at rest by [`Collider::rest_at`] through many small
    /// moves and a few large ones answers every query as one built afresh
    /// at the same positions, while remaking only the moved vertices' boxes.
    #[test]
    fn resting_with_slack_answers_as_a_fresh_collider() {
        let mesh = crate::mesh::shapes::grid(12, 12, 1.0);
        let offsets: Vec<u32> = (0..=mesh.polygon_sizes.len() as u32).map(|k| 4 * k).collect();
        let tris = crate::mesh::fan_triangles(&mesh.corner_verts, &offsets);
        let settings = ColliderSettings::new(0.02, 0.0);
        let mut x = mesh.positions.clone();
        let mut resting = Collider::new(&x, &tris, settings).unwrap();
        assert_eq!(resting.rest_at(&x, 0.01, true).unwrap(), x.len(), "fresh: every box made");
        let mut seed = 7u32;
        let mut rand = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) as f32 / (1 << 24) as f32 - 0.5
        };
        for round in 0..12 {
            // Rounding-sized moves everywhere, a bump in one place.
            for (v, p) in x.iter_mut().enumerate() {
                p.z += 1e-5 * rand();
                if v % 37 == round {
                    p.z += 0.1 * rand();
                }
            }
            let before = resting.generation();
            let remade = resting.rest_at(&x, 0.01, false).unwrap();
            assert!(remade < x.len() / 4, "round {round}: {remade} of {} boxes remade", x.len());
            // Moved positions are a new state even where no box was remade: a
            // clearance measured before must not be taken as still valid.
            assert_ne!(resting.generation(), before, "round {round}: generation kept after a move");
            let fresh = Collider::new(&x, &tris, settings).unwrap();
            for k in 0..40 {
                let p = Vec3::new(rand(), rand(), 0.1 * rand());
                let q = p + Vec3::new(0.2 * rand(), 0.2 * rand(), 0.4 * rand());
                // The same points and fractions; at a point on an edge shared by
                // two triangles either may be named (the trees differ).
                let point = |s: Option<SurfacePoint>| s.map(|s| s.point);
                assert_eq!(point(resting.closest_point(p)), point(fresh.closest_point(p)), "round {round}, point {k}");
                assert_eq!(point(resting.closest_point_within(p, 0.05)), point(fresh.closest_point_within(p, 0.05)), "round {round}, point {k}");
                assert_eq!(resting.is_within(p, 0.03), fresh.is_within(p, 0.03), "round {round}, point {k}");
                assert_eq!(resting.first_hit(p, q).map(|h| h.0), fresh.first_hit(p, q).map(|h| h.0), "round {round}, segment {k}");
            }
        }
        assert!(resting.rest_at(&x, f32::NAN, false).is_err());
        assert!(resting.rest_at(&x[1..], 0.01, false).is_err());
    }

    /// Boxes remade one by one leave the trees' shape as it was built: once
    /// as many have been remade as there are vertices, the next rest refits
    /// (and may rebuild) them whole, so that a collider kept at rest frame
    /// after frame never skips that for good, and pays it in proportion to
    /// the motion.
    #[test]
    fn resting_refits_whole_once_as_many_boxes_were_remade_as_there_are_vertices() {
        // 100 vertices, moved ten at a time.
        let mesh = crate::mesh::shapes::grid(9, 9, 1.0);
        let offsets: Vec<u32> = (0..=mesh.polygon_sizes.len() as u32).map(|k| 4 * k).collect();
        let tris = crate::mesh::fan_triangles(&mesh.corner_verts, &offsets);
        let mut x = mesh.positions.clone();
        let n = x.len();
        assert_eq!(n, 100);
        let mut resting = Collider::new(&x, &tris, ColliderSettings::new(0.02, 0.0)).unwrap();
        assert_eq!(resting.rest_at(&x, 0.01, true).unwrap(), n);
        // A tenth of the vertices moved by more than the slack each round.
        let step = n / 10;
        let mut remade = 0;
        for round in 0..12 {
            for p in x.iter_mut().skip((round * step) % n).take(step) {
                p.z += 0.05;
            }
            let made = resting.rest_at(&x, 0.01, false).unwrap();
            if remade >= n {
                assert_eq!(made, n, "round {round}: {remade} boxes remade one by one, the trees not refitted whole");
                remade = 0;
            } else {
                assert_eq!(made, step, "round {round}: only the moved vertices' boxes");
                remade += made;
            }
        }
    }

    proptest! {
        /// Wherever a moving point comes within the thickness of a moving
        /// triangle during the frame, its box in the drifting frame meets the
        /// triangle's swept box (and its vertex boxes likewise): the swept
        /// trees miss no contact, however the collider moves.
        #[test]
        fn the_drifting_frame_misses_no_contact(shift in point(3.0), wobble in prop::collection::vec(point(0.3), 4),
                                                s in point(1.5), e in point(1.5), far in 0.0f32..1000.0, thickness in 0.0f32..0.2) {
            let (p, t) = tetra();
            let mut c = Collider::new(&p, &t, ColliderSettings::new(thickness, 0.0)).unwrap();
            let moved: Vec<Vec3> = p.iter().zip(&wobble).map(|(&v, &w)| v + shift + w + Vec3::splat(far)).collect();
            c.update(&moved).unwrap();
            let (s, e) = (s, e + shift + Vec3::splat(far));
            let query = c.swept_query(Bounds::of_points(&[s]), Bounds::of_points(&[e]));
            for i in 0..=64 {
                let time = i as f64 / 64.0;
                let at = |v: u32| c.previous()[v as usize].as_dvec3().lerp(c.current()[v as usize].as_dvec3(), time);
                let x = s.as_dvec3().lerp(e.as_dvec3(), time);
                for (k, tri) in c.triangles().iter().enumerate() {
                    let d = point_triangle_distance_squared(x, at(tri[0]), at(tri[1]), at(tri[2])).sqrt();
                    if d <= thickness as f64 {
                        prop_assert!(c.swept_tree().primitive_bounds(k).overlaps(&query), "triangle {k} at {time}: {d}");
                    }
                }
                for v in 0..4u32 {
                    if (x - at(v)).length() <= thickness as f64 {
                        prop_assert!(c.swept_vertex_tree().primitive_bounds(v as usize).overlaps(&query), "vertex {v} at {time}");
                    }
                }
            }
        }
    }

    fn tetra() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        (
            vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
            vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        )
    }

    #[test]
    fn edges_and_closedness() {
        let (p, t) = tetra();
        let c = Collider::new(&p, &t, ColliderSettings::new(0.0, 0.0)).unwrap();
        assert_eq!(c.edges().len(), 6);
        assert!(c.is_closed());
        for (tri, ids) in c.triangles().iter().zip(c.triangle_edges()) {
            for k in 0..3 {
                let e = c.edges()[ids[k] as usize];
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                assert_eq!(e, [a.min(b), a.max(b)]);
            }
        }
        let open = Collider::new(&p, &t[..3], ColliderSettings::new(0.0, 0.0)).unwrap();
        assert!(!open.is_closed());
    }

    #[test]
    fn update_keeps_last_frame_and_checks_topology() {
        let (p, t) = tetra();
        let mut c = Collider::new(&p, &t, ColliderSettings::new(0.1, 0.5)).unwrap();
        let moved: Vec<Vec3> = p.iter().map(|&v| v + Vec3::new(2.0, 0.0, 0.0)).collect();
        c.update(&moved).unwrap();
        assert_eq!(c.previous(), &p[..]);
        assert_eq!(c.current(), &moved[..]);
        // A rigid translation is all drift: in the drifting frame the
        // collider's swept boxes are its boxes at rest, plus the thickness.
        assert_eq!(c.drift(), Vec3::new(2.0, 0.0, 0.0));
        let b = c.swept_box(0);
        assert!(b.min.x <= -0.1 + 1e-6 && b.max.x >= 1.1 - 1e-6 && b.max.x < 1.2, "{b:?}");
        assert_eq!(c.tree().primitive_bounds(0).min.x, 2.0 - 0.1, "the still tree holds the current boxes");
        // At rest the still trees serve as the swept ones; moving again, the
        // swept trees are refitted from wherever they were.
        c.hold().unwrap();
        assert_eq!(c.swept_tree().primitive_bounds(0), c.tree().primitive_bounds(0));
        assert_eq!(c.swept_vertex_tree().primitive_bounds(3), c.vertex_tree().primitive_bounds(3));
        let back: Vec<Vec3> = moved.iter().map(|&v| v + Vec3::new(0.0, 0.0, 5.0)).collect();
        c.update(&back).unwrap();
        assert_eq!(c.drift(), Vec3::new(0.0, 0.0, 5.0));
        assert_eq!(c.swept_tree().primitive_bounds(0), c.swept_box(0));
        assert!(c.swept_tree().primitive_bounds(0).max.z < 4.0, "boxes in the drifting frame, not over the sweep");
        let err = c.update(&moved[..3]).unwrap_err().to_string();
        assert_eq!(err, "collider had 4 vertices, update gave 3");
    }

    #[test]
    fn bad_input_is_named() {
        let (mut p, t) = tetra();
        let err = Collider::new(&p, &[[0, 1, 9]], ColliderSettings::new(0.0, 0.0)).unwrap_err().to_string();
        assert!(err.contains("triangle 0 refers to vertex 9"), "{err}");
        let err = Collider::new(&p, &t, ColliderSettings::new(-1.0, 0.0)).unwrap_err().to_string();
        assert!(err.contains("thickness"), "{err}");
        p[2].y = f32::NAN;
        let err = Collider::new(&p, &t, ColliderSettings::new(0.0, 0.0)).unwrap_err().to_string();
        assert!(err.contains("vertex 2"), "{err}");
        assert!(triangles_from_flat(&[0, 1]).is_err());
        assert!(triangles_from_flat(&[0, -1, 2]).unwrap_err().to_string().contains("negative"));
    }
}
