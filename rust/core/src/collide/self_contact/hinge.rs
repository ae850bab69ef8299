//! Pairs one hinge apart: which near pairs of skin elements are never
//! contacts, whatever patch tree gathers them.
//!
//! **The rule.** A pair whose two sides lie in two triangles of the skin
//! that share an edge, run it in opposite directions (the mesh's own
//! orientation) and keep one side over the whole motion (one direction has
//! a positive dot product with both normals at every moment, margins
//! included: [`keep_one_side`]) is never a contact and never a crossing.
//! Projected along that direction both triangles keep their orientation,
//! so they lie on the two sides of their shared edge: a corner of the one
//! that is not on the edge never meets the other, and an edge of the one
//! meets an edge of the other only at a shared corner, which makes them
//! neighbours. Such a pair cannot pass through itself; that it comes
//! within the Distance says how the skin is shaped there (a thin quad, a
//! strip squeezed along itself), not that it folds onto itself, and
//! pushing it apart would push the skin along itself (a spike).
//!
//! **Why it is decided here and not by the tree.** The patch tree drops
//! every pair inside a patch it proves cannot touch itself, contacts
//! within the Distance included. Which near pairs that drops depends on
//! where the tree's seams fall: a tree grouped on the dual graph pushed
//! apart other pairs than main's median cuts (issue 30, twelfth round:
//! 356 + 350 contacts on the character's first frames against 181 + 175).
//! With this rule every gathering drops the hinge pairs itself, so their
//! fate no longer depends on the tree (on a rolled grid squeezed along its
//! quads' diagonals, a corner against its quad's other triangle was a
//! contact at main's seams only; `tests.rs`). Pairs two polygons apart
//! round a vertex (an edge through a corner against the far side of a
//! triangle at that corner) are [`super::star`]'s.
//!
//! It is the tree's own acceptance test ([`super::bounds`]: a disk whose
//! normals fit a cone narrower than a half-turn and whose contour winds
//! once) applied to the smallest patch holding the pair, two triangles,
//! whose contour always winds once when the cone holds. The cone is the
//! tree's conservative one (a box of unit normals whose every corner must
//! lean one way): a hinge opened out, bent up to about a right angle,
//! keeps a side; one creased sharper, or whose triangles may fold flat
//! onto each other over the motion (a quad closing onto itself along a
//! diagonal), does not, and its pairs are contacts that the CCD stops at
//! the Distance.

use super::bounds::{keep_one_side, Motion};

/// Every directed edge of the skin's triangles with the corner opposite it.
#[derive(Debug, Clone)]
pub(super) struct Hinges {
    /// `[from, to, apex]`, sorted.
    directed: Vec<[u32; 3]>,
    /// Per vertex `v`, where the directed edges from `v` lie in `directed`:
    /// a dozen, scanned, where a binary search over all of them for every
    /// near pair a gathering considers was about a twentieth of the
    /// MakeHuman character's straight frames (issue 30, sixteenth round).
    from_offsets: Vec<u32>,
}

impl Hinges {
    pub(super) fn new(triangles: &[[u32; 3]]) -> Self {
        let mut directed: Vec<[u32; 3]> = triangles.iter().flat_map(|&[a, b, c]| [[a, b, c], [b, c, a], [c, a, b]]).collect();
        directed.sort_unstable();
        directed.dedup();
        let mut from_offsets = vec![0u32; directed.last().map_or(0, |d| d[0] as usize + 2)];
        for d in &directed {
            from_offsets[d[0] as usize + 1] += 1;
        }
        for v in 1..from_offsets.len() {
            from_offsets[v] += from_offsets[v - 1];
        }
        Hinges { directed, from_offsets }
    }

    /// Whether a triangle runs `from → to` with `apex` opposite.
    fn has(&self, from: u32, to: u32, apex: u32) -> bool {
        let from = from as usize;
        from + 1 < self.from_offsets.len() && self.directed[self.from_offsets[from] as usize..self.from_offsets[from + 1] as usize].contains(&[from as u32, to, apex])
    }

    /// Whether the sides `one` and `other` (a vertex and a triangle, or two
    /// edges) are one hinge apart over `motion` (see the module
    /// documentation): never a contact.
    pub(super) fn keep_apart(&self, motion: &Motion<'_>, one: &[u32], other: &[u32]) -> bool {
        match (one, other) {
            (&[v], &[a, b, c]) => {
                // The triangle holding `v` on the far side of one of `other`'s edges.
                [[a, b], [b, c], [c, a]].into_iter().any(|[x, y]| self.has(y, x, v) && keep_one_side(motion, &[[y, x, v], [a, b, c]]))
            }
            (&[p0, p1], &[q0, q1]) => {
                // Hinge edge `p_i – q_j`: one triangle holds `one` and `q_j`,
                // the other holds `other` and `p_i`, running it both ways.
                let (p, q) = ([p0, p1], [q0, q1]);
                (0..2).any(|i| {
                    (0..2).any(|j| {
                        let (pi, po, qj, qo) = (p[i], p[1 - i], q[j], q[1 - j]);
                        [(pi, qj), (qj, pi)].into_iter().any(|(x, y)| {
                            self.has(x, y, po) && self.has(y, x, qo) && keep_one_side(motion, &[[x, y, po], [y, x, qo]])
                        })
                    })
                })
            }
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;

    /// Two triangles `0 1 2` and `0 2 3` (a quad split along `0 2`), the
    /// second turned about the hinge by `angle` from flat.
    fn quad(angle: f32) -> Vec<Vec3> {
        let (s, c) = angle.sin_cos();
        vec![Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, -0.5, 0.0), Vec3::new(2.0, 0.0, 0.0), Vec3::new(1.0, 0.5 * c, 0.5 * s)]
    }

    #[test]
    fn a_corner_across_a_hinge_is_kept_apart_while_the_hinge_stays_open() {
        let hinges = Hinges::new(&[[0, 1, 2], [0, 2, 3]]);
        let margin = [0.0; 4];
        for (angle, kept) in [(0.0, true), (0.6, true), (1.2, true), (2.0, false), (3.0, false), (std::f32::consts::PI, false)] {
            let x = quad(angle);
            let motion = Motion { start: &x, end: &x, margin: &margin };
            assert_eq!(hinges.keep_apart(&motion, &[3], &[0, 1, 2]), kept, "corner 3 against 0 1 2 at {angle} rad");
            assert_eq!(hinges.keep_apart(&motion, &[1], &[0, 2, 3]), kept, "corner 1 against 0 2 3 at {angle} rad");
            // Edges 1 2 and 3 0 lie in the two triangles, hinge 0 2.
            assert_eq!(hinges.keep_apart(&motion, &[1, 2], &[3, 0]), kept, "edges at {angle} rad");
        }
        // Over a motion from open to bent, the normals in between count.
        let (open, bent) = (quad(0.0), quad(1.2));
        assert!(hinges.keep_apart(&Motion { start: &open, end: &bent, margin: &margin }, &[3], &[0, 1, 2]));
        let folded = quad(3.3);
        assert!(!hinges.keep_apart(&Motion { start: &open, end: &folded, margin: &margin }, &[3], &[0, 1, 2]));
        // Nor when a margin lets an opened hinge turn that far.
        let wide = [0.3; 4];
        assert!(!hinges.keep_apart(&Motion { start: &bent, end: &bent, margin: &wide }, &[3], &[0, 1, 2]));
    }

    #[test]
    fn triangles_that_do_not_share_an_edge_or_run_it_the_same_way_are_no_hinge() {
        let x = quad(0.0);
        let margin = [0.0; 4];
        let motion = Motion { start: &x, end: &x, margin: &margin };
        // Not joined: 3 is in no triangle of the skin.
        assert!(!Hinges::new(&[[0, 1, 2]]).keep_apart(&motion, &[3], &[0, 1, 2]));
        // Joined along 0 2 run the same way (flipped winding): overlapping in projection.
        assert!(!Hinges::new(&[[0, 1, 2], [2, 0, 3]]).keep_apart(&motion, &[3], &[0, 1, 2]));
    }
}
