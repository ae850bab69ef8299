//! Which vertices an iteration hook (the stepper's contact passes) moved,
//! iteration after iteration, for the accelerated solver.
//!
//! The acceleration ([`super::coarse`], [`super::chebyshev`]) extrapolates
//! the iteration's map `G`; a hook that holds vertices changes that map: the
//! correction fixes the moved vertices the hook does not report sliding
//! (Dirichlet rows of its coarse problem, [`super::coarse`]) and moves the
//! sliding ones along their surface only ([`Sliding`]), the extrapolation
//! restarts after an iteration whose hook moved a vertex, and the stopping
//! rule does not stop while the moved set changes (contacts still appearing
//! or letting go). Measured and not kept (issue 28, `docs/performance.md`):
//! the plain step everywhere after such an iteration passes the 150° Self
//! Collision tube with Converge but loses all acceleration while a contact
//! rests; the plain step only around the contacts (2 or 6 rings) spiked the
//! tube 1.2–1.8.

use glam::Vec3;

/// A vertex a hook left on a surface it may slide along (a contact with
/// kinetic friction or none): constrained only along its contact `normal`
/// (unit), its slip reduced by kinetic `friction` times how far a step
/// pushes it into the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sliding {
    pub vertex: u32,
    pub normal: Vec3,
    pub friction: f32,
}

impl Sliding {
    /// What the contact lets the vertex take of a step `r`: its part along
    /// the surface, shortened by `friction` times how far `r` pushes into
    /// the surface (nothing inside that cone). This is what the hook leaves
    /// of a plain step, so the coarse correction sees it as the residual.
    fn admitted_step(&self, r: Vec3) -> Vec3 {
        let along = self.along_surface(r);
        let length = along.length();
        let friction = self.friction * (-r.dot(self.normal)).max(0.0);
        if length > friction {
            along * ((length - friction) / length)
        } else {
            Vec3::ZERO
        }
    }

    /// `e` without its component along the normal.
    fn along_surface(&self, e: Vec3) -> Vec3 {
        e - self.normal * e.dot(self.normal)
    }
}

/// No entry in [`MovedVertices::slide`].
const NOT_SLIDING: u32 = u32::MAX;

/// The vertices the hook moved in the last iteration, which of them it
/// left sliding, and whether the moved set changed.
#[derive(Default)]
pub(super) struct MovedVertices {
    /// Ascending.
    moved: Vec<u32>,
    changed: bool,
    /// The moved vertices not sliding, ascending: fixed for the next
    /// iteration's correction.
    stuck: Vec<u32>,
    /// Per vertex: stuck (empty before the first update).
    mask: Vec<bool>,
    /// The moved vertices the hook left sliding, ascending.
    sliding: Vec<Sliding>,
    /// Per vertex: its index in `sliding`, or [`NOT_SLIDING`] (empty before the first update).
    slide: Vec<u32>,
}

impl MovedVertices {
    /// Starts a solve: nothing moved.
    pub(super) fn clear(&mut self) {
        self.forget();
        self.moved.clear();
        self.changed = false;
    }

    fn forget(&mut self) {
        for &v in &self.stuck {
            self.mask[v as usize] = false;
        }
        for s in &self.sliding {
            self.slide[s.vertex as usize] = NOT_SLIDING;
        }
        self.stuck.clear();
        self.sliding.clear();
    }

    /// Records which vertices the hook moved, `before` → `after`, bit for
    /// bit, and which of them it reports `sliding` (any order; entries for
    /// vertices it did not move are ignored).
    pub(super) fn update(&mut self, before: &[Vec3], after: &[Vec3], sliding: &[Sliding]) {
        let moved: Vec<u32> = before
            .iter()
            .zip(after)
            .enumerate()
            .filter(|(_, (a, b))| bytemuck::cast::<Vec3, [u32; 3]>(**a) != bytemuck::cast::<Vec3, [u32; 3]>(**b))
            .map(|(v, _)| v as u32)
            .collect();
        self.changed = moved != self.moved;
        self.forget();
        self.mask.resize(before.len(), false);
        self.slide.resize(before.len(), NOT_SLIDING);
        let mut reported: Vec<Sliding> = sliding.iter().copied().filter(|s| moved.binary_search(&s.vertex).is_ok()).collect();
        reported.sort_by_key(|s| s.vertex);
        reported.dedup_by_key(|s| s.vertex);
        for (k, s) in reported.iter().enumerate() {
            self.slide[s.vertex as usize] = k as u32;
        }
        self.stuck = moved.iter().copied().filter(|&v| self.slide[v as usize] == NOT_SLIDING).collect();
        for &v in &self.stuck {
            self.mask[v as usize] = true;
        }
        self.sliding = reported;
        self.moved = moved;
    }

    /// The stuck vertices, ascending and as a per-vertex mask, or `None`
    /// when none is.
    pub(super) fn held(&self) -> Option<(&[u32], &[bool])> {
        (!self.stuck.is_empty()).then_some((&self.stuck[..], &self.mask[..]))
    }

    /// Whether the hook left any vertex sliding in the last iteration.
    pub(super) fn any_sliding(&self) -> bool {
        !self.sliding.is_empty()
    }

    fn sliding_at(&self, v: usize) -> Option<&Sliding> {
        self.slide.get(v).and_then(|&k| self.sliding.get(k as usize))
    }

    fn is_stuck(&self, v: usize) -> bool {
        self.mask.get(v).copied().unwrap_or(false)
    }

    /// Vertex `v`'s plain step `r` as the coarse correction sees it: none
    /// where it is stuck, what its contact admits where it slides
    /// ([`Sliding::admitted_step`]), all of it elsewhere.
    pub(super) fn admitted_step(&self, v: usize, r: Vec3) -> Vec3 {
        match self.sliding_at(v) {
            Some(s) => s.admitted_step(r),
            None if self.is_stuck(v) => Vec3::ZERO,
            None => r,
        }
    }

    /// A correction `e` of vertex `v` as its contact admits it: none where it
    /// is stuck, along the surface where it slides, all of it elsewhere.
    pub(super) fn admitted_correction(&self, v: usize, e: Vec3) -> Vec3 {
        match self.sliding_at(v) {
            Some(s) => s.along_surface(e),
            None if self.is_stuck(v) => Vec3::ZERO,
            None => e,
        }
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
        moved.update(&before, &after, &[]);
        assert!(moved.any() && moved.changed());
        assert_eq!(moved.held().unwrap(), (&[3u32][..], &[false, false, false, true, false, false][..]));
        moved.update(&before, &after, &[]);
        assert!(moved.any() && !moved.changed(), "the same vertex moved again");
        moved.update(&before, &before, &[]);
        assert!(!moved.any() && moved.changed() && moved.held().is_none(), "the contact let go");
        moved.update(&before, &after, &[]);
        moved.clear();
        moved.update(&before, &before, &[]);
        moved.update(&before, &after, &[]);
        assert_eq!(moved.held().unwrap().1.iter().filter(|&&m| m).count(), 1, "a new solve forgets the last one's vertices");
    }

    #[test]
    fn a_sliding_vertex_takes_steps_and_corrections_along_its_surface_less_friction() {
        let before = vec![Vec3::ZERO; 4];
        let mut after = before.clone();
        after[1].z = 1.0;
        after[2].z = 1.0;
        let slide = Sliding { vertex: 2, normal: Vec3::Z, friction: 0.5 };
        let elsewhere = Sliding { vertex: 3, normal: Vec3::X, friction: 0.0 };
        let mut moved = MovedVertices::default();
        moved.clear();
        moved.update(&before, &after, &[slide, elsewhere]);
        assert_eq!(moved.held().unwrap().0, &[1u32][..], "the moved vertex not reported sliding stays fixed");
        assert!(moved.any_sliding());
        // A step 0.4 along the surface and 0.2 into it: friction takes 0.5 · 0.2.
        let step = Vec3::new(0.4, 0.0, -0.2);
        assert!((moved.admitted_step(2, step) - Vec3::new(0.3, 0.0, 0.0)).length() < 1e-6);
        assert_eq!(moved.admitted_step(2, Vec3::new(0.05, 0.0, -0.2)), Vec3::ZERO, "inside the friction cone");
        assert_eq!(moved.admitted_correction(2, step), Vec3::new(0.4, 0.0, 0.0));
        assert_eq!((moved.admitted_step(1, step), moved.admitted_correction(1, step)), (Vec3::ZERO, Vec3::ZERO), "stuck");
        assert_eq!((moved.admitted_step(3, step), moved.admitted_correction(3, step)), (step, step), "reported but not moved: free");
        moved.update(&before, &before, &[]);
        assert!(!moved.any_sliding() && moved.admitted_correction(2, step) == step, "the contact let go");
    }
}
