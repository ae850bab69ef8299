//! How far along its path the skin round a held patch goes, so that the
//! patch's border is a slope and not a step.
//!
//! **Why.** The first pass's fail-safe puts a patch back where the pass
//! started while the skin round it goes on to its target: at the border
//! the two ends differ by the whole path. Without Converge the solve
//! starts cold, at the input, and on a closing fold that path undoes the
//! last frame's contacts: on Blender's recorded 150° tube the step the
//! first pass left at frame 10 was 2.69 mean ring edges of spike, and a
//! plain iteration takes away about half of it, so that 4 iterations ended
//! the frame at 0.476 against the input's 0.175 and 1 iteration at 0.78
//! (issue 30, twenty-second round (b)). With every vertex's share of its path
//! growing from the patch by at most a slope per edge, the border ends no
//! farther from a smooth skin than that slope, whatever the iterations do.
//!
//! **Why the guarantee stands.** A vertex given a share goes to a point of
//! its own path, nearer its start; the fail-safe checks the pairs round it
//! again, as round the vertices it put back, and puts back what crosses.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::Vec3;

use super::held::Rings;

/// How the first pass leaves the skin round a patch its fail-safe holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeldBorder {
    /// At the rounds' ends: a step at the border, for a solve that
    /// converges (it smooths the step away; measured unchanged).
    Step,
    /// Part of the way, by [`SLOPE`] per edge from the patch ([`shares`]),
    /// for a fixed count of plain iterations.
    Sloped,
}

/// How far apart two neighbours' ends may be moved from their paths'
/// proportions, in lengths of the edge between them: the most the slope
/// round a held patch adds to the spike measure (in mean ring edges).
pub(super) const SLOPE: f32 = 0.25;

/// Every vertex near the `held` ones whose share of its path
/// `start → requested` is less than all of it, with that share: a vertex's
/// share is at most a neighbour's plus [`SLOPE`] times the edge between
/// them over the longer of their two paths, the held ones' share 0 (the
/// shortest such distance from the patch, by Dijkstra's search).
pub(super) fn shares(rings: &Rings, held: &[bool], start: &[Vec3], requested: &[Vec3]) -> Vec<(u32, f32)> {
    let path = |v: u32| (requested[v as usize] - start[v as usize]).length();
    let mut share: Vec<f32> = vec![f32::INFINITY; start.len()];
    // Shares are non-negative: their bits order as they do.
    let mut front: BinaryHeap<Reverse<(u32, u32)>> = BinaryHeap::new();
    for v in (0..start.len() as u32).filter(|&v| held[v as usize]) {
        share[v as usize] = 0.0;
        front.push(Reverse((0, v)));
    }
    let mut reached = Vec::new();
    while let Some(Reverse((bits, v))) = front.pop() {
        let at = f32::from_bits(bits);
        if at > share[v as usize] {
            continue;
        }
        for &w in rings.ring(v) {
            if held[w as usize] {
                continue;
            }
            let longer = path(v).max(path(w));
            if longer == 0.0 {
                continue;
            }
            let next = at + SLOPE * (start[v as usize] - start[w as usize]).length() / longer;
            if next < 1.0 && next < share[w as usize] {
                if share[w as usize] == f32::INFINITY {
                    reached.push(w);
                }
                share[w as usize] = next;
                front.push(Reverse((next.to_bits(), w)));
            }
        }
    }
    reached.sort_unstable();
    reached.into_iter().map(|v| (v, share[v as usize])).collect()
}
