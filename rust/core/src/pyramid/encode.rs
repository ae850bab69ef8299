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

/// Why a vertex is not encoded. Pinned vertices get no pyramid constraint and
/// follow their input (closeness 1); neighbours still see them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PinReason {
    /// On an open border, with a one-ring too small or too narrow to close
    /// (fewer than 3 neighbours, or all of them nearly on one line).
    Boundary,
    /// Its polygons do not form one fan (non-manifold edge, bow-tie, flipped face).
    NonManifold,
    /// No polygon uses it.
    Isolated,
    /// Fewer than 3 neighbours.
    LowValence,
    /// More than [`MAX_VALENCE`] neighbours.
    HighValence,
    /// The ring polygon has (next to) no area, so no normal.
    ZeroArea,
    /// The projected vertex is not strictly inside the kernel of its projected
    /// ring (or coincides with a neighbour): mean-value weights are unreliable.
    NotStarShaped,
    /// The encoding does not reproduce the rest position in f32 (safety net,
    /// like StretchMesh's bind-time self-test).
    Inexact,
}

impl PinReason {
    pub fn describe(self) -> &'static str {
        match self {
            PinReason::Boundary => "boundary corner without a usable one-ring",
            PinReason::NonManifold => "non-manifold",
            PinReason::Isolated => "isolated",
            PinReason::LowValence => "fewer than 3 neighbours",
            PinReason::HighValence => "too many neighbours",
            PinReason::ZeroArea => "one-ring without area",
            PinReason::NotStarShaped => "one-ring not star-shaped around the vertex",
            PinReason::Inexact => "encoding not reproducible in single precision",
        }
    }
}

/// The pyramid coordinates of a mesh.
#[derive(Debug, Clone)]
pub struct Encoding {
    vertex_count: usize,
    scale_safe: bool,
    /// Encoded vertices, ascending.
    vertices: Vec<u32>,
    /// Per encoded vertex: its neighbours at `ring_offsets[e]..ring_offsets[e+1]`.
    ring_offsets: Vec<u32>,
    ring: Vec<u32>,
    /// Mean-value weight of each neighbour (sum 1 per vertex).
    weights: Vec<f32>,
    /// Scale-safe: elevation tangent of each edge `v − v_j` over the plane.
    tangents: Vec<f32>,
    /// Plain: signed height of the vertex over its ring's plane.
    heights: Vec<f32>,
    pinned: Vec<(u32, PinReason)>,
    mean_edge_length: f32,
}

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

    let mut encoding = Encoding {
        vertex_count: n,
        scale_safe,
        vertices: Vec::new(),
        ring_offsets: vec![0],
        ring: Vec::new(),
        weights: Vec::new(),
        tangents: Vec::new(),
        heights: Vec::new(),
        pinned: Vec::new(),
        mean_edge_length,
    };
    for (v, result) in results.into_iter().enumerate() {
        match result {
            Ok(ring) => {
                encoding.vertices.push(v as u32);
                encoding.ring.extend_from_slice(topology.one_ring(v));
                encoding.ring_offsets.push(encoding.ring.len() as u32);
                encoding.weights.extend_from_slice(&ring.weights);
                encoding.tangents.extend_from_slice(&ring.tangents);
                encoding.heights.push(ring.height);
            }
            Err(reason) => encoding.pinned.push((v as u32, reason)),
        }
    }

    // Self-test: the runtime projection (f32) must give back the rest position.
    // Vertices that fail are pinned, and the encoding is rebuilt without them.
    let tolerance = 1e-4 * mean_edge_length.max(f32::MIN_POSITIVE);
    let inexact: Vec<u32> = (0..encoding.vertices.len())
        .into_par_iter()
        .filter_map(|e| {
            let v = encoding.vertices[e];
            match super::project::target(&encoding, e, rest) {
                Some(t) if (t - rest[v as usize]).length() <= tolerance => None,
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

impl Encoding {
    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }

    pub fn scale_safe(&self) -> bool {
        self.scale_safe
    }

    /// Encoded vertices, ascending.
    pub fn vertices(&self) -> &[u32] {
        &self.vertices
    }

    /// Number of encoded vertices.
    pub fn len(&self) -> usize {
        self.vertices.len()
    }

    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }

    /// Neighbours of encoded vertex `e`, counter-clockwise.
    #[inline]
    pub fn ring(&self, e: usize) -> &[u32] {
        &self.ring[self.ring_range(e)]
    }

    /// Mean-value weights of encoded vertex `e`, in ring order.
    #[inline]
    pub fn weights(&self, e: usize) -> &[f32] {
        &self.weights[self.ring_range(e)]
    }

    /// Scale-safe elevation tangents of encoded vertex `e` (empty in plain mode).
    #[inline]
    pub fn tangents(&self, e: usize) -> &[f32] {
        if self.scale_safe {
            &self.tangents[self.ring_range(e)]
        } else {
            &[]
        }
    }

    /// Plain height of encoded vertex `e` over its ring's plane.
    #[inline]
    pub fn height(&self, e: usize) -> f32 {
        self.heights[e]
    }

    #[inline]
    fn ring_range(&self, e: usize) -> std::ops::Range<usize> {
        self.ring_offsets[e] as usize..self.ring_offsets[e + 1] as usize
    }

    /// Pinned vertices with the reason, ascending.
    pub fn pinned(&self) -> &[(u32, PinReason)] {
        &self.pinned
    }

    /// Pinned vertex indices, ascending.
    pub fn pinned_vertices(&self) -> Vec<u32> {
        self.pinned.iter().map(|p| p.0).collect()
    }

    /// Mean rest edge length: the unit of [`crate::pyramid::PyramidDeformer::residual`].
    pub fn mean_edge_length(&self) -> f32 {
        self.mean_edge_length
    }

    /// Total stored neighbour entries (for bandwidth estimates).
    pub fn ring_entries(&self) -> usize {
        self.ring.len()
    }

    /// A copy with the listed vertices moved to the pinned list as `Inexact`.
    fn without(&self, drop: &[u32]) -> Encoding {
        let mut out = Encoding {
            vertices: Vec::new(),
            ring_offsets: vec![0],
            ring: Vec::new(),
            weights: Vec::new(),
            tangents: Vec::new(),
            heights: Vec::new(),
            pinned: self.pinned.clone(),
            ..*self
        };
        for e in 0..self.vertices.len() {
            let v = self.vertices[e];
            if drop.binary_search(&v).is_ok() {
                out.pinned.push((v, PinReason::Inexact));
                continue;
            }
            out.vertices.push(v);
            out.ring.extend_from_slice(self.ring(e));
            out.ring_offsets.push(out.ring.len() as u32);
            out.weights.extend_from_slice(self.weights(e));
            out.tangents.extend_from_slice(self.tangents(e));
            out.heights.push(self.heights[e]);
        }
        out.pinned.sort_unstable_by_key(|p| p.0);
        out
    }
}
