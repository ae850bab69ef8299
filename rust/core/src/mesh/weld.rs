//! Vertices that coincide at rest, welded for the solver.
//!
//! glTF, FBX and USD importers split a mesh's vertices wherever a UV or a
//! sharp normal changes, so a character arrives as shells whose borders lie
//! exactly on top of each other. A deformer that took the connectivity at its
//! word would see thousands of open edges and let the seams drift apart. A
//! [`Weld`] maps every vertex to one representative among those within a
//! tolerance of it at rest (chained: a cluster is welded whole), so that the
//! solver works on the surface the artist sees; results are scattered back,
//! and the user's mesh is never changed.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Default weld distance, relative to the rest bounding box's diagonal: far
/// below any edge of a real mesh (a 2 m figure gets 2 µm), far above the
/// rounding of positions written out and read back in single precision.
pub const WELD_TOLERANCE: f32 = 1e-6;

/// Edges shorter than this fraction of their neighbours' are slivers, welded
/// for the solver ([`Weld::by_distance_and_slivers`]).
pub const SLIVER_RATIO: f32 = 0.01;

/// The map from a mesh's vertices to the welded vertices the solver sees.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Weld {
    /// Per original vertex: its welded vertex, numbered in the order of each
    /// cluster's smallest original index.
    welded_of: Vec<u32>,
    /// Per welded vertex, its original vertices: `members[member_offsets[w]..member_offsets[w + 1]]`, ascending.
    member_offsets: Vec<u32>,
    members: Vec<u32>,
}

impl Weld {
    /// Welds the vertices of `rest` within `tolerance` × its bounding-box
    /// diagonal of each other. Expects finite positions (validated upstream).
    pub fn by_distance(rest: &[Vec3], tolerance: f32) -> Weld {
        let reach = f64::from(tolerance) * diagonal(rest);
        let pairs = if reach > 0.0 { close_pairs(rest, reach) } else { Vec::new() };
        Weld::from_pairs(rest.len(), &pairs)
    }

    /// [`Weld::by_distance`], and also the two ends of every edge of the
    /// polygons (`corner_verts` cut at `offsets`) shorter than `sliver_ratio`
    /// times the mean length of the other edges at both of its ends: a sliver
    /// whose two sides no ring, fit or encoding can keep apart without
    /// tearing, so the solver moves them as one (they end up on the same
    /// point, less than `sliver_ratio` of an edge from where they were).
    pub fn by_distance_and_slivers(rest: &[Vec3], corner_verts: &[i32], offsets: &[u32], tolerance: f32, sliver_ratio: f32) -> Weld {
        let reach = f64::from(tolerance) * diagonal(rest);
        let mut pairs = if reach > 0.0 { close_pairs(rest, reach) } else { Vec::new() };
        let edges = super::polygon_edges(corner_verts, offsets);
        let length = |[a, b]: [u32; 2]| f64::from((rest[a as usize] - rest[b as usize]).length());
        let mut sum = vec![0.0f64; rest.len()];
        let mut degree = vec![0u32; rest.len()];
        for &e in &edges {
            for v in e {
                sum[v as usize] += length(e);
                degree[v as usize] += 1;
            }
        }
        for &e in &edges {
            let l = length(e);
            let others = e.map(|v| {
                let v = v as usize;
                if degree[v] > 1 { (sum[v] - l) / f64::from(degree[v] - 1) } else { f64::INFINITY }
            });
            if l < f64::from(sliver_ratio) * others[0].min(others[1]) {
                pairs.push((e[0], e[1]));
            }
        }
        Weld::from_pairs(rest.len(), &pairs)
    }

    /// No two vertices welded.
    pub fn identity(vertex_count: usize) -> Weld {
        Weld::from_pairs(vertex_count, &[])
    }

    fn from_pairs(n: usize, pairs: &[(u32, u32)]) -> Weld {
        // Union–find towards the smallest index: the result does not depend on
        // the order in which pairs were found.
        let mut root: Vec<u32> = (0..n as u32).collect();
        fn find(root: &mut [u32], mut i: u32) -> u32 {
            while root[i as usize] != i {
                let up = root[root[i as usize] as usize];
                root[i as usize] = up;
                i = up;
            }
            i
        }
        for &(a, b) in pairs {
            let (ra, rb) = (find(&mut root, a), find(&mut root, b));
            let (low, high) = if ra < rb { (ra, rb) } else { (rb, ra) };
            root[high as usize] = low;
        }
        let mut welded_of = vec![0u32; n];
        let mut count = 0u32;
        for v in 0..n {
            let r = find(&mut root, v as u32);
            welded_of[v] = if r == v as u32 {
                count += 1;
                count - 1
            } else {
                welded_of[r as usize]
            };
        }
        let (member_offsets, members) = super::group_members(&welded_of, count as usize);
        Weld { welded_of, member_offsets, members }
    }

    /// Number of original vertices.
    pub fn vertex_count(&self) -> usize {
        self.welded_of.len()
    }

    /// Number of welded vertices.
    pub fn welded_count(&self) -> usize {
        self.member_offsets.len() - 1
    }

    /// True when no two vertices were welded: every map is the identity.
    pub fn is_identity(&self) -> bool {
        self.welded_count() == self.vertex_count()
    }

    /// The welded vertex of original vertex `v`.
    #[inline]
    pub fn welded_of(&self, v: usize) -> u32 {
        self.welded_of[v]
    }

    /// The original vertices of welded vertex `w`, ascending.
    #[inline]
    pub fn members(&self, w: usize) -> &[u32] {
        &self.members[self.member_offsets[w] as usize..self.member_offsets[w + 1] as usize]
    }

    /// Corner indices renumbered to welded vertices. Polygons keep their
    /// corners; one that welding folds onto itself (two of its corners
    /// welded) is reported as degenerate by the topology, like any other.
    pub fn corners(&self, corner_verts: &[i32]) -> Vec<i32> {
        corner_verts
            .iter()
            .map(|&c| if c >= 0 && (c as usize) < self.welded_of.len() { self.welded_of[c as usize] as i32 } else { c })
            .collect()
    }

    /// Per welded vertex, the mean of its members' values.
    pub fn gather(&self, values: &[Vec3]) -> Vec<Vec3> {
        (0..self.welded_count())
            .into_par_iter()
            .with_min_len(4096)
            .map(|w| {
                let members = self.members(w);
                if let [only] = members {
                    return values[*only as usize];
                }
                let sum: DVec3 = members.iter().map(|&v| values[v as usize].as_dvec3()).sum();
                (sum / members.len() as f64).as_vec3()
            })
            .collect()
    }

    /// Per welded vertex, the mean of its members' scalars (painted weights).
    pub fn gather_scalars(&self, values: &[f32]) -> Vec<f32> {
        (0..self.welded_count())
            .map(|w| {
                let members = self.members(w);
                members.iter().map(|&v| f64::from(values[v as usize])).sum::<f64>() as f32 / members.len() as f32
            })
            .collect()
    }

    /// Per original vertex, its welded vertex's value.
    pub fn scatter(&self, welded: &[Vec3], out: &mut [Vec3]) {
        out.par_iter_mut()
            .with_min_len(4096)
            .zip(self.welded_of.par_iter())
            .for_each(|(o, &w)| *o = welded[w as usize]);
    }

    /// Original vertices of a list of welded ones, ascending.
    pub fn expand(&self, welded: &[u32]) -> Vec<u32> {
        let mut out: Vec<u32> = welded.iter().flat_map(|&w| self.members(w as usize).iter().copied()).collect();
        out.sort_unstable();
        out
    }
}

fn diagonal(points: &[Vec3]) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    let (lo, hi) = points
        .par_iter()
        .fold(
            || (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN)),
            |(lo, hi), p| (lo.min(p.as_dvec3()), hi.max(p.as_dvec3())),
        )
        .reduce(|| (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN)), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    (hi - lo).length()
}

/// Cells this many times the reach: a vertex then needs to look into a
/// neighbouring cell only when it is within reach of that cell's face, which
/// few are, and a cell still holds only vertices far closer than an edge.
const CELL_PER_REACH: f64 = 64.0;

/// Every pair `(a, b)`, `a < b`, of vertices within `reach` of each other.
fn close_pairs(points: &[Vec3], reach: f64) -> Vec<(u32, u32)> {
    let cell = reach * CELL_PER_REACH;
    let cell_of = |p: DVec3| (p / cell).floor().as_i64vec3();
    let mut order: Vec<(glam::I64Vec3, u32)> =
        points.par_iter().enumerate().map(|(i, p)| (cell_of(p.as_dvec3()), i as u32)).collect();
    order.par_sort_unstable_by_key(|&(c, i)| (c.x, c.y, c.z, i));
    let run = |c: glam::I64Vec3| -> &[(glam::I64Vec3, u32)] {
        let key = (c.x, c.y, c.z);
        let start = order.partition_point(|&(d, _)| (d.x, d.y, d.z) < key);
        let end = start + order[start..].partition_point(|&(d, _)| (d.x, d.y, d.z) == key);
        &order[start..end]
    };
    let reach2 = reach * reach;
    let mut pairs: Vec<(u32, u32)> = points
        .par_iter()
        .enumerate()
        .flat_map_iter(|(a, p)| {
            let p = p.as_dvec3();
            let home = cell_of(p);
            let within = p / cell - home.as_dvec3(); // in [0, 1) per axis
            let near = |t: f64| -> &'static [i64] {
                if t * CELL_PER_REACH <= 1.0 {
                    &[0, -1]
                } else if (1.0 - t) * CELL_PER_REACH <= 1.0 {
                    &[0, 1]
                } else {
                    &[0]
                }
            };
            let mut found = Vec::new();
            for &dx in near(within.x) {
                for &dy in near(within.y) {
                    for &dz in near(within.z) {
                        for &(_, b) in run(home + glam::I64Vec3::new(dx, dy, dz)) {
                            if (b as usize) > a && (points[b as usize].as_dvec3() - p).length_squared() <= reach2 {
                                found.push((a as u32, b));
                            }
                        }
                    }
                }
            }
            found
        })
        .collect();
    pairs.sort_unstable();
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn split_duplicates_weld_and_scatter_back() {
        // Two triangles sharing an edge, split as a glTF importer would.
        let rest = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
        ];
        let weld = Weld::by_distance(&rest, WELD_TOLERANCE);
        assert_eq!(weld.welded_count(), 4);
        assert_eq!((0..6).map(|v| weld.welded_of(v)).collect::<Vec<_>>(), vec![0, 1, 2, 1, 2, 3]);
        assert_eq!(weld.members(1), &[1, 3]);
        assert_eq!(weld.corners(&[0, 1, 2, 3, 5, 4]), vec![0, 1, 2, 1, 3, 2]);
        let moved: Vec<Vec3> = rest.iter().enumerate().map(|(i, p)| *p + Vec3::splat(i as f32)).collect();
        let gathered = weld.gather(&moved);
        assert_eq!(gathered[1], Vec3::new(1.0, 0.0, 0.0) + Vec3::splat(2.0)); // mean of +1 and +3
        let mut out = vec![Vec3::ZERO; 6];
        weld.scatter(&gathered, &mut out);
        assert_eq!(out[1], out[3]);
        assert_eq!(weld.expand(&[1, 3]), vec![1, 3, 5]);
    }

    #[test]
    fn sliver_edges_are_welded_and_ordinary_short_ones_are_not() {
        // A row of three quads whose middle one is a sliver 1e-4 wide, beside one a fifth as wide.
        let xs = [0.0f32, 1.0, 1.0001, 2.0, 2.2];
        let rest: Vec<Vec3> = xs.iter().flat_map(|&x| [Vec3::new(x, 0.0, 0.0), Vec3::new(x, 1.0, 0.0)]).collect();
        let corners: Vec<i32> = (0..4).flat_map(|q| [2 * q, 2 * q + 2, 2 * q + 3, 2 * q + 1]).collect();
        let offsets: Vec<u32> = (0..=4).map(|q| 4 * q).collect();
        let weld = Weld::by_distance_and_slivers(&rest, &corners, &offsets, WELD_TOLERANCE, SLIVER_RATIO);
        assert_eq!(weld.welded_count(), rest.len() - 2);
        assert_eq!(weld.members(weld.welded_of(2) as usize), &[2, 4]);
        assert_eq!(weld.members(weld.welded_of(3) as usize), &[3, 5]);
        assert_eq!(weld.members(weld.welded_of(8) as usize), &[8]);
    }

    #[test]
    fn vertices_further_than_the_tolerance_stay_apart() {
        let rest = vec![Vec3::ZERO, Vec3::new(1e-3, 0.0, 0.0), Vec3::new(1.0, 1.0, 1.0)];
        assert!(Weld::by_distance(&rest, WELD_TOLERANCE).is_identity());
        assert_eq!(Weld::by_distance(&rest, 1e-3).welded_count(), 2);
    }

    proptest! {
        /// Against brute force, with clusters straddling cell borders.
        #[test]
        fn pairs_match_brute_force(seed_points in proptest::collection::vec((-50i32..50, -50i32..50, -3i32..3), 2..200), jitter in 0.0f32..2.0) {
            let reach_of = |pts: &[Vec3]| f64::from(1e-3f32) * diagonal(pts);
            let mut points: Vec<Vec3> = Vec::new();
            for (i, &(x, y, z)) in seed_points.iter().enumerate() {
                let p = Vec3::new(x as f32, y as f32, z as f32) * 0.01;
                points.push(p);
                if i % 3 == 0 {
                    // A near-duplicate, jittered around the reach.
                    points.push(p + Vec3::new(jitter, -jitter, 0.5 * jitter) * 1e-5);
                }
            }
            let reach = reach_of(&points);
            let mut expected = Vec::new();
            for a in 0..points.len() {
                for b in a + 1..points.len() {
                    if (points[a].as_dvec3() - points[b].as_dvec3()).length_squared() <= reach * reach {
                        expected.push((a as u32, b as u32));
                    }
                }
            }
            prop_assert_eq!(close_pairs(&points, reach), expected);
        }
    }
}
