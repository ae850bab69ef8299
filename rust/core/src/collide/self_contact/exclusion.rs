//! Which pairs of skin elements are neighbours, never tested against each
//! other: those sharing a vertex always (they touch by construction), and
//! with `rings = k` those with vertices within `k` edges of each other.

use rayon::prelude::*;

use crate::mesh::vertex_incidence;

/// The vertices within `rings` edges of each vertex (itself included),
/// ascending; with 0 rings only the vertex itself, stored implicitly.
#[derive(Debug, Clone)]
pub(super) struct Exclusion {
    rings: u32,
    offsets: Vec<u32>,
    near: Vec<u32>,
}

impl Exclusion {
    pub(super) fn new(vertex_count: usize, edges: &[[u32; 2]], rings: u32) -> Self {
        if rings == 0 {
            return Exclusion { rings, offsets: Vec::new(), near: Vec::new() };
        }
        let (adjacency_offsets, adjacent_edges) = vertex_incidence(vertex_count, edges.iter().map(|e| &e[..]));
        let neighbours = |v: usize| {
            adjacent_edges[adjacency_offsets[v] as usize..adjacency_offsets[v + 1] as usize].iter().map(move |&e| {
                let [a, b] = edges[e as usize];
                if a as usize == v { b } else { a }
            })
        };
        let lists: Vec<Vec<u32>> = (0..vertex_count)
            .into_par_iter()
            .map(|v| {
                let mut found = vec![v as u32];
                let mut frontier = vec![v as u32];
                for _ in 0..rings {
                    let mut next = Vec::new();
                    for &f in &frontier {
                        for w in neighbours(f as usize) {
                            if !found.contains(&w) {
                                found.push(w);
                                next.push(w);
                            }
                        }
                    }
                    frontier = next;
                }
                found.sort_unstable();
                found
            })
            .collect();
        let mut offsets = Vec::with_capacity(vertex_count + 1);
        offsets.push(0u32);
        let mut near = Vec::new();
        for list in lists {
            near.extend_from_slice(&list);
            offsets.push(near.len() as u32);
        }
        Exclusion { rings, offsets, near }
    }

    pub(super) fn rings(&self) -> u32 {
        self.rings
    }

    /// Whether an element with corners `a` and one with corners `b` are
    /// neighbours.
    pub(super) fn excluded(&self, a: &[u32], b: &[u32]) -> bool {
        if self.rings == 0 {
            return a.iter().any(|v| b.contains(v));
        }
        a.iter().any(|&v| {
            let near = &self.near[self.offsets[v as usize] as usize..self.offsets[v as usize + 1] as usize];
            b.iter().any(|w| near.binary_search(w).is_ok())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rings_grow_along_edges() {
        // A path 0 - 1 - 2 - 3 - 4.
        let edges = [[0, 1], [1, 2], [2, 3], [3, 4]];
        let zero = Exclusion::new(5, &edges, 0);
        assert!(zero.excluded(&[0, 1], &[1, 2]));
        assert!(!zero.excluded(&[0, 1], &[2, 3]));
        let one = Exclusion::new(5, &edges, 1);
        assert!(one.excluded(&[0], &[1, 4]));
        assert!(!one.excluded(&[0], &[2, 3]));
        let two = Exclusion::new(5, &edges, 2);
        assert!(two.excluded(&[0], &[2]));
        assert!(!two.excluded(&[0], &[3, 4]));
    }
}
