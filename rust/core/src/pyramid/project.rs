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
//! Both formulations of the constraint use this frame: the per-vertex target
//! projects to `m + s n`, the linearised row `x_i − Σ w_j x_j` projects to `s n`.

use glam::Vec3;

use super::encode::Encoding;

/// The local frame of one encoded vertex: target = `mean + offset · normal`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// `Σ w_j x_j`.
    pub mean: Vec3,
    /// Unit normal of the current ring polygon.
    pub normal: Vec3,
    /// Signed offset along the normal.
    pub offset: f32,
}

impl Frame {
    #[inline]
    pub fn target(&self) -> Vec3 {
        self.mean + self.offset * self.normal
    }
}

/// The frame of encoded vertex `e` at positions `x`, or `None` when the
/// current ring has collapsed (no normal) or produced a non-finite value.
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
    let length = area.length();
    if !(length > 0.0 && length.is_finite()) {
        return None;
    }
    // One division, then products: what the four-lane kernel does too.
    let normal = area * (1.0 / length);
    let mut mean = Vec3::ZERO;
    for (&j, &w) in ring.iter().zip(weights) {
        mean += w * x[j as usize];
    }
    let offset = if encoding.scale_safe() {
        let mut s = 0.0;
        for ((&j, &w), &t) in ring.iter().zip(weights).zip(encoding.tangents(e)) {
            let d = mean - x[j as usize];
            let along = d.dot(normal);
            s += w * t * (d.length_squared() - along * along).max(0.0).sqrt();
        }
        s
    } else {
        let mut centroid = Vec3::ZERO;
        for &j in ring {
            centroid += x[j as usize];
        }
        centroid /= k as f32;
        encoding.height(e) - (mean - centroid).dot(normal)
    };
    let frame = Frame {
        mean,
        normal,
        offset,
    };
    (frame.mean.is_finite() && frame.offset.is_finite()).then_some(frame)
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
