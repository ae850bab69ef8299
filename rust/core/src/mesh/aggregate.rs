//! Greedy one-ring aggregation of a graph: the coarsening step of the
//! solver's coarse level ([`crate::solve`]) and of the strain pass's block
//! levels ([`crate::strain::Hierarchy`]).

/// The members of each group, given each node's group `of` (`< count`):
/// `(offsets, members)`, group `g`'s nodes ascending at
/// `members[offsets[g]..offsets[g + 1]]`.
pub fn group_members(of: &[u32], count: usize) -> (Vec<u32>, Vec<u32>) {
    let mut offsets = vec![0u32; count + 1];
    for &g in of {
        offsets[g as usize + 1] += 1;
    }
    for g in 0..count {
        offsets[g + 1] += offsets[g];
    }
    let mut fill = offsets.clone();
    let mut members = vec![0u32; of.len()];
    for (v, &g) in of.iter().enumerate() {
        members[fill[g as usize] as usize] = v as u32;
        fill[g as usize] += 1;
    }
    (offsets, members)
}

/// One round of aggregation of a graph of `nodes` nodes whose `edges` list
/// every edge in both directions, sorted and without duplicates. In node
/// order, a node none of whose neighbours is taken starts an aggregate with
/// all of them; then every node left joins a neighbour's aggregate (or
/// stays alone). Sequential: deterministic. Returns each node's aggregate
/// and the number of aggregates.
pub fn aggregate_once(nodes: usize, edges: &[(u32, u32)]) -> (Vec<u32>, usize) {
    let mut offsets = vec![0usize; nodes + 1];
    for &(a, _) in edges {
        offsets[a as usize + 1] += 1;
    }
    for a in 0..nodes {
        offsets[a + 1] += offsets[a];
    }
    let neighbours = |a: usize| edges[offsets[a]..offsets[a + 1]].iter().map(|e| e.1 as usize);
    let mut of = vec![u32::MAX; nodes];
    let mut next = 0u32;
    for a in 0..nodes {
        if of[a] == u32::MAX && neighbours(a).all(|b| of[b] == u32::MAX) {
            of[a] = next;
            for b in neighbours(a) {
                of[b] = next;
            }
            next += 1;
        }
    }
    for a in 0..nodes {
        if of[a] == u32::MAX {
            let joined = neighbours(a).map(|b| of[b]).find(|&o| o != u32::MAX);
            of[a] = joined.unwrap_or_else(|| {
                next += 1;
                next - 1
            });
        }
    }
    (of, next as usize)
}

/// The edges between the aggregates `of` of the nodes of `edges` (both
/// directions, sorted, without duplicates or loops), in the form
/// [`aggregate_once`] takes.
pub fn aggregate_edges(edges: &[(u32, u32)], of: &[u32]) -> Vec<(u32, u32)> {
    let mut coarse: Vec<(u32, u32)> = edges.iter().map(|&(a, b)| (of[a as usize], of[b as usize])).filter(|e| e.0 != e.1).collect();
    coarse.sort_unstable();
    coarse.dedup();
    coarse
}

#[cfg(test)]
mod tests {
    use super::*;

    fn both_ways(edges: &[(u32, u32)]) -> Vec<(u32, u32)> {
        let mut all: Vec<(u32, u32)> = edges.iter().flat_map(|&(a, b)| [(a, b), (b, a)]).collect();
        all.sort_unstable();
        all.dedup();
        all
    }

    #[test]
    fn a_chain_is_cut_into_one_rings() {
        // 0-1-2-3-4-5-6: 0 takes 1; 2 has a taken neighbour, 3 takes 2
        // and 4; 5 has a taken neighbour, 6 takes 5.
        let edges = both_ways(&(0..6).map(|i| (i, i + 1)).collect::<Vec<_>>());
        let (of, count) = aggregate_once(7, &edges);
        assert_eq!(of, vec![0, 0, 1, 1, 1, 2, 2]);
        assert_eq!(count, 3);
        assert_eq!(aggregate_edges(&edges, &of), vec![(0, 1), (1, 0), (1, 2), (2, 1)]);
    }

    #[test]
    fn isolated_nodes_stay_alone() {
        let (of, count) = aggregate_once(3, &[]);
        assert_eq!((of, count), (vec![0, 1, 2], 3));
    }
}
