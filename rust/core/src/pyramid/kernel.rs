//! The hot loop of the default solve: Algorithm 1 for a block of encoded
//! vertices at once (structure of arrays across vertices, one vertex per
//! lane: eight with AVX2, four with SSE2 or plain arrays; see [`super::lanes`]).
//!
//! [`project::frame`](super::project::frame) is the reference; this kernel
//! evaluates the same formulas with the same operations in the same order,
//! one vertex per lane, so its targets equal the scalar ones (IEEE
//! operations are correctly rounded whatever the lane; Rust never contracts
//! to FMA). The only difference is the sign of an exact zero, from padding:
//! rows are packed into *blocks* of one row per lane, and a block's slots run
//! to the longest ring of its rows; a shorter ring is padded by repeating its
//! last neighbour with weight 0, which adds `cross(a, a) = 0` to the vector
//! area and `0·x = 0` to the weighted sums.
//!
//! The lane width is chosen when the encoding is packed, from what the CPU
//! running it has ([`Width::best`]), so the wheel keeps running anywhere.

use glam::Vec3;

use super::encoding::Encoding;
use super::lanes::{Wide, F4};
use crate::solve::DiagonalChunk;

/// Rows per block: the lane type the kernel runs in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Width {
    /// [`F4`]: SSE2 on x86-64, plain arrays elsewhere.
    Four,
    /// [`super::lanes::F8`]: AVX2 (x86-64 only).
    Eight,
}

impl Width {
    /// The widest the CPU running this supports.
    pub fn best() -> Width {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Width::Eight;
        }
        Width::Four
    }

    /// Every width this CPU can run (for tests that compare them).
    pub fn available() -> Vec<Width> {
        if Width::best() == Width::Eight { vec![Width::Four, Width::Eight] } else { vec![Width::Four] }
    }

    pub fn lanes(self) -> usize {
        match self {
            Width::Four => 4,
            Width::Eight => 8,
        }
    }
}

/// The encoding repacked for the kernel. Entry `(b, j, l)` (block `b`, ring
/// slot `j`, lane `l`) lives at `offsets[b] + lanes·j + l`.
#[derive(Debug, Clone)]
pub struct Packed {
    width: Width,
    rows: usize,
    vertex_count: usize,
    scale_safe: bool,
    /// Entry offset of each block, `blocks + 1` values.
    offsets: Vec<u32>,
    /// The row's own vertex per lane (`blocks · lanes`; padding lanes repeat a real row).
    vertices: Vec<u32>,
    index: Vec<u32>,
    weight: Vec<f32>,
    /// Scale-safe: `w_j · t_j` (the product the scalar code forms first).
    weighted_tangent: Vec<f32>,
    /// Plain: 1 for a real neighbour, 0 for padding (centroid sum).
    unit: Vec<f32>,
    /// Plain: per lane, the ring length and the stored height.
    valence: Vec<f32>,
    height: Vec<f32>,
}

impl Packed {
    /// Packed for the widest lanes this CPU has.
    pub fn new(encoding: &Encoding) -> Self {
        Packed::with_width(encoding, Width::best())
    }

    /// Packed for `width`, which this CPU must support ([`Width::available`]).
    pub fn with_width(encoding: &Encoding, width: Width) -> Self {
        assert!(Width::available().contains(&width), "{width:?} lanes are not supported by this CPU");
        let lanes = width.lanes();
        let rows = encoding.len();
        let blocks = rows.div_ceil(lanes);
        let scale_safe = encoding.scale_safe();
        let mut packed = Packed {
            width,
            rows,
            vertex_count: encoding.vertex_count(),
            scale_safe,
            offsets: Vec::with_capacity(blocks + 1),
            vertices: Vec::with_capacity(blocks * lanes),
            index: Vec::new(),
            weight: Vec::new(),
            weighted_tangent: Vec::new(),
            unit: Vec::new(),
            valence: Vec::new(),
            height: Vec::new(),
        };
        packed.offsets.push(0);
        for b in 0..blocks {
            // Padding lanes of the last block repeat its first row.
            let lane_row = |l: usize| if b * lanes + l < rows { b * lanes + l } else { b * lanes };
            let slots = (0..lanes).map(|l| encoding.ring(lane_row(l)).len()).max().unwrap_or(0);
            for l in 0..lanes {
                let e = lane_row(l);
                packed.vertices.push(encoding.vertices()[e]);
                if !scale_safe {
                    packed.valence.push(encoding.ring(e).len() as f32);
                    packed.height.push(encoding.height(e));
                }
            }
            for j in 0..slots {
                for l in 0..lanes {
                    let e = lane_row(l);
                    let ring = encoding.ring(e);
                    let real = j < ring.len();
                    let jj = j.min(ring.len() - 1);
                    packed.index.push(ring[jj]);
                    let w = if real { encoding.weights(e)[j] } else { 0.0 };
                    packed.weight.push(w);
                    if scale_safe {
                        packed
                            .weighted_tangent
                            .push(if real { w * encoding.tangents(e)[j] } else { 0.0 });
                    } else {
                        packed.unit.push(if real { 1.0 } else { 0.0 });
                    }
                }
            }
            packed.offsets.push(packed.index.len() as u32);
        }
        packed
    }

    pub fn rows(&self) -> usize {
        self.rows
    }

    pub fn width(&self) -> Width {
        self.width
    }

    /// Targets `m + s n` of rows `rows` (a range of encoded vertices) at
    /// positions `x`, written to `out[..rows.len()]`; a row whose ring has
    /// collapsed stays put.
    pub fn targets(&self, x: &[Vec3], rows: std::ops::Range<usize>, out: &mut [Vec3]) {
        assert_eq!(x.len(), self.vertex_count, "positions of another mesh");
        assert!(rows.end <= self.rows && out.len() >= rows.len());
        match self.width {
            Width::Four => self.targets_in::<F4>(x, rows, out),
            // SAFETY: packed for eight lanes only where the CPU has AVX2 (`with_width`).
            #[cfg(target_arch = "x86_64")]
            Width::Eight => unsafe { self.targets_avx2(x, rows, out) },
            #[cfg(not(target_arch = "x86_64"))]
            Width::Eight => unreachable!("eight lanes are x86-64 only"),
        }
    }

    /// The fused diagonal step of one chunk with these targets as the only
    /// varying rows (see [`crate::solve::Constraint::solve_chunk`]): each
    /// target goes from the kernel's registers straight into its vertex's
    /// weighted average, with no target buffer and no separate passes to
    /// start from the constant sums and to divide.
    pub fn solve_chunk(&self, x: &[Vec3], rows: std::ops::Range<usize>, chunk: &DiagonalChunk<'_>, out: &mut [Vec3]) {
        assert_eq!(x.len(), self.vertex_count, "positions of another mesh");
        assert!(rows.end <= self.rows && chunk.weights.len() == rows.len());
        assert!(chunk.constant.len() == out.len() && chunk.inverse.len() == out.len());
        match self.width {
            Width::Four => self.solve_chunk_in::<F4>(x, rows, chunk, out),
            // SAFETY: as in `targets`.
            #[cfg(target_arch = "x86_64")]
            Width::Eight => unsafe { self.solve_chunk_avx2(x, rows, chunk, out) },
            #[cfg(not(target_arch = "x86_64"))]
            Width::Eight => unreachable!("eight lanes are x86-64 only"),
        }
    }

    /// [`Self::targets_in`] compiled with AVX2, where [`super::lanes::F8`]'s
    /// methods are inlined.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn targets_avx2(&self, x: &[Vec3], rows: std::ops::Range<usize>, out: &mut [Vec3]) {
        self.targets_in::<super::lanes::F8>(x, rows, out)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn solve_chunk_avx2(&self, x: &[Vec3], rows: std::ops::Range<usize>, chunk: &DiagonalChunk<'_>, out: &mut [Vec3]) {
        self.solve_chunk_in::<super::lanes::F8>(x, rows, chunk, out)
    }

    #[inline(always)]
    fn targets_in<W: Wide>(&self, x: &[Vec3], rows: std::ops::Range<usize>, out: &mut [Vec3]) {
        if rows.is_empty() {
            return;
        }
        let (first, last) = (rows.start / W::LANES, (rows.end - 1) / W::LANES);
        let mut cache = [[W::ZERO; 3]; super::encode::MAX_VALENCE];
        for b in first..=last {
            // Copies with a constant slot count for the common ring sizes
            // (fully unrolled) were tried and measured no faster.
            let lanes = self.block(b, x, &mut cache);
            self.for_each_point(b, x, &lanes, |r, t| {
                if rows.contains(&r) {
                    out[r - rows.start] = t;
                }
            });
        }
    }

    #[inline(always)]
    fn solve_chunk_in<W: Wide>(&self, x: &[Vec3], rows: std::ops::Range<usize>, chunk: &DiagonalChunk<'_>, out: &mut [Vec3]) {
        let (constant, inverse) = (chunk.constant, chunk.inverse);
        // Vertices of the chunk are written in order; `next` is the first one
        // not yet written. Those without a row (pinned) only have the constant sum.
        let mut next = 0;
        let fill_to = |end: usize, out: &mut [Vec3], next: &mut usize| {
            for k in *next..end {
                out[k] = constant[k] * inverse[k];
            }
            *next = end;
        };
        let lanes_of = W::LANES;
        let all_valid = (1u32 << lanes_of) - 1;
        if !rows.is_empty() {
            let (first, last) = (rows.start / lanes_of, (rows.end - 1) / lanes_of);
            let mut cache = [[W::ZERO; 3]; super::encode::MAX_VALENCE];
            for b in first..=last {
                let lanes = self.block(b, x, &mut cache);
                let r0 = b * lanes_of;
                let v0 = self.vertices[r0] as usize;
                // The common case: a whole block of rows in the chunk, for
                // consecutive vertices (vertices ascend, so the last is
                // v0 + lanes − 1), all with a frame: the same sums, a block
                // of vertices at a time.
                if lanes.valid == all_valid
                    && r0 >= rows.start
                    && r0 + lanes_of <= rows.end
                    && self.vertices[r0 + lanes_of - 1] as usize == v0 + lanes_of - 1
                {
                    let k = v0 - chunk.base;
                    fill_to(k, out, &mut next);
                    let c = W::load_points(&constant[k..k + lanes_of]);
                    let w = W::load(&chunk.weights[r0 - rows.start..]);
                    let i = W::load(&inverse[k..]);
                    let [tx, ty, tz] = lanes.target;
                    let o = [(c[0] + tx * w) * i, (c[1] + ty * w) * i, (c[2] + tz * w) * i];
                    W::store_points(o, &mut out[k..k + lanes_of]);
                    next = k + lanes_of;
                    continue;
                }
                self.for_each_point(b, x, &lanes, |r, t| {
                    if !rows.contains(&r) {
                        return;
                    }
                    let k = self.vertices[r] as usize - chunk.base;
                    fill_to(k, out, &mut next);
                    out[k] = (constant[k] + t * chunk.weights[r - rows.start]) * inverse[k];
                    next = k + 1;
                });
            }
        }
        fill_to(out.len(), out, &mut next);
    }

    #[inline(always)]
    fn slots(&self, b: usize) -> usize {
        (self.offsets[b + 1] - self.offsets[b]) as usize / self.width.lanes()
    }

    /// The targets of block `b`; `cache` has one entry per slot.
    #[inline(always)]
    fn block<W: Wide, const K: usize>(&self, b: usize, x: &[Vec3], cache: &mut [[W; 3]; K]) -> Lanes<W> {
        let n = W::LANES;
        let start = self.offsets[b] as usize;
        // Small caches are only used for blocks of exactly that many slots.
        let slots = if K < super::encode::MAX_VALENCE { K } else { self.slots(b) };
        let zero = W::ZERO;

        // The block's slot entries, a lane each per slot; iterating them by
        // exact chunks lets the compiler drop every bounds check of the loops.
        let end = start + n * slots;
        let index = self.index[start..end].chunks_exact(n);
        let mut slot = index.zip(self.weight[start..end].chunks_exact(n));
        // SAFETY: every stored index is a vertex of the encoding's mesh
        // (checked when the topology was built), the callers checked that `x`
        // has that many vertices, and each chunk has one index per lane.
        let gather = |ix: &[u32]| unsafe { W::gather_xyz(x, ix) };

        // Pass 1: gather, vector area relative to the first neighbour, mean.
        let Some((i0, w0)) = slot.next() else {
            return Lanes { target: [zero; 3], valid: 0 };
        };
        let [ox, oy, oz] = gather(i0);
        cache[0] = [ox, oy, oz];
        let w0 = W::load(w0);
        let (mut mx, mut my, mut mz) = (zero + w0 * ox, zero + w0 * oy, zero + w0 * oz);
        let (mut ax, mut ay, mut az) = (zero, zero, zero);
        let mut previous = [zero; 3];
        for (j, (cached, (ix, w))) in cache[1..slots].iter_mut().zip(slot).enumerate() {
            let [px, py, pz] = gather(ix);
            *cached = [px, py, pz];
            let w = W::load(w);
            mx = mx + w * px;
            my = my + w * py;
            mz = mz + w * pz;
            let current = [px - ox, py - oy, pz - oz];
            if j >= 1 {
                let [bx, by, bz] = previous;
                let [cx, cy, cz] = current;
                ax = ax + (by * cz - cy * bz);
                ay = ay + (bz * cx - cz * bx);
                az = az + (bx * cy - cx * by);
            }
            previous = current;
        }
        let ((tx, ty, tz), area_valid) = if self.scale_safe {
            // Pass 2, scale-safe: the projected edge lengths |(m − x_j) × a| / |a|
            // from the unnormalised area vector, so no square root or division
            // stands between the two passes.
            let scale = W::normalising_power_of_two(ax, ay, az);
            let (ax, ay, az) = (ax * scale, ay * scale, az * scale);
            let area2 = ax * ax + ay * ay + az * az;
            let mut s = zero;
            let tangent = self.weighted_tangent[start..end].chunks_exact(n);
            for (&[px, py, pz], t) in cache[..slots].iter().zip(tangent) {
                let (dx, dy, dz) = (mx - px, my - py, mz - pz);
                let (cx, cy, cz) = (dy * az - dz * ay, dz * ax - dx * az, dx * ay - dy * ax);
                s = s + W::load(t) * (cx * cx + cy * cy + cz * cz).sqrt();
            }
            let k = s / area2;
            ((mx + ax * k, my + ay * k, mz + az * k), area2.gt(zero) & area2.finite())
        } else {
            // Pass 2, plain: the offset of the mean from the ring centroid along the normal.
            let length = (ax * ax + ay * ay + az * az).sqrt();
            let inverse = W::splat(1.0) / length;
            let (nx, ny, nz) = (ax * inverse, ay * inverse, az * inverse);
            let (mut cx, mut cy, mut cz) = (zero, zero, zero);
            let unit = self.unit[start..end].chunks_exact(n);
            for (&[px, py, pz], u) in cache[..slots].iter().zip(unit) {
                let u = W::load(u);
                cx = cx + u * px;
                cy = cy + u * py;
                cz = cz + u * pz;
            }
            let k = W::load(&self.valence[b * n..]);
            let (cx, cy, cz) = (cx / k, cy / k, cz / k);
            let dot = (mx - cx) * nx + (my - cy) * ny + (mz - cz) * nz;
            let offset = W::load(&self.height[b * n..]) - dot;
            ((mx + nx * offset, my + ny * offset, mz + nz * offset), length.gt(zero) & length.finite())
        };
        let valid = area_valid & tx.finite() & ty.finite() & tz.finite();
        Lanes { target: [tx, ty, tz], valid: valid.to_bits() }
    }

    /// Calls `f(row, target)` for each lane of block `b` in order; a row
    /// without a frame stays put.
    #[inline(always)]
    fn for_each_point<W: Wide>(&self, b: usize, x: &[Vec3], lanes: &Lanes<W>, mut f: impl FnMut(usize, Vec3)) {
        let n = W::LANES;
        let mut t = [[0.0f32; MAX_LANES]; 3];
        for (c, target) in t.iter_mut().zip(lanes.target) {
            target.store(c);
        }
        for l in 0..n {
            let r = b * n + l;
            let point = if lanes.valid & (1 << l) != 0 {
                Vec3::new(t[0][l], t[1][l], t[2][l])
            } else {
                // No frame: stay put (the row is neutral).
                x[self.vertices[r] as usize]
            };
            f(r, point);
        }
    }
}

/// The widest block, in lanes.
const MAX_LANES: usize = 8;

/// The targets of one block, one row per lane, and which lanes have a frame
/// (bit `l` of `valid`).
struct Lanes<W> {
    target: [W; 3],
    valid: u32,
}
