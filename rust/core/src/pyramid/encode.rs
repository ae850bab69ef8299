//! Bind time: one-ring → mean-value weights and normal offsets.
//!
//! For an interior vertex `v` with ring `v_0 … v_{k−1}` (counter-clockwise
//! around the outward normal):
//! * `n` = normalised vector area of the ring polygon, `Σ v_j × v_{j+1}`; it
//!   does not depend on `v`, so it can be rebuilt from the neighbours alone;
//! * the plane through the ring centroid `l` with normal `n`; `v'`, `v_j'` are
//!   the projections on it, `h_j = (v_j − l)·n`, `b = (v − l)·n`;
//! * Floater's mean-value weights of `v'` with respect to the polygon `v_j'`;
//! * plain mode stores `b`; scale-safe mode stores, per neighbour, the tangent
//!   of the edge's elevation over the plane `t_j = (b − h_j)/|v' − v_j'|`.
//!
//! A boundary vertex's ring is open: it starts and ends at its neighbours on
//! the border. Its normal is that of the ring closed by the chord between them
//! (what [`super::project::frame`] measures at run time, unchanged), and its
//! mean-value weights are taken on the ring closed by a virtual neighbour in
//! the gap ([`OpenRingClosing`]), whose weight is then shared out among the
//! real neighbours it is made of. Both lifts only need weights that sum to 1
//! and reproduce the projected vertex, so the projection and the kernels treat
//! open rings like closed ones.
//!
//! Everything is computed in f64; only the results are stored in f32.

// `!(x > limit)` on purpose throughout: a NaN must fail these checks, not pass them.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use glam::{DVec3, Vec3};
use rayon::prelude::*;

pub use super::encoding::{Encoding, PinReason};
use crate::mesh::Topology;
use crate::{Error, Result};

/// Rings with more neighbours are pinned: mean-value weights of very high
/// valence fans (poles of 100+ triangles) are tiny and ill-conditioned, and
/// StretchMesh draws the same line (128).
pub const MAX_VALENCE: usize = 64;

/// Smallest wedge angle (radians) at the projected vertex: below it, or within
/// it of π, the vertex sits (almost) on the border of its ring's kernel and
/// mean-value weights explode.
const MIN_WEDGE: f64 = 1e-3;

/// Ring polygons whose vector area is below this fraction of the squared mean
/// neighbour distance have no usable normal.
const MIN_RELATIVE_AREA: f64 = 1e-8;

/// Steepest rest elevation of an edge over the ring's plane (its tangent)
/// that the pyramid coordinates are trusted with. Beyond it the ring is folded
/// at rest (a sharp crease or step): the ring's normal, and with it every
/// lifted target, turns fast with the neighbours, and under bending the
/// converged result spikes there (a 90° cuff step: tangents 1.5 and 2.5,
/// spike growing with iterations to twice the input's). Smooth surfaces stay
/// far below (a 24-sided tube: 0.13). Such vertices get a ring fit instead
/// ([`super::ring_fit`]).
pub const MAX_REST_ELEVATION: f64 = 1.0;

/// Units in the last place of a vertex's largest coordinate that the bind's
/// self-test allows the runtime (single-precision) projection to miss its
/// rest position by: the projection sums a ring of weighted neighbours.
const ROUNDING_ULPS: f32 = 16.0;

/// Shortest projected distance to a neighbour, relative to the ring's mean,
/// that the mean-value weights are trusted with. A nearly coincident neighbour
/// (a sliver polygon) takes almost all of the weight (they go as `1/r`), so
/// the pair of vertices locks onto each other and barely feels the rest of
/// either ring: under bending it lags behind as a spike (a column of quads
/// squeezed to 2e-3 of their width: spike 0.37 against the input's 0.32).
/// Such vertices get a ring fit instead, which weighs neighbours equally.
pub const MIN_RELATIVE_NEIGHBOUR_DISTANCE: f64 = 0.02;

struct Ring {
    weights: Vec<f32>,
    tangents: Vec<f32>,
    height: f32,
}

/// Encodes every vertex of `topology` at `rest` positions.
pub fn encode(topology: &Topology, rest: &[Vec3], scale_safe: bool) -> Result<Encoding> {
    let n = topology.vertex_count();
    if rest.len() != n {
        return Err(Error::invalid(format!(
            "rest positions: {} vertices given, the mesh has {n}",
            rest.len()
        )));
    }
    crate::mesh::validate_positions("rest positions", rest)?;

    let edges = topology.edges();
    let mean_edge_length = if edges.is_empty() {
        0.0
    } else {
        // Fixed-order sum so the figure never depends on threads.
        let total: f64 = edges
            .iter()
            .map(|&[a, b]| (rest[a as usize].as_dvec3() - rest[b as usize].as_dvec3()).length())
            .sum();
        (total / edges.len() as f64) as f32
    };

    let results: Vec<std::result::Result<Ring, PinReason>> = (0..n)
        .into_par_iter()
        .with_min_len(256)
        .map(|v| encode_vertex(topology, rest, v, scale_safe))
        .collect();

    let mut encoding = Encoding::empty(n, scale_safe, mean_edge_length);
    for (v, result) in results.into_iter().enumerate() {
        match result {
            Ok(ring) => encoding.push(v as u32, topology.one_ring(v), &ring.weights, &ring.tangents, ring.height),
            Err(reason) => encoding.pin(v as u32, reason),
        }
    }

    // Self-test: the runtime projection (f32) must give back the rest position.
    // Vertices that fail are pinned, and the encoding is rebuilt without them.
    // Within a ten-thousandth of the mean edge, or within what single
    // precision resolves where the vertex sits (a few units in the last place
    // of its coordinates), whichever is larger: on a 5M-vertex tube of length 2
    // the first is 9e-8, below the rounding of coordinates near 1, and 638k
    // vertices (those beyond z ≈ 0.75) failed it and lost their pyramid rows.
    let tolerance = 1e-4 * mean_edge_length.max(f32::MIN_POSITIVE);
    let inexact: Vec<u32> = (0..encoding.len())
        .into_par_iter()
        .filter_map(|e| {
            let v = encoding.vertices()[e];
            let resolution = ROUNDING_ULPS * f32::EPSILON * rest[v as usize].abs().max_element();
            match super::project::target(&encoding, e, rest) {
                Some(t) if (t - rest[v as usize]).length() <= tolerance.max(resolution) => None,
                _ => Some(v),
            }
        })
        .collect();
    if !inexact.is_empty() {
        encoding = encoding.without(&inexact);
    }
    Ok(encoding)
}

fn encode_vertex(
    topology: &Topology,
    rest: &[Vec3],
    v: usize,
    scale_safe: bool,
) -> std::result::Result<Ring, PinReason> {
    if topology.is_isolated(v) {
        return Err(PinReason::Isolated);
    }
    if topology.is_non_manifold(v) {
        return Err(PinReason::NonManifold);
    }
    let open = topology.is_boundary(v);
    let ring = topology.one_ring(v);
    let k = ring.len();
    if k < 3 {
        return Err(if open { PinReason::Boundary } else { PinReason::LowValence });
    }
    if k > MAX_VALENCE {
        return Err(PinReason::HighValence);
    }
    let p: Vec<DVec3> = ring.iter().map(|&j| rest[j as usize].as_dvec3()).collect();
    let x = rest[v].as_dvec3();
    let centroid = p.iter().sum::<DVec3>() / k as f64;
    // Relative to the centroid: same sum for a closed loop, less cancellation.
    // An open ring is closed by the chord from its last neighbour to its first,
    // which is the polygon `project::frame` measures at run time too.
    let area: DVec3 = (0..k)
        .map(|j| (p[j] - centroid).cross(p[(j + 1) % k] - centroid))
        .sum();
    let spread = p
        .iter()
        .map(|q| (*q - centroid).length_squared())
        .sum::<f64>()
        / k as f64;
    if !(area.length() > MIN_RELATIVE_AREA * spread * k as f64) {
        return Err(PinReason::ZeroArea);
    }
    let normal = area.normalize();
    let height = (x - centroid).dot(normal);
    let heights: Vec<f64> = p.iter().map(|q| (*q - centroid).dot(normal)).collect();
    let projected = x - height * normal;
    // The neighbours in the tangent plane, relative to the projected vertex.
    let mut d: Vec<DVec3> = (0..k)
        .map(|j| (p[j] - heights[j] * normal) - projected)
        .collect();
    let closing = if open {
        let closing = OpenRingClosing::new(&d).ok_or(PinReason::Boundary)?;
        d.push(closing.point);
        Some(closing)
    } else {
        None
    };
    let raw = mean_value_weights(&d, normal)?;
    let r: Vec<f64> = d.iter().map(|d| d.length()).collect();
    let mean_r = r[..k].iter().sum::<f64>() / k as f64;
    if r[..k].iter().any(|&r| !(r >= MIN_RELATIVE_NEIGHBOUR_DISTANCE * mean_r)) {
        return Err(PinReason::NotStarShaped);
    }
    if (0..k).any(|j| !((height - heights[j]).abs() <= MAX_REST_ELEVATION * r[j])) {
        return Err(PinReason::Folded);
    }
    // Only real neighbours are stored: the virtual one's weight goes to the
    // neighbours it is an affine combination of, so weights still sum to 1 and
    // reproduce the projected vertex, which is all both lifts rely on.
    let weights: Vec<f64> = match closing {
        Some(closing) => closing.redistribute(&raw),
        None => raw,
    };
    if weights.iter().any(|w| !w.is_finite()) {
        return Err(PinReason::NotStarShaped);
    }
    let tangents: Vec<f32> = if scale_safe {
        (0..k)
            .map(|j| ((height - heights[j]) / r[j]) as f32)
            .collect()
    } else {
        Vec::new()
    };
    Ok(Ring {
        weights: weights.iter().map(|&w| w as f32).collect(),
        tangents,
        height: height as f32,
    })
}

/// Floater's mean-value weights of the origin with respect to the polygon
/// `d` (points relative to the vertex, in the plane normal to `normal`,
/// counter-clockwise), normalised to sum 1. The origin must be strictly inside
/// the polygon's kernel, away from its corners.
fn mean_value_weights(d: &[DVec3], normal: DVec3) -> std::result::Result<Vec<f64>, PinReason> {
    let k = d.len();
    let r: Vec<f64> = d.iter().map(|d| d.length()).collect();
    let mean_r = r.iter().sum::<f64>() / k as f64;
    if r.iter().any(|&r| !(r > 1e-6 * mean_r)) {
        return Err(PinReason::NotStarShaped);
    }
    // Signed wedge angles at the projected vertex; strictly inside the kernel
    // means all in (0, π) summing to 2π.
    let angles: Vec<f64> = (0..k)
        .map(|j| {
            let (a, b) = (d[j], d[(j + 1) % k]);
            a.cross(b).dot(normal).atan2(a.dot(b))
        })
        .collect();
    let total: f64 = angles.iter().sum();
    if angles
        .iter()
        .any(|&a| !(MIN_WEDGE..=std::f64::consts::PI - MIN_WEDGE).contains(&a))
        || (total - std::f64::consts::TAU).abs() > 1e-6
    {
        return Err(PinReason::NotStarShaped);
    }
    let half_tan: Vec<f64> = angles.iter().map(|a| (a * 0.5).tan()).collect();
    let raw: Vec<f64> = (0..k)
        .map(|j| (half_tan[(j + k - 1) % k] + half_tan[j]) / r[j])
        .collect();
    let sum: f64 = raw.iter().sum();
    if !(sum.is_finite() && sum > 0.0) {
        return Err(PinReason::NotStarShaped);
    }
    Ok(raw.iter().map(|w| w / sum).collect())
}

/// Largest weight, relative to the chord, that the virtual neighbour of an
/// open ring may take: beyond it the ring is a sliver (all neighbours nearly on
/// one line through the vertex) and the weights would amplify rounding.
const MAX_CLOSING_REACH: f64 = 16.0;

/// The virtual neighbour that closes an open one-ring (a boundary vertex).
///
/// The ring `r_0 … r_{k−1}` (counter-clockwise, first and last on the border)
/// leaves a gap between `r_{k−1}` and `r_0`. The virtual neighbour
/// `g = (1 + λ) c − λ q`, with `c` the chord's midpoint and `q` the mean of the
/// inner neighbours, sits in that gap on the far side of the vertex, so that
/// the vertex is inside the closed ring and gets mean-value weights like any
/// interior vertex. Being an affine combination of real neighbours, `g` never
/// needs to be stored or evaluated: its weight is shared out among them.
#[derive(Debug, Clone, Copy)]
struct OpenRingClosing {
    /// `g`, relative to the projected vertex.
    point: DVec3,
    /// `λ`.
    reach: f64,
    /// Number of real neighbours.
    k: usize,
}

impl OpenRingClosing {
    /// From the real neighbours relative to the projected vertex (k ≥ 3);
    /// `None` when the ring is too narrow to close.
    fn new(d: &[DVec3]) -> Option<Self> {
        let k = d.len();
        let chord_middle = 0.5 * (d[0] + d[k - 1]);
        let inner = d[1..k - 1].iter().sum::<DVec3>() / (k - 2) as f64;
        let outward = chord_middle - inner;
        let length = outward.length();
        let mean_r = d.iter().map(|q| q.length()).sum::<f64>() / k as f64;
        if !(length > 1e-9 * mean_r) {
            return None;
        }
        let direction = outward / length;
        // The vertex (the origin here) lies `beyond` past the chord along
        // `direction` (negative when the fan spans more than a half turn); put
        // `g` a mean ring radius past whichever is further.
        let beyond = (-chord_middle).dot(direction).max(0.0);
        let reach = (beyond + mean_r) / length;
        if !(reach <= MAX_CLOSING_REACH) {
            return None;
        }
        Some(Self { point: chord_middle + reach * outward, reach, k })
    }

    /// `k` real weights from the `k + 1` weights of the closed ring.
    fn redistribute(&self, closed: &[f64]) -> Vec<f64> {
        let k = self.k;
        let virtual_weight = closed[k];
        let mut weights = closed[..k].to_vec();
        let at_chord_end = 0.5 * (1.0 + self.reach) * virtual_weight;
        weights[0] += at_chord_end;
        weights[k - 1] += at_chord_end;
        let per_inner = self.reach * virtual_weight / (k - 2) as f64;
        for w in &mut weights[1..k - 1] {
            *w -= per_inner;
        }
        weights
    }
}

