//! Solver tests on hand-made constraints, independent of pyramid coordinates.

#![allow(clippy::needless_range_loop)] // the dense reference reads like the textbook

use glam::Vec3;

use super::*;
use crate::Result;

/// A spring per edge: row `e_a − e_b`, projecting to the current edge
/// direction at its rest length — a coupled constraint like the strain
/// limits that will plug in later.
struct Springs {
    rows: Rows,
    edges: Vec<[u32; 2]>,
    rest: Vec<f32>,
}

impl Springs {
    fn new(edges: Vec<[u32; 2]>, positions: &[Vec3]) -> Self {
        let mut rows = Rows::new();
        for &[a, b] in &edges {
            rows.push([(a, 1.0), (b, -1.0)]);
        }
        let rest = edges
            .iter()
            .map(|&[a, b]| (positions[a as usize] - positions[b as usize]).length())
            .collect();
        Springs { rows, edges, rest }
    }
}

impl Constraint for Springs {
    fn name(&self) -> &str {
        "springs"
    }
    fn rows(&self) -> &Rows {
        &self.rows
    }
    fn project_row(&self, context: &Context<'_>, i: usize) -> Vec3 {
        let [a, b] = self.edges[i];
        let d = context.positions[a as usize] - context.positions[b as usize];
        d.normalize_or_zero() * self.rest[i]
    }
}

fn chain(n: usize) -> (Vec<Vec3>, Vec<[u32; 2]>) {
    let positions = (0..n).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
    let edges = (0..n as u32 - 1).map(|i| [i, i + 1]).collect();
    (positions, edges)
}

#[test]
fn closeness_alone_returns_the_input_in_one_iteration() {
    let input: Vec<Vec3> = (0..10)
        .map(|i| Vec3::new(i as f32, 2.0 * i as f32, -1.0))
        .collect();
    let mut solver = Solver::new(10);
    solver
        .add(Box::new(Closeness::all(10)), vec![0.5; 10])
        .unwrap();
    assert_eq!(solver.prepare().unwrap(), SystemKind::Diagonal);
    let mut x = vec![Vec3::ZERO; 10];
    solver.solve(&input, &mut x, 1, None).unwrap();
    for (a, b) in x.iter().zip(&input) {
        assert!((*a - *b).length() < 1e-6);
    }
}

#[test]
fn coupled_rows_use_cholesky_and_solve_the_normal_equations() {
    // A stretched chain with its two ends held: the springs pull it back to
    // its rest length between the ends, evenly.
    let (rest, edges) = chain(11);
    let mut solver = Solver::new(11);
    solver
        .add(Box::new(Springs::new(edges, &rest)), vec![1.0; 10])
        .unwrap();
    let mut weights = vec![0.0; 11];
    weights[0] = 1e3;
    weights[10] = 1e3;
    solver.add(Box::new(Closeness::all(11)), weights).unwrap();
    assert_eq!(solver.prepare().unwrap(), SystemKind::Cholesky);
    let input: Vec<Vec3> = rest.iter().map(|p| *p * 2.0).collect();
    let mut x = input.clone();
    solver.solve(&input, &mut x, 50, None).unwrap();
    // Ends at 0 and 20, springs of rest 1 stretched evenly: x_i ≈ 2 i.
    for (i, p) in x.iter().enumerate() {
        assert!((p.x - 2.0 * i as f32).abs() < 0.05, "vertex {i}: {p}");
        assert!(p.y.abs() < 1e-5 && p.z.abs() < 1e-5);
    }
    // And the chain with free ends relaxes to the rest length exactly.
    let mut free = Solver::new(11);
    let (rest, edges) = chain(11);
    free.add(Box::new(Springs::new(edges, &rest)), vec![1.0; 10])
        .unwrap();
    free.add(Box::new(Closeness::all(11)), vec![1e-4; 11])
        .unwrap();
    let input: Vec<Vec3> = rest.iter().map(|p| *p * 1.5).collect();
    let mut x = input.clone();
    free.solve(&input, &mut x, 200, None).unwrap();
    for i in 0..10 {
        let length = (x[i + 1] - x[i]).length();
        assert!((length - 1.0).abs() < 0.01, "edge {i} has length {length}");
    }
}

#[test]
fn each_iteration_matches_a_dense_reference_solve() {
    // One iteration with springs + closeness, compared with the normal
    // equations solved densely (Gaussian elimination in f64) in the test.
    let (rest, edges) = chain(6);
    let input: Vec<Vec3> = rest
        .iter()
        .enumerate()
        .map(|(i, p)| *p * 1.3 + Vec3::new(0.0, (i % 2) as f32, 0.0))
        .collect();
    let spring_w = [1.0f32, 2.0, 0.5, 1.5, 1.0];
    let close_w = [0.3f32, 0.1, 0.2, 0.05, 0.4, 0.6];
    let springs = Springs::new(edges.clone(), &rest);
    let mut projections = vec![Vec3::ZERO; 5];
    springs.project(
        &Context {
            positions: &input,
            input: &input,
        },
        &mut projections,
    );
    let mut solver = Solver::new(6);
    solver.add(Box::new(springs), spring_w.to_vec()).unwrap();
    solver
        .add(Box::new(Closeness::all(6)), close_w.to_vec())
        .unwrap();
    let mut x = input.clone();
    solver.solve(&input, &mut x, 1, None).unwrap();

    let n = 6;
    let mut m = vec![vec![0f64; n]; n];
    let mut rhs = vec![[0f64; 3]; n];
    for (r, &[a, b]) in edges.iter().enumerate() {
        let w = spring_w[r] as f64;
        let (a, b) = (a as usize, b as usize);
        m[a][a] += w;
        m[b][b] += w;
        m[a][b] -= w;
        m[b][a] -= w;
        for c in 0..3 {
            rhs[a][c] += w * projections[r][c] as f64;
            rhs[b][c] -= w * projections[r][c] as f64;
        }
    }
    for i in 0..n {
        m[i][i] += close_w[i] as f64;
        for c in 0..3 {
            rhs[i][c] += close_w[i] as f64 * input[i][c] as f64;
        }
    }
    // Gaussian elimination (SPD, no pivoting needed).
    for i in 0..n {
        for j in i + 1..n {
            let f = m[j][i] / m[i][i];
            for k in i..n {
                m[j][k] -= f * m[i][k];
            }
            for c in 0..3 {
                rhs[j][c] -= f * rhs[i][c];
            }
        }
    }
    let mut solution = vec![[0f64; 3]; n];
    for i in (0..n).rev() {
        for c in 0..3 {
            let mut s = rhs[i][c];
            for k in i + 1..n {
                s -= m[i][k] * solution[k][c];
            }
            solution[i][c] = s / m[i][i];
        }
    }
    for i in 0..n {
        for c in 0..3 {
            assert!(
                (x[i][c] as f64 - solution[i][c]).abs() < 1e-5,
                "vertex {i} coord {c}: {} vs {}",
                x[i][c],
                solution[i][c]
            );
        }
    }
}

#[test]
fn hook_sees_every_iteration_and_can_move_vertices() {
    let (rest, edges) = chain(5);
    let mut solver = Solver::new(5);
    solver
        .add(Box::new(Springs::new(edges, &rest)), vec![1.0; 4])
        .unwrap();
    solver
        .add(Box::new(Closeness::all(5)), vec![0.1; 5])
        .unwrap();
    let input: Vec<Vec3> = rest.iter().map(|p| *p * 1.2).collect();
    let mut x = input.clone();
    let mut seen = Vec::new();
    let mut hook = |iteration: usize, before: &[Vec3], after: &mut [Vec3]| -> Result<()> {
        seen.push((iteration, before.to_vec()));
        // A "collider": the plane y = 0.25 keeps every vertex above it.
        for p in after.iter_mut() {
            p.y = p.y.max(0.25);
        }
        Ok(())
    };
    solver.solve(&input, &mut x, 3, Some(&mut hook)).unwrap();
    assert_eq!(seen.iter().map(|s| s.0).collect::<Vec<_>>(), vec![0, 1, 2]);
    assert_eq!(
        seen[0].1, input,
        "the first iteration starts from the given positions"
    );
    assert!(
        seen[1].1.iter().all(|p| p.y >= 0.25),
        "iteration 1 starts from the hooked result"
    );
    assert!(x.iter().all(|p| p.y >= 0.25));
}

#[test]
fn hook_errors_stop_the_solve() {
    let mut solver = Solver::new(3);
    solver
        .add(Box::new(Closeness::all(3)), vec![1.0; 3])
        .unwrap();
    let input = vec![Vec3::ONE; 3];
    let mut x = input.clone();
    let mut hook = |_: usize, _: &[Vec3], _: &mut [Vec3]| -> Result<()> {
        Err(crate::Error::Numerical("stop".into()))
    };
    assert!(solver.solve(&input, &mut x, 2, Some(&mut hook)).is_err());
}

#[test]
fn changing_weights_refactorises() {
    let (rest, edges) = chain(4);
    let mut solver = Solver::new(4);
    solver
        .add(Box::new(Springs::new(edges, &rest)), vec![1.0; 3])
        .unwrap();
    let close = solver
        .add(Box::new(Closeness::all(4)), vec![1e-3; 4])
        .unwrap();
    let input: Vec<Vec3> = rest.iter().map(|p| *p * 3.0).collect();
    let mut soft = input.clone();
    solver.solve(&input, &mut soft, 20, None).unwrap();
    solver.set_weights(close, &[1e6; 4]).unwrap();
    let mut hard = input.clone();
    solver.solve(&input, &mut hard, 20, None).unwrap();
    assert!(
        (soft[3] - soft[0]).length() < 4.0,
        "soft closeness lets the springs win"
    );
    for (a, b) in hard.iter().zip(&input) {
        assert!(
            (*a - *b).length() < 1e-3,
            "hard closeness follows the input"
        );
    }
}

#[test]
fn bad_input_is_refused() {
    let mut solver = Solver::new(3);
    let mut rows = Rows::new();
    rows.push([(0, 1.0), (5, -1.0)]);
    struct Bad(Rows);
    impl Constraint for Bad {
        fn name(&self) -> &str {
            "bad"
        }
        fn rows(&self) -> &Rows {
            &self.0
        }
        fn project_row(&self, _: &Context<'_>, _: usize) -> Vec3 {
            Vec3::ZERO
        }
    }
    let err = solver
        .add(Box::new(Bad(rows)), vec![1.0])
        .unwrap_err()
        .to_string();
    assert!(err.contains("vertex 5"), "{err}");
    let err = solver
        .add(Box::new(Closeness::all(3)), vec![1.0; 2])
        .unwrap_err()
        .to_string();
    assert!(err.contains("2 weights given for 3 rows"), "{err}");
    let err = solver
        .add(Box::new(Closeness::all(3)), vec![1.0, -1.0, 1.0])
        .unwrap_err()
        .to_string();
    assert!(err.contains("row 1"), "{err}");
    solver
        .add(Box::new(Closeness::all(3)), vec![1.0, 0.0, 1.0])
        .unwrap();
    let err = solver.prepare().unwrap_err().to_string();
    assert!(err.contains("vertex 1"), "{err}");
    let mut x = vec![Vec3::ZERO; 2];
    assert!(solver.solve(&[Vec3::ZERO; 2], &mut x, 1, None).is_err());
    let mut x = vec![Vec3::ZERO; 3];
    let err = solver
        .solve(&[Vec3::ZERO, Vec3::NAN, Vec3::ZERO], &mut x, 1, None)
        .unwrap_err()
        .to_string();
    assert!(err.contains("vertex 1"), "{err}");
}

#[test]
fn singular_coupled_system_is_an_error_not_garbage() {
    // Springs only, no closeness: translation is free, the matrix singular.
    let (rest, edges) = chain(4);
    let mut solver = Solver::new(4);
    solver
        .add(Box::new(Springs::new(edges, &rest)), vec![1.0; 3])
        .unwrap();
    solver
        .add(Box::new(Closeness::all(4)), vec![0.0; 4])
        .unwrap();
    assert!(matches!(solver.prepare(), Err(crate::Error::Numerical(_))));
}
