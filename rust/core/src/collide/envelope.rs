//! Where a collider that moves between the in-loop passes stays while it
//! moves: a box per vertex, and a tree over its triangles' boxes.
//!
//! A compliant collider recedes after every solver iteration, so a
//! [`super::Clearance`] measured against its positions of one pass is stale
//! at the next. Its vertices move only between where they stand and their
//! goals, though, and a little sideways as the skin they rest on moves. A
//! clearance measured against an [`Envelope`] — each vertex's box around
//! both, grown by a margin — holds for every pass in which the collider is
//! still inside it: a triangle whose corners are in their boxes lies in the
//! union of the boxes, so a skin element proven farther than the thickness
//! from every such union is farther from the collider wherever it stands.
//! [`Envelope::holds`] checks that (one pass over the collider's vertices);
//! when a vertex leaves, the clearance is measured again.

use glam::Vec3;
use rayon::prelude::*;

use super::bvh::{BoxTree, Bounds};
use super::collider::{Collider, ColliderSettings};
use crate::mesh::validate_positions;
use crate::{Error, Result};

/// The region a collider's vertices stay in over some passes.
#[derive(Debug, Clone)]
pub struct Envelope {
    /// Per vertex: the box it stays in.
    vertex: Vec<Bounds>,
    /// Over the triangles: the union of their corners' boxes, grown by the
    /// thickness (what a clearance measures distances to).
    tree: BoxTree,
    settings: ColliderSettings,
    triangle_count: usize,
}

impl Envelope {
    /// The boxes around each vertex's current position and `towards` (its
    /// goal), grown by `margin`.
    pub fn new(collider: &Collider, towards: &[Vec3], margin: f32) -> Result<Self> {
        if towards.len() != collider.vertex_count() {
            return Err(Error::invalid(format!(
                "envelope: {} positions given for a collider of {} vertices",
                towards.len(),
                collider.vertex_count()
            )));
        }
        validate_positions("envelope positions", towards)?;
        if !(margin.is_finite() && margin >= 0.0) {
            return Err(Error::invalid(format!("envelope margin is {margin}; it must be finite and ≥ 0")));
        }
        let vertex: Vec<Bounds> = collider
            .current()
            .par_iter()
            .zip(towards)
            .map(|(&p, &q)| Bounds::of_points(&[p, q]).inflated(margin))
            .collect();
        let thickness = collider.settings().thickness;
        let boxes: Vec<Bounds> = collider
            .triangles()
            .par_iter()
            .map(|t| t.iter().fold(Bounds::EMPTY, |b, &v| b.union(vertex[v as usize])).inflated(thickness))
            .collect();
        // The collider's own tree is over the same triangles in the same
        // order, laid out by where they stand: refitted to these boxes it
        // answers exactly as one built afresh (queries are exact whatever a
        // tree's shape), without the build that cost the flesh bench's
        // compliant row 0.30 G instructions a run (issue 29). Never rebuilt
        // here: boxes grown by the margin overlap far more than the
        // collider's, so its cost measured against the collider's build
        // (7–8× on the bench) says nothing of the layout, which the
        // collider's own tree keeps.
        let mut tree = collider.tree().clone();
        tree.rebuild_ratio = f64::INFINITY;
        tree.update(&boxes)?;
        Ok(Envelope { tree, vertex, settings: collider.settings(), triangle_count: collider.triangles().len() })
    }

    /// Whether `collider` (same settings and triangles) stands inside the
    /// envelope: every vertex in its box.
    pub fn holds(&self, collider: &Collider) -> bool {
        collider.settings() == self.settings
            && collider.triangles().len() == self.triangle_count
            && collider.vertex_count() == self.vertex.len()
            && collider.current().par_iter().with_min_len(4096).zip(&self.vertex).all(|(&p, b)| b.contains(p))
    }

    /// The tree over the triangles' boxes (thickness included).
    pub fn tree(&self) -> &BoxTree {
        &self.tree
    }

    /// Every corner of the vertices' boxes lies within this box.
    pub(super) fn bounds(&self) -> Bounds {
        self.tree.bounds()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::shapes::{quad_sphere, PolyMesh};

    fn sphere() -> (PolyMesh, Collider) {
        let mesh = quad_sphere(4, 0.3);
        let tris = crate::mesh::fan_triangles(&mesh.corner_verts, &mesh.input().validate().unwrap());
        let c = Collider::new(&mesh.positions, &tris, ColliderSettings::new(0.01, 0.0)).unwrap();
        (mesh, c)
    }

    #[test]
    fn holds_while_the_vertices_stay_between_start_and_goal() {
        let (mesh, mut c) = sphere();
        let goal: Vec<Vec3> = mesh.positions.iter().map(|&p| p + Vec3::Z * 0.1).collect();
        let envelope = Envelope::new(&c, &goal, 0.01).unwrap();
        assert!(envelope.holds(&c));
        let halfway: Vec<Vec3> = mesh.positions.iter().map(|&p| p + Vec3::new(0.005, 0.0, 0.05)).collect();
        c.set_positions(&halfway, &halfway).unwrap();
        assert!(envelope.holds(&c), "halfway, a little sideways");
        let beyond: Vec<Vec3> = mesh.positions.iter().map(|&p| p + Vec3::Z * 0.12).collect();
        c.set_positions(&beyond, &beyond).unwrap();
        assert!(!envelope.holds(&c), "past the goal by more than the margin");
        c.set_positions(&halfway, &halfway).unwrap();
        c.set_settings(ColliderSettings::new(0.02, 0.0)).unwrap();
        assert!(!envelope.holds(&c), "another thickness");
    }

    /// The envelope's tree is the collider's own refitted to the envelope's
    /// boxes, not one built afresh (a build once a frame cost the compliant
    /// flesh bench 0.30 G instructions), and every query finds exactly
    /// the triangles whose envelope boxes overlap it.
    #[test]
    fn the_tree_is_the_colliders_refitted_and_finds_every_overlapping_box() {
        let (mesh, c) = sphere();
        let goal: Vec<Vec3> = mesh.positions.iter().map(|&p| p * 1.1 + Vec3::new(0.02, 0.0, 0.05)).collect();
        let envelope = Envelope::new(&c, &goal, 0.01).unwrap();
        assert_eq!(envelope.tree().rebuild_count(), c.tree().rebuild_count(), "not built again");
        assert_eq!(envelope.tree().refit_count(), c.tree().refit_count() + 1, "the collider's tree, refitted once");
        let boxes: Vec<Bounds> = (0..c.triangles().len()).map(|t| envelope.tree().primitive_bounds(t)).collect();
        for k in 0..200 {
            let centre = Vec3::new((k % 7) as f32 * 0.1 - 0.3, (k % 11) as f32 * 0.06 - 0.3, (k % 13) as f32 * 0.05 - 0.25);
            let query = Bounds { min: centre, max: centre }.inflated(0.02 + 0.001 * (k % 5) as f32);
            let mut found = Vec::new();
            envelope.tree().query(&query, |t| {
                found.push(t);
                true
            });
            found.sort_unstable();
            let overlapping: Vec<usize> = (0..boxes.len()).filter(|&t| boxes[t].overlaps(&query)).collect();
            assert_eq!(found, overlapping, "query {k}");
        }
    }

    #[test]
    fn bad_input_is_refused() {
        let (mesh, c) = sphere();
        assert!(Envelope::new(&c, &mesh.positions[1..], 0.01).is_err());
        assert!(Envelope::new(&c, &mesh.positions, f32::NAN).is_err());
        let mut nan = mesh.positions.clone();
        nan[0].x = f32::NAN;
        assert!(Envelope::new(&c, &nan, 0.01).is_err());
    }
}
