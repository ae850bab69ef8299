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
//! The rotation is the rotational part of the offsets' covariance, extracted
//! by Müller et al. 2016 ("A robust method to extract the rotational part of
//! deformations"): a short quaternion iteration from the identity, robust to
//! the rank-deficient covariances of flat or two-neighbour rings, and
//! deterministic (no SVD, no warm start).

use glam::{DMat3, DQuat, DVec3, Vec3};

use super::encoding::PinReason;
use crate::mesh::Topology;
use crate::solve::{Constraint, Context, Rows};

/// Iterations of the rotation extraction at most; it stops earlier once the
/// correction is below [`ROTATION_TOLERANCE`] radians.
const ROTATION_ITERATIONS: usize = 48;
const ROTATION_TOLERANCE: f64 = 1e-9;

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
        let rotation = rotational_part(&covariance);
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

/// The rotation `R` maximising `tr(Rᵀ A)` (Müller et al. 2016), from the
/// identity. For a rank-deficient `A` the undetermined part stays the identity's.
pub fn rotational_part(a: &DMat3) -> DQuat {
    let scale = a.x_axis.length() + a.y_axis.length() + a.z_axis.length();
    let mut q = DQuat::IDENTITY;
    if !(scale > 0.0) || !scale.is_finite() {
        return q;
    }
    for _ in 0..ROTATION_ITERATIONS {
        let r = DMat3::from_quat(q);
        let torque = r.x_axis.cross(a.x_axis) + r.y_axis.cross(a.y_axis) + r.z_axis.cross(a.z_axis);
        let alignment = r.x_axis.dot(a.x_axis) + r.y_axis.dot(a.y_axis) + r.z_axis.dot(a.z_axis);
        let omega = torque / (alignment.abs() + 1e-12 * scale);
        let angle = omega.length();
        if !(angle > ROTATION_TOLERANCE) {
            break;
        }
        q = (DQuat::from_axis_angle(omega / angle, angle) * q).normalize();
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
