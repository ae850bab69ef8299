//! At which one time along the gathered paths a set of positions fits them
//! best ([`PathFits::best`]): the coverage check of the in-loop passes
//! (`Candidates::fitted` in `resolve`), asked at every round.
//!
//! Each vertex's path is the straight line `start → reference`, with a
//! margin; the times tried are `k / FIT_STEPS`. What one vertex contributes
//! (at which times it lies beyond its margin) depends only on its own
//! position, path and margin, so a fit once worked out is kept with the
//! positions it was worked out for, and the next query of positions that
//! differ at a few vertices (a round's corrections, the fail-safe's put
//! back vertices; the paths changed only where a gathering went around a
//! few vertices) works out only those vertices again. Worked out in full at
//! every round, over the skin and all 33 times, this check was 1.4G of the
//! MakeHuman character's 30.8G instructions over frames 1–11 (issue 30,
//! twenty-sixth round).

use glam::Vec3;
use rayon::prelude::*;

/// How finely a fit looks for the time along the gathered paths at which
/// positions fit them best (1/n of the paths).
const FIT_STEPS: usize = 32;

/// Per vertex, bits `0..=FIT_STEPS`: beyond its margin (`> margin`) at time
/// `k / FIT_STEPS`; then the same two ends asked the other way round, not
/// within it (`!(≤ margin)`), which the first question of a fit is (the
/// two differ only for a NaN distance, and then the answer is the full
/// check's).
const NOT_WITHIN_AT_START: usize = FIT_STEPS + 1;
const NOT_WITHIN_AT_END: usize = FIT_STEPS + 2;
const MARKS: usize = FIT_STEPS + 3;

/// At most this many fits (of different positions) are kept: an in-loop
/// pass asks about the iteration's start and its end, the next iteration
/// starts where this one ended.
const KEPT: usize = 2;

/// A fit is worked out again only at the vertices that changed while they
/// are at most 1/n of the skin; more, the positions are new ones (another
/// iteration's), and most fit the end or the start of the paths as a whole,
/// which the first question answers by one pass without the other times.
const INCREMENTAL: usize = 8;

/// The `k`-th of the times tried.
fn fit_time(k: usize) -> f32 {
    k as f32 / FIT_STEPS as f32
}

/// The gathered paths: vertex `v` goes from `start[v]` to `reference[v]`
/// and may stray `margin[v]` from that path.
pub(super) struct Paths<'a> {
    pub start: &'a [Vec3],
    pub reference: &'a [Vec3],
    pub margin: &'a [f32],
}

impl Paths<'_> {
    /// Where vertex `v`'s path is at time `t`.
    fn at(&self, v: usize, t: f32) -> Vec3 {
        self.start[v] + t * (self.reference[v] - self.start[v])
    }

    /// Whether every vertex of `x` is within its margin of its path at time `t`.
    fn all_within(&self, x: &[Vec3], t: f32) -> bool {
        (0..x.len()).into_par_iter().with_min_len(4096).all(|v| (x[v] - self.at(v, t)).length() <= self.margin[v])
    }

    /// Vertex `v`'s marks at `x` (its bits: see [`MARKS`]), each distance
    /// the same expression as [`Self::at`]'s (the path `reference − start`
    /// worked out once: the same value), so the same decisions. The times'
    /// tests are made into an array first, a loop the compiler runs several
    /// times at once (as the full check's counts were), then packed.
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(≤)` is the first question's form, NaN included
    fn marks(&self, x: Vec3, v: usize) -> u64 {
        let (start, margin) = (self.start[v], self.margin[v]);
        let path = self.reference[v] - start;
        let off = |k: usize| (x - (start + fit_time(k) * path)).length();
        let mut beyond = [0u8; FIT_STEPS + 1];
        for (k, b) in beyond.iter_mut().enumerate() {
            *b = u8::from(off(k) > margin);
        }
        let mut marks = beyond.iter().enumerate().fold(0u64, |marks, (k, &b)| marks | u64::from(b) << k);
        marks |= u64::from(!(off(0) <= margin)) << NOT_WITHIN_AT_START | u64::from(!(off(FIT_STEPS) <= margin)) << NOT_WITHIN_AT_END;
        marks
    }
}

/// One set of positions' fit: each vertex's marks and how many vertices
/// have each.
#[derive(Debug, Clone)]
struct Fit {
    x: Vec<Vec3>,
    marks: Vec<u64>,
    counts: [usize; MARKS],
    /// Vertices whose path or margin changed since their marks were made.
    repathed: Vec<u32>,
}

impl Fit {
    fn new(paths: &Paths<'_>, x: &[Vec3]) -> Self {
        let marks: Vec<u64> = (0..x.len()).into_par_iter().with_min_len(4096).map(|v| paths.marks(x[v], v)).collect();
        let counts = marks
            .par_chunks(4096)
            .map(|chunk| {
                let mut counts = [0usize; MARKS];
                chunk.iter().for_each(|&m| add(&mut counts, m));
                counts
            })
            .reduce(
                || [0usize; MARKS],
                |mut a, b| {
                    a.iter_mut().zip(b).for_each(|(a, b)| *a += b);
                    a
                },
            );
        Fit { x: x.to_vec(), marks, counts, repathed: Vec::new() }
    }

    /// The vertices at which `x` differs from the fit's positions (bit for
    /// bit), if at most `limit` do.
    fn differences(&self, x: &[Vec3], limit: usize) -> Option<Vec<u32>> {
        if x.len() != self.x.len() {
            return None;
        }
        // Compared a block of vertices at a time as words (a `memcmp`),
        // vertex by vertex only in the blocks that differ.
        const BLOCK: usize = 16;
        let mine: &[u32] = bytemuck::cast_slice(&self.x);
        let theirs: &[u32] = bytemuck::cast_slice(x);
        let mut changed = Vec::new();
        for (b, (a, c)) in mine.chunks(3 * BLOCK).zip(theirs.chunks(3 * BLOCK)).enumerate() {
            if a == c {
                continue;
            }
            for (i, (p, q)) in a.chunks_exact(3).zip(c.chunks_exact(3)).enumerate() {
                if p != q {
                    changed.push((b * BLOCK + i) as u32);
                }
            }
            if changed.len() > limit {
                return None;
            }
        }
        Some(changed)
    }

    /// The fit at `x`, which differs from the fit's positions only at the
    /// vertices `changed`, with the paths now `paths`.
    fn update(&mut self, paths: &Paths<'_>, x: &[Vec3], changed: &[u32]) {
        for &v in changed.iter().chain(&std::mem::take(&mut self.repathed)) {
            let v = v as usize;
            let marks = paths.marks(x[v], v);
            remove(&mut self.counts, self.marks[v]);
            add(&mut self.counts, marks);
            self.marks[v] = marks;
            self.x[v] = x[v];
        }
    }

    /// The vertices beyond their margins at the one time that leaves out
    /// the fewest, and how many: none where every vertex is within its
    /// margin at the paths' end or at their start.
    fn answer(&self) -> (Vec<bool>, usize) {
        if self.counts[NOT_WITHIN_AT_END] == 0 || self.counts[NOT_WITHIN_AT_START] == 0 {
            return (vec![false; self.marks.len()], 0);
        }
        // The first of the times that leave out the fewest.
        let best = (0..=FIT_STEPS).min_by_key(|&k| self.counts[k]).expect("FIT_STEPS + 1 times");
        (self.marks.iter().map(|&m| m >> best & 1 != 0).collect(), self.counts[best])
    }
}

fn add(counts: &mut [usize; MARKS], marks: u64) {
    for_each_mark(marks, |k| counts[k] += 1);
}

fn remove(counts: &mut [usize; MARKS], marks: u64) {
    for_each_mark(marks, |k| counts[k] -= 1);
}

/// Calls `f` with the number of each bit set in `marks`.
fn for_each_mark(mut marks: u64, mut f: impl FnMut(usize)) {
    while marks != 0 {
        f(marks.trailing_zeros() as usize);
        marks &= marks - 1;
    }
}

/// The fits of the last positions asked about, most recent first, kept
/// with the gathered paths (`Candidates`) they were worked out against.
#[derive(Debug, Clone, Default)]
pub(super) struct PathFits {
    fits: Vec<Fit>,
}

impl PathFits {
    /// The paths of `vertices` changed (a gathering around them): their
    /// marks are worked out again at the next query.
    pub(super) fn repathed(&mut self, vertices: &[u32]) {
        for fit in &mut self.fits {
            fit.repathed.extend_from_slice(vertices);
        }
    }

    /// The vertices of `x` beyond their margins of the `paths` at the one
    /// time (for every vertex) that leaves out the fewest, and how many.
    /// The end and the start of the paths are tried first (an iteration
    /// after the one that gathered ends near the end; the rounds of the one
    /// that gathered start at the start); then every 1/[`FIT_STEPS`].
    ///
    /// The same answer as working every vertex out at every time: a kept
    /// fit's marks are each vertex's own, made by the same expression,
    /// and the ones that changed (position, or path and margin) are made
    /// again before the counts are read.
    pub(super) fn best(&mut self, paths: &Paths<'_>, x: &[Vec3]) -> (Vec<bool>, usize) {
        let limit = x.len() / INCREMENTAL;
        for i in 0..self.fits.len() {
            if let Some(changed) = self.fits[i].differences(x, limit) {
                let mut fit = self.fits.remove(i);
                fit.update(paths, x, &changed);
                let answer = fit.answer();
                self.fits.insert(0, fit);
                return answer;
            }
        }
        if paths.all_within(x, fit_time(FIT_STEPS)) || paths.all_within(x, fit_time(0)) {
            return (vec![false; x.len()], 0);
        }
        let fit = Fit::new(paths, x);
        let answer = fit.answer();
        self.fits.insert(0, fit);
        self.fits.truncate(KEPT);
        answer
    }

    /// For the tests: the positions of the fits kept.
    #[cfg(test)]
    pub(super) fn kept_positions(&self) -> Vec<&[Vec3]> {
        self.fits.iter().map(|fit| fit.x.as_slice()).collect()
    }

    /// For the tests: the same question worked out in full, every vertex at
    /// every time, nothing kept (the check as it was before fits were kept).
    #[cfg(test)]
    pub(super) fn best_in_full(paths: &Paths<'_>, x: &[Vec3]) -> (Vec<bool>, usize) {
        let within = |t: f32| (0..x.len()).all(|v| (x[v] - paths.at(v, t)).length() <= paths.margin[v]);
        if within(1.0) || within(0.0) {
            return (vec![false; x.len()], 0);
        }
        let outside = |v: usize, t: f32| (x[v] - paths.at(v, t)).length() > paths.margin[v];
        let counts: Vec<usize> = (0..=FIT_STEPS).map(|k| (0..x.len()).filter(|&v| outside(v, fit_time(k))).count()).collect();
        let best = (0..=FIT_STEPS).min_by_key(|&k| counts[k]).expect("FIT_STEPS + 1 times");
        ((0..x.len()).map(|v| outside(v, fit_time(best))).collect(), counts[best])
    }
}
