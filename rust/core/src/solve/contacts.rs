//! Which vertices an iteration hook (the stepper's contact passes) moved,
//! iteration after iteration, for the accelerated solver.
//!
//! The acceleration ([`super::coarse`], [`super::chebyshev`]) extrapolates
//! the iteration's map `G`; a hook that holds vertices changes that map, and
//! accelerated across it the iterate overshoots into the contacts, the hook
//! throws it back, and the two fight: with Converge a tube bent 150° against
//! itself (Self Collision) spiked 0.461 where its skinning input spikes
//! 0.148. So an iteration that follows one whose hook moved a vertex takes
//! the plain step everywhere (issue 28, measured in `docs/performance.md`).
//! Taking it only around the contacts (the moved vertices and 2 or 6 rings
//! of neighbours, the rest of the mesh accelerated) converged a sliding
//! sphere's frames 2–4× closer, but spiked the tube 1.7–1.8: the
//! acceleration elsewhere drives the fold into the contacts faster than the
//! passes resolve it.

use glam::Vec3;

/// The vertices the hook moved in the last iteration, and whether that set changed.
#[derive(Default)]
pub(super) struct MovedVertices {
    /// Ascending.
    moved: Vec<u32>,
    changed: bool,
}

impl MovedVertices {
    /// Starts a solve: nothing moved.
    pub(super) fn clear(&mut self) {
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
        self.moved = moved;
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
        moved.update(&before, &after);
        assert!(moved.any() && !moved.changed(), "the same vertex moved again");
        moved.update(&before, &before);
        assert!(!moved.any() && moved.changed(), "the contact let go");
    }
}
