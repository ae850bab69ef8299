//! The hot loop of the default solve: Algorithm 1 for four encoded vertices
//! at once (structure of arrays across vertices, SSE2 on x86-64, plain arrays
//! elsewhere).
//!
//! [`project::frame`](super::project::frame) is the reference; this kernel
//! evaluates the same formulas with the same operations in the same order,
//! one vertex per lane, so its targets equal the scalar ones (IEEE
//! operations are correctly rounded whatever the lane; Rust never contracts
//! to FMA). The only difference is the sign of an exact zero, from padding:
//! rows are packed four by four into *blocks*, and a block's slots run to the
//! longest ring of its four rows; a shorter ring is padded by repeating its
//! last neighbour with weight 0, which adds `cross(a, a) = 0` to the vector
//! area and `0·x = 0` to the weighted sums.
//!
//! Only SSE2 is used, which every x86-64 CPU has, so the wheel keeps running
//! anywhere; no runtime dispatch is needed.

use glam::Vec3;

use super::encoding::Encoding;
use crate::solve::DiagonalChunk;

/// Rows per block.
pub const LANES: usize = 4;

/// The encoding repacked for the kernel. Entry `(b, j, l)` (block `b`, ring
/// slot `j`, lane `l`) lives at `offsets[b] + LANES·j + l`.
#[derive(Debug, Clone)]
pub struct Packed {
    rows: usize,
    vertex_count: usize,
    scale_safe: bool,
    /// Entry offset of each block, `blocks + 1` values.
    offsets: Vec<u32>,
    /// The row's own vertex per lane (`blocks · LANES`; padding lanes repeat a real row).
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
    pub fn new(encoding: &Encoding) -> Self {
        let rows = encoding.len();
        let blocks = rows.div_ceil(LANES);
        let scale_safe = encoding.scale_safe();
        let mut packed = Packed {
            rows,
            vertex_count: encoding.vertex_count(),
            scale_safe,
            offsets: Vec::with_capacity(blocks + 1),
            vertices: Vec::with_capacity(blocks * LANES),
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
            let lane_row = |l: usize| if b * LANES + l < rows { b * LANES + l } else { b * LANES };
            let slots = (0..LANES).map(|l| encoding.ring(lane_row(l)).len()).max().unwrap_or(0);
            for l in 0..LANES {
                let e = lane_row(l);
                packed.vertices.push(encoding.vertices()[e]);
                if !scale_safe {
                    packed.valence.push(encoding.ring(e).len() as f32);
                    packed.height.push(encoding.height(e));
                }
            }
            for j in 0..slots {
                for l in 0..LANES {
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

    /// Targets `m + s n` of rows `rows` (a range of encoded vertices) at
    /// positions `x`, written to `out[..rows.len()]`; a row whose ring has
    /// collapsed stays put.
    pub fn targets(&self, x: &[Vec3], rows: std::ops::Range<usize>, out: &mut [Vec3]) {
        assert_eq!(x.len(), self.vertex_count, "positions of another mesh");
        assert!(rows.end <= self.rows && out.len() >= rows.len());
        if rows.is_empty() {
            return;
        }
        let (first, last) = (rows.start / LANES, (rows.end - 1) / LANES);
        let mut cache = [[F4::ZERO; 3]; super::encode::MAX_VALENCE];
        for b in first..=last {
            // Copies with a constant slot count for the common ring sizes
            // (fully unrolled) were tried and measured no faster.
            let lanes = self.block(b, x, &mut cache);
            for (l, t) in self.points(b, x, &lanes).iter().enumerate() {
                let r = b * LANES + l;
                if rows.contains(&r) {
                    out[r - rows.start] = *t;
                }
            }
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
        if !rows.is_empty() {
            let (first, last) = (rows.start / LANES, (rows.end - 1) / LANES);
            let mut cache = [[F4::ZERO; 3]; super::encode::MAX_VALENCE];
            for b in first..=last {
                let lanes = self.block(b, x, &mut cache);
                let r0 = b * LANES;
                let v0 = self.vertices[r0] as usize;
                // The common case: a whole block of rows in the chunk, for four
                // consecutive vertices (vertices ascend, so the last is v0 + 3),
                // all with a frame: the same sums, four vertices at a time.
                if lanes.valid == ALL_VALID
                    && r0 >= rows.start
                    && r0 + LANES <= rows.end
                    && self.vertices[r0 + LANES - 1] as usize == v0 + LANES - 1
                {
                    let k = v0 - chunk.base;
                    fill_to(k, out, &mut next);
                    let c = F4::load_points(&constant[k..k + LANES]);
                    let w = F4::load(&chunk.weights[r0 - rows.start..]);
                    let i = F4::load(&inverse[k..]);
                    let [tx, ty, tz] = lanes.target;
                    let o = [(c[0] + tx * w) * i, (c[1] + ty * w) * i, (c[2] + tz * w) * i];
                    F4::store_points(o, &mut out[k..k + LANES]);
                    next = k + LANES;
                    continue;
                }
                for (l, t) in self.points(b, x, &lanes).iter().enumerate() {
                    let r = r0 + l;
                    if !rows.contains(&r) {
                        continue;
                    }
                    let k = self.vertices[r] as usize - chunk.base;
                    fill_to(k, out, &mut next);
                    out[k] = (constant[k] + *t * chunk.weights[r - rows.start]) * inverse[k];
                    next = k + 1;
                }
            }
        }
        fill_to(out.len(), out, &mut next);
    }

    #[inline(always)]
    fn slots(&self, b: usize) -> usize {
        (self.offsets[b + 1] - self.offsets[b]) as usize / LANES
    }

    /// The four targets of block `b`; `cache` has one entry per slot.
    #[inline(always)]
    fn block<const K: usize>(&self, b: usize, x: &[Vec3], cache: &mut [[F4; 3]; K]) -> Lanes {
        let start = self.offsets[b] as usize;
        // Small caches are only used for blocks of exactly that many slots.
        let slots = if K < super::encode::MAX_VALENCE { K } else { self.slots(b) };
        let zero = F4::ZERO;

        // The block's slot entries, four lanes per slot; iterating them by
        // exact chunks lets the compiler drop every bounds check of the loops.
        let end = start + LANES * slots;
        let index = self.index[start..end].chunks_exact(LANES);
        let mut slot = index.zip(self.weight[start..end].chunks_exact(LANES));
        let gather = |ix: &[u32]| {
            // SAFETY: every stored index is a vertex of the encoding's mesh
            // (checked when the topology was built) and `targets` checked
            // that `x` has that many vertices.
            unsafe { F4::gather_xyz(x, [ix[0], ix[1], ix[2], ix[3]]) }
        };

        // Pass 1: gather, vector area relative to the first neighbour, mean.
        let Some((i0, w0)) = slot.next() else {
            return Lanes { target: [zero; 3], valid: 0 };
        };
        let [ox, oy, oz] = gather(i0);
        cache[0] = [ox, oy, oz];
        let w0 = F4::load(w0);
        let (mut mx, mut my, mut mz) = (zero + w0 * ox, zero + w0 * oy, zero + w0 * oz);
        let (mut ax, mut ay, mut az) = (zero, zero, zero);
        let mut previous = [zero; 3];
        for (j, (cached, (ix, w))) in cache[1..slots].iter_mut().zip(slot).enumerate() {
            let [px, py, pz] = gather(ix);
            *cached = [px, py, pz];
            let w = F4::load(w);
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
            let scale = F4::normalising_power_of_two(ax, ay, az);
            let (ax, ay, az) = (ax * scale, ay * scale, az * scale);
            let area2 = ax * ax + ay * ay + az * az;
            let mut s = zero;
            let tangent = self.weighted_tangent[start..end].chunks_exact(LANES);
            for (&[px, py, pz], t) in cache[..slots].iter().zip(tangent) {
                let (dx, dy, dz) = (mx - px, my - py, mz - pz);
                let (cx, cy, cz) = (dy * az - dz * ay, dz * ax - dx * az, dx * ay - dy * ax);
                s = s + F4::load(t) * (cx * cx + cy * cy + cz * cz).sqrt();
            }
            let k = s / area2;
            ((mx + ax * k, my + ay * k, mz + az * k), area2.gt(zero) & area2.finite())
        } else {
            // Pass 2, plain: the offset of the mean from the ring centroid along the normal.
            let length = (ax * ax + ay * ay + az * az).sqrt();
            let inverse = F4::splat(1.0) / length;
            let (nx, ny, nz) = (ax * inverse, ay * inverse, az * inverse);
            let (mut cx, mut cy, mut cz) = (zero, zero, zero);
            let unit = self.unit[start..end].chunks_exact(LANES);
            for (&[px, py, pz], u) in cache[..slots].iter().zip(unit) {
                let u = F4::load(u);
                cx = cx + u * px;
                cy = cy + u * py;
                cz = cz + u * pz;
            }
            let k = F4::load(&self.valence[b * LANES..]);
            let (cx, cy, cz) = (cx / k, cy / k, cz / k);
            let dot = (mx - cx) * nx + (my - cy) * ny + (mz - cz) * nz;
            let offset = F4::load(&self.height[b * LANES..]) - dot;
            ((mx + nx * offset, my + ny * offset, mz + nz * offset), length.gt(zero) & length.finite())
        };
        let valid = area_valid & tx.finite() & ty.finite() & tz.finite();
        Lanes { target: [tx, ty, tz], valid: valid.to_bits() }
    }

    /// The four targets of block `b` as points; a row without a frame stays put.
    #[inline(always)]
    fn points(&self, b: usize, x: &[Vec3], lanes: &Lanes) -> [Vec3; LANES] {
        let [tx, ty, tz] = lanes.target.map(F4::to_array);
        std::array::from_fn(|l| {
            if lanes.valid & (1 << l) != 0 {
                Vec3::new(tx[l], ty[l], tz[l])
            } else {
                // No frame: stay put (the row is neutral).
                x[self.vertices[b * LANES + l] as usize]
            }
        })
    }
}

/// The targets of one block, one row per lane, and which lanes have a frame
/// (bit `l` of `valid`).
struct Lanes {
    target: [F4; 3],
    valid: u32,
}

/// Every lane has a frame.
const ALL_VALID: u32 = (1 << LANES) - 1;

pub use f4::F4;

#[cfg(target_arch = "x86_64")]
mod f4 {
    #![allow(unused_unsafe)]
    use std::arch::x86_64::*;
    use std::ops::{Add, BitAnd, Div, Mul, Sub};

    // `gather_xyz` reads a point as 16 bytes from its first float.
    const _: () = assert!(std::mem::size_of::<glam::Vec3>() == 12);

    /// Four f32 lanes (SSE2, part of every x86-64 CPU).
    #[derive(Clone, Copy, Debug)]
    pub struct F4(__m128);

    impl F4 {
        pub const ZERO: F4 = F4(unsafe { std::mem::transmute::<[f32; 4], __m128>([0.0; 4]) });

        #[inline(always)]
        pub fn new(a: f32, b: f32, c: f32, d: f32) -> F4 {
            F4(unsafe { _mm_setr_ps(a, b, c, d) })
        }
        #[inline(always)]
        pub fn splat(v: f32) -> F4 {
            F4(unsafe { _mm_set1_ps(v) })
        }
        /// The first four values of `s`.
        #[inline(always)]
        pub fn load(s: &[f32]) -> F4 {
            let s = &s[..4];
            F4(unsafe { _mm_loadu_ps(s.as_ptr()) })
        }
        #[inline(always)]
        pub fn sqrt(self) -> F4 {
            F4(unsafe { _mm_sqrt_ps(self.0) })
        }
        /// Lane mask `self > other`.
        #[inline(always)]
        pub fn gt(self, other: F4) -> F4 {
            F4(unsafe { _mm_cmpgt_ps(self.0, other.0) })
        }
        /// Lane mask "finite": `x − x == 0` fails exactly for ±∞ and NaN.
        #[inline(always)]
        pub fn finite(self) -> F4 {
            F4(unsafe { _mm_cmpeq_ps(_mm_sub_ps(self.0, self.0), _mm_setzero_ps()) })
        }
        #[inline(always)]
        pub fn to_array(self) -> [f32; 4] {
            unsafe { std::mem::transmute::<__m128, [f32; 4]>(self.0) }
        }
        /// `[x, y, z]` lanes of the points `x[index[l]]`: one 16-byte load per
        /// point and a 4×3 transpose, instead of twelve scalar loads and their
        /// inserts (the gathers are most of the kernel's work). The last point
        /// of `x` has no fourth float after it to over-read, so it is loaded
        /// by parts.
        ///
        /// # Safety
        /// Every index is below `x.len()`.
        #[inline(always)]
        pub unsafe fn gather_xyz(x: &[glam::Vec3], index: [u32; 4]) -> [F4; 3] {
            let last = x.len() - 1;
            let row = |i: u32| -> __m128 {
                let i = i as usize;
                if i < last {
                    // Vec3 is three packed f32; x[i + 1] exists, so 16 bytes are in bounds.
                    unsafe { _mm_loadu_ps(x.as_ptr().add(i) as *const f32) }
                } else {
                    let p = unsafe { *x.get_unchecked(i) };
                    unsafe { _mm_setr_ps(p.x, p.y, p.z, 0.0) }
                }
            };
            let (r0, r1, r2, r3) = (row(index[0]), row(index[1]), row(index[2]), row(index[3]));
            unsafe {
                let xy01 = _mm_unpacklo_ps(r0, r1); // x0 x1 y0 y1
                let xy23 = _mm_unpacklo_ps(r2, r3); // x2 x3 y2 y3
                let zw01 = _mm_unpackhi_ps(r0, r1); // z0 z1 w0 w1
                let zw23 = _mm_unpackhi_ps(r2, r3); // z2 z3 w2 w3
                [
                    F4(_mm_movelh_ps(xy01, xy23)),
                    F4(_mm_movehl_ps(xy23, xy01)),
                    F4(_mm_movelh_ps(zw01, zw23)),
                ]
            }
        }
        /// Per lane, the power of two that brings the largest of `|a|, |b|, |c|`
        /// into [1, 2) (see [`crate::pyramid::project::normalising_power_of_two`]).
        #[inline(always)]
        pub fn normalising_power_of_two(a: F4, b: F4, c: F4) -> F4 {
            unsafe {
                let exponent = _mm_castsi128_ps(_mm_set1_epi32(crate::pyramid::project::EXPONENT as i32));
                // Exponent fields are non-negative floats: their float maximum is the integer one.
                let e = _mm_max_ps(
                    _mm_max_ps(_mm_and_ps(a.0, exponent), _mm_and_ps(b.0, exponent)),
                    _mm_and_ps(c.0, exponent),
                );
                let bits = _mm_sub_epi32(_mm_set1_epi32(crate::pyramid::project::REFLECTED_EXPONENT as i32), _mm_castps_si128(e));
                F4(_mm_castsi128_ps(bits))
            }
        }
        /// Lanes of a comparison mask as bits (lane `l` is bit `l`).
        #[inline(always)]
        pub fn to_bits(self) -> u32 {
            unsafe { _mm_movemask_ps(self.0) as u32 }
        }
        /// `[x, y, z]` lanes of four packed points: three 16-byte loads and a
        /// transpose.
        #[inline(always)]
        pub fn load_points(p: &[glam::Vec3]) -> [F4; 3] {
            let p: &[f32; 12] = bytemuck::cast_slice(&p[..4]).try_into().expect("four points");
            unsafe {
                // r0 = x0 y0 z0 x1, r1 = y1 z1 x2 y2, r2 = z2 x3 y3 z3
                let r0 = _mm_loadu_ps(p.as_ptr());
                let r1 = _mm_loadu_ps(p.as_ptr().add(4));
                let r2 = _mm_loadu_ps(p.as_ptr().add(8));
                let x23 = _mm_shuffle_ps::<0b00_01_00_10>(r1, r2); // x2 . x3 .
                let x = _mm_shuffle_ps::<0b10_00_11_00>(r0, x23); // x0 x1 x2 x3
                let y01 = _mm_shuffle_ps::<0b00_00_00_01>(r0, r1); // y0 . y1 .
                let y23 = _mm_shuffle_ps::<0b00_10_00_11>(r1, r2); // y2 . y3 .
                let y = _mm_shuffle_ps::<0b10_00_10_00>(y01, y23);
                let z01 = _mm_shuffle_ps::<0b00_01_00_10>(r0, r1); // z0 . z1 .
                let z23 = _mm_shuffle_ps::<0b00_11_00_00>(r2, r2); // z2 . z3 .
                let z = _mm_shuffle_ps::<0b10_00_10_00>(z01, z23);
                [F4(x), F4(y), F4(z)]
            }
        }
        /// Stores `[x, y, z]` lanes as four packed points (the inverse of
        /// [`F4::load_points`]).
        #[inline(always)]
        pub fn store_points([x, y, z]: [F4; 3], p: &mut [glam::Vec3]) {
            let p: &mut [f32; 12] = bytemuck::cast_slice_mut(&mut p[..4]).try_into().expect("four points");
            unsafe {
                let (x, y, z) = (x.0, y.0, z.0);
                let xy01 = _mm_unpacklo_ps(x, y); // x0 y0 x1 y1
                let xy23 = _mm_unpackhi_ps(x, y); // x2 y2 x3 y3
                let zx = _mm_shuffle_ps::<0b00_01_00_00>(z, x); // z0 . x1 .
                let r0 = _mm_shuffle_ps::<0b10_00_01_00>(xy01, zx); // x0 y0 z0 x1
                let yz = _mm_shuffle_ps::<0b00_01_00_01>(y, z); // y1 . z1 .
                let r1 = _mm_shuffle_ps::<0b01_00_10_00>(yz, xy23); // y1 z1 x2 y2
                let zxy = _mm_shuffle_ps::<0b11_10_11_10>(z, xy23); // z2 z3 x3 y3
                let r2 = _mm_shuffle_ps::<0b01_11_10_00>(zxy, zxy); // z2 x3 y3 z3
                _mm_storeu_ps(p.as_mut_ptr(), r0);
                _mm_storeu_ps(p.as_mut_ptr().add(4), r1);
                _mm_storeu_ps(p.as_mut_ptr().add(8), r2);
            }
        }
    }

    macro_rules! op {
        ($trait:ident, $method:ident, $intrinsic:ident) => {
            impl $trait for F4 {
                type Output = F4;
                #[inline(always)]
                fn $method(self, rhs: F4) -> F4 {
                    F4(unsafe { $intrinsic(self.0, rhs.0) })
                }
            }
        };
    }
    op!(Add, add, _mm_add_ps);
    op!(Sub, sub, _mm_sub_ps);
    op!(Mul, mul, _mm_mul_ps);
    op!(Div, div, _mm_div_ps);
    op!(BitAnd, bitand, _mm_and_ps);
}

#[cfg(not(target_arch = "x86_64"))]
mod f4 {
    use std::ops::{Add, BitAnd, Div, Mul, Sub};

    /// Four f32 lanes as a plain array (the compiler vectorises it where it can).
    #[derive(Clone, Copy, Debug)]
    pub struct F4([f32; 4]);

    const TRUE: f32 = f32::from_bits(u32::MAX);

    impl F4 {
        pub const ZERO: F4 = F4([0.0; 4]);

        #[inline(always)]
        pub fn new(a: f32, b: f32, c: f32, d: f32) -> F4 {
            F4([a, b, c, d])
        }
        #[inline(always)]
        pub fn splat(v: f32) -> F4 {
            F4([v; 4])
        }
        #[inline(always)]
        pub fn load(s: &[f32]) -> F4 {
            F4([s[0], s[1], s[2], s[3]])
        }
        #[inline(always)]
        pub fn sqrt(self) -> F4 {
            F4(self.0.map(f32::sqrt))
        }
        #[inline(always)]
        pub fn gt(self, other: F4) -> F4 {
            F4(std::array::from_fn(|l| if self.0[l] > other.0[l] { TRUE } else { 0.0 }))
        }
        #[inline(always)]
        pub fn finite(self) -> F4 {
            F4(self.0.map(|v| if v.is_finite() { TRUE } else { 0.0 }))
        }
        #[inline(always)]
        pub fn to_array(self) -> [f32; 4] {
            self.0
        }
        /// `[x, y, z]` lanes of the points `x[index[l]]`.
        ///
        /// # Safety
        /// Every index is below `x.len()`.
        #[inline(always)]
        pub unsafe fn gather_xyz(x: &[glam::Vec3], index: [u32; 4]) -> [F4; 3] {
            let p = index.map(|i| unsafe { *x.get_unchecked(i as usize) });
            [
                F4(p.map(|p| p.x)),
                F4(p.map(|p| p.y)),
                F4(p.map(|p| p.z)),
            ]
        }
        /// Per lane, [`crate::pyramid::project::normalising_power_of_two`].
        #[inline(always)]
        pub fn normalising_power_of_two(a: F4, b: F4, c: F4) -> F4 {
            F4(std::array::from_fn(|l| {
                crate::pyramid::project::normalising_power_of_two(glam::Vec3::new(a.0[l], b.0[l], c.0[l]))
            }))
        }
        #[inline(always)]
        pub fn to_bits(self) -> u32 {
            (0..4).map(|l| ((self.0[l].to_bits() != 0) as u32) << l).sum()
        }
        /// `[x, y, z]` lanes of four packed points.
        #[inline(always)]
        pub fn load_points(p: &[glam::Vec3]) -> [F4; 3] {
            let p = &p[..4];
            [F4(std::array::from_fn(|l| p[l].x)), F4(std::array::from_fn(|l| p[l].y)), F4(std::array::from_fn(|l| p[l].z))]
        }
        /// Stores `[x, y, z]` lanes as four packed points.
        #[inline(always)]
        pub fn store_points([x, y, z]: [F4; 3], p: &mut [glam::Vec3]) {
            for (l, p) in p[..4].iter_mut().enumerate() {
                *p = glam::Vec3::new(x.0[l], y.0[l], z.0[l]);
            }
        }
    }

    macro_rules! op {
        ($trait:ident, $method:ident, $op:tt) => {
            impl $trait for F4 {
                type Output = F4;
                #[inline(always)]
                fn $method(self, rhs: F4) -> F4 {
                    F4(std::array::from_fn(|l| self.0[l] $op rhs.0[l]))
                }
            }
        };
    }
    op!(Add, add, +);
    op!(Sub, sub, -);
    op!(Mul, mul, *);
    op!(Div, div, /);

    impl BitAnd for F4 {
        type Output = F4;
        #[inline(always)]
        fn bitand(self, rhs: F4) -> F4 {
            F4(std::array::from_fn(|l| f32::from_bits(self.0[l].to_bits() & rhs.0[l].to_bits())))
        }
    }
}
