//! Strain limits: no skin edge longer than `(1 + ε)` times its rest length.
//!
//! Seed 002 §2 (constitutive strain limiting, after Li et al. 2021): the
//! limit is an inequality per edge, `l_e ≤ (1 + ε_e)·l_e⁰`. Here it is a
//! projection — an over-long edge is shortened to its limit, the correction
//! split between its ends by their inverse masses — so that it can run in the
//! same projection loop as the contacts ([`crate::sequence::StrainMode`]).
//!
//! The sweep is Gauss–Seidel in edge order: sequential, hence deterministic,
//! and it converges much faster than a Jacobi average on the long chains of
//! stretched edges a dragging collider makes. Only over-long edges do work.
//! Where the material an over-stretched region needs lies many edges away,
//! the sweeps still carry it one edge each: [`Hierarchy`] (`multilevel`)
//! moves whole blocks of vertices first, and over-relaxed sweeps
//! ([`EdgeLimits::project_relaxed`]) finish what it leaves.

use glam::Vec3;

mod along;
mod multilevel;
pub use multilevel::Hierarchy;

use crate::mesh::validate_positions;
use crate::{Error, Result};

/// How far each part of the skin may stretch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MaxStretch<'a> {
    /// The same ε on every edge.
    Uniform(f32),
    /// One ε per vertex (`f32::INFINITY` = no limit); an edge takes the mean
    /// of its two ends, so an edge leaving the limited region is unlimited.
    PerVertex(&'a [f32]),
}

/// Rest lengths and length limits of the skin's edges.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EdgeLimits {
    edges: Vec<[u32; 2]>,
    rest: Vec<f32>,
    /// `(1 + ε_e)·rest_e`, infinite where unlimited.
    limit: Vec<f32>,
    /// CSR of the edges at each vertex: `edges_at[at[v]..at[v + 1]]`.
    at: Vec<u32>,
    edges_at: Vec<u32>,
}

/// Checks ε: 0 or more (infinite for no limit), one per vertex when per vertex.
pub fn validate_max_stretch(stretch: MaxStretch<'_>, vertex_count: usize) -> Result<()> {
    let check = |what: String, eps: f32| -> Result<()> {
        if eps.is_nan() || eps < 0.0 {
            return Err(Error::invalid(format!("{what} is {eps}; it must be 0 or more (infinite for no limit)")));
        }
        Ok(())
    };
    match stretch {
        MaxStretch::Uniform(eps) => check("max stretch".into(), eps),
        MaxStretch::PerVertex(eps) => {
            if eps.len() != vertex_count {
                return Err(Error::invalid(format!("max stretch has {} values but the mesh has {vertex_count} vertices", eps.len())));
            }
            eps.iter().enumerate().try_for_each(|(v, &e)| check(format!("max stretch of vertex {v}"), e))
        }
    }
}

/// Lifts `p` onto its plane (`n·x ≥ level`, see [`EdgeLimits::project_above`])
/// where it is below it; no plane, or a zero `n`, leaves it.
pub fn keep_above(p: &mut Vec3, plane: Option<&(Vec3, f32)>) {
    if let Some(&(n, level)) = plane {
        let h = n.dot(*p);
        if h < level {
            *p += n * (level - h);
        }
    }
}

impl EdgeLimits {
    /// Limits for `edges` of a mesh at rest at `rest_positions`.
    pub fn new(edges: &[[u32; 2]], rest_positions: &[Vec3], stretch: MaxStretch<'_>) -> Result<Self> {
        let n = rest_positions.len();
        validate_positions("rest positions", rest_positions)?;
        if let Some(e) = edges.iter().position(|e| e.iter().any(|&v| v as usize >= n)) {
            return Err(Error::invalid(format!("edge {e} refers to a vertex beyond the {n} vertices")));
        }
        validate_max_stretch(stretch, n)?;
        let per_vertex: Option<&[f32]> = match stretch {
            MaxStretch::Uniform(_) => None,
            MaxStretch::PerVertex(eps) => Some(eps),
        };
        let rest: Vec<f32> = edges
            .iter()
            .map(|&[a, b]| (rest_positions[a as usize] - rest_positions[b as usize]).length())
            .collect();
        let limit = edges
            .iter()
            .zip(&rest)
            .map(|(&[a, b], &l0)| {
                let eps = match (stretch, per_vertex) {
                    (_, Some(eps)) => 0.5 * (eps[a as usize] + eps[b as usize]),
                    (MaxStretch::Uniform(eps), None) => eps,
                    (MaxStretch::PerVertex(_), None) => unreachable!("per-vertex values checked above"),
                };
                // A degenerate rest edge has no meaningful ratio: leave it free.
                if l0 > 0.0 { (1.0 + eps) * l0 } else { f32::INFINITY }
            })
            .collect();
        let mut at = vec![0u32; n + 1];
        for &[a, b] in edges {
            at[a as usize + 1] += 1;
            at[b as usize + 1] += 1;
        }
        for v in 0..n {
            at[v + 1] += at[v];
        }
        let mut fill = at.clone();
        let mut edges_at = vec![0u32; at[n] as usize];
        for (e, &[a, b]) in edges.iter().enumerate() {
            for v in [a as usize, b as usize] {
                edges_at[fill[v] as usize] = e as u32;
                fill[v] += 1;
            }
        }
        Ok(EdgeLimits { edges: edges.to_vec(), rest, limit, at, edges_at })
    }

    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }

    pub fn rest_lengths(&self) -> &[f32] {
        &self.rest
    }

    /// Largest `l_e / limit_e` over the limited edges (≤ 1 when every limit
    /// holds; 0 when no edge is limited).
    pub fn worst_ratio(&self, x: &[Vec3]) -> f32 {
        self.edges
            .iter()
            .zip(&self.limit)
            .filter(|(_, l)| l.is_finite())
            .map(|(&[a, b], &l)| (x[a as usize] - x[b as usize]).length() / l)
            .fold(0.0, f32::max)
    }

    /// Whether an edge at vertex `v` is longer than `(1 + tolerance)` times
    /// its limit in `x`.
    pub(crate) fn past_limit_at(&self, x: &[Vec3], v: u32, tolerance: f32) -> bool {
        let v = v as usize;
        self.edges_at[self.at[v] as usize..self.at[v + 1] as usize].iter().any(|&e| {
            let ([a, b], limit) = (self.edges[e as usize], self.limit[e as usize]);
            (x[a as usize] - x[b as usize]).length() > (1.0 + tolerance) * limit
        })
    }

    /// Largest `l_e / rest_e` over the limited edges.
    pub fn worst_stretch(&self, x: &[Vec3]) -> f32 {
        self.edges
            .iter()
            .zip(self.rest.iter().zip(&self.limit))
            .filter(|(_, (_, l))| l.is_finite())
            .map(|(&[a, b], (&l0, _))| (x[a as usize] - x[b as usize]).length() / l0)
            .fold(0.0, f32::max)
    }

    /// Up to `sweeps` Gauss–Seidel sweeps shortening every edge longer than
    /// its limit to the limit; a vertex with inverse mass 0 does not move.
    /// Stops early once no edge exceeds its limit by more than `tolerance`
    /// (relative). Returns the number of sweeps run.
    pub fn project(&self, x: &mut [Vec3], inverse_mass: &[f32], sweeps: usize, tolerance: f32) -> usize {
        self.project_above(x, inverse_mass, &[], sweeps, tolerance)
    }

    /// [`Self::project`], keeping every vertex `v` that has a plane
    /// (`above[v] = (n, level)` with a unit `n`; a zero `n` is none) in its
    /// half-space `n·x ≥ level`: an end an edge correction pushes below its
    /// plane is projected back onto it, so that it moves only along the
    /// plane or away from it (a contact slides along the collider, never
    /// into it). An edge limit and a half-space are both convex, so the
    /// sweeps head for a point of all of them where there is one. `above`
    /// is empty or has one entry per vertex.
    ///
    /// The first sweep visits every edge; later ones only the edges at the
    /// vertices the sweep before moved (the others were within their limit
    /// when last visited and their ends have not moved since), in edge
    /// order, so the work follows the stretched region, not the mesh.
    pub fn project_above(&self, x: &mut [Vec3], inverse_mass: &[f32], above: &[(Vec3, f32)], sweeps: usize, tolerance: f32) -> usize {
        self.project_relaxed(x, inverse_mass, above, sweeps, tolerance, 1.0)
    }

    /// [`Self::project_above`] with over-relaxation: each over-long edge is
    /// shortened by `relaxation` (in `[1, 2)`) times its excess, so it ends a
    /// little below its limit and the sweeps carry a correction further
    /// (projected successive over-relaxation; both the limits and the
    /// half-spaces are convex, so the sweeps still head for a point of all
    /// of them). Used after [`Hierarchy::project`], where the remaining
    /// excess is spread thin over long chains of edges at their limit.
    pub fn project_relaxed(
        &self,
        x: &mut [Vec3],
        inverse_mass: &[f32],
        above: &[(Vec3, f32)],
        sweeps: usize,
        tolerance: f32,
        relaxation: f32,
    ) -> usize {
        let keep = |p: &mut Vec3, v: usize| keep_above(p, above.get(v));
        // The edges of the next sweep: all of them (`full`), or those at the
        // vertices this sweep moved, each vertex listed once (`mark` holds the
        // sweep that last listed it). Where most of the mesh moves, listing
        // them costs more than visiting every edge, so the next sweep is
        // full again.
        let mut full = true;
        let mut active: Vec<u32> = Vec::new();
        let mut moved: Vec<u32> = Vec::new();
        let mut mark: Vec<usize> = vec![usize::MAX; x.len()];
        let mut listed: Vec<u64> = Vec::new();
        for sweep in 0..sweeps {
            let mut worst = 0.0f32;
            let visit: &mut dyn Iterator<Item = usize> = if full { &mut (0..self.edges.len()) } else { &mut active.iter().map(|&e| e as usize) };
            let mut moves = |v: usize, moved: &mut Vec<u32>| {
                if mark[v] != sweep {
                    mark[v] = sweep;
                    moved.push(v as u32);
                }
            };
            for e in visit {
                let ([a, b], limit) = (self.edges[e], self.limit[e]);
                let (a, b) = (a as usize, b as usize);
                let delta = x[a] - x[b];
                let length = delta.length();
                #[allow(clippy::neg_cmp_op_on_partial_ord)] // a NaN length must not count as within
                if !(length > limit) {
                    continue;
                }
                worst = worst.max(length / limit - 1.0);
                let (wa, wb) = (inverse_mass[a], inverse_mass[b]);
                let w = wa + wb;
                if w <= 0.0 {
                    continue;
                }
                let correction = delta * ((length - limit) * relaxation / (length * w));
                if wa > 0.0 {
                    x[a] -= correction * wa;
                    keep(&mut x[a], a);
                    moves(a, &mut moved);
                }
                if wb > 0.0 {
                    x[b] += correction * wb;
                    keep(&mut x[b], b);
                    moves(b, &mut moved);
                }
            }
            if worst <= tolerance || moved.is_empty() {
                return sweep + 1;
            }
            full = moved.len() > x.len() / 8;
            if !full {
                // The edges at the moved vertices, in edge order: marked in a
                // bit set and read back word by word (sorting the list took a
                // fifth of the flesh benchmark's unified step, more than the
                // sweeps themselves).
                let words = self.edges.len().div_ceil(64);
                if listed.len() != words {
                    listed = vec![0u64; words];
                }
                let (mut lowest, mut highest) = (usize::MAX, 0usize);
                for &v in &moved {
                    let v = v as usize;
                    for &e in &self.edges_at[self.at[v] as usize..self.at[v + 1] as usize] {
                        let w = e as usize / 64;
                        listed[w] |= 1 << (e % 64);
                        lowest = lowest.min(w);
                        highest = highest.max(w);
                    }
                }
                active.clear();
                for w in lowest..=highest.max(lowest) {
                    let Some(word) = listed.get_mut(w) else { break };
                    let mut bits = std::mem::take(word);
                    while bits != 0 {
                        active.push((w * 64) as u32 + bits.trailing_zeros());
                        bits &= bits - 1;
                    }
                }
            }
            moved.clear();
        }
        sweeps
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chain(n: usize) -> (Vec<Vec3>, Vec<[u32; 2]>) {
        let x = (0..n).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
        let e = (0..n as u32 - 1).map(|i| [i, i + 1]).collect();
        (x, e)
    }

    #[test]
    fn an_over_stretched_chain_is_brought_back_within_its_limit() {
        let (rest, edges) = chain(20);
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(0.1)).unwrap();
        // Both ends pulled out to twice the length; the first end is fixed.
        let mut x: Vec<Vec3> = rest.iter().map(|p| *p * 2.0).collect();
        let mut w = vec![1.0; 20];
        w[0] = 0.0;
        let sweeps = limits.project(&mut x, &w, 5000, 1e-3);
        assert!(sweeps < 5000, "did not converge");
        assert!(limits.worst_ratio(&x) <= 1.0 + 1e-3, "ratio {}", limits.worst_ratio(&x));
        assert!(limits.worst_stretch(&x) <= 1.1 * (1.0 + 1e-3));
        assert_eq!(x[0], Vec3::ZERO, "a vertex of inverse mass 0 moved");
    }

    #[test]
    fn a_vertex_is_past_its_limit_where_one_of_its_own_edges_is() {
        let (rest, edges) = chain(4);
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(0.1)).unwrap();
        // Only the edge 2–3 is long: 1.2 against a limit of 1.1.
        let x = [0.0, 1.0, 2.0, 3.2].map(|t| Vec3::new(t, 0.0, 0.0));
        let past: Vec<bool> = (0..4).map(|v| limits.past_limit_at(&x, v, 0.01)).collect();
        assert_eq!(past, [false, false, true, true]);
        // 1.2 is within 10 % of the limit.
        assert!(!limits.past_limit_at(&x, 3, 0.1));
    }

    #[test]
    fn a_vertex_on_its_plane_slides_along_it_instead_of_crossing_it() {
        // A fixed vertex below a plane z ≥ 0 and a free one resting on it,
        // stretched sideways: shortening the edge straight would pull the
        // free one under the plane; it slides along it instead.
        let rest = [Vec3::new(0.0, 0.0, -1.0), Vec3::ZERO];
        let limits = EdgeLimits::new(&[[0, 1]], &rest, MaxStretch::Uniform(0.1)).unwrap();
        let mut x = vec![rest[0], Vec3::new(2.0, 0.0, 0.0)];
        let above = [(Vec3::ZERO, 0.0), (Vec3::Z, 0.0)];
        let sweeps = limits.project_above(&mut x, &[0.0, 1.0], &above, 1000, 1e-4);
        assert!(sweeps < 1000, "did not converge");
        assert!(limits.worst_ratio(&x) <= 1.0 + 1e-4, "ratio {}", limits.worst_ratio(&x));
        assert!(x[1].z >= -1e-6, "crossed its plane: {:?}", x[1]);
        assert!(x[1].x > 0.0 && x[1].x < 0.46, "slid to {:?}", x[1]);
        // Without the plane the same projection pulls it under.
        let mut free = vec![rest[0], Vec3::new(2.0, 0.0, 0.0)];
        limits.project(&mut free, &[0.0, 1.0], 1000, 1e-4);
        assert!(free[1].z < -0.1, "{:?}", free[1]);
    }

    #[test]
    fn over_relaxed_sweeps_reach_the_limit_in_fewer_sweeps() {
        // A long chain pulled out to twice its length from a fixed end: the
        // excess has to travel the whole chain.
        let (rest, edges) = chain(60);
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(0.1)).unwrap();
        let mut w = vec![1.0; 60];
        w[0] = 0.0;
        let start: Vec<Vec3> = rest.iter().map(|p| *p * 2.0).collect();
        let sweeps = |relaxation: f32| {
            let mut x = start.clone();
            let n = limits.project_relaxed(&mut x, &w, &[], 100_000, 1e-3, relaxation);
            assert!(limits.worst_ratio(&x) <= 1.0 + 1e-3, "relaxation {relaxation}: ratio {}", limits.worst_ratio(&x));
            assert_eq!(x[0], Vec3::ZERO);
            n
        };
        let (plain, relaxed) = (sweeps(1.0), sweeps(1.6));
        assert!(relaxed * 2 < plain, "{plain} plain sweeps, {relaxed} over-relaxed");
    }

    #[test]
    fn edges_within_the_limit_are_untouched() {
        let (rest, edges) = chain(5);
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(0.1)).unwrap();
        let mut x: Vec<Vec3> = rest.iter().map(|p| *p * 1.05).collect();
        let before = x.clone();
        limits.project(&mut x, &[1.0; 5], 10, 0.0);
        assert_eq!(x, before);
    }

    #[test]
    fn per_vertex_limits_leave_unlimited_edges_free() {
        let (rest, edges) = chain(3);
        let eps = [0.0, 0.0, f32::INFINITY];
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::PerVertex(&eps)).unwrap();
        let mut x = vec![Vec3::ZERO, Vec3::X * 2.0, Vec3::X * 10.0];
        limits.project(&mut x, &[1.0; 3], 100, 0.0);
        assert!(((x[1] - x[0]).length() - 1.0).abs() < 1e-4);
        assert!((x[2] - x[1]).length() > 5.0, "an unlimited edge was shortened");
    }

    #[test]
    fn bad_limits_are_named() {
        let (rest, edges) = chain(3);
        let err = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(-1.0)).unwrap_err().to_string();
        assert!(err.contains("max stretch"), "{err}");
        let err = EdgeLimits::new(&edges, &rest, MaxStretch::PerVertex(&[0.1, f32::NAN, 0.1])).unwrap_err().to_string();
        assert!(err.contains("vertex 1"), "{err}");
        let err = EdgeLimits::new(&edges, &rest, MaxStretch::PerVertex(&[0.1])).unwrap_err().to_string();
        assert!(err.contains("3 vertices"), "{err}");
    }
}
