//! Which pairs of skin elements are neighbours, never tested against each
//! other: those sharing a vertex always (they touch by construction), and
//! with `rings = k` those with vertices within `k` edges of each other.
//! The two diagonals of a quad split both ways cross by construction: they
//! are neighbours too (with a ring or more they share a side's vertex).

use rayon::prelude::*;

use crate::mesh::vertex_incidence;

/// The vertices within `rings` edges of each vertex (itself included),
/// ascending; with 0 rings only the vertex itself, stored implicitly.
#[derive(Debug, Clone)]
pub(super) struct Exclusion {
    rings: u32,
    /// Per quad, both orders of its two diagonals (`[a0, a1, b0, b1]`, each
    /// diagonal ascending), sorted.
    diagonals: Vec<[u32; 4]>,
    /// Per vertex `v`, where the diagonals starting at `v` (`a0 == v`) lie in
    /// `diagonals`: a few, scanned, where a binary search over all of them
    /// for every edge pair a gathering considers was a twentieth of the
    /// MakeHuman character's straight frames (issue 30, sixteenth round).
    diagonal_offsets: Vec<u32>,
    offsets: Vec<u32>,
    near: Vec<u32>,
}

impl Exclusion {
    pub(super) fn new(vertex_count: usize, edges: &[[u32; 2]], rings: u32, quads: &[[u32; 4]]) -> Self {
        let mut diagonals: Vec<[u32; 4]> = quads
            .iter()
            .flat_map(|&[a, b, c, d]| {
                let (one, other) = ([a.min(c), a.max(c)], [b.min(d), b.max(d)]);
                [[one[0], one[1], other[0], other[1]], [other[0], other[1], one[0], one[1]]]
            })
            .collect();
        diagonals.sort_unstable();
        let mut diagonal_offsets = vec![0u32; if diagonals.is_empty() { 0 } else { vertex_count + 1 }];
        for d in &diagonals {
            diagonal_offsets[d[0] as usize + 1] += 1;
        }
        for v in 1..diagonal_offsets.len() {
            diagonal_offsets[v] += diagonal_offsets[v - 1];
        }
        if rings == 0 {
            return Exclusion { rings, diagonals, diagonal_offsets, offsets: Vec::new(), near: Vec::new() };
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
        Exclusion { rings, diagonals, diagonal_offsets, offsets, near }
    }

    pub(super) fn rings(&self) -> u32 {
        self.rings
    }

    /// Whether an element with corners `a` and one with corners `b` are
    /// neighbours.
    pub(super) fn excluded(&self, a: &[u32], b: &[u32]) -> bool {
        if self.rings == 0 {
            return a.iter().any(|v| b.contains(v)) || self.crossing_diagonals(a, b);
        }
        a.iter().any(|&v| {
            let near = &self.near[self.offsets[v as usize] as usize..self.offsets[v as usize + 1] as usize];
            b.iter().any(|w| near.binary_search(w).is_ok())
        })
    }
}

impl Exclusion {
    /// Whether `a` and `b` are the two diagonals of one quad.
    fn crossing_diagonals(&self, a: &[u32], b: &[u32]) -> bool {
        if self.diagonals.is_empty() || a.len() != 2 || b.len() != 2 {
            return false;
        }
        let key = [a[0].min(a[1]), a[0].max(a[1]), b[0].min(b[1]), b[0].max(b[1])];
        let from = key[0] as usize;
        self.diagonals[self.diagonal_offsets[from] as usize..self.diagonal_offsets[from + 1] as usize].contains(&key)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rings_grow_along_edges() {
        // A path 0 - 1 - 2 - 3 - 4.
        let edges = [[0, 1], [1, 2], [2, 3], [3, 4]];
        let zero = Exclusion::new(5, &edges, 0, &[]);
        assert!(zero.excluded(&[0, 1], &[1, 2]));
        assert!(!zero.excluded(&[0, 1], &[2, 3]));
        let one = Exclusion::new(5, &edges, 1, &[]);
        assert!(one.excluded(&[0], &[1, 4]));
        assert!(!one.excluded(&[0], &[2, 3]));
        let two = Exclusion::new(5, &edges, 2, &[]);
        assert!(two.excluded(&[0], &[2]));
        assert!(!two.excluded(&[0], &[3, 4]));
    }

    #[test]
    fn a_quads_two_diagonals_are_neighbours_its_opposite_sides_are_not() {
        // The quad 0 1 2 3 with both diagonals among its edges.
        let edges = [[0, 1], [1, 2], [2, 3], [0, 3], [0, 2], [1, 3]];
        let zero = Exclusion::new(4, &edges, 0, &[[0, 1, 2, 3]]);
        assert!(zero.excluded(&[2, 0], &[1, 3]));
        assert!(zero.excluded(&[1, 3], &[0, 2]));
        assert!(!zero.excluded(&[0, 1], &[2, 3]), "opposite sides may still meet");
        assert!(!zero.excluded(&[1], &[0, 2, 3]), "a corner may still meet the far triangle");
    }
}
