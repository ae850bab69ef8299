//! Ring fit: how vertices the pyramid encoding cannot describe still deform
//! with their neighbourhood.
//!
//! A non-manifold vertex, a bow-tie, a ring folded at rest or without area, a
//! pole of too high a valence: none has an ordered one-ring with usable
//! mean-value weights, so none gets a pyramid row ([`super::encode`]). Made to
//! follow the input instead, such a vertex is a hard point in a shape-kept
//! surface: along a non-manifold edge line it makes a crease or a spike.
//!
//! Here each such vertex `i` keeps its rest offset from the mean of its edge
//! neighbours, carried along by how that neighbourhood moved: the row `e_i`
//! projects to `c(x) + s·R·(r_i − c(r))`, with `c` the mean of the neighbours
//! (current `x`, rest `r`), `R` the best-fit rotation of the rest offsets
//! (the neighbours' and the vertex's own) onto the current ones, and `s` the
//! best-fit uniform scale of the neighbours' offsets in scale-safe mode (so a
//! uniform scale is reproduced exactly, like the pyramid rows), else 1. A rigid
//! motion (and a uniform scale) is a fixed point; the rows are identity rows,
//! so the global matrix stays diagonal in the per-vertex targets formulation.
//!
//! The rotation is the rotational part of the offsets' covariance `A = U Σ Vᵀ`:
//! `R = U Vᵀ`, or the nearest proper rotation when `A` reflects (Kabsch).
//! `V` comes from a Jacobi eigensolve of the symmetric `AᵀA` (a few sweeps
//! of 3 × 3 rotations, quadratically convergent), the two leading columns of
//! `U` from `A v / σ`, and the third from their cross product, so flat rings
//! (rank 2) are exact too. Only where `A` has rank 1 (collinear offsets: the
//! rotation about that line is undetermined) does it fall back to Müller et
//! al. 2016 ("A robust method to extract the rotational part of
//! deformations") from the identity, which leaves the undetermined part at the
//! identity's. That iteration is linear in the conditioning of `A`: on the
//! anisotropic rings of a tube's rim it ran out of its 48 steps every time, a
//! third of a 100k-vertex frame.
//!
//! The closed form costs about 30 times a pyramid row, so it runs once per row
//! and solve: later iterations of the same solve refine the row's previous
//! rotation by a few of Müller's steps, which from that close start converge
//! within a step or two (and a row's rotation keeps converging across the
//! iterations). Every solve starts afresh ([`Constraint::begin_solve`]): a
//! result depends on its own input only, never on the solves before it.

use std::sync::atomic::{AtomicU64, Ordering};

use glam::{DMat3, DQuat, DVec3, Vec3};

use super::encoding::PinReason;
use crate::mesh::Topology;
use crate::solve::{Constraint, Context, Rows};
use crate::Result;

/// Iterations of the rotation extraction at most; it stops earlier once the
/// correction is below [`ROTATION_TOLERANCE`] radians.
const ROTATION_ITERATIONS: usize = 48;
const ROTATION_TOLERANCE: f64 = 1e-9;

/// Müller steps refining a row's rotation from its previous iteration's, at most.
const REFINE_ITERATIONS: usize = 2;
/// A correction below this (radians) ends the refinement: far below what
/// single-precision positions resolve.
const REFINE_TOLERANCE: f64 = 1e-7;

/// A neighbour closer than this fraction of the mean neighbour distance makes
/// a sliver (see [`super::encode::MIN_RELATIVE_NEIGHBOUR_DISTANCE`]).
const SLIVER: f64 = super::encode::MIN_RELATIVE_NEIGHBOUR_DISTANCE;

/// Which pinned vertices a ring fit can hold, and their neighbours.
#[derive(Debug, Clone, Default)]
pub struct RingFitVertices {
    /// `(vertex, why it has no pyramid row)`, ascending.
    pub fitted: Vec<(u32, PinReason)>,
    /// `(vertex, reason)` of the pinned vertices that stay pinned (fewer than
    /// two edge neighbours), ascending.
    pub pinned: Vec<(u32, PinReason)>,
}

impl RingFitVertices {
    /// Splits the encoding's pinned vertices: those with at least two edge
    /// neighbours are fitted, the rest stay pinned.
    pub fn split(topology: &Topology, pinned: &[(u32, PinReason)]) -> Self {
        let degree = edge_degrees(topology);
        let mut out = RingFitVertices::default();
        for &(v, reason) in pinned {
            if degree[v as usize] >= 2 {
                out.fitted.push((v, reason));
            } else {
                out.pinned.push((v, reason));
            }
        }
        out.fitted.sort_unstable_by_key(|&(v, _)| v);
        out.pinned.sort_unstable_by_key(|&(v, _)| v);
        out
    }
}

fn edge_degrees(topology: &Topology) -> Vec<u32> {
    let mut degree = vec![0u32; topology.vertex_count()];
    for &[a, b] in topology.edges() {
        degree[a as usize] += 1;
        degree[b as usize] += 1;
    }
    degree
}

/// Identity rows on the fitted vertices, projecting to the rest offset from
/// their neighbours' mean carried by the neighbours' best-fit similarity.
pub struct RingFit {
    rows: Rows,
    vertices: Vec<u32>,
    /// Per row: neighbours at `offsets[r]..offsets[r + 1]`.
    offsets: Vec<u32>,
    neighbours: Vec<u32>,
    /// Per neighbour entry: its rest offset from the neighbours' rest mean.
    rest_offsets: Vec<Vec3>,
    /// Per row: the vertex's own rest offset from its neighbours' rest mean,
    /// or from its anchor when it has one.
    own_offsets: Vec<Vec3>,
    /// Per row: a nearly coincident neighbour of lower index the vertex is
    /// carried from instead of its neighbours' mean (`u32::MAX`: none).
    anchors: Vec<u32>,
    scale_safe: bool,
    /// Per row: its rotation at its last projection in this solve.
    rotations: Rotations,
}

/// One quaternion per row, written by that row's projection only; "none yet"
/// (NaN) at the start of every solve. A row is projected by one thread at a
/// time, so relaxed atomics suffice: they only let `project_row(&self)` keep
/// the start of the row's next projection.
struct Rotations(Vec<[AtomicU64; 4]>);

impl Rotations {
    const NONE: [f64; 4] = [f64::NAN; 4];

    fn new(rows: usize) -> Self {
        Rotations((0..rows).map(|_| Self::NONE.map(|c| AtomicU64::new(c.to_bits()))).collect())
    }

    fn get(&self, r: usize) -> Option<DQuat> {
        let q = DQuat::from_array(self.0[r].each_ref().map(|c| f64::from_bits(c.load(Ordering::Relaxed))));
        (!q.is_nan()).then_some(q)
    }

    fn set(&self, r: usize, q: DQuat) {
        for (slot, c) in self.0[r].iter().zip(q.to_array()) {
            slot.store(c.to_bits(), Ordering::Relaxed);
        }
    }

    fn forget(&mut self) {
        for row in &mut self.0 {
            for (slot, c) in row.iter_mut().zip(Self::NONE) {
                *slot.get_mut() = c.to_bits();
            }
        }
    }
}

impl RingFit {
    /// Rows for `vertices` (ascending, each with at least two edge neighbours
    /// in `topology`) at `rest`.
    pub fn new(topology: &Topology, rest: &[Vec3], vertices: &[u32], scale_safe: bool) -> Self {
        let mut wanted = vec![u32::MAX; topology.vertex_count()];
        for (r, &v) in vertices.iter().enumerate() {
            wanted[v as usize] = r as u32;
        }
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); vertices.len()];
        for &[a, b] in topology.edges() {
            if wanted[a as usize] != u32::MAX {
                lists[wanted[a as usize] as usize].push(b);
            }
            if wanted[b as usize] != u32::MAX {
                lists[wanted[b as usize] as usize].push(a);
            }
        }
        let mut offsets = vec![0u32];
        let (mut neighbours, mut rest_offsets, mut own_offsets) = (Vec::new(), Vec::new(), Vec::new());
        let mut anchors = Vec::new();
        for (list, &v) in lists.iter_mut().zip(vertices) {
            list.sort_unstable();
            list.dedup();
            debug_assert!(list.len() >= 2, "ring fit of vertex {v} with {} neighbours", list.len());
            let centre = list.iter().map(|&j| rest[j as usize].as_dvec3()).sum::<DVec3>() / list.len() as f64;
            for &j in list.iter() {
                neighbours.push(j);
                rest_offsets.push((rest[j as usize].as_dvec3() - centre).as_vec3());
            }
            // A sliver: the nearest neighbour almost on the vertex. Equal
            // weights would let the pair drift apart (by the fit's error,
            // huge next to their distance); carrying the vertex from that
            // neighbour keeps the sliver one. Only from a lower index, so
            // that a pair (or a collapsed cluster) is never carried from
            // itself and stays tied to the rest of the surface.
            let own = rest[v as usize].as_dvec3();
            let distance = |j: u32| (rest[j as usize].as_dvec3() - own).length();
            let mean = list.iter().map(|&j| distance(j)).sum::<f64>() / list.len() as f64;
            let anchor = list
                .iter()
                .copied()
                .filter(|&j| j < v && distance(j) < SLIVER * mean)
                .min_by(|&a, &b| distance(a).total_cmp(&distance(b)).then(a.cmp(&b)));
            match anchor {
                Some(a) => {
                    own_offsets.push((own - rest[a as usize].as_dvec3()).as_vec3());
                    anchors.push(a);
                }
                None => {
                    own_offsets.push((own - centre).as_vec3());
                    anchors.push(u32::MAX);
                }
            }
            offsets.push(neighbours.len() as u32);
        }
        RingFit {
            rotations: Rotations::new(vertices.len()),
            rows: Rows::identity(vertices),
            vertices: vertices.to_vec(),
            offsets,
            neighbours,
            rest_offsets,
            own_offsets,
            anchors,
            scale_safe,
        }
    }

    pub fn vertices(&self) -> &[u32] {
        &self.vertices
    }

    /// The vertices carried from a nearly coincident neighbour (slivers).
    pub fn anchored(&self) -> Vec<u32> {
        self.vertices.iter().zip(&self.anchors).filter(|(_, &a)| a != u32::MAX).map(|(&v, _)| v).collect()
    }

    /// The target of row `r` at positions `x`.
    pub fn target(&self, r: usize, x: &[Vec3]) -> Vec3 {
        let range = self.offsets[r] as usize..self.offsets[r + 1] as usize;
        let ring = &self.neighbours[range.clone()];
        let rest = &self.rest_offsets[range];
        let own_rest = self.own_offsets[r].as_dvec3();
        let centre = ring.iter().map(|&j| x[j as usize].as_dvec3()).sum::<DVec3>() / ring.len() as f64;
        let own = x[self.vertices[r] as usize].as_dvec3() - centre;
        // Covariance Σ p qᵀ of current p onto rest q offsets, the vertex's
        // own included (unless carried from an anchor: its offset is tiny).
        let mut covariance = if self.anchors[r] == u32::MAX { outer(own, own_rest) } else { DMat3::ZERO };
        let mut rest_norm = 0.0;
        for (&j, q) in ring.iter().zip(rest) {
            let (p, q) = (x[j as usize].as_dvec3() - centre, q.as_dvec3());
            covariance += outer(p, q);
            rest_norm += q.length_squared();
        }
        let rotation = match self.rotations.get(r) {
            Some(previous) => refine_rotation(&covariance, previous, REFINE_ITERATIONS, REFINE_TOLERANCE),
            None => rotational_part(&covariance),
        };
        self.rotations.set(r, rotation);
        let scale = if self.scale_safe && rest_norm > 0.0 {
            // Best-fit uniform scale of the neighbours' offsets alone: the
            // vertex itself cannot inflate its own target.
            let fit: f64 = ring
                .iter()
                .zip(rest)
                .map(|(&j, q)| (x[j as usize].as_dvec3() - centre).dot(rotation * q.as_dvec3()))
                .sum();
            (fit / rest_norm).max(0.0)
        } else {
            1.0
        };
        let origin = match self.anchors[r] {
            u32::MAX => centre,
            a => x[a as usize].as_dvec3(),
        };
        (origin + scale * (rotation * own_rest)).as_vec3()
    }
}

fn outer(p: DVec3, q: DVec3) -> DMat3 {
    DMat3::from_cols(p * q.x, p * q.y, p * q.z)
}

/// Below this ratio of the second to the first singular value, `A` counts as
/// rank 1 and the rotation about its one direction as undetermined.
const RANK_ONE: f64 = 1e-6;

/// The rotation `R` maximising `tr(Rᵀ A)`: the polar rotation of `A` with the
/// reflection (if any) taken out of its weakest direction. For a rank-1 `A`,
/// the undetermined part stays the identity's.
pub fn rotational_part(a: &DMat3) -> DQuat {
    let scale = a.x_axis.length() + a.y_axis.length() + a.z_axis.length();
    if !(scale > 0.0) || !scale.is_finite() {
        return DQuat::IDENTITY;
    }
    let [v1, v2] = leading_eigenvectors(a.transpose() * *a);
    let u1 = *a * v1;
    let s1 = u1.length();
    let u1 = u1 / s1;
    let u2 = *a * v2;
    let u2 = u2 - u1 * u1.dot(u2);
    let s2 = u2.length();
    if !(s2 > RANK_ONE * s1) {
        return rotation_by_iteration(a);
    }
    let u2 = u2 / s2;
    // R maps v1 → u1, v2 → u2 and so v1 × v2 → u1 × u2: proper by construction.
    let from = DMat3::from_cols(v1, v2, v1.cross(v2));
    let to = DMat3::from_cols(u1, u2, u1.cross(u2));
    DQuat::from_mat3(&(to * from.transpose())).normalize()
}

/// The eigenvectors of the two largest eigenvalues of a symmetric `s`, by
/// cyclic Jacobi rotations.
fn leading_eigenvectors(s: DMat3) -> [DVec3; 2] {
    let mut m = s.to_cols_array_2d(); // m[column][row]; symmetric, so either way
    let mut v = DMat3::IDENTITY.to_cols_array_2d();
    let size = m[0][0].abs() + m[1][1].abs() + m[2][2].abs();
    for _sweep in 0..16 {
        let off = m[0][1].abs() + m[0][2].abs() + m[1][2].abs();
        if !(off > 1e-10 * size) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if m[p][q] == 0.0 {
                continue;
            }
            // The rotation that zeroes m[p][q] (Numerical Recipes' stable form).
            let theta = (m[q][q] - m[p][p]) / (2.0 * m[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let c = 1.0 / (t * t + 1.0).sqrt();
            let sn = t * c;
            for k in 0..3 {
                let (mkp, mkq) = (m[k][p], m[k][q]);
                m[k][p] = c * mkp - sn * mkq;
                m[k][q] = sn * mkp + c * mkq;
            }
            for k in 0..3 {
                let (mpk, mqk) = (m[p][k], m[q][k]);
                m[p][k] = c * mpk - sn * mqk;
                m[q][k] = sn * mpk + c * mqk;
            }
            for column in &mut v {
                let (vp, vq) = (column[p], column[q]);
                column[p] = c * vp - sn * vq;
                column[q] = sn * vp + c * vq;
            }
        }
    }
    // v[k] is the k-th row of the accumulated rotation; eigenvector i is its column i.
    let vector = |i: usize| DVec3::new(v[0][i], v[1][i], v[2][i]);
    let mut order = [0, 1, 2];
    order.sort_by(|&i, &j| m[j][j].total_cmp(&m[i][i]));
    [vector(order[0]), vector(order[1])]
}

/// Müller et al. 2016 from the identity: for rank-1 `A`, where the closed
/// form has no second direction.
fn rotation_by_iteration(a: &DMat3) -> DQuat {
    refine_rotation(a, DQuat::IDENTITY, ROTATION_ITERATIONS, ROTATION_TOLERANCE)
}

/// At most `iterations` of Müller et al.'s steps from `start`, until a
/// correction is below `tolerance` radians.
fn refine_rotation(a: &DMat3, start: DQuat, iterations: usize, tolerance: f64) -> DQuat {
    let scale = a.x_axis.length() + a.y_axis.length() + a.z_axis.length();
    let mut q = start;
    if !(scale > 0.0) || !scale.is_finite() {
        return q;
    }
    for _ in 0..iterations {
        let r = DMat3::from_quat(q);
        let torque = r.x_axis.cross(a.x_axis) + r.y_axis.cross(a.y_axis) + r.z_axis.cross(a.z_axis);
        let alignment = r.x_axis.dot(a.x_axis) + r.y_axis.dot(a.y_axis) + r.z_axis.dot(a.z_axis);
        let omega = torque / (alignment.abs() + 1e-12 * scale);
        let angle = omega.length();
        if !(angle > tolerance) {
            break;
        }
        // A small correction (every refinement step) needs no sine and cosine:
        // the quaternion (ω/2, 1), normalised, is its rotation to third order.
        let turn = if angle < 0.05 {
            DQuat::from_xyzw(0.5 * omega.x, 0.5 * omega.y, 0.5 * omega.z, 1.0)
        } else {
            DQuat::from_axis_angle(omega / angle, angle)
        };
        q = (turn * q).normalize();
    }
    q
}

impl Constraint for RingFit {
    fn name(&self) -> &str {
        "ring fit (vertices without a pyramid row)"
    }

    fn rows(&self) -> &Rows {
        &self.rows
    }

    fn begin_solve(&mut self, _input: &[Vec3]) -> Result<()> {
        self.rotations.forget();
        Ok(())
    }

    #[inline]
    fn project_row(&self, context: &Context<'_>, row: usize) -> Vec3 {
        self.target(row, context.positions)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotational_part_recovers_large_rotations() {
        // Deterministic pseudo-random rotations of a non-degenerate point set,
        // including angles past a half turn's neighbourhood.
        let points = [
            DVec3::new(1.0, 0.2, -0.3),
            DVec3::new(-0.4, 1.1, 0.5),
            DVec3::new(0.3, -0.7, 0.9),
            DVec3::new(-0.8, -0.2, -0.6),
        ];
        for k in 0..40 {
            let t = k as f64;
            let axis = DVec3::new((t * 1.3).sin(), (t * 0.7).cos(), (t * 2.1).sin() + 0.1).normalize();
            let angle = 0.1 + 3.0 * ((t * 0.37).sin() * 0.5 + 0.5);
            let truth = DQuat::from_axis_angle(axis, angle);
            let mut a = DMat3::ZERO;
            for p in points {
                a += outer(truth * p, p);
            }
            let found = rotational_part(&a);
            for p in points {
                assert!((found * p - truth * p).length() < 1e-6, "angle {angle}: {:?} vs {:?}", found * p, truth * p);
            }
        }
    }
}
