//! End to end on the Scalable-CCD cloth-funnel step 227→228: our BVH broad
//! phase plus our narrow phase must find every pair that Mathematica says
//! collides (`mma_bool`), for vertex–face and edge–edge self-collision.

use std::collections::HashSet;

use glam::DVec3;
use rayon::prelude::*;

use super::data::{read_bools, read_pairs, read_ply, read_queries, require};
use crate::collide::bvh::{BoxTree, Bounds};
use crate::collide::ccd::{self, CcdParams};

/// Unique edges in libigl `igl::edges` order: sorted by (max index, min index).
fn igl_edges(faces: &[[u32; 3]]) -> Vec<[u32; 2]> {
    let mut edges: Vec<[u32; 2]> = faces
        .iter()
        .flat_map(|f| (0..3).map(move |k| (f[k], f[(k + 1) % 3])))
        .map(|(a, b)| [a.max(b), a.min(b)])
        .collect();
    edges.sort_unstable();
    edges.dedup();
    edges.into_iter().map(|[hi, lo]| [lo, hi]).collect()
}

struct Outcome {
    found: HashSet<[usize; 2]>,
    candidates: usize,
}

fn vertex_face(x0: &[DVec3], x1: &[DVec3], faces: &[[u32; 3]], params: &CcdParams) -> Outcome {
    let boxes: Vec<Bounds> = faces
        .iter()
        .map(|f| {
            let pts: Vec<DVec3> = f.iter().flat_map(|&v| [x0[v as usize], x1[v as usize]]).collect();
            Bounds::of_points_f64(&pts)
        })
        .collect();
    let tree = BoxTree::build(&boxes).unwrap();
    let per_vertex: Vec<(Vec<[usize; 2]>, usize)> = (0..x0.len())
        .into_par_iter()
        .map(|v| {
            let q = Bounds::of_points_f64(&[x0[v], x1[v]]);
            let mut hits = Vec::new();
            let mut candidates = 0;
            tree.query(&q, |f| {
                let [a, b, c] = faces[f].map(|i| i as usize);
                if a != v && b != v && c != v {
                    candidates += 1;
                    if ccd::vertex_triangle(x0[v], x0[a], x0[b], x0[c], x1[v], x1[a], x1[b], x1[c], params).is_some() {
                        hits.push([v, f]);
                    }
                }
                true
            });
            (hits, candidates)
        })
        .collect();
    Outcome {
        candidates: per_vertex.iter().map(|p| p.1).sum(),
        found: per_vertex.into_iter().flat_map(|p| p.0).collect(),
    }
}

fn edge_edge(x0: &[DVec3], x1: &[DVec3], edges: &[[u32; 2]], params: &CcdParams) -> Outcome {
    let boxes: Vec<Bounds> = edges
        .iter()
        .map(|e| {
            let (a, b) = (e[0] as usize, e[1] as usize);
            Bounds::of_points_f64(&[x0[a], x0[b], x1[a], x1[b]])
        })
        .collect();
    let tree = BoxTree::build(&boxes).unwrap();
    let per_edge: Vec<(Vec<[usize; 2]>, usize)> = (0..edges.len())
        .into_par_iter()
        .map(|i| {
            let [a, b] = edges[i].map(|v| v as usize);
            let mut hits = Vec::new();
            let mut candidates = 0;
            tree.query(&boxes[i], |j| {
                let [c, d] = edges[j].map(|v| v as usize);
                if j > i && a != c && a != d && b != c && b != d {
                    candidates += 1;
                    if ccd::edge_edge(x0[a], x0[b], x0[c], x0[d], x1[a], x1[b], x1[c], x1[d], params).is_some() {
                        hits.push([i, j]);
                    }
                }
                true
            });
            (hits, candidates)
        })
        .collect();
    Outcome {
        candidates: per_edge.iter().map(|p| p.1).sum(),
        found: per_edge.into_iter().flat_map(|p| p.0).collect(),
    }
}

#[test]
#[cfg_attr(not(any(shared_data, require_shared_data)), ignore = "../shared/data is absent: the shared test data sits beside the checkout (or set $TEGUMENT_DATA_DIR)")]
fn cloth_funnel_end_to_end_finds_every_true_pair() {
    let root = require("ccd/scalable-ccd-cloth-funnel/cloth-funnel");
    let (x0, faces) = read_ply(&root.join("frames/227.ply"));
    let (x1, faces1) = read_ply(&root.join("frames/228.ply"));
    assert_eq!(faces, faces1, "topology changes between frames");
    let edges = igl_edges(&faces);
    let (nv, ne) = (x0.len(), edges.len());

    for tolerance in [1e-6, 1e-8] {
        let params = CcdParams { tolerance, ..Default::default() };
        let vf = vertex_face(&x0, &x1, &faces, &params);
        let ee = edge_edge(&x0, &x1, &edges, &params);

        for (stem, outcome) in [("227vf", &vf), ("227ee", &ee)] {
            let pairs = read_pairs(&root.join(format!("boxes/{stem}.json")));
            let truths = read_bools(&root.join(format!("mma_bool/{stem}_mma_bool.json")));
            let queries = read_queries(&root.join(format!("queries/{stem}.csv")));
            assert_eq!(pairs.len(), truths.len());
            assert_eq!(pairs.len(), queries.len());
            let mut truth_set = HashSet::new();
            let mut labelled_negatives = HashSet::new();
            for ((pair, &truth), query) in pairs.iter().zip(&truths).zip(&queries) {
                let key = if stem == "227vf" {
                    let (v, f) = if pair[0] < nv { (pair[0], pair[1]) } else { (pair[1], pair[0]) };
                    let f = f - nv - ne;
                    // The ids must point at the query's own points.
                    let [a, b, c] = faces[f].map(|i| i as usize);
                    assert_eq!(query.points, [x0[v], x0[a], x0[b], x0[c], x1[v], x1[a], x1[b], x1[c]], "{stem} pair {pair:?}");
                    [v, f]
                } else {
                    let (i, j) = (pair[0].min(pair[1]) - nv, pair[0].max(pair[1]) - nv);
                    let [ea, eb] = [edges[i], edges[j]].map(|e| e.map(|v| v as usize));
                    let as_given = [x0[ea[0]], x0[ea[1]], x0[eb[0]], x0[eb[1]], x1[ea[0]], x1[ea[1]], x1[eb[0]], x1[eb[1]]];
                    let swapped = [x0[eb[0]], x0[eb[1]], x0[ea[0]], x0[ea[1]], x1[eb[0]], x1[eb[1]], x1[ea[0]], x1[ea[1]]];
                    assert!(query.points == as_given || query.points == swapped, "{stem} pair {pair:?}");
                    [i, j]
                };
                if truth {
                    truth_set.insert(key);
                } else {
                    labelled_negatives.insert(key);
                }
            }
            let missed: Vec<_> = truth_set.iter().filter(|k| !outcome.found.contains(*k)).collect();
            let false_labelled = outcome.found.iter().filter(|k| labelled_negatives.contains(*k)).count();
            let unlabelled = outcome.found.iter().filter(|k| !truth_set.contains(*k) && !labelled_negatives.contains(*k)).count();
            let negatives = outcome.candidates - truth_set.len();
            println!(
                "cloth-funnel end to end, tol {tolerance:.0e}, {stem}: {} narrow-phase candidates, {} true pairs, {} found, \
                 {} missed, {} false positives among labelled negatives ({} labelled), {} positives outside the labelled pairs; \
                 false-positive rate {:.4}% of {negatives} negative candidates",
                outcome.candidates,
                truth_set.len(),
                outcome.found.len(),
                missed.len(),
                false_labelled,
                labelled_negatives.len(),
                unlabelled,
                100.0 * (outcome.found.len() - (truth_set.len() - missed.len())) as f64 / negatives.max(1) as f64,
            );
            assert!(missed.is_empty(), "{stem}: true pairs missed: {missed:?}");
            assert!(!truth_set.is_empty());
            // False positives among all narrow-phase candidates: at most what was measured on
            // 2026-11-25 (vf 64 / 7,292 and ee 155 / 33,663 at 1e-6; 0 and 6 at 1e-8) plus a
            // tenth of a percent of the candidates; a CCD reporting every candidate fails.
            let false_positives = outcome.found.len() - (truth_set.len() - missed.len());
            let measured = match (stem, tolerance) {
                ("227vf", t) if t == 1e-6 => 64,
                ("227ee", t) if t == 1e-6 => 155,
                ("227ee", _) => 6,
                _ => 0,
            };
            let allowed = measured + negatives / 1000;
            assert!(
                false_positives <= allowed,
                "{stem}, tolerance {tolerance:.0e}: {false_positives} false positives among {negatives} negative candidates, \
                 measured {measured} (at most {allowed} allowed)"
            );
        }
    }
}

#[test]
fn igl_edge_order() {
    let edges = igl_edges(&[[0, 1, 2], [2, 1, 3]]);
    assert_eq!(edges, vec![[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]]);
}
