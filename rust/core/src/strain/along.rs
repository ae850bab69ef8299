//! How far a patch of skin exceeds its edge limits along a direction: the
//! fine edges' excess restricted to the multilevel blocks.
//!
//! A coarse block pair of [`super::Hierarchy`] stands for the skin between
//! two block centres. Measured by the chord between them, a pair on a
//! collider's curved side sees the skin shorter than it is (over a sphere
//! of radius 0.3, a block 27 edges across loses ~1.6 % to the chord) and so
//! sees none of the ~1 % excess the last rounds of the unified pass work
//! on. Measured by the edges themselves it sees it wherever it is: each
//! edge adds its excess over its limit and its limit, both weighted by how
//! much the edge points along the pair, `(d̂·u)²`; summed over the edges
//! between the two centres, their quotient is the relative excess of the
//! skin along the pair, whatever the skin's bend.
//!
//! The weights are a quadratic form in `u`, so a block's or a pair's edges
//! sum to two symmetric 3 × 3 tensors, summed again level by level: one
//! pass over the edges a cycle, not one per pair.

use glam::Vec3;

/// A symmetric 3 × 3 tensor: xx, yy, zz, xy, xz, yz.
type Symmetric = [f32; 6];

/// `w·d̂d̂ᵀ` for a unit `d̂`.
fn outer(d: Vec3, w: f32) -> Symmetric {
    [w * d.x * d.x, w * d.y * d.y, w * d.z * d.z, w * d.x * d.y, w * d.x * d.z, w * d.y * d.z]
}

/// `uᵀ·t·u`.
fn along(t: &Symmetric, u: Vec3) -> f32 {
    t[0] * u.x * u.x + t[1] * u.y * u.y + t[2] * u.z * u.z + 2.0 * (t[3] * u.x * u.y + t[4] * u.x * u.z + t[5] * u.y * u.z)
}

/// Edges' excess over their limits and their limits, each as a tensor of
/// their directions (see the module's doc).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(super) struct Excess {
    excess: Symmetric,
    limit: Symmetric,
}

impl Excess {
    /// One edge from end to end `d`, of length limit `limit` (finite); an
    /// edge of no length adds nothing.
    pub(super) fn of_edge(d: Vec3, limit: f32) -> Excess {
        let length = d.length();
        if length.is_nan() || length <= 0.0 {
            return Excess::default();
        }
        let unit = d / length;
        let over = (length - limit).max(0.0);
        Excess { excess: if over > 0.0 { outer(unit, over) } else { [0.0; 6] }, limit: outer(unit, limit) }
    }

    /// Adds `weight` times `other`.
    pub(super) fn add(&mut self, other: &Excess, weight: f32) {
        for k in 0..6 {
            self.excess[k] += weight * other.excess[k];
            self.limit[k] += weight * other.limit[k];
        }
    }

    /// The skin's length along the unit `u` over its limit there: 1 where
    /// no edge along `u` exceeds its limit (or there are no edges), more
    /// where some do. Edges within their limits do not make up for those
    /// beyond: slack beside an over-long edge does not shorten it.
    pub(super) fn ratio_along(&self, u: Vec3) -> f32 {
        let limit = along(&self.limit, u);
        if limit > 0.0 { 1.0 + along(&self.excess, u).max(0.0) / limit } else { 1.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_chain_stretched_in_one_edge_counts_its_share_of_the_length() {
        // Three unit edges along x at their limit 1, one of them 1.3 long.
        let mut sum = Excess::default();
        for length in [1.0, 1.3, 1.0] {
            sum.add(&Excess::of_edge(Vec3::X * length, 1.0), 1.0);
        }
        assert!((sum.ratio_along(Vec3::X) - 1.1).abs() < 1e-6, "{}", sum.ratio_along(Vec3::X));
        // Across the chain there is nothing to shorten.
        assert_eq!(sum.ratio_along(Vec3::Y), 1.0);
    }

    #[test]
    fn slack_does_not_hide_excess_and_bends_do_not_matter() {
        // An edge 10 % over its limit beside one 10 % under it: the excess stays.
        let mut sum = Excess::of_edge(Vec3::X * 1.1, 1.0);
        sum.add(&Excess::of_edge(Vec3::X * 0.9, 1.0), 1.0);
        assert!((sum.ratio_along(Vec3::X) - 1.05).abs() < 1e-6);
        // Two edges 10 % over, bent by 20° each way from the measuring
        // direction: the chord between their ends is shorter than the two,
        // but the excess along it is still the edges' 10 %.
        let (c, s) = (20f32.to_radians().cos(), 20f32.to_radians().sin());
        let mut bent = Excess::of_edge(Vec3::new(c, s, 0.0) * 1.1, 1.0);
        bent.add(&Excess::of_edge(Vec3::new(c, -s, 0.0) * 1.1, 1.0), 1.0);
        assert!((bent.ratio_along(Vec3::X) - 1.1).abs() < 1e-6, "{}", bent.ratio_along(Vec3::X));
    }
}
