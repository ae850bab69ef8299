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
//! 3. **Edge–edge**: each skin edge against the collider edges; the correction
//!    moves the edge's contact point out along the edges' common normal,
//!    split between its two vertices by their barycentric weights. Several
//!    contacts on a vertex are averaged (Jacobi).
//! 4. Repeat detection on the vertices that moved, up to
//!    [`ResolveParams::max_rounds`] rounds. Vertices still in violation after
//!    the last round are **pinched** (e.g. squeezed between two colliders):
//!    they are reported, their displacement is bounded, never NaN.
//!
//! # Use in the two passes (seed 000, Algorithm 2)
//!
//! ```text
//! // once per frame
//! for c in colliders { c.update(&collider_positions_this_frame)?; }
//! let set = ColliderSet::new(colliders.iter());
//! // pass 1: from last frame's collision-free output towards this frame's input
//! let mut x = input.clone();
//! let stats = set.resolve_path(&last_output, &mut x, &edges, &ResolveParams::first_pass())?;
//! // pass 2: inside the solver loop
//! for _ in 0..iterations {
//!     let before = x.clone();
//!     solver.iterate(&mut x);                         // global + local step
//!     let s = set.resolve_path(&before, &mut x, &edges, &ResolveParams::in_loop())?;
//!     // s.pinched → soft constraints / report
//! }
//! ```
//!
//! The start positions must be collision-free (they are the output of the
//! previous call); the result then is too, up to pinched vertices.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::bvh::Bounds;
use super::ccd::{self, CcdParams};
use super::collider::Collider;
use super::geometry::{triangle_normal, unit};
use crate::mesh::validate_positions;
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
    /// Test skin edges against collider edges (needs the `edges` argument).
    pub edge_edge: bool,
    /// Apply friction (off for passes where it would double count).
    pub friction: bool,
}

impl ResolveParams {
    /// Pass 1: colliders sweep over the frame, friction on.
    pub fn first_pass() -> Self {
        ResolveParams { motion: ColliderMotion::Swept, max_rounds: 8, edge_edge: true, friction: true }
    }
    /// Pass 2: colliders at their current positions, friction on.
    pub fn in_loop() -> Self {
        ResolveParams { motion: ColliderMotion::AtCurrent, max_rounds: 8, edge_edge: true, friction: true }
    }
}

/// What [`ColliderSet::resolve_path`] did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ContactStats {
    /// Vertex–triangle projections applied (over all rounds).
    pub vertex_contacts: usize,
    /// Edge–edge projections applied (over all rounds).
    pub edge_contacts: usize,
    /// Vertices whose end position changed, ascending.
    pub moved: Vec<u32>,
    /// Vertices still in violation after the last round, ascending.
    pub pinched: Vec<u32>,
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
        let outward = colliders.iter().map(|c| outward_sign(c)).collect();
        let scale = colliders
            .iter()
            .flat_map(|c| c.current().iter().chain(c.previous()))
            .map(|p| p.abs().max_element() as f64)
            .fold(1e-3, f64::max);
        ColliderSet { colliders, outward, scale }
    }

    pub fn colliders(&self) -> &[&'a Collider] {
        &self.colliders
    }

    /// Distance added beyond the thickness when projecting, so that f32
    /// rounding of the result cannot put it back inside.
    fn slack(&self, thickness: f64) -> f64 {
        4e-7 * self.scale + 1e-4 * thickness
    }

    fn ccd_params(&self, thickness: f64) -> CcdParams {
        CcdParams { min_separation: thickness, tolerance: 1e-7 * self.scale, ..Default::default() }
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

    /// Earliest vertex–triangle contact of the path `s → e`.
    fn earliest_vertex_hit(&self, s: Vec3, e: Vec3, motion: ColliderMotion) -> Option<VertexHit> {
        let query = Bounds::of_points(&[s, e]);
        let (s64, e64) = (d(s), d(e));
        let mut best: Option<VertexHit> = None;
        for (c, col) in self.colliders.iter().enumerate() {
            let mut params = self.ccd_params(col.settings().thickness as f64);
            col.tree().query(&query, |t| {
                if let Some(b) = &best {
                    params.t_max = b.hit.toi.max(f64::MIN_POSITIVE);
                }
                let ([a0, b0, c0], [a1, b1, c1]) = self.triangle_ends(c, t, motion);
                if let Some(hit) = ccd::vertex_triangle(s64, a0, b0, c0, e64, a1, b1, c1, &params) {
                    if best.is_none_or(|b| hit.toi < b.hit.toi) {
                        best = Some(VertexHit { collider: c, triangle: t, hit });
                    }
                }
                true
            });
        }
        best
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
        params: &ResolveParams,
    ) -> Option<(DVec3, DVec3)> {
        let [ia, ib] = edge.map(|v| v as usize);
        let (sa, sb, ea, eb) = (d(start[ia]), d(start[ib]), d(end[ia]), d(end[ib]));
        let query = Bounds::of_points(&[start[ia], start[ib], end[ia], end[ib]]);
        let mut best: Option<(usize, usize, ccd::CcdHit)> = None;
        let mut seen: Vec<u32> = Vec::new();
        for (c, col) in self.colliders.iter().enumerate() {
            let mut ccd_params = self.ccd_params(col.settings().thickness as f64);
            seen.clear();
            col.tree().query(&query, |t| {
                for &e in &col.triangle_edges()[t] {
                    if seen.contains(&e) {
                        continue;
                    }
                    seen.push(e);
                    if let Some((_, _, b)) = &best {
                        ccd_params.t_max = b.toi.max(f64::MIN_POSITIVE);
                    }
                    let ([c0, c1], [c0e, c1e]) = self.edge_ends(c, e as usize, params.motion);
                    if let Some(hit) = ccd::edge_edge(sa, sb, c0, c1, ea, eb, c0e, c1e, &ccd_params) {
                        if best.is_none_or(|(_, _, b)| hit.toi < b.toi) {
                            best = Some((c, e as usize, hit));
                        }
                    }
                }
                true
            });
        }
        let (c, e, hit) = best?;
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
        let (wa, wb) = (1.0 - u, u);
        let lambda = depth / (wa * wa + wb * wb);
        let (da, db) = (wa * lambda * n, wb * lambda * n);
        (da.is_finite() && db.is_finite()).then_some((da, db))
    }

    /// Outward direction at collider edge `e`: the normalised sum of its
    /// faces' outward normals at the current positions.
    fn edge_outward(&self, c: usize, e: usize) -> Option<DVec3> {
        let col = self.colliders[c];
        let mut sum = DVec3::ZERO;
        for &t in col.edge_triangles(e) {
            let [a, b, cc] = col.triangles()[t as usize].map(|v| d(col.current()[v as usize]));
            if let Some(n) = triangle_normal(a, b, cc) {
                sum += n;
            }
        }
        unit(sum * self.outward[c])
    }

    /// Makes the motion `start → end` collision-free against the colliders by
    /// changing `end` (see the module documentation).
    pub fn resolve_path(
        &self,
        start: &[Vec3],
        end: &mut [Vec3],
        edges: &[[u32; 2]],
        params: &ResolveParams,
    ) -> Result<ContactStats> {
        let n = start.len();
        if end.len() != n {
            return Err(Error::invalid(format!(
                "start has {n} positions but end has {}; both must have one per skin vertex",
                end.len()
            )));
        }
        validate_positions("start positions", start)?;
        validate_positions("end positions", end)?;
        if let Some((i, e)) = edges.iter().enumerate().find(|(_, e)| e[0] as usize >= n || e[1] as usize >= n) {
            return Err(Error::invalid(format!("edge {i} refers to vertex {}, but the skin has {n} vertices", e[0].max(e[1]))));
        }
        let mut stats = ContactStats::default();
        if self.colliders.is_empty() || n == 0 {
            return Ok(stats);
        }
        let use_edges = params.edge_edge && !edges.is_empty();
        let vertex_edges = if use_edges { incident_edges(n, edges) } else { (Vec::new(), Vec::new()) };
        let requested: Vec<Vec3> = end.to_vec();
        let mut moved = vec![false; n];
        let mut active: Vec<u32> = (0..n as u32).collect();
        let mut active_edges: Vec<u32> = if use_edges { (0..edges.len() as u32).collect() } else { Vec::new() };
        let mut converged = false;
        for _ in 0..params.max_rounds.max(1) {
            stats.rounds += 1;
            let mut changed = vec![false; n];
            // Vertex–triangle.
            let updates: Vec<(u32, Vec3)> = active
                .par_iter()
                .filter_map(|&i| {
                    let (s, e) = (start[i as usize], end[i as usize]);
                    let hit = self.earliest_vertex_hit(s, e, params.motion)?;
                    self.project_vertex(s, e, &hit, params).map(|p| (i, p))
                })
                .collect();
            stats.vertex_contacts += updates.len();
            for (i, p) in updates {
                end[i as usize] = p;
                changed[i as usize] = true;
            }
            // Edge–edge.
            if use_edges {
                let corrections: Vec<(u32, DVec3, DVec3)> = active_edges
                    .par_iter()
                    .filter_map(|&k| {
                        self.edge_correction(start, end, edges[k as usize], params).map(|(da, db)| (k, da, db))
                    })
                    .collect();
                stats.edge_contacts += corrections.len();
                let mut sum: Vec<(DVec3, u32)> = Vec::new();
                if !corrections.is_empty() {
                    sum = vec![(DVec3::ZERO, 0); n];
                    for (k, da, db) in &corrections {
                        let [a, b] = edges[*k as usize];
                        sum[a as usize].0 += *da;
                        sum[a as usize].1 += 1;
                        sum[b as usize].0 += *db;
                        sum[b as usize].1 += 1;
                    }
                }
                for (i, (delta, count)) in sum.iter().enumerate() {
                    if *count > 0 {
                        let p = (d(end[i]) + *delta / *count as f64).as_vec3();
                        if p.is_finite() {
                            end[i] = p;
                            changed[i] = true;
                        }
                    }
                }
            }
            let next: Vec<u32> = (0..n as u32).filter(|&i| changed[i as usize]).collect();
            for &i in &next {
                moved[i as usize] = true;
            }
            if next.is_empty() {
                converged = true;
                break;
            }
            if use_edges {
                let mut es: Vec<u32> = next
                    .iter()
                    .flat_map(|&i| {
                        let (offsets, list) = &vertex_edges;
                        list[offsets[i as usize] as usize..offsets[i as usize + 1] as usize].iter().copied()
                    })
                    .collect();
                es.sort_unstable();
                es.dedup();
                active_edges = es;
            }
            active = next;
        }
        if !converged {
            // Verify the vertices moved in the last round; those still in
            // violation are pinched.
            let mut pinched: Vec<u32> = active
                .par_iter()
                .copied()
                .filter(|&i| {
                    let (s, e) = (start[i as usize], end[i as usize]);
                    self.earliest_vertex_hit(s, e, params.motion)
                        .and_then(|h| self.project_vertex(s, e, &h, params))
                        .is_some()
                })
                .collect();
            if use_edges {
                let bad_edges: Vec<u32> = active_edges
                    .par_iter()
                    .copied()
                    .filter(|&k| self.edge_correction(start, end, edges[k as usize], params).is_some())
                    .collect();
                pinched.extend(bad_edges.iter().flat_map(|&k| edges[k as usize]));
            }
            pinched.sort_unstable();
            pinched.dedup();
            // Bound the displacement of pinched vertices: no farther from the
            // requested end than the step length plus twice the largest thickness.
            let max_thickness =
                self.colliders.iter().map(|c| c.settings().thickness as f64).fold(0.0, f64::max);
            for &i in &pinched {
                let i = i as usize;
                let limit = (d(requested[i]) - d(start[i])).length() + 2.0 * max_thickness + self.slack(max_thickness);
                let offset = d(end[i]) - d(requested[i]);
                if offset.length() > limit {
                    end[i] = (d(requested[i]) + offset * (limit / offset.length())).as_vec3();
                }
            }
            stats.pinched = pinched;
        }
        for i in 0..n {
            if moved[i] {
                stats.moved.push(i as u32);
                stats.max_correction = stats.max_correction.max((end[i] - requested[i]).length());
            }
        }
        Ok(stats)
    }
}

/// +1 if a closed collider's triangles wind outward (positive volume), −1 if
/// inward, 0 for open colliders (sides are then decided per contact).
fn outward_sign(c: &Collider) -> f64 {
    if !c.is_closed() {
        return 0.0;
    }
    let p = c.current();
    let volume: f64 = c
        .triangles()
        .iter()
        .map(|t| {
            let [a, b, cc] = t.map(|v| d(p[v as usize]));
            a.dot(b.cross(cc))
        })
        .sum();
    if volume > 0.0 {
        1.0
    } else if volume < 0.0 {
        -1.0
    } else {
        0.0
    }
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

/// CSR lists of the edges incident to every vertex.
fn incident_edges(n: usize, edges: &[[u32; 2]]) -> (Vec<u32>, Vec<u32>) {
    let mut offsets = vec![0u32; n + 1];
    for e in edges {
        offsets[e[0] as usize + 1] += 1;
        offsets[e[1] as usize + 1] += 1;
    }
    for i in 0..n {
        offsets[i + 1] += offsets[i];
    }
    let mut fill = offsets.clone();
    let mut list = vec![0u32; offsets[n] as usize];
    for (k, e) in edges.iter().enumerate() {
        for &v in e {
            list[fill[v as usize] as usize] = k as u32;
            fill[v as usize] += 1;
        }
    }
    (offsets, list)
}
