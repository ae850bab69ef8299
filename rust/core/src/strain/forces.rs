//! The strain limits' forces: one multiplier per edge, kept from iteration
//! to iteration and from frame to frame, so that the limits are part of the
//! solve's fixed point rather than a correction redone after every
//! iteration.
//!
//! A solve iteration of the pyramid constraints and closeness knows nothing
//! of the limits: where a collider tents the skin and the limits draw the
//! material it needs from far around, every iteration pulls that material
//! back towards the input (closeness) and a projection after the iteration
//! has to draw it in again, over the whole stretched region. With the
//! multipliers the limits act in every iteration as the forces they exerted
//! last: [`EdgeForces::apply`] moves each vertex by `W_i · Σ_e λ_e·u_e`
//! (`u_e` the unit vector along edge `e` towards its other end, `W_i` the
//! vertex's inverse mass) after the solver's step, which is where the
//! constrained problem's fixed point puts it (`x = G(x) + W·Jᵀλ`, `G` the
//! iteration). The projection ([`EdgeLimits::project_forces`]) then only
//! corrects what changed, and updates the multipliers, releasing those that
//! pull an edge shorter than its limit: projected Gauss–Seidel on the
//! complementarity conditions of the limits.
//!
//! Where no edge ever reaches its limit every multiplier stays 0 and the
//! solve is exactly the one without limits.

use glam::Vec3;

use super::EdgeLimits;

/// One multiplier `λ_e ≥ 0` per edge of an [`EdgeLimits`], in units of
/// length per inverse mass (a vertex of inverse mass `W` is moved `W·λ`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EdgeForces {
    pub(super) lambda: Vec<f32>,
}

impl EdgeForces {
    /// No force on any edge of `limits`.
    pub fn new(limits: &EdgeLimits) -> Self {
        EdgeForces { lambda: vec![0.0; limits.edges.len()] }
    }

    /// Makes these the forces of `limits`' edges: kept when the edge count is
    /// the same (a sequence's edges never change; new limits on the same
    /// edges start from the forces of the old ones), zero otherwise.
    pub(super) fn fit(&mut self, limits: &EdgeLimits) {
        if self.lambda.len() != limits.edges.len() {
            self.lambda = vec![0.0; limits.edges.len()];
        }
    }

    /// The multipliers, per edge.
    pub fn multipliers(&self) -> &[f32] {
        &self.lambda
    }

    /// Edges holding a force.
    pub fn active(&self) -> usize {
        self.lambda.iter().filter(|&&l| l > 0.0).count()
    }

    /// Forgets every force.
    pub fn clear(&mut self) {
        self.lambda.iter_mut().for_each(|l| *l = 0.0);
    }

    /// Moves every vertex by its edges' forces, `W_i · Σ_e λ_e·u_e` with the
    /// directions `u_e` taken at `x` before any move (the same for both ends,
    /// whatever the order). Unlimited edges hold no force.
    pub fn apply(&self, limits: &EdgeLimits, x: &mut [Vec3], inverse_mass: &[f32]) {
        if self.lambda.len() != limits.edges.len() {
            return;
        }
        let pulls: Vec<(usize, Vec3)> = self
            .lambda
            .iter()
            .enumerate()
            .filter(|(_, &l)| l > 0.0)
            .filter_map(|(e, &l)| {
                let [a, b] = limits.edges[e];
                let delta = x[b as usize] - x[a as usize];
                let length = delta.length();
                (length > 0.0 && length.is_finite()).then(|| (e, delta * (l / length)))
            })
            .collect();
        for (e, pull) in pulls {
            let [a, b] = limits.edges[e].map(|v| v as usize);
            x[a] += pull * inverse_mass[a];
            x[b] -= pull * inverse_mass[b];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::strain::MaxStretch;

    fn chain(n: usize) -> (Vec<Vec3>, Vec<[u32; 2]>) {
        let x = (0..n).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
        let e = (0..n as u32 - 1).map(|i| [i, i + 1]).collect();
        (x, e)
    }

    /// A chain whose ends are pulled apart every "iteration" (a map that
    /// sends each free vertex half way back to where it was pulled, as
    /// closeness does): with the forces applied before the projection, the
    /// projection has nothing left to do once the forces are right, and they
    /// are the same iteration after iteration.
    #[test]
    fn applied_forces_make_the_limited_state_a_fixed_point() {
        let (rest, edges) = chain(6);
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(0.1)).unwrap();
        // The input stretches the chain to 1.5×; the first vertex is held.
        let input: Vec<Vec3> = rest.iter().map(|p| *p * 1.5).collect();
        let mut w = vec![1.0; 6];
        w[0] = 0.0;
        let mut forces = EdgeForces::new(&limits);
        let mut x = input.clone();
        let mut moves = Vec::new();
        for _ in 0..60 {
            // The iteration: half way towards the input.
            let mut next: Vec<Vec3> = x.iter().zip(&input).map(|(x, i)| (*x + *i) * 0.5).collect();
            forces.apply(&limits, &mut next, &w);
            let before = next.clone();
            limits.project_forces(&mut next, &w, &[], &mut forces, 100, 1e-6, 1.0);
            moves.push(before.iter().zip(&next).map(|(a, b)| (*a - *b).length()).fold(0.0, f32::max));
            x = next;
        }
        assert!(limits.worst_ratio(&x) <= 1.0 + 1e-4, "ratio {}", limits.worst_ratio(&x));
        assert!(moves[59] < 1e-4 * moves[0], "the projection still moves {} (first {})", moves[59], moves[0]);
        // Every edge of the stretched chain pulls; the tension grows towards
        // the held end (each vertex further out is pulled back to the input).
        let lambda = forces.multipliers();
        assert!(lambda.iter().all(|&l| l > 0.0), "{lambda:?}");
        assert!(lambda.windows(2).all(|p| p[0] > p[1]), "{lambda:?}");
    }

    /// Once the pull goes, the forces go: a chain at rest releases every
    /// multiplier and ends where the iteration wants it.
    #[test]
    fn forces_no_longer_needed_are_released() {
        let (rest, edges) = chain(6);
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(0.1)).unwrap();
        let mut w = vec![1.0; 6];
        w[0] = 0.0;
        let mut forces = EdgeForces::new(&limits);
        let stretched: Vec<Vec3> = rest.iter().map(|p| *p * 1.5).collect();
        let mut x = stretched.clone();
        limits.project_forces(&mut x, &w, &[], &mut forces, 100, 1e-6, 1.0);
        assert!(forces.active() > 0);
        for _ in 0..200 {
            let mut next: Vec<Vec3> = x.iter().zip(&rest).map(|(x, i)| (*x + *i) * 0.5).collect();
            forces.apply(&limits, &mut next, &w);
            limits.project_forces(&mut next, &w, &[], &mut forces, 100, 1e-6, 1.0);
            x = next;
        }
        assert_eq!(forces.active(), 0, "{:?}", forces.multipliers());
        let off = x.iter().zip(&rest).map(|(a, b)| (*a - *b).length()).fold(0.0, f32::max);
        assert!(off < 1e-4, "{off}");
    }

    #[test]
    fn without_forces_nothing_moves() {
        let (rest, edges) = chain(4);
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(0.1)).unwrap();
        let forces = EdgeForces::new(&limits);
        let mut x: Vec<Vec3> = rest.iter().map(|p| *p * 3.0).collect();
        let before = x.clone();
        forces.apply(&limits, &mut x, &[1.0; 4]);
        assert_eq!(x, before);
    }
}
