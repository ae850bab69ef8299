//! [`SelfCollision`]: what self-collision keeps of a bind (the patch tree,
//! element ownership, rest positions) and what it derives from the
//! settings (neighbour exclusion, the per-vertex separations at rest).
//!
//! It triangulates the mesh on its own, each quad both ways
//! ([`either_split_triangles`]): its triangles are the four of the two
//! splits and its edges the sides with both diagonals, so that a contact
//! either split would have is a contact between two of its elements.

use glam::Vec3;
use rayon::prelude::*;

use super::bounds::{Motion, NodeBounds};
use super::exclusion::Exclusion;
use super::gather::{ownership, scale_of, ElementPair, Focus, Gather};
use super::held::Rings;
use super::hinge::Hinges;
use super::star::Stars;
use super::settings::SelfSettings;
use super::tree::PatchTree;
use crate::collide::geometry::{point_triangle_distance_squared, segment_crosses_triangle, segment_segment_distance_squared};
use crate::mesh::{either_split_triangles, triangle_edges, validate_positions, MeshInput};
use crate::{Error, Result};

/// The skin's contact with itself, bound to one skin.
#[derive(Debug, Clone)]
pub struct SelfCollision {
    pub(super) vertex_count: usize,
    pub(super) tree: PatchTree,
    /// Per tree position, the polygon its triangle comes from.
    pub(super) polygon: Vec<u32>,
    pub(super) owns: Vec<u8>,
    /// Its edges: the polygons' sides, fan diagonals and both diagonals of quads.
    edges: Vec<[u32; 2]>,
    /// The quads split both ways (their two diagonals cross: not a contact).
    quads: Vec<[u32; 4]>,
    rest: Vec<Vec3>,
    /// Rounding allowance of the f32 boxes (relative to the rest's size).
    pub(super) rounding: f32,
    exclusion: Exclusion,
    /// Per vertex, the separation its pairs keep: the thickness, or half the
    /// rest distance of its closest pair where that is less; with the
    /// thickness and rings it was measured for.
    separation: Option<(f32, u32, Vec<f32>)>,
    /// The pairs one hinge apart, never contacts whatever the tree.
    pub(super) hinges: Hinges,
    /// The pairs two polygons apart round a vertex, never contacts whatever the tree.
    pub(super) stars: Stars,
    /// Every vertex's ring along the polygons' sides: the fail-safe holds a
    /// vertex with its ring ([`super::held`]).
    pub(super) rings: Rings,
}

impl SelfCollision {
    /// Binds self-collision to a polygon mesh at rest (`mesh.positions`):
    /// each quad split both ways, other polygons by their fan.
    pub fn new(mesh: MeshInput<'_>) -> Result<Self> {
        let offsets = mesh.validate()?;
        let rest = mesh.positions;
        let (triangles, quads) = either_split_triangles(mesh.corner_verts, &offsets);
        let (triangles, polygon_of): (Vec<[u32; 3]>, Vec<u32>) = triangles.into_iter().unzip();
        let edges = triangle_edges(&triangles);
        // A polygon's triangles stay together; a quad's first split (its
        // first two triangles) is the surface whose topology decides disks.
        let mut unit_offsets = vec![0u32];
        let mut surface = Vec::with_capacity(triangles.len());
        for (t, &p) in polygon_of.iter().enumerate() {
            if t > 0 && polygon_of[t - 1] != p {
                unit_offsets.push(t as u32);
            }
            let first_of_polygon = *unit_offsets.last().expect("starts with 0") as usize;
            surface.push(t - first_of_polygon < 2 || !split_both_ways(&triangles, &polygon_of, first_of_polygon));
        }
        if !triangles.is_empty() {
            unit_offsets.push(triangles.len() as u32);
        }
        let tree = PatchTree::build_in_units(&triangles, &unit_offsets, &surface, rest);
        let hinges = Hinges::new(&triangles);
        let corners: Vec<u32> = mesh.corner_verts.iter().map(|&c| c as u32).collect();
        let polygons: Vec<&[u32]> = offsets.windows(2).map(|w| &corners[w[0] as usize..w[1] as usize]).collect();
        let stars = Stars::new(rest.len(), &polygons, &triangles, &polygon_of).placed_in(&tree.order);
        let polygon = tree.order.iter().map(|&t| polygon_of[t as usize]).collect();
        let owns = ownership(&tree, rest.len());
        let rings = Rings::new(rest.len(), mesh.corner_verts, &offsets);
        Ok(SelfCollision {
            vertex_count: rest.len(),
            owns,
            tree,
            polygon,
            rounding: 4e-6 * scale_of(rest),
            rest: rest.to_vec(),
            exclusion: Exclusion::new(rest.len(), &edges, 0, &quads),
            edges,
            quads,
            separation: None,
            hinges,
            stars,
            rings,
        })
    }

    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }

    /// Readies the neighbour exclusion and the separations at rest for
    /// `settings` (kept while they stay the same).
    pub fn prepare(&mut self, settings: &SelfSettings) -> Result<()> {
        settings.validate()?;
        if self.exclusion.rings() != settings.rings {
            self.exclusion = Exclusion::new(self.vertex_count, &self.edges, settings.rings, &self.quads);
            self.separation = None;
        }
        if self.separation.as_ref().is_some_and(|(t, r, _)| *t == settings.thickness && *r == settings.rings) {
            return Ok(());
        }
        let thickness = settings.thickness;
        // At most a quarter of the shortest edge at a vertex: a contact never
        // asks to keep skin farther apart than the mesh's own spacing.
        let mut separation = vec![thickness; self.vertex_count];
        for &[a, b] in &self.edges {
            let quarter = 0.25 * (self.rest[a as usize] - self.rest[b as usize]).length();
            for v in [a, b] {
                separation[v as usize] = separation[v as usize].min(quarter);
            }
        }
        if thickness > 0.0 {
            // Pairs already within the thickness at rest (overlapping shells,
            // skin resting on skin): each keeps half its rest distance.
            let zero = vec![0.0; self.vertex_count];
            let motion = Motion { start: &self.rest, end: &self.rest, margin: &zero };
            let exclusion = &self.exclusion;
            let accept = |a: &[u32], b: &[u32]| !exclusion.excluded(a, b);
            let pairs = self.gather(&motion, thickness, true, None, &accept, None, None);
            let close: Vec<(ElementPair, f32)> = pairs
                .into_par_iter()
                .filter_map(|pair| {
                    let d = distance(&pair, &self.rest);
                    (d < thickness).then_some((pair, d))
                })
                .collect();
            for (pair, d) in close {
                for v in pair.corners {
                    separation[v as usize] = separation[v as usize].min(0.5 * d);
                }
            }
        }
        self.separation = Some((thickness, settings.rings, separation));
        Ok(())
    }

    /// The separations of [`Self::prepare`] (the thickness everywhere before it).
    pub(super) fn separations(&self) -> &[f32] {
        self.separation.as_ref().map_or(&[], |(_, _, s)| s)
    }

    /// The separation a pair keeps: the least of its corners'.
    pub(super) fn pair_separation(&self, pair: &ElementPair) -> f64 {
        let s = self.separations();
        pair.corners.iter().map(|&v| s[v as usize]).fold(f32::INFINITY, f32::min) as f64
    }

    pub(super) fn excluded(&self, a: &[u32], b: &[u32]) -> bool {
        self.exclusion.excluded(a, b)
    }

    /// Per tree position, whether its triangle takes part: any corner with a
    /// weight above 0. None (all) without weights.
    pub fn takes_part(&self, weights: Option<&[f32]>) -> Result<Option<Vec<bool>>> {
        let Some(weights) = weights else { return Ok(None) };
        if weights.len() != self.vertex_count {
            return Err(Error::invalid(format!("self-collision weights: {} given for {} vertices", weights.len(), self.vertex_count)));
        }
        if let Some(v) = weights.iter().position(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::invalid(format!("self-collision weight of vertex {v} is {}; it must be finite and ≥ 0", weights[v])));
        }
        Ok(Some(self.tree.triangles.iter().map(|t| t.iter().any(|&v| weights[v as usize] > 0.0)).collect()))
    }

    /// Runs a gathering over `motion` (only pairs with a triangle in
    /// `focus`, if given), with the tree's `bounds` over it if already
    /// made ([`Self::bounds`]), else fitting them.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn gather(
        &self,
        motion: &Motion<'_>,
        reach: f32,
        cull: bool,
        takes_part: Option<&[bool]>,
        accept: &(dyn Fn(&[u32], &[u32]) -> bool + Sync),
        focus: Option<&Focus>,
        bounds: Option<&NodeBounds>,
    ) -> Vec<ElementPair> {
        if focus.is_some_and(Focus::is_empty) {
            return Vec::new();
        }
        let fitted;
        let bounds = match bounds {
            Some(b) => b,
            None => {
                fitted = self.bounds(motion, takes_part);
                &fitted
            }
        };
        Gather { tree: &self.tree, owns: &self.owns, bounds, motion: *motion, reach: reach + self.rounding, cull, hinges: &self.hinges, stars: &self.stars, polygon: &self.polygon, star_memo: self.stars.memo_over(&bounds.triangle_cone), takes_part, accept, focus }.run()
    }

    /// The patch tree's bounds over `motion`.
    pub(super) fn bounds(&self, motion: &Motion<'_>, takes_part: Option<&[bool]>) -> NodeBounds {
        NodeBounds::new(&self.tree, motion, takes_part)
    }

    /// [`Self::bounds`] made again for `motion` from those of a motion
    /// that differed only at the vertices flagged in `changed`.
    pub(super) fn refit_bounds(&self, bounds: &mut NodeBounds, motion: &Motion<'_>, takes_part: Option<&[bool]>, changed: &[bool]) {
        bounds.refit_around(&self.tree, motion, takes_part, changed);
    }

    /// The triangles (tree positions) with a corner among `vertices`.
    pub(super) fn focus_around(&self, vertices: &[bool]) -> Focus {
        Focus::around(&self.tree, vertices)
    }

    /// The pairs of polygons (the mesh's indices, ascending within a pair,
    /// pairs ascending) that intersect at `positions` under some split of
    /// their quads: an edge (side or either diagonal) of one properly
    /// crosses a triangle (of either split) of the other. Polygons that are
    /// neighbours (sharing a vertex, or within the rings) are not counted;
    /// only those taking part.
    pub fn intersections(&self, positions: &[Vec3], takes_part: Option<&[bool]>) -> Result<Vec<[u32; 2]>> {
        let crossing: Vec<[u32; 2]> = self.meeting(positions, takes_part, 0.0, None)?.into_iter().filter(|&(_, crossing)| crossing).map(|(pair, _)| pair).collect();
        Ok(self.polygon_pairs(&crossing))
    }

    /// The polygon pairs (ascending, each once) of tree-position pairs.
    pub(super) fn polygon_pairs(&self, pairs: &[[u32; 2]]) -> Vec<[u32; 2]> {
        let mut polygons: Vec<[u32; 2]> = pairs
            .iter()
            .map(|&[p, q]| {
                let (a, b) = (self.polygon[p as usize], self.polygon[q as usize]);
                [a.min(b), a.max(b)]
            })
            .collect();
        polygons.sort_unstable();
        polygons.dedup();
        polygons
    }

    /// The pairs of triangles (tree positions) that intersect or come
    /// within `touching` of each other at `positions`, each with whether it
    /// intersects; with a `focus`, only pairs with a triangle in it.
    pub(super) fn meeting(&self, positions: &[Vec3], takes_part: Option<&[bool]>, touching: f32, focus: Option<&Focus>) -> Result<Vec<([u32; 2], bool)>> {
        if positions.len() != self.vertex_count {
            return Err(Error::invalid(format!("{} positions given for a skin of {} vertices", positions.len(), self.vertex_count)));
        }
        validate_positions("positions", positions)?;
        if focus.is_some_and(Focus::is_empty) {
            return Ok(Vec::new());
        }
        let zero = vec![0.0; self.vertex_count];
        let motion = Motion { start: positions, end: positions, margin: &zero };
        let bounds = NodeBounds::new(&self.tree, &motion, takes_part);
        let exclusion = &self.exclusion;
        let accept = |a: &[u32], b: &[u32]| !exclusion.excluded(a, b);
        // Touching pairs are found only where the curvature test cannot rule out a contact.
        let gather = Gather { tree: &self.tree, owns: &self.owns, bounds: &bounds, motion, reach: touching + self.rounding, cull: true, hinges: &self.hinges, stars: &self.stars, polygon: &self.polygon, star_memo: self.stars.memo_over(&bounds.triangle_cone), takes_part, accept: &accept, focus };
        let mut found: Vec<([u32; 2], bool)> = gather
            .triangle_pairs()
            .into_par_iter()
            .filter_map(|[p, q]| {
                let (tp, tq) = (self.tree.triangles[p as usize], self.tree.triangles[q as usize]);
                let crossing = crosses(positions, tp, tq) || crosses(positions, tq, tp);
                (crossing || (touching > 0.0 && triangles_within(positions, tp, tq, touching))).then_some(([p, q], crossing))
            })
            .collect();
        found.sort_unstable();
        Ok(found)
    }
}

/// Whether the polygon whose triangles start at `first` is a quad split both
/// ways (`abc acd abd bcd`, [`either_split_triangles`]), not a fan.
fn split_both_ways(triangles: &[[u32; 3]], polygon_of: &[u32], first: usize) -> bool {
    let count = polygon_of[first..].iter().take(5).take_while(|&&p| p == polygon_of[first]).count();
    count == 4 && triangles[first + 2] == [triangles[first][0], triangles[first][1], triangles[first + 1][2]]
}

/// Whether triangles `a` and `b` (not crossing) come within `reach`: the
/// least of their vertex–triangle and edge–edge distances.
fn triangles_within(x: &[Vec3], a: [u32; 3], b: [u32; 3], reach: f32) -> bool {
    let (pa, pb) = (a.map(|v| x[v as usize].as_dvec3()), b.map(|v| x[v as usize].as_dvec3()));
    let r2 = (reach as f64) * (reach as f64);
    let vertex = |p: &[glam::DVec3; 3], t: &[glam::DVec3; 3]| p.iter().any(|&v| point_triangle_distance_squared(v, t[0], t[1], t[2]) <= r2);
    let edges = (0..3).any(|i| (0..3).any(|j| segment_segment_distance_squared(pa[i], pa[(i + 1) % 3], pb[j], pb[(j + 1) % 3]) <= r2));
    vertex(&pa, &pb) || vertex(&pb, &pa) || edges
}

/// Whether an edge of triangle `a` properly crosses triangle `b`.
fn crosses(x: &[Vec3], a: [u32; 3], b: [u32; 3]) -> bool {
    let [p, q, r] = b.map(|v| x[v as usize].as_dvec3());
    (0..3).any(|k| segment_crosses_triangle(x[a[k] as usize].as_dvec3(), x[a[(k + 1) % 3] as usize].as_dvec3(), p, q, r))
}

/// The distance between a pair's two elements at `x`.
pub(super) fn distance(pair: &ElementPair, x: &[Vec3]) -> f32 {
    let [a, b, c, d] = pair.corners.map(|v| x[v as usize].as_dvec3());
    let squared = if pair.edge_edge { segment_segment_distance_squared(a, b, c, d) } else { point_triangle_distance_squared(a, b, c, d) };
    squared.sqrt() as f32
}
