//! Which vertices an iteration hook (the stepper's contact passes) moved,
//! iteration after iteration, for the accelerated solver.
//!
//! The acceleration ([`super::coarse`], [`super::chebyshev`]) extrapolates
//! the iteration's map `G`; a hook that holds vertices changes that map: the
//! correction fixes the moved vertices (Dirichlet rows of its coarse
//! problem, [`super::coarse`]), the extrapolation
//! restarts after an iteration whose hook moved a vertex, and the stopping
//! rule does not stop while the moved set changes (contacts still appearing
//! or letting go). Measured and not kept (issue 28, `docs/performance.md`):
//! the plain step everywhere after such an iteration passes the 150° Self
//! Collision tube with Converge but loses all acceleration while a contact
//! rests; the plain step only around the contacts (2 or 6 rings) spiked the
//! tube 1.2–1.8.

use glam::Vec3;

/// The vertices the hook moved in the last iteration, and whether that set changed.
#[derive(Default)]
pub(super) struct MovedVertices {
    /// Ascending.
    moved: Vec<u32>,
    changed: bool,
    /// Per vertex: moved (empty before the first update).
    mask: Vec<bool>,
}

impl MovedVertices {
    /// Starts a solve: nothing moved.
    pub(super) fn clear(&mut self) {
        for &v in &self.moved {
            self.mask[v as usize] = false;
        }
        self.moved.clear();
        self.changed = false;
    }

    /// Records which vertices the hook moved, `before` → `after`, bit for bit.
    pub(super) fn update(&mut self, before: &[Vec3], after: &[Vec3]) {
        let moved: Vec<u32> = before
            .iter()
            .zip(after)
            .enumerate()
            .filter(|(_, (a, b))| bytemuck::cast::<Vec3, [u32; 3]>(**a) != bytemuck::cast::<Vec3, [u32; 3]>(**b))
            .map(|(v, _)| v as u32)
            .collect();
        self.changed = moved != self.moved;
        for &v in &self.moved {
            self.mask[v as usize] = false;
        }
        self.mask.resize(before.len(), false);
        for &v in &moved {
            self.mask[v as usize] = true;
        }
        self.moved = moved;
    }

    /// The moved vertices, ascending and as a per-vertex mask, or `None`
    /// when none moved.
    pub(super) fn held(&self) -> Option<(&[u32], &[bool])> {
        self.any().then_some((&self.moved[..], &self.mask[..]))
    }

    /// Whether the hook moved any vertex in the last iteration.
    pub(super) fn any(&self) -> bool {
        !self.moved.is_empty()
    }

    /// Whether the hook moved another set of vertices than in the iteration
    /// before (contacts still appearing or letting go).
    pub(super) fn changed(&self) -> bool {
        self.changed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_what_moved_and_whether_that_changed() {
        let before = vec![Vec3::ZERO; 6];
        let mut after = before.clone();
        after[3].z = 1.0;
        let mut moved = MovedVertices::default();
        moved.clear();
        moved.update(&before, &after);
        assert!(moved.any() && moved.changed());
        assert_eq!(moved.held().unwrap(), (&[3u32][..], &[false, false, false, true, false, false][..]));
        moved.update(&before, &after);
        assert!(moved.any() && !moved.changed(), "the same vertex moved again");
        moved.update(&before, &before);
        assert!(!moved.any() && moved.changed() && moved.held().is_none(), "the contact let go");
        moved.update(&before, &after);
        moved.clear();
        moved.update(&before, &before);
        moved.update(&before, &after);
        assert_eq!(moved.held().unwrap().1.iter().filter(|&&m| m).count(), 1, "a new solve forgets the last one's vertices");
    }
}
