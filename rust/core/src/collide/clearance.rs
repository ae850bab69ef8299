//! Clearances of the skin from the colliders, measured once and reused by
//! every in-loop pass of a frame.
//!
//! Most of a skin is nowhere near a collider, yet each pass used to look
//! every vertex, edge and triangle up in the colliders' BVHs. A [`Clearance`]
//! records, for every skin vertex at reference positions `x` (the start of
//! the in-loop passes), a lower bound `D` on its distance to the colliders'
//! BVH leaf boxes (each a triangle's box at its current positions, grown by
//! the thickness, so a point outside every box is farther than the thickness
//! from every collider triangle where it stands). It serves passes in which
//! the colliders stand still at their current positions. A later pass then
//! proves an element apart without a lookup by the ball argument:
//!
//! - a vertex moving from `s` to `e` stays within `r = max(|s − x|, |e − x|)`
//!   of `x` (a ball is convex), so it is clear when `r < D`;
//! - a point `(1−u)·a(t) + u·b(t)` of a moving edge is within
//!   `max(r_a, r_b)` of the point `(1−u)·x_a + u·x_b` of the reference edge,
//!   whose distance to the boxes is at least `max((D_a + D_b − L)/2, max(D_a, D_b) − L)`
//!   (distance is 1-Lipschitz; `L` the reference edge's length);
//! - a point of a triangle is within its longest edge `L` of each corner, so
//!   the reference triangle keeps `max_k D_k − L`, and a moving triangle is
//!   clear when `max_k r_k` is less.
//!
//! The clearance belongs to the colliders' state it was measured against:
//! every change of a collider's positions or settings gives it a new
//! [`Collider::generation`], and a stale clearance is not used. A collider
//! that moves between passes (a compliant one, receding) is measured by its
//! [`Envelope`] instead ([`Clearance::with_envelopes`]): the clearance then
//! holds for as long as the collider stays inside it.

use glam::Vec3;
use rayon::prelude::*;

use super::bvh::Bounds;
use super::bvh::BoxTree;
use super::collider::Collider;
use super::envelope::Envelope;
use super::planes::{rounding_margin, LocalPlanes};
use super::skin::{ascending_unique, Skin};
use crate::mesh::validate_positions;
use crate::{Error, Result};

/// The planes' boxes, as a fraction of the clearance's radius: a vertex
/// resting on a collider moves much less than that over a frame's in-loop
/// passes, and half the box has a quarter of the triangles to bound (on the
/// benchmark's sliding contact, the measurement took 43 ms at the whole
/// radius, 25 ms at half, with the same passes after it).
pub(super) const PLANE_REACH: f32 = 0.5;

/// Distance bounds of a skin's vertices, edges and triangles at reference
/// positions from a set of colliders.
#[derive(Debug, Clone)]
pub struct Clearance {
    reference: Vec<Vec3>,
    /// Per vertex: a lower bound on the distance from `reference[i]` to every
    /// leaf box, less a rounding margin, capped at the radius searched.
    vertex: Vec<f32>,
    /// Per skin edge and triangle: the same for every point of the element
    /// at the reference positions (0 when nothing can be said).
    edge: Vec<f32>,
    triangle: Vec<f32>,
    /// Per vertex: the least of its own bound and those of its edges and
    /// triangles. A vertex that stays within it keeps all of them proven.
    guard: Vec<f32>,
    /// What each collider was measured as: its state, or its envelope.
    measured: Vec<Measured>,
    /// The radius searched and the rounding margin of the measurement.
    radius: f32,
    margin: f64,
    /// Per vertex: whether some collider's box lies within the radius.
    near: Vec<bool>,
    /// The edges and triangles around the near vertices, ascending: where
    /// the resting contacts are, whose elements every pass lists again.
    near_edges: Vec<u32>,
    near_triangles: Vec<u32>,
    /// Supporting planes of the colliders around the vertices near them
    /// ([`Self::with_planes`]).
    planes: Option<LocalPlanes>,
}

impl Clearance {
    /// Measures the clearance of `skin` at `positions` from `colliders`,
    /// searching up to `radius` (larger clearances are recorded as `radius`:
    /// a vertex that moves farther than that since `positions` is looked up
    /// again).
    pub fn new(colliders: &[&Collider], skin: &Skin, positions: &[Vec3], radius: f32) -> Result<Self> {
        Self::with_envelopes(colliders, colliders.iter().map(|_| None).collect(), skin, positions, radius)
    }

    /// [`Self::new`], measuring collider `c` by `envelopes[c]` where given
    /// (see [`Envelope`]): the clearance then serves every pass in which the
    /// collider stands still inside its envelope, wherever it stands there.
    pub fn with_envelopes(colliders: &[&Collider], envelopes: Vec<Option<Envelope>>, skin: &Skin, positions: &[Vec3], radius: f32) -> Result<Self> {
        if envelopes.len() != colliders.len() {
            return Err(Error::invalid(format!("{} envelopes given for {} colliders", envelopes.len(), colliders.len())));
        }
        validate_positions("reference positions", positions)?;
        if positions.len() != skin.vertex_count() {
            return Err(Error::invalid(format!("{} reference positions given for a skin of {} vertices", positions.len(), skin.vertex_count())));
        }
        if !(radius.is_finite() && radius >= 0.0) {
            return Err(Error::invalid(format!("clearance radius is {radius}; it must be finite and ≥ 0")));
        }
        // Boxes are f32, grown by the thickness in f32: allow for their
        // rounding (envelopes reach beyond the colliders' positions).
        let reach = envelopes.iter().flatten().flat_map(|e| [e.bounds().min, e.bounds().max]);
        let margin = rounding_margin(colliders, positions.iter().copied().chain(reach), radius);
        let trees: Vec<&BoxTree> = colliders.iter().zip(&envelopes).map(|(c, e)| e.as_ref().map_or(c.tree(), Envelope::tree)).collect();
        let roots: Vec<Bounds> = trees.iter().map(|t| t.bounds()).collect();
        // Per vertex: the distance bound, and whether any box lies within the radius.
        let (vertex, near): (Vec<f64>, Vec<bool>) = positions
            .par_iter()
            .map(|&p| {
                let query = Bounds { min: p - Vec3::splat(radius), max: p + Vec3::splat(radius) };
                let mut nearest = radius as f64;
                for (tree, root) in trees.iter().zip(&roots) {
                    if root.overlaps(&query) {
                        nearest = tree.nearest_distance(p, nearest);
                    }
                }
                ((nearest - margin).max(0.0), nearest < radius as f64)
            })
            .unzip();
        let at = |v: u32| positions[v as usize].as_dvec3();
        let edge_bounds = || -> Vec<f32> {
            skin.edges()
                .par_iter()
                .map(|&[a, b]| {
                    let (da, db) = (vertex[a as usize], vertex[b as usize]);
                    let length = (at(a) - at(b)).length();
                    (0.5 * (da + db - length)).max(da.max(db) - length)
                })
                .map(round_down)
                .collect()
        };
        let triangle_bounds = || -> Vec<f32> {
            skin.triangles()
                .par_iter()
                .map(|&corners| {
                    let x = corners.map(at);
                    let longest = (x[0] - x[1]).length().max((x[1] - x[2]).length()).max((x[2] - x[0]).length());
                    corners.iter().map(|&v| vertex[v as usize]).fold(0.0, f64::max) - longest
                })
                .map(round_down)
                .collect()
        };
        // Independent, and each too short to keep both cores busy alone.
        let (edge, triangle) = rayon::join(edge_bounds, triangle_bounds);
        let vertex: Vec<f32> = vertex.into_iter().map(round_down).collect();
        let guard = (0..positions.len() as u32)
            .into_par_iter()
            .map(|v| {
                let edges = skin.edges_of(v).iter().map(|&k| edge[k as usize]);
                let triangles = skin.triangles_of(v).iter().map(|&k| triangle[k as usize]);
                edges.chain(triangles).fold(vertex[v as usize], f32::min)
            })
            .collect();
        let near_vertices: Vec<u32> = (0..positions.len() as u32).filter(|&v| near[v as usize]).collect();
        let near_edges = ascending_unique(near_vertices.iter().flat_map(|&v| skin.edges_of(v).iter().copied()), skin.edges().len());
        let near_triangles = ascending_unique(near_vertices.iter().flat_map(|&v| skin.triangles_of(v).iter().copied()), skin.triangles().len());
        Ok(Clearance {
            reference: positions.to_vec(),
            guard,
            radius,
            margin,
            near_edges,
            near_triangles,
            near,
            planes: None,
            vertex,
            edge,
            triangle,
            measured: colliders
                .iter()
                .zip(envelopes)
                .map(|(c, e)| e.map_or(Measured::State(c.generation()), |e| Measured::Envelope(Box::new(e))))
                .collect(),
        })
    }

    /// How far around each skin vertex to look: four collider thicknesses and
    /// two mean skin edges (at `positions`). That covers what a vertex near a
    /// collider moves over one frame's iterations and keeps the search cheap;
    /// a vertex that moves farther is simply looked up again.
    pub fn default_radius(colliders: &[&Collider], skin: &Skin, positions: &[Vec3]) -> f32 {
        let thickness = colliders.iter().map(|c| c.settings().thickness).fold(0.0, f32::max);
        let edges = skin.edges();
        // Summed in fixed chunks, so the radius does not depend on how the
        // work was shared out.
        let chunks: Vec<f64> = edges
            .par_chunks(8192)
            .map(|chunk| chunk.iter().map(|&[a, b]| positions[a as usize].distance(positions[b as usize]) as f64).sum())
            .collect();
        let total: f64 = chunks.iter().sum();
        4.0 * thickness + 2.0 * (total / edges.len().max(1) as f64) as f32
    }

    /// Adds the colliders' supporting planes around every vertex the
    /// clearance found near them ([`LocalPlanes`]), for passes in which the
    /// colliders stand still at their current positions (the in-loop passes).
    /// `colliders` must be the ones measured against.
    pub fn with_planes(mut self, colliders: &[&Collider]) -> Result<Self> {
        if !self.is_valid_for(colliders, self.reference.len()) {
            return Err(Error::invalid("the planes must be measured against the colliders of the clearance, unchanged".to_string()));
        }
        // Planes hold where the collider stands; an enveloped one moves.
        if self.measured.iter().any(|m| matches!(m, Measured::Envelope(_))) {
            return Err(Error::invalid("a clearance measured against envelopes has no planes: the colliders move within them".to_string()));
        }
        let outward: Vec<f64> = colliders.iter().map(|c| c.outward_sign()).collect();
        self.planes = Some(LocalPlanes::new(colliders, &outward, &self.reference, &self.near, PLANE_REACH * self.radius, self.margin));
        Ok(self)
    }

    /// The planes of [`Self::with_planes`], if measured.
    pub fn planes(&self) -> Option<&LocalPlanes> {
        self.planes.as_ref()
    }

    /// The planes, keeping nothing else: the next frame's first pass moves
    /// them along with the colliders ([`LocalPlanes::drifting`]).
    pub fn into_planes(self) -> Option<LocalPlanes> {
        self.planes
    }

    /// Whether this clearance was measured against exactly these colliders in
    /// their present state (or, where measured by an envelope, with the
    /// collider inside it), for a skin of `vertex_count` vertices.
    pub fn is_valid_for(&self, colliders: &[&Collider], vertex_count: usize) -> bool {
        self.reference.len() == vertex_count
            && self.measured.len() == colliders.len()
            && self.measured.iter().zip(colliders).all(|(m, c)| match m {
                Measured::State(generation) => *generation == c.generation(),
                Measured::Envelope(envelope) => envelope.holds(c),
            })
    }

    /// For a step `start → end` of the skin, the vertices, edges and
    /// triangles [`Self::clear`] does not prove apart: what a pass must test.
    /// (The same proof, listing the rest: a pass runs it over the whole skin
    /// every iteration, so it goes straight to the short lists.)
    pub fn unproven(&self, skin: &Skin, start: &[Vec3], end: &[Vec3]) -> Unproven {
        // One pass over the whole skin: how far each vertex got, and the
        // vertices that passed their guard. An edge or triangle all of whose
        // vertices stayed within their guard is proven; only those around
        // the others need the test.
        const CHUNK: usize = 4096;
        let mut reach = vec![0.0f32; self.reference.len()];
        let loud: Vec<u32> = reach
            .par_chunks_mut(CHUNK)
            .enumerate()
            .flat_map_iter(|(chunk, out)| {
                let first = chunk * CHUNK;
                let mut loud = Vec::new();
                for (k, r) in out.iter_mut().enumerate() {
                    *r = self.reach_of(first + k, start, end);
                    if *r >= self.guard[first + k] {
                        loud.push((first + k) as u32);
                    }
                }
                loud
            })
            .collect();
        let vertices = loud.iter().copied().filter(|&i| reach[i as usize] >= self.vertex[i as usize]).collect();
        let edge_unproven = |k: u32| {
            let [a, b] = skin.edges()[k as usize];
            reach[a as usize].max(reach[b as usize]) >= self.edge[k as usize]
        };
        let triangle_unproven = |k: u32| {
            let [a, b, c] = skin.triangles()[k as usize];
            reach[a as usize].max(reach[b as usize]).max(reach[c as usize]) >= self.triangle[k as usize]
        };
        // An unproven element has a loud corner. Around the near vertices
        // (the resting contacts, loud in every pass) the elements are listed
        // once per clearance and only filtered here; around the few loud
        // vertices elsewhere they are gathered.
        let far_loud: Vec<u32> = loud.iter().copied().filter(|&v| !self.near[v as usize]).collect();
        let edges = gather_unproven(&self.near_edges, &far_loud, |v| skin.edges_of(v), edge_unproven, skin.edges().len());
        let triangles = gather_unproven(&self.near_triangles, &far_loud, |v| skin.triangles_of(v), triangle_unproven, skin.triangles().len());
        Unproven { vertices, edges, triangles }
    }

    /// How far vertex `i` gets from its reference position over `start →
    /// end` (its path lies in the ball of that radius), rounded up to f32.
    ///
    /// In f32, which a pass runs over the whole skin every iteration: the
    /// difference, squares, sum and root each round by at most one part in
    /// 2²⁴, about five parts in all, so growing the result by one part in 2²⁰
    /// keeps it an upper bound.
    fn reach_of(&self, i: usize, start: &[Vec3], end: &[Vec3]) -> f32 {
        const UP: f32 = 1.0 + 1.0 / (1 << 20) as f32;
        let (x, s, e) = (self.reference[i], start[i], end[i]);
        (s - x).length_squared().max((e - x).length_squared()).sqrt() * UP
    }

    /// [`Self::unproven`] where `wider`, a clearance of a wider reach
    /// measured since against the same colliders (both valid for them as
    /// they stand, [`Self::is_valid_for`]), proves apart too: what neither
    /// proves apart, except that a vertex with one of this clearance's
    /// planes is listed wherever this one leaves it (a plane may lift a
    /// vertex that a lookup would leave where it is). Each proof holds on
    /// its own, so an element either proves apart has no contact to find.
    ///
    /// Read from `wider`'s lists, which are the shorter where the skin moved
    /// farther than this clearance's radius since it was measured (issue 29:
    /// the unified strain rounds, whose multilevel cycles move a wide band).
    pub fn unproven_with(&self, wider: &Clearance, skin: &Skin, start: &[Vec3], end: &[Vec3]) -> Unproven {
        let Unproven { vertices, mut edges, mut triangles } = wider.unproven(skin, start, end);
        let reach = |v: u32| self.reach_of(v as usize, start, end);
        let unproven = |v: u32| reach(v) >= self.vertex[v as usize];
        let vertices: Vec<u32> = vertices.into_iter().filter(|&v| unproven(v)).collect();
        let with_planes: Vec<u32> = match &self.planes {
            Some(planes) => (0..self.reference.len() as u32).into_par_iter().with_min_len(4096).filter(|&v| planes.has_planes(v) && unproven(v)).collect(),
            None => Vec::new(),
        };
        edges.retain(|&k| {
            let [a, b] = skin.edges()[k as usize];
            reach(a).max(reach(b)) >= self.edge[k as usize]
        });
        triangles.retain(|&k| {
            let [a, b, c] = skin.triangles()[k as usize];
            reach(a).max(reach(b)).max(reach(c)) >= self.triangle[k as usize]
        });
        Unproven { vertices: merge_ascending(&vertices, &with_planes), edges, triangles }
    }

    /// The radius searched: a vertex that moves farther than this from where
    /// it was measured is tested again.
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// [`Self::reach_of`] every vertex.
    fn reach(&self, start: &[Vec3], end: &[Vec3]) -> Vec<f32> {
        (0..self.reference.len()).into_par_iter().with_min_len(4096).map(|i| self.reach_of(i, start, end)).collect()
    }

    /// For a step `start → end` of the skin, which vertices, edges and
    /// triangles (by index) are proven to stay out of every leaf box.
    pub fn clear(&self, skin: &Skin, start: &[Vec3], end: &[Vec3]) -> Clear {
        let reach = self.reach(start, end);
        let vertex = reach.par_iter().zip(&self.vertex).map(|(&r, &d)| r < d).collect();
        let edge = skin.edges().par_iter().zip(&self.edge).map(|(&[a, b], &d)| reach[a as usize].max(reach[b as usize]) < d).collect();
        let triangle = skin
            .triangles()
            .par_iter()
            .zip(&self.triangle)
            .map(|(&[a, b, c], &d)| reach[a as usize].max(reach[b as usize]).max(reach[c as usize]) < d)
            .collect();
        Clear { vertex, edge, triangle }
    }
}

/// What a collider was measured as.
#[derive(Debug, Clone)]
enum Measured {
    /// Its state ([`Collider::generation`]).
    State(u64),
    /// Wherever it stands inside this envelope.
    Envelope(Box<Envelope>),
}

/// The elements [`Clearance::unproven`] leaves to the pairwise tests, by
/// index, ascending.
pub struct Unproven {
    pub vertices: Vec<u32>,
    pub edges: Vec<u32>,
    pub triangles: Vec<u32>,
}

/// What [`Clearance::clear`] proved for one step.
pub struct Clear {
    pub vertex: Vec<bool>,
    pub edge: Vec<bool>,
    pub triangle: Vec<bool>,
}

/// The unproven elements among `listed` (ascending) and around the vertices
/// `loud`, ascending, each once.
fn gather_unproven<'s>(listed: &[u32], loud: &[u32], around: impl Fn(u32) -> &'s [u32], unproven: impl Fn(u32) -> bool + Sync, count: usize) -> Vec<u32> {
    let kept: Vec<u32> = listed.par_iter().with_min_len(1024).copied().filter(|&k| unproven(k)).collect();
    let gathered = ascending_unique(loud.iter().flat_map(|&v| around(v).iter().copied()).filter(|&k| unproven(k)), count);
    merge_ascending(&kept, &gathered)
}

/// The union of two ascending lists, ascending, each value once.
fn merge_ascending(a: &[u32], b: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let next = a[i].min(b[j]);
        out.push(next);
        i += (a[i] == next) as usize;
        j += (b[j] == next) as usize;
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

/// The largest f32 not above `x` (0 for negative or NaN `x`: nothing proven).
fn round_down(x: f64) -> f32 {
    if !(x > 0.0) {
        return 0.0;
    }
    let f = x as f32;
    if f as f64 > x { f32::from_bits(f.to_bits() - 1) } else { f }
}



#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use crate::collide::collider::ColliderSettings;
    use crate::collide::geometry::{point_triangle_distance_squared, triangle_samples};
    use crate::mesh::shapes::grid;
    use proptest::prelude::*;

    /// A small collider: two triangles moving over the frame.
    fn collider(shift: Vec3, thickness: f32) -> Collider {
        let rest = [Vec3::new(-0.3, -0.3, 0.0), Vec3::new(0.4, -0.2, 0.1), Vec3::new(0.1, 0.5, -0.1), Vec3::new(-0.2, 0.3, 0.3)];
        let tris = [[0, 1, 2], [0, 2, 3]];
        let mut c = Collider::new(&rest, &tris, ColliderSettings::new(thickness, 0.0)).unwrap();
        c.update(&rest.map(|p| p + shift)).unwrap();
        c
    }

    /// The smallest distance between a moving skin point and the collider's
    /// triangles at their current positions (the step sampled densely).
    fn sampled_distance(c: &Collider, points: impl Fn(f64) -> Vec<DVec3>) -> f64 {
        let mut min = f64::INFINITY;
        let at = |v: u32| c.current()[v as usize].as_dvec3();
        for i in 0..=40 {
            let t = i as f64 / 40.0;
            for tri in c.triangles() {
                for p in points(t) {
                    min = min.min(point_triangle_distance_squared(p, at(tri[0]), at(tri[1]), at(tri[2])).sqrt());
                }
            }
        }
        min
    }

    fn small(range: f32) -> impl Strategy<Value = Vec3> {
        (-range..range, -range..range, -range..range).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

        /// Whatever the clearance proves clear stays farther than the
        /// thickness from the collider at its current positions.
        #[test]
        fn what_is_clear_stays_apart(offset in small(0.6), shift in small(0.1), wobble in prop::collection::vec(small(0.08), 2 * 64),
                                     thickness in 0.0f32..0.05, radius in 0.05f32..0.5) {
            let mesh = grid(6, 6, 0.6);
            assert!(mesh.positions.len() <= 64);
            let skin = Skin::from_mesh(mesh.input()).unwrap();
            let c = collider(shift, thickness);
            let reference: Vec<Vec3> = mesh.positions.iter().map(|&p| p + offset).collect();
            let clearance = Clearance::new(&[&c], &skin, &reference, radius).unwrap();
            prop_assert!(clearance.is_valid_for(&[&c], reference.len()));
            let start: Vec<Vec3> = reference.iter().zip(&wobble[..64]).map(|(&p, &w)| p + w).collect();
            let end: Vec<Vec3> = reference.iter().zip(&wobble[64..]).map(|(&p, &w)| p + w).collect();
            let clear = clearance.clear(&skin, &start, &end);
            // The short lists a pass uses hold exactly what is not proven.
            let unproven = clearance.unproven(&skin, &start, &end);
            let rest = |proven: &[bool]| proven.iter().enumerate().filter(|(_, &p)| !p).map(|(k, _)| k as u32).collect::<Vec<u32>>();
            prop_assert_eq!(&unproven.vertices, &rest(&clear.vertex));
            prop_assert_eq!(&unproven.edges, &rest(&clear.edge));
            prop_assert_eq!(&unproven.triangles, &rest(&clear.triangle));
            let path = |v: u32, t: f64| start[v as usize].as_dvec3().lerp(end[v as usize].as_dvec3(), t);
            let sep = thickness as f64;
            for (i, _) in clear.vertex.iter().enumerate().filter(|(_, &c)| c) {
                let d = sampled_distance(&c, |t| vec![path(i as u32, t)]);
                prop_assert!(d > sep, "vertex {i} clear but reaches {d} <= {sep}");
            }
            for (k, _) in clear.edge.iter().enumerate().filter(|(_, &c)| c) {
                let [a, b] = skin.edges()[k];
                let d = sampled_distance(&c, |t| (0..=6).map(|j| path(a, t).lerp(path(b, t), j as f64 / 6.0)).collect());
                prop_assert!(d > sep, "edge {k} clear but reaches {d} <= {sep}");
            }
            for (k, _) in clear.triangle.iter().enumerate().filter(|(_, &c)| c) {
                let [a, b, cc] = skin.triangles()[k];
                let d = sampled_distance(&c, |t| triangle_samples(path(a, t), path(b, t), path(cc, t)));
                prop_assert!(d > sep, "triangle {k} clear but reaches {d} <= {sep}");
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]

        /// Measured against a collider's envelope, whatever the clearance
        /// proves clear stays farther than the thickness from the collider
        /// wherever it stands inside the envelope; outside, it is stale.
        #[test]
        fn what_is_clear_of_an_envelope_stays_apart_wherever_the_collider_stands_in_it(
            offset in small(0.4), goal_shift in small(0.15), fractions in prop::collection::vec(0.0f32..1.0, 4),
            sideways in prop::collection::vec(small(0.02), 4), thickness in 0.0f32..0.03, radius in 0.05f32..0.3) {
            let mesh = grid(6, 6, 0.6);
            let skin = Skin::from_mesh(mesh.input()).unwrap();
            let mut c = collider(Vec3::ZERO, thickness);
            let start = c.current().to_vec();
            let goal: Vec<Vec3> = start.iter().map(|&p| p + goal_shift).collect();
            let margin = 0.02;
            let envelope = Envelope::new(&c, &goal, margin).unwrap();
            let reference: Vec<Vec3> = mesh.positions.iter().map(|&p| p + offset).collect();
            let clearance = Clearance::with_envelopes(&[&c], vec![Some(envelope)], &skin, &reference, radius).unwrap();
            prop_assert!(clearance.clone().with_planes(&[&c]).is_err(), "an enveloped clearance has no planes");
            // Somewhere between start and goal, a little sideways: inside.
            let inside: Vec<Vec3> = (0..4).map(|v| start[v].lerp(goal[v], fractions[v]) + sideways[v]).collect();
            c.set_positions(&inside, &inside).unwrap();
            prop_assert!(clearance.is_valid_for(&[&c], reference.len()));
            let clear = clearance.clear(&skin, &reference, &reference);
            let sep = thickness as f64;
            for (i, _) in clear.vertex.iter().enumerate().filter(|(_, &k)| k) {
                let d = sampled_distance(&c, |_| vec![reference[i].as_dvec3()]);
                prop_assert!(d > sep, "vertex {i} clear but at {d} <= {sep}");
            }
            for (k, _) in clear.triangle.iter().enumerate().filter(|(_, &k)| k) {
                let [a, b, cc] = skin.triangles()[k];
                let at = |v: u32| reference[v as usize].as_dvec3();
                let d = sampled_distance(&c, |_| triangle_samples(at(a), at(b), at(cc)));
                prop_assert!(d > sep, "triangle {k} clear but at {d} <= {sep}");
            }
            // Beyond the goal by more than the margin: stale.
            let beyond: Vec<Vec3> = goal.iter().map(|&p| p + goal_shift.normalize_or(Vec3::X) * 0.05).collect();
            c.set_positions(&beyond, &beyond).unwrap();
            prop_assert!(!clearance.is_valid_for(&[&c], reference.len()));
        }
    }

    #[test]
    fn far_skin_is_clear_and_touching_skin_is_not() {
        let mesh = grid(6, 6, 1.2);
        let skin = Skin::from_mesh(mesh.input()).unwrap();
        let c = collider(Vec3::ZERO, 0.01);
        for (lift, expect) in [(2.0, true), (0.0, false)] {
            let x: Vec<Vec3> = mesh.positions.iter().map(|&p| p + Vec3::new(0.0, 0.0, lift)).collect();
            let clearance = Clearance::new(&[&c], &skin, &x, 0.5).unwrap();
            let clear = clearance.clear(&skin, &x, &x);
            assert_eq!(clear.vertex.iter().all(|&c| c), expect, "lift {lift}");
            assert_eq!(clear.edge.iter().all(|&c| c), expect, "lift {lift}");
            assert_eq!(clear.triangle.iter().all(|&c| c), expect, "lift {lift}");
        }
    }

    #[test]
    fn a_moved_collider_makes_the_clearance_stale() {
        let mesh = grid(3, 3, 1.0);
        let skin = Skin::from_mesh(mesh.input()).unwrap();
        let mut c = collider(Vec3::ZERO, 0.01);
        let clearance = Clearance::new(&[&c], &skin, &mesh.positions, 0.2).unwrap();
        assert!(clearance.is_valid_for(&[&c], mesh.positions.len()));
        assert!(!clearance.is_valid_for(&[&c], mesh.positions.len() + 1));
        let copy = c.clone();
        assert!(clearance.is_valid_for(&[&copy], mesh.positions.len()), "a clone is the same state");
        c.update(copy.current()).unwrap();
        assert!(!clearance.is_valid_for(&[&c], mesh.positions.len()), "a new frame is a new state");
        assert!(!clearance.is_valid_for(&[&copy, &copy], mesh.positions.len()));
        assert!(Clearance::new(&[&c], &skin, &mesh.positions[1..], 0.2).is_err());
        assert!(Clearance::new(&[&c], &skin, &mesh.positions, f32::NAN).is_err());
    }
}
