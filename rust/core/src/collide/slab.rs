//! Slab proofs that a skin element (a vertex, an edge or a triangle moving
//! over the step) stays apart from a patch of collider triangles, all pairs
//! at once ([`proximity::separated_along`]), before any test per pair.
//!
//! A patch is gathered once per element: each collider vertex the
//! candidate triangles share appears once, with its two end positions in
//! f64, and the triangles refer to those entries. A closed collider's vertex
//! belongs to about six triangles, and a sliding contact takes up to five
//! slabs, so the corners were otherwise fetched, converted and interpolated
//! about thirty times each (the sliding benchmark frames spent 40 % of their
//! first pass doing so).

use std::cell::RefCell;

use glam::DVec3;

use super::collider::Collider;
use super::geometry::triangle_normal;
use super::proximity;

/// Parts of the step that get a slab each when one slab for the whole step
/// does not prove a skin edge or triangle apart from a moving collider (a
/// contact sliding over a curved collider). Against a still collider such a
/// failure is nearly always a real contact, and slicing would only add work.
/// With each slab taken in the middle of its part, four prove as many of the
/// benchmark's sliding contacts as eight did with slabs taken at the end.
pub(super) const SLICES: usize = 4;

/// Candidate collider triangles around one skin element, their corners
/// listed once.
#[derive(Default)]
pub(super) struct Patch {
    /// Per collider vertex: the gathering that last listed it and where.
    listed: Vec<(u32, u32)>,
    gathering: u32,
    /// The listed corners at the start and the end of the step (the same for
    /// a collider standing still).
    start: Vec<DVec3>,
    end: Vec<DVec3>,
    swept: bool,
    /// The candidate triangles, by listed corner.
    triangles: Vec<[u32; 3]>,
    /// Their centroids at the start, and how far they move over the step
    /// (a centroid moves linearly, as the corners do).
    centroids: Vec<(DVec3, DVec3)>,
}

thread_local! {
    /// One patch per thread, reused from element to element.
    static PATCH: RefCell<Patch> = RefCell::new(Patch::default());
}

impl Patch {
    /// Runs `f` with this thread's patch. (Taken out of its cell rather than
    /// borrowed in place, so a nested use just gets a fresh one.)
    pub(super) fn with<R>(f: impl FnOnce(&mut Patch) -> R) -> R {
        let mut patch = PATCH.with(|cell| std::mem::take(&mut *cell.borrow_mut()));
        let result = f(&mut patch);
        let _ = PATCH.try_with(|cell| *cell.borrow_mut() = patch);
        result
    }

    /// Lists `triangles` of `collider` and their corners, at the step's two
    /// ends if the collider `swept`, at its current positions otherwise.
    pub(super) fn gather(&mut self, collider: &Collider, triangles: &[u32], swept: bool) {
        let (all, previous, current) = (collider.triangles(), collider.previous(), collider.current());
        if self.listed.len() < current.len() {
            self.listed.resize(current.len(), (0, 0));
        }
        self.gathering = self.gathering.wrapping_add(1);
        if self.gathering == 0 {
            // Wrapped: stale marks could pass for this gathering's.
            self.listed.fill((0, 0));
            self.gathering = 1;
        }
        self.start.clear();
        self.end.clear();
        self.triangles.clear();
        self.centroids.clear();
        self.swept = swept;
        for &t in triangles {
            let corners = all[t as usize].map(|v| {
                let slot = &mut self.listed[v as usize];
                if slot.0 != self.gathering {
                    *slot = (self.gathering, self.start.len() as u32);
                    let now = current[v as usize].as_dvec3();
                    self.start.push(if swept { previous[v as usize].as_dvec3() } else { now });
                    self.end.push(now);
                }
                slot.1
            });
            self.triangles.push(corners);
            let [a, b, c] = corners.map(|k| k as usize);
            let (first, last) = ((self.start[a] + self.start[b] + self.start[c]) / 3.0, (self.end[a] + self.end[b] + self.end[c]) / 3.0);
            self.centroids.push((first, last - first));
        }
    }

    /// Listed corner `k` at time `t` of the step.
    fn at(&self, k: u32, t: f64) -> DVec3 {
        let (q, p) = (self.start[k as usize], self.end[k as usize]);
        if !self.swept || t == 1.0 {
            p
        } else {
            q + t * (p - q)
        }
    }

    /// Whether a skin element (corners `start → end`, at most 3) provably
    /// stays farther than `separation` from every triangle of the patch
    /// (and so from their edges and vertices) over the step: by one slab
    /// for the whole step, or, if `sliced` and the collider sweeps, by one
    /// for each of [`SLICES`] equal parts of it (a contact that slides or
    /// passes a curved collider needs several directions). Resting contacts
    /// on a locally convex collider pass; anything else falls through to
    /// the pairwise tests.
    pub(super) fn apart(&self, start: &[DVec3], end: &[DVec3], separation: f64, sliced: bool) -> bool {
        if self.triangles.is_empty() {
            return true;
        }
        self.apart_over(start, end, separation, 0.0, 1.0)
            || (sliced
                && self.swept
                && (0..SLICES).all(|k| self.apart_over(start, end, separation, k as f64 / SLICES as f64, (k + 1) as f64 / SLICES as f64)))
    }

    /// One slab, over the part `t0..t1` of the step. Its direction is the
    /// normal of the triangle nearest to the element at the middle of the
    /// part; its frame translates with that triangle's first corner.
    fn apart_over(&self, start: &[DVec3], end: &[DVec3], separation: f64, t0: f64, t1: f64) -> bool {
        let count = start.len().min(3);
        let (mut from, mut to) = ([DVec3::ZERO; 3], [DVec3::ZERO; 3]);
        for k in 0..count {
            from[k] = start[k] + t0 * (end[k] - start[k]);
            to[k] = start[k] + t1 * (end[k] - start[k]);
        }
        let (from, to) = (&from[..count], &to[..count]);
        // The triangle nearest to the element halfway through the part: a
        // contact sliding over a curved collider is then bounded by the
        // tangent plane in the middle of its slide, where the surface falls
        // away least at both ends.
        let middle = 0.5 * (t0 + t1);
        let centre = (from.iter().chain(to).copied().sum::<DVec3>()) / (2 * count) as f64;
        let mut anchor = (f64::INFINITY, 0);
        for (k, &(first, motion)) in self.centroids.iter().enumerate() {
            let gap = (first + middle * motion - centre).length_squared();
            if gap < anchor.0 {
                anchor = (gap, k);
            }
        }
        let [a, b, c] = self.triangles[anchor.1];
        let Some(n) = triangle_normal(self.at(a, middle), self.at(b, middle), self.at(c, middle)) else { return false };
        let shift = self.at(a, t1) - self.at(a, t0);
        let corners = (0..self.start.len() as u32).map(|k| (self.at(k, t0), self.at(k, t1)));
        proximity::separated_along(n, shift, from, to, corners, separation)
    }
}
