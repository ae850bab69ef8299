//! Which vertices the fail-safe puts back: the corners of the pairs whose
//! paths still cross, and with them every vertex that moved while most of
//! its one-ring is held.
//!
//! **Why the rings.** The fail-safe puts a crossing pair's corners back
//! where the pass started. Where a fold's crease is squeezed, the pairs
//! round a vertex can hold its whole ring while the vertex itself is in
//! none of them and moves on with the input: it leaves its ring behind, a
//! spike (the 150° tube's vertex 792 with Converge, 1.32 mean ring edges
//! against the input's 0.12; issue 30, fourteenth round), and every later
//! pass of the frame holds ring and spike where they are. A held patch must
//! move as a patch: a vertex more than half of whose ring is held is held
//! too, which also fills the notches of a held patch's outline, and only
//! those (a vertex beside a straight or convex outline has at most half of
//! its ring inside it, so the patch grows no farther than its notches).
//!
//! **Why the guarantee stands.** Putting a vertex back is what the
//! fail-safe does to a crossing pair's corners: the caller re-checks the
//! pairs round the whole batch, so the pairs of a vertex held for its ring
//! are checked as any other's. Each batch holds at least one vertex that had
//! moved, so the loop ends, at the latest with every vertex at its start,
//! where nothing crosses.

use crate::mesh::{polygon_edges, vertex_incidence};

/// Every vertex's neighbours along the polygons' sides (the one-ring the
/// spike measure averages), as compressed rows.
#[derive(Debug, Clone, Default)]
pub(super) struct Rings {
    offsets: Vec<u32>,
    neighbours: Vec<u32>,
}

impl Rings {
    /// The rings of a polygon mesh in Blender's layout (`offsets`: each
    /// polygon's first corner, then the corner count).
    pub(super) fn new(vertex_count: usize, corner_verts: &[i32], offsets: &[u32]) -> Self {
        let edges = polygon_edges(corner_verts, offsets);
        let (offsets, incident) = vertex_incidence(vertex_count, edges.iter().map(|e| &e[..]));
        let edges = &edges;
        let neighbours = (0..vertex_count)
            .flat_map(|v| {
                let row = offsets[v] as usize..offsets[v + 1] as usize;
                incident[row].iter().map(move |&e| {
                    let [a, b] = edges[e as usize];
                    if a as usize == v { b } else { a }
                })
            })
            .collect();
        Rings { offsets, neighbours }
    }

    pub(super) fn ring(&self, v: u32) -> &[u32] {
        &self.neighbours[self.offsets[v as usize] as usize..self.offsets[v as usize + 1] as usize]
    }

    /// Whether more than half of `v`'s ring is `held`.
    fn mostly_held(&self, v: u32, held: &[bool]) -> bool {
        let ring = self.ring(v);
        2 * ring.iter().filter(|&&w| held[w as usize]).count() > ring.len()
    }
}

/// The vertices one fail-safe has put back so far (one pass's, or one
/// in-loop pass's).
#[derive(Debug, Clone)]
pub struct Held {
    flags: Vec<bool>,
}

impl Held {
    /// None held, of a skin of `vertex_count` vertices.
    pub fn none(vertex_count: usize) -> Self {
        Held { flags: vec![false; vertex_count] }
    }

    /// Which vertices are held so far.
    pub(super) fn flags(&self) -> &[bool] {
        &self.flags
    }

    /// The batch to put back now: the `crossing` corners, and every vertex
    /// that `moved` more than half of whose ring is held with them (the
    /// module documentation says why), each once and ascending. They are
    /// counted as held from here on.
    pub(super) fn batch(&mut self, rings: &Rings, crossing: &[u32], moved: impl Fn(u32) -> bool) -> Vec<u32> {
        let mut batch: Vec<u32> = Vec::with_capacity(crossing.len());
        for &v in crossing {
            if !self.flags[v as usize] {
                self.flags[v as usize] = true;
                batch.push(v);
            }
        }
        // A vertex held for its ring can tip its own neighbours' rings.
        let mut next = 0;
        while next < batch.len() {
            let v = batch[next];
            next += 1;
            for &w in rings.ring(v) {
                if !self.flags[w as usize] && moved(w) && rings.mostly_held(w, &self.flags) {
                    self.flags[w as usize] = true;
                    batch.push(w);
                }
            }
        }
        batch.sort_unstable();
        batch
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::shapes::grid;

    /// The vertex of `grid(n, n, 1)` at column `i`, row `j`.
    fn at(n: usize, i: usize, j: usize) -> u32 {
        (j * (n + 1) + i) as u32
    }

    fn rings_of(n: usize) -> (Rings, usize) {
        let mesh = grid(n, n, 1.0);
        let offsets = mesh.input().validate().unwrap();
        (Rings::new(mesh.positions.len(), &mesh.corner_verts, &offsets), mesh.positions.len())
    }

    #[test]
    fn a_vertex_whose_whole_ring_is_held_is_held_with_it() {
        let (rings, count) = rings_of(6);
        let ring = [at(6, 2, 3), at(6, 4, 3), at(6, 3, 2), at(6, 3, 4)];
        let mut held = Held::none(count);
        let batch = held.batch(&rings, &ring, |_| true);
        let mut expected = ring.to_vec();
        expected.push(at(6, 3, 3));
        expected.sort_unstable();
        assert_eq!(batch, expected);
    }

    #[test]
    fn a_vertex_that_did_not_move_is_not_put_back() {
        let (rings, count) = rings_of(6);
        let ring = [at(6, 2, 3), at(6, 4, 3), at(6, 3, 2), at(6, 3, 4)];
        let centre = at(6, 3, 3);
        let batch = Held::none(count).batch(&rings, &ring, |v| v != centre);
        assert!(!batch.contains(&centre));
    }

    #[test]
    fn a_held_patch_fills_its_notches_and_grows_no_farther() {
        // A held U: its notch (2, 2) has three of its four neighbours held;
        // every vertex along the outside has one.
        let n = 8;
        let (rings, count) = rings_of(n);
        let mut held = Held::none(count);
        let l: Vec<u32> = vec![at(n, 1, 2), at(n, 1, 3), at(n, 2, 3), at(n, 3, 3), at(n, 3, 2)];
        let batch = held.batch(&rings, &l, |_| true);
        assert_eq!(batch.len(), l.len() + 1, "{batch:?}");
        assert!(batch.contains(&at(n, 2, 2)));
        // Held again later, the same vertices are not put back twice.
        assert!(held.batch(&rings, &l, |_| true).is_empty());
    }

    #[test]
    fn a_held_diagonal_staircase_does_not_spread() {
        // Every vertex next to a staircase (away from the grid's border)
        // has two of its four neighbours on it: exactly half, not held.
        let n = 10;
        let (rings, count) = rings_of(n);
        let stairs: Vec<u32> = (2..7).flat_map(|k| [at(n, k, k), at(n, k + 1, k)]).collect();
        let batch = Held::none(count).batch(&rings, &stairs, |_| true);
        assert_eq!(batch.len(), stairs.len());
    }
}
