//! Algorithm 1 of the seed: where the encoding puts a vertex, given the
//! current positions of its neighbours.
//!
//! With `m = Σ w_j x_j` and `h_j` the neighbours' heights over their current
//! plane, the mean-value-weighted projected position is `m − (Σ w_j h_j) n`
//! (mean-value coordinates reproduce linear functions in the plane), so the
//! target is always `m + s·n` with a scalar offset
//! * plain: `s = b − (m − l)·n` (`l` the current ring centroid),
//! * scale-safe: `s = Σ w_j t_j |(m − x_j)_⊥|`, the stored elevation tangents
//!   times the current projected edge lengths, so a uniform scale of the
//!   neighbours scales `s` with them.
//!
//! Scale-safe evaluates `s·n` without normalising the ring's vector area `a`:
//! `|(m − x_j)_⊥| = |(m − x_j) × a| / |a|`, so `s·n = a · Σ w_j t_j |(m − x_j) × a| / |a|²`.
//! That keeps the square root and the division off the path between the two
//! passes over the ring (the four-lane kernel spends its time there
//! otherwise). `a` is first scaled by a power of two, which is exact, to a
//! length near 1, so the products stay as far from overflow and underflow as
//! the edge lengths themselves.
//!
//! Both formulations of the constraint use this frame: the per-vertex target
//! projects to `m + s n`, the linearised row `x_i − Σ w_j x_j` projects to `s n`.

use glam::Vec3;

use super::encoding::Encoding;

/// The exponent field of an f32.
pub(crate) const EXPONENT: u32 = 0x7f80_0000;
/// `REFLECTED_EXPONENT − e` is the exponent field of `2^(127 − E)` for the
/// field `e = E << 23`.
pub(crate) const REFLECTED_EXPONENT: u32 = 0x7f00_0000;

/// The power of two that brings the largest component of `v` (in magnitude)
/// into [1, 2): scaling by it is exact. 0 when that component is 2^127 or
/// more, and not finite when it is infinite or NaN: either way the scaled
/// vector then fails the area check.
#[inline(always)]
pub(crate) fn normalising_power_of_two(v: Vec3) -> f32 {
    let e = (v.x.to_bits() & EXPONENT).max(v.y.to_bits() & EXPONENT).max(v.z.to_bits() & EXPONENT);
    f32::from_bits(REFLECTED_EXPONENT.wrapping_sub(e))
}

/// The local frame of one encoded vertex: target = `mean + lift`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// `Σ w_j x_j`.
    pub mean: Vec3,
    /// `s n`: the signed offset along the current ring normal.
    pub lift: Vec3,
}

impl Frame {
    #[inline]
    pub fn target(&self) -> Vec3 {
        self.mean + self.lift
    }
}

/// The frame of encoded vertex `e` at positions `x`, or `None` when the
/// current ring has collapsed (no normal) or produced a non-finite value.
///
/// The four-lane kernel evaluates exactly these operations in this order.
#[inline]
pub fn frame(encoding: &Encoding, e: usize, x: &[Vec3]) -> Option<Frame> {
    let ring = encoding.ring(e);
    let weights = encoding.weights(e);
    let k = ring.len();
    let origin = x[ring[0] as usize];
    // Vector area relative to the first neighbour: for a closed loop the
    // terms touching it vanish, and the differences keep precision far from
    // the world origin.
    let mut area = Vec3::ZERO;
    let mut previous = x[ring[1] as usize] - origin;
    for j in 2..k {
        let current = x[ring[j] as usize] - origin;
        area += previous.cross(current);
        previous = current;
    }
    let mut mean = Vec3::ZERO;
    for (&j, &w) in ring.iter().zip(weights) {
        mean += w * x[j as usize];
    }
    let lift = if encoding.scale_safe() {
        let a = area * normalising_power_of_two(area);
        let area2 = a.length_squared();
        if !(area2 > 0.0 && area2.is_finite()) {
            return None;
        }
        let mut s = 0.0;
        for ((&j, &w), &t) in ring.iter().zip(weights).zip(encoding.tangents(e)) {
            s += w * t * (mean - x[j as usize]).cross(a).length();
        }
        a * (s / area2)
    } else {
        let length = area.length();
        if !(length > 0.0 && length.is_finite()) {
            return None;
        }
        // One division, then products: what the four-lane kernel does too.
        let normal = area * (1.0 / length);
        let mut centroid = Vec3::ZERO;
        for &j in ring {
            centroid += x[j as usize];
        }
        centroid /= k as f32;
        normal * (encoding.height(e) - (mean - centroid).dot(normal))
    };
    let frame = Frame { mean, lift };
    frame.target().is_finite().then_some(frame)
}

/// The target position of encoded vertex `e`.
#[inline]
pub fn target(encoding: &Encoding, e: usize, x: &[Vec3]) -> Option<Vec3> {
    frame(encoding, e, x).map(|f| f.target())
}

/// `|x_v − target_v|` of encoded vertex `e`. A collapsed ring has no target;
/// its residual is then the distance to the weighted neighbour mean, so that
/// collapse never looks like success.
#[inline]
pub fn residual(encoding: &Encoding, e: usize, x: &[Vec3]) -> f32 {
    let v = encoding.vertices()[e] as usize;
    match frame(encoding, e, x) {
        Some(f) => (x[v] - f.target()).length(),
        None => {
            let mut mean = Vec3::ZERO;
            for (&j, &w) in encoding.ring(e).iter().zip(encoding.weights(e)) {
                mean += w * x[j as usize];
            }
            (x[v] - mean).length()
        }
    }
}
