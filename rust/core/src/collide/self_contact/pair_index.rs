//! Where in the candidates' list the pairs of given vertices are
//! ([`PairIndex`]), kept through the changes a gathering around a few
//! vertices makes to the list: it drops every pair with a corner among
//! them and appends their new pairs, the others keeping their order.
//!
//! Why: finding the pairs to drop by a pass over the whole list was about a
//! quarter of such a gathering on the MakeHuman character (5.6M of 21M
//! instructions, issue 30, twenty-fifth round (a)), where the list is kept
//! for a whole frame of up to 26 of them. Per-vertex lists of positions
//! made again whenever the list changed did not pay (twenty-fourth round
//! (a)); this index is made once per list and follows its changes.
//!
//! Each pair gets an id when the index is made (its position then) or when
//! it is appended (the next unused): the list's order is always that of the
//! ids, so a live pair's position is the number of live ids below its own,
//! read from one bit per id and a running count per 64 ids.

use super::gather::ElementPair;

/// The index is made again from the list once this many times more entries
/// were appended than it was made with (their lookups are a pass over the
/// appended entries).
const REMAKE_AFTER: usize = 1;

#[derive(Debug, Clone, Default)]
pub(super) struct PairIndex {
    /// Per vertex `v`, the ids of the pairs listed when the index was made
    /// with `v` as a corner: `ids[starts[v]..starts[v + 1]]`.
    starts: Vec<u32>,
    ids: Vec<u32>,
    /// The pairs appended since, one entry per corner: (vertex, id).
    appended: Vec<(u32, u32)>,
    /// One bit per id: still listed.
    live: Vec<u64>,
    /// Per 64 ids, how many ids below them are live.
    live_below: Vec<u32>,
    /// How many ids were given.
    next: u32,
}

impl PairIndex {
    /// The index of `pairs` over `vertex_count` vertices.
    pub(super) fn new(pairs: &[ElementPair], vertex_count: usize) -> Self {
        // The pairs' corners grouped by vertex, each corner `4 id + k`
        // standing for pair `id`.
        let corners: Vec<u32> = pairs.iter().flat_map(|pair| pair.corners).collect();
        let (starts, mut ids) = crate::mesh::group_members(&corners, vertex_count);
        ids.iter_mut().for_each(|corner| *corner /= 4);
        let mut index = PairIndex { starts, ids, appended: Vec::new(), live: Vec::new(), live_below: Vec::new(), next: 0 };
        index.give_ids(pairs.len());
        index
    }

    /// Whether the index should be made again from the list (too many
    /// entries were appended since it was made).
    pub(super) fn stale(&self) -> bool {
        self.appended.len() > REMAKE_AFTER * self.ids.len().max(1024)
    }

    /// Ids for `count` pairs appended to the list, live.
    fn give_ids(&mut self, count: usize) {
        let next = self.next as usize + count;
        self.live.resize(next.div_ceil(64), 0);
        for id in self.next as usize..next {
            self.live[id / 64] |= 1 << (id % 64);
        }
        let from = (self.next as usize / 64).min(self.live_below.len());
        self.next = next as u32;
        self.count_from(from);
    }

    /// `live_below` again from word `from` on.
    fn count_from(&mut self, from: usize) {
        self.live_below.truncate(from);
        let mut below = if from == 0 { 0 } else { self.live_below[from - 1] + self.live[from - 1].count_ones() };
        for &word in &self.live[from..] {
            self.live_below.push(below);
            below += word.count_ones();
        }
    }

    fn is_live(&self, id: u32) -> bool {
        self.live[id as usize / 64] >> (id % 64) & 1 != 0
    }

    /// The position in the list of live pair `id`.
    fn position(&self, id: u32) -> usize {
        let (word, bit) = (id as usize / 64, id % 64);
        self.live_below[word] as usize + (self.live[word] & ((1u64 << bit) - 1)).count_ones() as usize
    }

    /// The positions, ascending, of the listed pairs with a corner among
    /// `vertices` (`flags` the same vertices, per vertex), which the list
    /// drops: from here on they are not listed.
    pub(super) fn drop_pairs_of(&mut self, vertices: &[u32], flags: &[bool]) -> Vec<usize> {
        let mut dropped: Vec<u32> = vertices.iter().flat_map(|&v| &self.ids[self.starts[v as usize] as usize..self.starts[v as usize + 1] as usize]).copied().filter(|&id| self.is_live(id)).collect();
        dropped.extend(self.appended.iter().filter(|&&(v, id)| flags[v as usize] && self.is_live(id)).map(|&(_, id)| id));
        dropped.sort_unstable();
        dropped.dedup();
        let positions = dropped.iter().map(|&id| self.position(id)).collect();
        for &id in &dropped {
            self.live[id as usize / 64] &= !(1 << (id % 64));
        }
        if let Some(&first) = dropped.first() {
            self.count_from(first as usize / 64);
        }
        positions
    }

    /// `pairs` were appended to the list.
    pub(super) fn append(&mut self, pairs: &[ElementPair]) {
        let first = self.next;
        self.give_ids(pairs.len());
        for (k, pair) in pairs.iter().enumerate() {
            self.appended.extend(pair.corners.iter().map(|&v| (v, first + k as u32)));
        }
    }
}

/// Keeps in `values` (in their order) all but the entries at `dropped`
/// (ascending positions), moving each run of kept entries once.
pub(super) fn compact<T: Copy>(values: &mut Vec<T>, dropped: &[usize]) {
    let Some(&first) = dropped.first() else { return };
    let mut kept = first;
    for (k, &at) in dropped.iter().enumerate() {
        let end = dropped.get(k + 1).copied().unwrap_or(values.len());
        values.copy_within(at + 1..end, kept);
        kept += end - at - 1;
    }
    values.truncate(kept);
}
