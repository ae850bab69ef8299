//! Fast projection of the edges at their limit (Goldenthal et al. 2007,
//! "Efficient Simulation of Inextensible Cloth"), with contact planes.
//!
//! Gauss–Seidel sweeps carry a correction about one edge per sweep, so a band
//! of `k` edges at their limit, all of which must give a little for the worst
//! one to hold, takes on the order of `k²` sweeps (on the flesh benchmark a
//! band some 50 edges wide took 14 rounds of 4 × 16 sweeps to go from 1.054
//! to 1.0075 of the limit). Here the active constraints are solved together:
//! Newton steps on the constraint manifold, each solving
//! `(J M⁻¹ Jᵀ) δλ = −C` over the active constraints only (preconditioned
//! conjugate gradients, matrix-free: the matrix is sparse, symmetric positive
//! definite and as large as the active set, not the mesh) and moving
//! `x += M⁻¹ Jᵀ δλ`. A few steps reach the limit, the work follows the band.
//!
//! The constraints, each written `c(x) ≥ 0`:
//! * an edge at (or within [`HYSTERESIS`] of) its limit: `L − |x_a − x_b|`;
//! * a vertex on its contact plane (`n·x ≥ level`, the plane of its last push
//!   out of a collider): `n·x − level`, active where it touches.
//!
//! Both are inequalities: a constraint whose accumulated multiplier turns
//! negative (an edge pushing its ends apart, a plane pulling its vertex in)
//! leaves the set and comes back only if violated again. Everything runs in
//! a fixed order on one thread, so results do not depend on the thread count.

use glam::{DVec3, Vec3};

use super::EdgeLimits;

/// Edges this close to their limit (relative) join the active set, so that
/// the step does not stretch the band's edges that only just hold.
const HYSTERESIS: f32 = 1e-3;
/// A vertex this close above its plane (relative to its edges' limits) is
/// touching it.
const TOUCHING: f32 = 1e-3;
/// Diagonal regularisation of `J M⁻¹ Jᵀ`, relative to its diagonal: the
/// active set can hold more constraints than a patch has degrees of freedom
/// (a vertex on its plane with every edge at its limit), and there the
/// matrix is only semi-definite.
const REGULARISATION: f64 = 1e-6;
/// Halvings of a Newton step that increases the violation, at most.
const LINE_SEARCH_HALVINGS: usize = 8;
/// Conjugate-gradient iterations per Newton step, at most.
const MAX_CG_ITERATIONS: usize = 4000;

/// What [`EdgeLimits::project_fast`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FastProjection {
    /// Every limit holds within the tolerance and every active plane holds.
    pub converged: bool,
    /// Newton steps run.
    pub steps: usize,
    /// Largest active set of a step (edges and planes).
    pub constraints: usize,
    /// Conjugate-gradient iterations over all steps.
    pub cg_iterations: usize,
}

/// One active constraint: up to two vertices (local indices; the second is
/// `NONE` for a plane) with the constraint's gradient at each.
struct Row {
    vertices: [u32; 2],
    gradient: [DVec3; 2],
    /// The constraint's value (negative when violated).
    value: f64,
    /// Length scale the residual is measured in.
    scale: f64,
    /// Edge index, or `edges.len() + vertex` for a plane.
    id: usize,
}

const NONE: u32 = u32::MAX;

impl EdgeLimits {
    /// Brings every limited edge within `tolerance` (relative) of its limit
    /// while keeping the vertices that have a plane (`above`, as in
    /// [`Self::project_above`]) on or above it, in at most `max_steps` Newton
    /// steps. A vertex with inverse mass 0 does not move. When the steps do
    /// not converge, `x` is left at the best iterate (the one with the least
    /// violation, the start included), so a fallback can take over from
    /// there.
    pub fn project_fast(
        &self,
        x: &mut [Vec3],
        inverse_mass: &[f32],
        above: &[(Vec3, f32)],
        tolerance: f32,
        max_steps: usize,
    ) -> FastProjection {
        let n = x.len();
        let mut outcome = FastProjection::default();
        // Per constraint (edges, then planes): accumulated multiplier, and
        // whether it left the set with the wrong sign.
        let mut lambda = vec![0f64; self.edges.len() + n];
        let mut dropped = vec![false; self.edges.len() + n];
        let mut local = vec![NONE; n];
        let mut vertices: Vec<u32> = Vec::new();
        let mut rows: Vec<Row> = Vec::new();
        let mut best: Option<(f32, Vec<Vec3>)> = None;
        let plane_of = |v: usize| above.get(v).filter(|(normal, _)| *normal != Vec3::ZERO);
        loop {
            // The active set, and how far the worst constraint is violated
            // (relative to its limit, planes to their edges' limits).
            for &v in &vertices {
                local[v as usize] = NONE;
            }
            vertices.clear();
            rows.clear();
            let mut worst = 0.0f32;
            let mut index = |v: usize, vertices: &mut Vec<u32>| -> u32 {
                if local[v] == NONE {
                    local[v] = vertices.len() as u32;
                    vertices.push(v as u32);
                }
                local[v]
            };
            for (e, (&[a, b], &limit)) in self.edges.iter().zip(&self.limit).enumerate() {
                let (a, b) = (a as usize, b as usize);
                if !limit.is_finite() || inverse_mass[a] + inverse_mass[b] <= 0.0 {
                    continue;
                }
                let delta = x[a] - x[b];
                let length = delta.length();
                let ratio = length / limit;
                worst = worst.max(ratio - 1.0);
                let joins = ratio >= 1.0 - HYSTERESIS && !(dropped[e] && ratio <= 1.0);
                if !joins || length <= 0.0 {
                    continue;
                }
                let u = (delta / length).as_dvec3();
                let (la, lb) = (index(a, &mut vertices), index(b, &mut vertices));
                rows.push(Row {
                    vertices: [la, lb],
                    gradient: [-u, u],
                    value: f64::from(limit - length),
                    scale: f64::from(limit),
                    id: e,
                });
            }
            // Planes at the active edges' free ends.
            let edge_rows = rows.len();
            let mut scale_at = vec![f32::INFINITY; vertices.len()];
            for row in &rows[..edge_rows] {
                for &v in &row.vertices {
                    scale_at[v as usize] = scale_at[v as usize].min(row.scale as f32);
                }
            }
            for l in 0..vertices.len() {
                let v = vertices[l] as usize;
                let Some(&(normal, level)) = plane_of(v) else {
                    continue;
                };
                if inverse_mass[v] <= 0.0 {
                    continue;
                }
                let gap = normal.dot(x[v]) - level;
                let scale = scale_at[l];
                worst = worst.max(-gap / scale);
                let id = self.edges.len() + v;
                if gap > TOUCHING * scale || (dropped[id] && gap >= 0.0) {
                    continue;
                }
                rows.push(Row {
                    vertices: [l as u32, NONE],
                    gradient: [normal.as_dvec3(), DVec3::ZERO],
                    value: f64::from(gap),
                    scale: f64::from(scale),
                    id,
                });
            }
            outcome.constraints = outcome.constraints.max(rows.len());
            if best.as_ref().is_none_or(|(w, _)| worst < *w) {
                best = Some((worst, x.to_vec()));
            }
            if worst <= tolerance {
                outcome.converged = true;
                return outcome;
            }
            if outcome.steps == max_steps || rows.is_empty() {
                break;
            }
            outcome.steps += 1;
            let weights: Vec<f64> = vertices
                .iter()
                .map(|&v| f64::from(inverse_mass[v as usize]))
                .collect();
            let (step, iterations) = solve(&rows, &weights, tolerance);
            outcome.cg_iterations += iterations;
            // x += M⁻¹ Jᵀ δλ.
            let mut moves = vec![DVec3::ZERO; vertices.len()];
            for (row, &d) in rows.iter().zip(&step) {
                for (&v, g) in row.vertices.iter().zip(&row.gradient) {
                    if v != NONE {
                        moves[v as usize] += *g * d;
                    }
                }
            }
            // Backtracking: the linearised step can overshoot far from the
            // manifold (a long chain shortened by a third folds over); halve
            // it until the violation drops.
            let origin: Vec<Vec3> = vertices.iter().map(|&v| x[v as usize]).collect();
            let before = self.violation(x, inverse_mass, above);
            let mut fraction = 1.0;
            for _ in 0..LINE_SEARCH_HALVINGS {
                for (((&v, m), &w), o) in vertices.iter().zip(&moves).zip(&weights).zip(&origin) {
                    x[v as usize] = *o + (*m * (w * fraction)).as_vec3();
                }
                if self.violation(x, inverse_mass, above) < before {
                    break;
                }
                fraction *= 0.5;
            }
            for (row, &d) in rows.iter().zip(&step) {
                lambda[row.id] += d;
                dropped[row.id] = lambda[row.id] < 0.0;
            }
        }
        if let Some((_, best)) = best {
            x.copy_from_slice(&best);
        }
        outcome
    }
}

impl EdgeLimits {
    /// Sum of squared excesses: of the limited edges over their limits and
    /// of the planed vertices below their planes (the line search's merit).
    fn violation(&self, x: &[Vec3], inverse_mass: &[f32], above: &[(Vec3, f32)]) -> f64 {
        let edges: f64 = self
            .edges
            .iter()
            .zip(&self.limit)
            .filter(|(&[a, b], l)| {
                l.is_finite() && inverse_mass[a as usize] + inverse_mass[b as usize] > 0.0
            })
            .map(|(&[a, b], &l)| {
                f64::from(((x[a as usize] - x[b as usize]).length() - l).max(0.0)).powi(2)
            })
            .sum();
        let planes: f64 = above
            .iter()
            .zip(x)
            .zip(inverse_mass)
            .filter(|((&(normal, _), _), &w)| normal != Vec3::ZERO && w > 0.0)
            .map(|((&(normal, level), p), _)| f64::from((level - normal.dot(*p)).max(0.0)).powi(2))
            .sum();
        edges + planes
    }
}

/// Solves `(J W Jᵀ + αD) δλ = −C` for the rows' multipliers by conjugate
/// gradients preconditioned with the diagonal, to a residual of a tenth of
/// `tolerance` times each row's scale. Returns `δλ` and the iterations.
fn solve(rows: &[Row], weights: &[f64], tolerance: f32) -> (Vec<f64>, usize) {
    let m = rows.len();
    let diagonal: Vec<f64> = rows
        .iter()
        .map(|row| {
            let d: f64 = row
                .vertices
                .iter()
                .zip(&row.gradient)
                .filter(|(v, _)| **v != NONE)
                .map(|(v, g)| weights[*v as usize] * g.length_squared())
                .sum();
            d * (1.0 + REGULARISATION) + f64::MIN_POSITIVE
        })
        .collect();
    let mut scratch = vec![DVec3::ZERO; weights.len()];
    let mut apply = |p: &[f64], out: &mut [f64]| {
        scratch.iter_mut().for_each(|s| *s = DVec3::ZERO);
        for (row, &pk) in rows.iter().zip(p) {
            for (&v, g) in row.vertices.iter().zip(&row.gradient) {
                if v != NONE {
                    scratch[v as usize] += *g * pk;
                }
            }
        }
        for (k, row) in rows.iter().enumerate() {
            let mut sum = diagonal[k] * REGULARISATION / (1.0 + REGULARISATION) * p[k];
            for (&v, g) in row.vertices.iter().zip(&row.gradient) {
                if v != NONE {
                    sum += weights[v as usize] * g.dot(scratch[v as usize]);
                }
            }
            out[k] = sum;
        }
    };
    let limit: Vec<f64> = rows
        .iter()
        .map(|row| 0.1 * f64::from(tolerance) * row.scale)
        .collect();
    let holds = |r: &[f64]| r.iter().zip(&limit).all(|(r, l)| r.abs() <= *l);
    let mut solution = vec![0f64; m];
    let mut residual: Vec<f64> = rows.iter().map(|row| -row.value).collect();
    if holds(&residual) {
        return (solution, 0);
    }
    let mut z: Vec<f64> = residual.iter().zip(&diagonal).map(|(r, d)| r / d).collect();
    let mut direction = z.clone();
    let mut rz: f64 = residual.iter().zip(&z).map(|(r, z)| r * z).sum();
    let mut product = vec![0f64; m];
    for iteration in 1..=MAX_CG_ITERATIONS {
        apply(&direction, &mut product);
        let curvature: f64 = direction.iter().zip(&product).map(|(p, q)| p * q).sum();
        if !(curvature > 0.0) {
            return (solution, iteration);
        }
        let alpha = rz / curvature;
        for k in 0..m {
            solution[k] += alpha * direction[k];
            residual[k] -= alpha * product[k];
        }
        if holds(&residual) {
            return (solution, iteration);
        }
        for k in 0..m {
            z[k] = residual[k] / diagonal[k];
        }
        let next: f64 = residual.iter().zip(&z).map(|(r, z)| r * z).sum();
        let beta = next / rz;
        rz = next;
        for k in 0..m {
            direction[k] = z[k] + beta * direction[k];
        }
    }
    (solution, MAX_CG_ITERATIONS)
}

#[cfg(test)]
mod tests {
    use super::super::MaxStretch;
    use super::*;

    fn chain(n: usize) -> (Vec<Vec3>, Vec<[u32; 2]>) {
        let x = (0..n).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
        let e = (0..n as u32 - 1).map(|i| [i, i + 1]).collect();
        (x, e)
    }

    #[test]
    fn a_short_over_stretched_chain_reaches_its_limit_in_one_step() {
        let (rest, edges) = chain(4);
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(0.1)).unwrap();
        let mut x: Vec<Vec3> = rest.iter().map(|p| *p * 1.15).collect();
        let outcome = limits.project_fast(&mut x, &[0.0, 1.0, 1.0, 1.0], &[], 1e-4, 3);
        assert!(outcome.converged && outcome.steps == 1, "{outcome:?}");
        assert!(limits.worst_ratio(&x) <= 1.0 + 1e-4);
        assert_eq!(x[0], Vec3::ZERO);
    }

    #[test]
    fn contacts_slide_along_their_planes_and_never_cross_them() {
        // A chain lying on the plane z ≥ 0 except its fixed first vertex
        // below it, stretched sideways: shortened straight, the chain would
        // be pulled under the plane.
        let (rest, edges) = chain(30);
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(0.1)).unwrap();
        let mut x: Vec<Vec3> = rest
            .iter()
            .map(|p| Vec3::new(p.x * 1.5, 0.0, 0.0))
            .collect();
        x[0] = Vec3::new(0.0, 0.0, -0.5);
        let mut w = vec![1.0; 30];
        w[0] = 0.0;
        let mut above = vec![(Vec3::Z, 0.0); 30];
        above[0] = (Vec3::ZERO, 0.0);
        let outcome = limits.project_fast(&mut x, &w, &above, 1e-4, 20);
        assert!(
            outcome.converged,
            "{outcome:?}, ratio {}",
            limits.worst_ratio(&x)
        );
        assert!(limits.worst_ratio(&x) <= 1.0 + 1e-4);
        for (v, p) in x.iter().enumerate().skip(1) {
            assert!(p.z >= -1e-4, "vertex {v} crossed its plane: {p:?}");
        }
        // Vertices at the far end are lifted off nothing: a plane only pushes.
        assert!(x[29].z.abs() < 1e-3, "{:?}", x[29]);
    }

    #[test]
    fn edges_within_their_limits_and_planes_that_do_not_pull_are_left_alone() {
        // A chain whose middle is slack: the fast projection must not pull
        // the slack edges to their limit (an edge only pulls, never pushes).
        let (rest, edges) = chain(5);
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(0.1)).unwrap();
        let mut x = vec![
            Vec3::ZERO,
            Vec3::X * 1.5,
            Vec3::X * 2.0,
            Vec3::X * 2.5,
            Vec3::X * 4.0,
        ];
        let w = [0.0, 1.0, 1.0, 1.0, 0.0];
        let outcome = limits.project_fast(&mut x, &w, &[], 1e-4, 20);
        assert!(outcome.converged, "{outcome:?}");
        assert!(limits.worst_ratio(&x) <= 1.0 + 1e-4);
        let lengths: Vec<f32> = x.windows(2).map(|p| (p[1] - p[0]).length()).collect();
        assert!(lengths.iter().all(|&l| l <= 1.1 + 1e-3), "{lengths:?}");
        assert_eq!(x[0], Vec3::ZERO);
        assert_eq!(x[4], Vec3::X * 4.0);
    }

    #[test]
    fn a_grid_patch_gives_the_same_result_with_one_or_two_threads() {
        // The projection runs in a fixed order: the thread pool cannot change it.
        let n = 20;
        let rest: Vec<Vec3> = (0..n * n)
            .map(|i| Vec3::new((i % n) as f32, (i / n) as f32, 0.0))
            .collect();
        let mut edges = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let v = (j * n + i) as u32;
                if i + 1 < n {
                    edges.push([v, v + 1]);
                }
                if j + 1 < n {
                    edges.push([v, v + n as u32]);
                }
            }
        }
        let limits = EdgeLimits::new(&edges, &rest, MaxStretch::Uniform(0.05)).unwrap();
        // A bump pulled up in the middle, the border held.
        let start: Vec<Vec3> = rest
            .iter()
            .map(|p| {
                *p + Vec3::Z * 6.0 * (-((p.x - 9.5).powi(2) + (p.y - 9.5).powi(2)) / 8.0).exp()
            })
            .collect();
        let w: Vec<f32> = rest
            .iter()
            .map(|p| {
                if p.x == 0.0 || p.y == 0.0 || p.x == 19.0 || p.y == 19.0 {
                    0.0
                } else {
                    1.0
                }
            })
            .collect();
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut x = start.clone();
                let outcome = limits.project_fast(&mut x, &w, &[], 1e-4, 20);
                (x, outcome)
            })
        };
        let (one, outcome) = run(1);
        assert!(
            outcome.converged,
            "{outcome:?}, ratio {}",
            limits.worst_ratio(&one)
        );
        assert!(limits.worst_ratio(&one) <= 1.0 + 1e-4);
        assert_eq!(one, run(2).0);
    }
}
