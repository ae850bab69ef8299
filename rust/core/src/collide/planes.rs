//! Supporting planes of the colliders around the skin in contact, measured
//! once per frame and used by every in-loop pass; and for the first pass,
//! measured in the frame that moves with colliders translating together
//! ([`LocalPlanes::drifting`]), where a vertex they carry barely moves.
//!
//! Through a frame's in-loop passes the colliders stand still, yet every pass
//! pulls the thousands of skin vertices resting on them back in (the solver
//! does not know about contacts) and every pass looked each of them, its
//! edges and its triangles up in the BVH again, proved the resting ones apart
//! and found the first contact of the others: about 30 ms a pass on the
//! benchmark's sliding contact. [`LocalPlanes`] does that lookup once.
//!
//! For a skin vertex near a collider, at reference positions `x` (the start
//! of the in-loop passes), take the box `B = x ± R` and every collider
//! triangle whose box at its current position, grown by the thickness, meets
//! `B` (found through the collider's BVH of those boxes). A
//! triangle that is not among them keeps every point of `B` farther than its
//! thickness. For a unit direction `n`, let
//! `level = max(n·q + thickness)` over the corners `q` of those triangles:
//! every point `y` of `B` with `n·y ≥ level` is farther than the thickness
//! from every triangle that is (all of a triangle lies below its corners'
//! highest level). So a skin element whose corners, at both ends of a step,
//! lie in `B` and on or above the level — a convex set, so its whole swept
//! volume does — cannot touch a still collider during the step: vertex–face,
//! edge–edge and collider vertex–skin face contacts alike.
//!
//! Each vertex keeps up to [`PLANES_PER_VERTEX`] such planes, the normals of
//! the collider triangles nearest to it (outward on closed colliders, towards
//! the vertex on open ones), and only those it is itself above: on a locally
//! convex collider they are the triangles' own planes lifted by the
//! thickness. In a crease or where two colliders meet no plane qualifies and
//! the passes fall back to the pairwise tests.
//!
//! The planes also resolve: a vertex whose step starts above a plane and
//! ends below it, inside its box, is lifted back along that plane's normal
//! (the plane needing the smallest lift), with the same position-based
//! friction as a contact with a triangle ([`super::response`]). Its new step
//! is then proven clear by the same plane, so no second lookup is needed.

use glam::{DVec3, Vec3, Vec4};
use rayon::prelude::*;

use super::bvh::Bounds;
use super::collider::Collider;
use super::friction::{friction, Hold};
use super::geometry::triangle_normal;

/// Planes kept per skin vertex: the normals of the nearest collider
/// triangles. More cover a vertex sliding farther within a frame; each costs
/// a few dot products per test.
pub const PLANES_PER_VERTEX: usize = 4;

/// A half-space `normal·y ≥ level` clear of the colliders within a vertex's box.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Plane {
    normal: DVec3,
    level: f64,
    /// The collider whose triangle gave the normal: its friction applies to
    /// contacts resolved against this plane.
    collider: u32,
}

/// What the planes say about one vertex's step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum VertexStep {
    /// Proven to keep its distance from every collider.
    Clear,
    /// Lifted to this end position, whose step is proven clear, and how
    /// friction left it there.
    Lifted(Vec3, Hold),
    /// Nothing proven: the pairwise tests decide.
    Unknown,
}

/// How a lifted vertex is pushed out and rubs along the plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lift {
    /// Distance added above the level (per collider, from its thickness).
    pub slack: f64,
    pub static_friction: f64,
    pub kinetic_friction: f64,
}

/// Supporting planes of the still colliders around each skin vertex near
/// them (see the module documentation).
#[derive(Debug, Clone, Default)]
pub struct LocalPlanes {
    /// Per vertex, its box `reference ± radius` (meaningful where it has planes).
    boxes: Vec<Bounds>,
    /// CSR offsets into `planes`, one more than the vertices.
    offsets: Vec<u32>,
    planes: Vec<Plane>,
    /// Planes of colliders that stand still over the pass (the in-loop
    /// passes), as opposed to planes drifting with translating colliders
    /// (the first pass): only on still ones does a resting vertex keep its
    /// friction reference where it rests (see [`resting_reference`]).
    still: bool,
}

impl LocalPlanes {
    /// Measures the planes of the vertices `near` (the others get none) at
    /// `positions`, within `radius`, against `colliders` at their current
    /// positions. `outward` is each collider's winding sign (0 for open
    /// colliders); `margin` absorbs the f32 rounding of the BVH's boxes and
    /// of the dot products.
    pub fn new(colliders: &[&Collider], outward: &[f64], positions: &[Vec3], near: &[bool], radius: f32, margin: f64) -> LocalPlanes {
        LocalPlanes::gather(positions.len(), true, |v| {
            let p = positions[v];
            let area = Bounds { min: p - Vec3::splat(radius), max: p + Vec3::splat(radius) };
            if !near[v] {
                return (area, Vec::new());
            }
            (area, vertex_planes(colliders, outward, p, &area, margin))
        })
    }

    /// Each vertex's box and planes from `of(v)`, in parallel.
    fn gather(n: usize, still: bool, of: impl Fn(usize) -> (Bounds, Vec<Plane>) + Sync) -> LocalPlanes {
        let per_vertex: Vec<(Bounds, Vec<Plane>)> = (0..n).into_par_iter().with_min_len(1024).map(&of).collect();
        let mut offsets = Vec::with_capacity(n + 1);
        let mut planes = Vec::new();
        let mut boxes = Vec::with_capacity(n);
        offsets.push(0);
        for (area, own) in per_vertex {
            boxes.push(area);
            planes.extend(own);
            offsets.push(planes.len() as u32);
        }
        LocalPlanes { boxes, offsets, planes, still }
    }

    /// Planes for a pass in which the colliders sweep (the first pass), if
    /// they share one drift ([`Collider::drift`]) and barely move in its
    /// frame (a rigid translation). In the frame that moves with the drift
    /// and meets the world at the end of the step, a skin step runs from
    /// `start + drift` to its end, and the colliders stay within their drift
    /// spread of where they are now, which the levels and the lookup allow
    /// for. Returns the planes and the starts in that frame, for
    /// [`Self::vertex_step`] and [`Self::clears`].
    ///
    /// A vertex's planes are last frame's, `carried`, moved along with the
    /// colliders, where it had some and its start lies in their box:
    /// `carried` must have been measured for this skin against these
    /// colliders, in this order, with these settings, standing where this
    /// step starts them (their previous positions). The other `vertices`
    /// are measured around `start + drift`, within `radius`, against the
    /// colliders' current positions.
    pub fn drifting(
        colliders: &[&Collider],
        outward: &[f64],
        start: &[Vec3],
        vertices: &[u32],
        radius: f32,
        carried: Option<&LocalPlanes>,
    ) -> Option<(LocalPlanes, Vec<Vec3>)> {
        let drift = colliders.first()?.drift();
        let thinnest = colliders.iter().map(|c| c.settings().thickness as f64).fold(f64::INFINITY, f64::min);
        let spread = colliders.iter().map(|c| c.drift_spread()).fold(0.0, f64::max);
        // Colliders that move apart, or deform or turn within the frame, would
        // raise the levels past any use.
        if vertices.is_empty() || colliders.iter().any(|c| c.drift() != drift) || !(spread <= thinnest) {
            return None;
        }
        let shifted: Vec<Vec3> = start.par_iter().with_min_len(4096).map(|&p| p + drift).collect();
        let mut near = vec![false; start.len()];
        for &v in vertices {
            near[v as usize] = true;
        }
        // `p + drift` rounds to f32 by at most half an ulp per component.
        // Over every vertex: a carried plane may serve any corner of an
        // element, active or not.
        let largest = shifted.par_iter().with_min_len(4096).map(|p| p.abs().max_element()).reduce(|| 0.0f32, f32::max);
        let margin = rounding_margin(colliders, std::iter::once(Vec3::splat(largest)), radius) + spread + 2.0 * f32::EPSILON as f64 * largest as f64;
        let carried = carried.filter(|c| c.boxes.len() == start.len());
        let d = drift.as_dvec3();
        let planes = LocalPlanes::gather(start.len(), false, |v| {
            let p = shifted[v];
            if let Some(carried) = carried {
                let own = carried.of(v as u32);
                // Moved along with the colliders: a point of the moved box
                // that is `margin` (the spread and the rounding) inside it
                // and above a moved level keeps as far from the colliders at
                // every instant as the point `margin` nearer to them did
                // from where they stood.
                let held = carried.boxes[v];
                let area = Bounds { min: held.min + drift, max: held.max + drift }.inflated(-(margin as f32));
                if !own.is_empty() && area.contains(p) {
                    let moved = own.iter().map(|plane| Plane { level: plane.level + plane.normal.dot(d) + margin, ..*plane });
                    return (area, moved.filter(|plane| above(plane, p)).collect());
                }
            }
            let area = Bounds { min: p - Vec3::splat(radius), max: p + Vec3::splat(radius) };
            if !near[v] {
                return (area, Vec::new());
            }
            (area, vertex_planes(colliders, outward, p, &area, margin))
        });
        Some((planes, shifted))
    }

    /// Vertices with at least one plane.
    pub fn vertex_count(&self) -> usize {
        self.offsets.windows(2).filter(|w| w[1] > w[0]).count()
    }

    /// Whether vertex `v` has a plane.
    pub fn has_planes(&self, v: u32) -> bool {
        !self.of(v).is_empty()
    }

    fn of(&self, v: u32) -> &[Plane] {
        let v = v as usize;
        match self.offsets.get(v..v + 2) {
            Some(&[a, b]) => &self.planes[a as usize..b as usize],
            _ => &[],
        }
    }

    /// Whether a skin element (its vertices `corners`, moving `start → end`)
    /// is proven apart from the still colliders by a plane of one of its
    /// vertices.
    pub fn clears(&self, corners: &[u32], start: &[Vec3], end: &[Vec3]) -> bool {
        corners.iter().any(|&v| {
            let area = &self.boxes[v as usize];
            self.of(v).iter().any(|plane| {
                corners.iter().all(|&w| {
                    let (s, e) = (start[w as usize], end[w as usize]);
                    area.contains(s) && area.contains(e) && above(plane, s) && above(plane, e)
                })
            })
        })
    }

    /// Vertex `v`'s step `s → e` against its planes: clear, lifted out along
    /// the plane that needs the smallest lift, or unknown. `lift(collider)`
    /// gives the slack and friction of a collider.
    ///
    /// A step may leave the box (a vertex pulled deep into a collider that
    /// carried it): it is then lifted if it crosses a level inside the box,
    /// since up to that point it stays in the box and above the level.
    pub fn vertex_step(&self, v: u32, s: Vec3, e: Vec3, lift: impl Fn(usize) -> Lift) -> VertexStep {
        let planes = self.of(v);
        let area = &self.boxes[v as usize];
        if planes.is_empty() || !area.contains(s) {
            return VertexStep::Unknown;
        }
        let inside = area.contains(e);
        let (s64, e64) = (s.as_dvec3(), e.as_dvec3());
        // (lift, plane, where the step crosses its level)
        let mut best: Option<(f64, &Plane, DVec3)> = None;
        for plane in planes {
            let (hs, he) = (plane.normal.dot(s64), plane.normal.dot(e64));
            if hs < plane.level {
                continue;
            }
            if he >= plane.level {
                if inside {
                    return VertexStep::Clear;
                }
                continue;
            }
            let lift = plane.level - he;
            if best.is_some_and(|(b, _, _)| lift >= b) {
                continue;
            }
            let contact = s64 + (e64 - s64) * ((hs - plane.level) / (hs - he));
            if inside || area.contains(contact.as_vec3()) {
                best = Some((lift, plane, contact));
            }
        }
        let Some((_, plane, contact)) = best else { return VertexStep::Unknown };
        let n = plane.normal;
        let Lift { slack, static_friction, kinetic_friction } = lift(plane.collider as usize);
        let (hs, he) = (n.dot(s64), n.dot(e64));
        // The contact is where the step crossed the level, or, on still
        // planes, where the vertex rests if it starts on it (see
        // [`resting_reference`]); friction holds it there.
        let depth = plane.level + slack - he;
        let mut out = e64 + depth * n;
        let reference = if self.still { resting_reference(hs - plane.level, slack, s64, contact) } else { contact };
        let (change, hold) = friction(out - reference, n, depth, static_friction, kinetic_friction);
        out -= change;
        let out = out.as_vec3();
        // Rounded to f32, the new end must still be in the box and above.
        if out.is_finite() && area.contains(out) && above(plane, out) {
            VertexStep::Lifted(out, hold)
        } else {
            VertexStep::Unknown
        }
    }
}

/// Where a still collider's friction measures a contact's slip from: the
/// step's start `s` if it starts resting on the surface (`height` above the
/// level within twice the `slack` the last lift left it at), otherwise where
/// the step crossed the level (`crossing`). A resting vertex pulled in again
/// by the next solver iteration crosses the level a little along its step
/// (`slack / (slack + depth)` of it): measured from there, static friction
/// would let it creep that far every iteration and no fixed point would hold
/// it (a rough sphere dragging a skin: 0.087 of drag after 10 plain
/// iterations, 0.004 after 1,000, issue 28). Measured from where it rests, a
/// statically held vertex stays put however many iterations run.
pub(crate) fn resting_reference(height: f64, slack: f64, s: DVec3, crossing: DVec3) -> DVec3 {
    if height <= 2.0 * slack {
        s
    } else {
        crossing
    }
}

/// The allowance for the f32 rounding of the trees' boxes (grown by the
/// thickness in f32) and of dot products, for lookups within `reach` of
/// `positions`: some 30 ulps of the largest coordinate, or of the thickness
/// or reach where those are larger (a box corner's coordinate is below
/// twice the larger of them, so half of that still covers its rounding).
pub(super) fn rounding_margin(colliders: &[&Collider], positions: impl Iterator<Item = Vec3>, reach: f32) -> f64 {
    let coordinates = colliders
        .iter()
        .flat_map(|c| c.current().iter().chain(c.previous()).copied())
        .chain(positions)
        .map(|p| p.abs().max_element())
        .fold(1e-3f32, f32::max);
    let thickest = colliders.iter().map(|c| c.settings().thickness).fold(0.0f32, f32::max);
    4e-6 * coordinates.max(thickest).max(reach) as f64
}

/// A bound on how far the f32 sweep of [`vertex_planes`] may fall below
/// the exact `n·q + thickness` with the f64 normal. Rounding the normal to
/// f32 moves `n·q` by at most half an ulp of 1 per component times
/// `|q|₁ ≤ 3·extent`; the three products and three sums each round by half
/// an ulp of a value below `3·extent + thickness`. Seven half-ulps in all:
/// four ulps cover them.
fn f32_sweep_rounding(colliders: &[&Collider]) -> f64 {
    let largest = colliders.iter().map(|c| 3.0 * c.extent() as f64 + c.settings().thickness as f64).fold(0.0, f64::max);
    4.0 * f32::EPSILON as f64 * largest
}

fn above(plane: &Plane, p: Vec3) -> bool {
    plane.normal.dot(p.as_dvec3()) >= plane.level
}

/// The planes of one vertex at `p` with box `area` (see the module documentation).
fn vertex_planes(colliders: &[&Collider], outward: &[f64], p: Vec3, area: &Bounds, margin: f64) -> Vec<Plane> {
    // The tree's boxes (current corners grown by the thickness) are grown
    // in f32; the query is grown a little more so that rounding cannot drop
    // a triangle that reaches the box. A few more than reach it only raise
    // the levels a little.
    let query = area.inflated(margin as f32);
    let p64 = p.as_dvec3();
    // (collider, triangle, squared distance from p to its centroid)
    let mut found: Vec<(u32, u32, f32)> = Vec::new();
    for (c, col) in colliders.iter().enumerate() {
        let (tris, current) = (col.triangles(), col.current());
        col.tree().query(&query, |t| {
            let [a, b, cc] = tris[t].map(|v| current[v as usize]);
            found.push((c as u32, t as u32, ((a + b + cc) / 3.0 - p).length_squared()));
            true
        });
    }
    if found.is_empty() {
        // Nothing reaches the box: it alone keeps whatever stays in it clear.
        return vec![Plane { normal: DVec3::Z, level: f64::NEG_INFINITY, collider: 0 }];
    }
    let nearest = PLANES_PER_VERTEX.min(found.len());
    found.select_nth_unstable_by(nearest - 1, |a, b| a.2.total_cmp(&b.2));
    let mut normals: Vec<(DVec3, u32)> = Vec::with_capacity(nearest);
    for &(c, t, _) in &found[..nearest] {
        let col = colliders[c as usize];
        let [a, b, cc] = col.triangles()[t as usize].map(|v| col.current()[v as usize].as_dvec3());
        let Some(n) = triangle_normal(a, b, cc) else { continue };
        let n = match outward[c as usize] {
            o if o != 0.0 => n * o,
            _ if n.dot(p64 - a) < 0.0 => -n,
            _ => n,
        };
        normals.push((n, c));
    }
    if normals.is_empty() {
        return Vec::new();
    }
    // Every plane's level in one sweep over the corners, the four planes in
    // the lanes of one f32 vector; the sweep's rounding is added after.
    let lane = |k: usize| normals[k.min(normals.len() - 1)].0.as_vec3();
    let (nx, ny, nz) = (
        Vec4::new(lane(0).x, lane(1).x, lane(2).x, lane(3).x),
        Vec4::new(lane(0).y, lane(1).y, lane(2).y, lane(3).y),
        Vec4::new(lane(0).z, lane(1).z, lane(2).z, lane(3).z),
    );
    let mut top = Vec4::splat(f32::NEG_INFINITY);
    for &(c, t, _) in &found {
        let col = colliders[c as usize];
        let thickness = Vec4::splat(col.settings().thickness);
        for &v in &col.triangles()[t as usize] {
            let q = col.current()[v as usize];
            top = top.max(nx * q.x + ny * q.y + nz * q.z + thickness);
        }
    }
    let rounding = f32_sweep_rounding(colliders);
    normals
        .into_iter()
        .zip(top.to_array())
        .map(|((normal, collider), level)| Plane { normal, level: level as f64 + rounding + margin, collider })
        .filter(|plane| above(plane, p))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::fan_triangles;
    use crate::collide::clearance::Clearance;
    use crate::collide::collider::ColliderSettings;
    use crate::collide::geometry::{point_triangle_distance_squared, triangle_samples};
    use crate::collide::skin::Skin;
    use crate::mesh::shapes::{grid, quad_sphere};
    use proptest::prelude::*;

    /// A collider that came from `came_from` away during the frame and now
    /// stands still (the planes serve the passes after its sweep), and the
    /// height of its top near the origin.
    fn arrived(valley: bool, thickness: f32, came_from: Vec3) -> (Collider, f32) {
        let (still, top) = collider(valley, thickness);
        let start: Vec<Vec3> = still.current().iter().map(|&p| p + came_from).collect();
        let mut c = Collider::new(&start, still.triangles(), still.settings()).unwrap();
        c.update(still.current()).unwrap();
        (c, top)
    }

    /// A still collider and the height of its top near the origin: a coarse
    /// sphere (closed and convex) or an open V-shaped valley along y (a
    /// crease, where no plane may let the skin through).
    fn collider(valley: bool, thickness: f32) -> (Collider, f32) {
        let settings = ColliderSettings::new(thickness, 0.3);
        if valley {
            let p = [
                Vec3::new(-0.5, -0.5, 0.2),
                Vec3::new(0.0, -0.5, 0.0),
                Vec3::new(0.0, 0.5, 0.0),
                Vec3::new(-0.5, 0.5, 0.2),
                Vec3::new(0.5, -0.5, 0.2),
                Vec3::new(0.5, 0.5, 0.2),
            ];
            let tris = [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]];
            (Collider::new(&p, &tris, settings).unwrap(), 0.0)
        } else {
            let sphere = quad_sphere(4, 0.5);
            let offsets: Vec<u32> = std::iter::once(0).chain(sphere.polygon_sizes.iter().scan(0u32, |a, &s| { *a += s as u32; Some(*a) })).collect();
            let tris = fan_triangles(&sphere.corner_verts, &offsets);
            (Collider::new(&sphere.positions, &tris, settings).unwrap(), 0.5)
        }
    }

    /// The smallest distance between points sampled on a moving skin element
    /// and the (still) collider's triangles.
    fn sampled_distance(c: &Collider, points: &dyn Fn(f64) -> Vec<DVec3>) -> f64 {
        let at = |v: u32| c.current()[v as usize].as_dvec3();
        let mut min = f64::INFINITY;
        for i in 0..=40 {
            for p in points(i as f64 / 40.0) {
                for tri in c.triangles() {
                    min = min.min(point_triangle_distance_squared(p, at(tri[0]), at(tri[1]), at(tri[2])).sqrt());
                }
            }
        }
        min
    }

    fn small(range: f32) -> impl Strategy<Value = Vec3> {
        (-range..range, -range..range, -range..range).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    fn lift(_: usize) -> Lift {
        Lift { slack: 1e-3, static_friction: 0.3, kinetic_friction: 0.2 }
    }

    /// Checks that whatever `planes` clear or lift keeps farther than `sep`
    /// by `distance`, the smallest sampled distance of a moving skin point
    /// set from the collider: the vertices' steps (the planes see them start
    /// at `from`, the world at `start`), and the skin's edges and triangles.
    fn planes_keep_apart(
        planes: &LocalPlanes,
        from: &[Vec3],
        start: &[Vec3],
        end: &[Vec3],
        skin: &Skin,
        sep: f64,
        distance: impl Fn(&dyn Fn(f64) -> Vec<DVec3>) -> f64,
    ) -> Result<(), TestCaseError> {
        let segment = |a: Vec3, b: Vec3| move |t: f64| vec![a.as_dvec3().lerp(b.as_dvec3(), t)];
        for v in 0..start.len() as u32 {
            let (s, e) = (start[v as usize], end[v as usize]);
            match planes.vertex_step(v, from[v as usize], e, lift) {
                VertexStep::Clear => {
                    let d = distance(&segment(s, e));
                    prop_assert!(d > sep, "vertex {v} cleared but reaches {d} <= {sep}");
                }
                VertexStep::Lifted(lifted, _) => {
                    let d = distance(&segment(s, lifted));
                    prop_assert!(d > sep, "vertex {v} lifted to {lifted:?} but its step reaches {d} <= {sep}");
                }
                VertexStep::Unknown => {}
            }
        }
        let path = |v: u32, t: f64| start[v as usize].as_dvec3().lerp(end[v as usize].as_dvec3(), t);
        for edge in skin.edges() {
            if planes.clears(edge, from, end) {
                let d = distance(&|t| (0..=6).map(|j| path(edge[0], t).lerp(path(edge[1], t), j as f64 / 6.0)).collect());
                prop_assert!(d > sep, "edge {edge:?} cleared but reaches {d} <= {sep}");
            }
        }
        for tri in skin.triangles() {
            if planes.clears(tri, from, end) {
                let d = distance(&|t| {
                    let [a, b, cc] = tri.map(|v| path(v, t));
                    triangle_samples(a, b, cc)
                });
                prop_assert!(d > sep, "triangle {tri:?} cleared but reaches {d} <= {sep}");
            }
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

        /// A skin resting on (or just above, or pushed into) a still collider
        /// wobbles: whatever the planes clear stays farther than the
        /// thickness over its step, and a lifted vertex's new step does too.
        #[test]
        fn what_the_planes_clear_or_lift_stays_apart(valley in any::<bool>(), offset in small(0.04), wobble in prop::collection::vec(small(0.02), 2 * 36),
                                                   thickness in 0.0f32..0.03, came_from in small(0.1)) {
            let (c, top) = arrived(valley, thickness, came_from);
            let mesh = grid(5, 5, 0.3);
            let skin = Skin::from_mesh(mesh.input()).unwrap();
            let reference: Vec<Vec3> = mesh.positions.iter().map(|&p| p + Vec3::new(0.0, 0.0, top + thickness + 0.004) + offset).collect();
            let clearance = Clearance::new(&[&c], &skin, &reference, 0.2).unwrap().with_planes(&[&c]).unwrap();
            let planes = clearance.planes().unwrap();
            let start: Vec<Vec3> = reference.iter().zip(&wobble[..36]).map(|(&p, &w)| p + w).collect();
            let end: Vec<Vec3> = reference.iter().zip(&wobble[36..]).map(|(&p, &w)| p + w).collect();
            planes_keep_apart(planes, &start, &start, &end, &skin, thickness as f64, |points| sampled_distance(&c, points))?;
        }
    }

    /// The smallest distance between points sampled on a moving skin element
    /// and the collider's triangles moving from their previous to their
    /// current positions, at the same instants.
    fn sampled_distance_moving(c: &Collider, points: &dyn Fn(f64) -> Vec<DVec3>) -> f64 {
        let mut min = f64::INFINITY;
        for i in 0..=40 {
            let t = i as f64 / 40.0;
            let at = |v: u32| c.previous()[v as usize].as_dvec3().lerp(c.current()[v as usize].as_dvec3(), t);
            for p in points(t) {
                for tri in c.triangles() {
                    min = min.min(point_triangle_distance_squared(p, at(tri[0]), at(tri[1]), at(tri[2])).sqrt());
                }
            }
        }
        min
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]

        /// A collider carries a skin along while translating (and, a little,
        /// deforming); the solve's target pulls the skin into it. Whatever
        /// the first pass's planes, measured in the frame drifting with the
        /// collider or carried along from where it stood, clear or lift keeps
        /// farther than the thickness from the moving collider at every
        /// instant of its step.
        #[test]
        fn what_the_drifting_planes_clear_or_lift_stays_apart_from_the_moving_collider(
            valley in any::<bool>(), offset in small(0.02), wobble in prop::collection::vec(small(0.01), 2 * 36),
            thickness in 0.001f32..0.03, shift in small(0.1), deform in 0.0f32..0.004, pull in 0.0f32..0.1, seed in 0u32..1000,
            carry in any::<bool>(),
        ) {
            let (still, top) = collider(valley, thickness);
            let previous: Vec<Vec3> = still.current().to_vec();
            // Each vertex translates by `shift`, give or take up to `deform`.
            let jitter = |v: usize| {
                let h = |k: u32| ((v as u32).wrapping_mul(2654435761).wrapping_add(seed * 97 + k) % 1000) as f32 / 500.0 - 1.0;
                Vec3::new(h(1), h(2), h(3)) * (deform / 3f32.sqrt())
            };
            let current: Vec<Vec3> = previous.iter().enumerate().map(|(v, &p)| p + shift + jitter(v)).collect();
            let mut c = Collider::new(&previous, still.triangles(), still.settings()).unwrap();
            c.update(&current).unwrap();
            let mesh = grid(5, 5, 0.3);
            let skin = Skin::from_mesh(mesh.input()).unwrap();
            // Resting on the collider where it was, pulled into where it is.
            let rest: Vec<Vec3> = mesh.positions.iter().map(|&p| p + Vec3::new(0.0, 0.0, top + thickness + 0.004) + offset).collect();
            let start: Vec<Vec3> = rest.iter().zip(&wobble[..36]).map(|(&p, &w)| p + w).collect();
            let end: Vec<Vec3> = rest.iter().zip(&wobble[36..]).map(|(&p, &w)| p + shift + w - Vec3::Z * pull).collect();
            let all: Vec<u32> = (0..36).collect();
            // Or last frame's planes, measured where the collider stood, carried along.
            let carried = carry.then(|| {
                let before = Collider::new(&previous, still.triangles(), still.settings()).unwrap();
                Clearance::new(&[&before], &skin, &rest, 0.2).unwrap().with_planes(&[&before]).unwrap().into_planes().unwrap()
            });
            let Some((planes, from)) = LocalPlanes::drifting(&[&c], &[c.outward_sign()], &start, &all, 0.05, carried.as_ref()) else {
                prop_assert!(c.drift_spread() > thickness as f64, "no planes for a collider moving {} within its frame", c.drift_spread());
                return Ok(());
            };
            planes_keep_apart(&planes, &from, &start, &end, &skin, thickness as f64, |points| sampled_distance_moving(&c, points))?;
        }
    }

    #[test]
    fn drifting_planes_need_colliders_that_translate_together() {
        let (a, _) = collider(false, 0.01);
        let moved = |c: &Collider, by: Vec3| {
            let mut m = Collider::new(c.current(), c.triangles(), c.settings()).unwrap();
            m.update(&c.current().iter().map(|&p| p + by).collect::<Vec<_>>()).unwrap();
            m
        };
        let start = [Vec3::new(0.0, 0.0, 0.52)];
        let (up, also_up, sideways) = (moved(&a, Vec3::Z * 0.03), moved(&a, Vec3::Z * 0.03), moved(&a, Vec3::X * 0.03));
        assert!(up.drift_spread() < 1e-6, "a translation spreads {}", up.drift_spread());
        let (planes, from) = LocalPlanes::drifting(&[&up, &also_up], &[1.0, 1.0], &start, &[0], 0.05, None).expect("one shared drift");
        assert_eq!(from[0], start[0] + Vec3::Z * 0.03);
        assert_eq!(planes.vertex_count(), 1);
        assert!(LocalPlanes::drifting(&[&up, &sideways], &[1.0, 1.0], &start, &[0], 0.05, None).is_none(), "two drifts");
        // Grown by a tenth: the vertices move up to 5 cm within the frame, past the thickness.
        let mut grown = Collider::new(a.current(), a.triangles(), a.settings()).unwrap();
        grown.update(&a.current().iter().map(|&p| p * 1.1).collect::<Vec<_>>()).unwrap();
        assert!(grown.drift_spread() > 0.04);
        assert!(LocalPlanes::drifting(&[&grown], &[1.0], &start, &[0], 0.05, None).is_none(), "deforming");
    }

    #[test]
    fn a_vertex_resting_on_a_convex_collider_is_lifted_without_a_lookup_and_one_in_a_crease_is_not() {
        for (valley, expect_planes) in [(false, true), (true, false)] {
            let thickness = 0.01;
            let (c, top) = collider(valley, thickness);
            // One vertex resting just above the top (at the crease for the valley).
            let rest = Vec3::new(0.0, 0.0, top + thickness + 2e-3);
            let skin = Skin::vertices_only(1);
            let clearance = Clearance::new(&[&c], &skin, &[rest], 0.1).unwrap().with_planes(&[&c]).unwrap();
            let planes = clearance.planes().unwrap();
            // The solver pulls it 5 mm in and 3 mm sideways.
            let pulled = rest + Vec3::new(0.003, 0.0, -0.005);
            match (planes.vertex_step(0, rest, pulled, lift), expect_planes) {
                (VertexStep::Lifted(p, _), true) => {
                    assert!(p.z > top + thickness && p.distance(pulled) < 0.01, "lifted to {p:?}");
                    // Friction holds it nearer to where it touched than a frictionless lift.
                    let frictionless = |_: usize| Lift { static_friction: 0.0, kinetic_friction: 0.0, ..lift(0) };
                    let VertexStep::Lifted(free, _) = planes.vertex_step(0, rest, pulled, frictionless) else { panic!("no frictionless lift") };
                    assert!(p.distance(rest) < free.distance(rest), "with friction {p:?}, without {free:?}");
                }
                (VertexStep::Unknown, false) => {}
                (other, _) => panic!("valley {valley}: {other:?}"),
            }
            assert_eq!(planes.vertex_count(), usize::from(expect_planes), "valley {valley}");
        }
    }
}
