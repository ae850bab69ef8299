//! Whether given skin vertices' steps still meet a collider: the check a
//! caller needs after changing some vertices' ends itself (putting them back
//! where a pass started, as the self-collision fail-safe does).

use glam::Vec3;
use rayon::prelude::*;

use super::{ColliderSet, ResolveParams};
use crate::collide::skin::Skin;

impl ColliderSet<'_> {
    /// The vertices among `vertices`, and the corners of the edges and
    /// triangles around them, whose steps `start → end` meet a collider
    /// (ascending).
    pub fn violations(&self, start: &[Vec3], end: &[Vec3], skin: &Skin, vertices: &[u32], params: &ResolveParams) -> Vec<u32> {
        if self.colliders.is_empty() || vertices.is_empty() {
            return Vec::new();
        }
        let mut bad: Vec<u32> = vertices
            .par_iter()
            .copied()
            .filter(|&i| skin.inverse_mass(i) > 0.0 && self.vertex_correction(start[i as usize], end[i as usize], params).is_some())
            .collect();
        let (edges, triangles) = skin.touching(vertices, (&[], &[]));
        let (_, _, shared) = self.shared_corrections(start, end, skin, &edges, &triangles, params, None);
        bad.extend(shared.iter().map(|(v, ..)| *v));
        bad.sort_unstable();
        bad.dedup();
        bad
    }
}
