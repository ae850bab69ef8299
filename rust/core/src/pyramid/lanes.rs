//! The SIMD lane types the pyramid kernel is written in: [`F4`] (four f32
//! lanes; SSE2 on x86-64, which every x86-64 CPU has, plain arrays elsewhere)
//! and, on x86-64 CPUs with AVX2, [`F8`] (eight lanes).
//!
//! The kernel is one generic function over [`Wide`]; each type performs the
//! same IEEE operations per lane (correctly rounded whatever the width), so
//! both widths give the scalar reference's results. Eight lanes pay off more
//! than their arithmetic suggests: a block's time is mostly a chain of
//! latencies (the gathers, a square root per neighbour, then a division), and
//! an eight-lane block waits on the same chain for twice the vertices. One
//! sweep of the 100k-vertex benchmark sphere, one thread: 1.16 ms with four
//! lanes, 0.84 ms with eight (`cargo bench -p tegument-core --bench
//! pyramid`). Blocks of eight rows pad more on irregular rings (each block
//! runs to its longest ring); with the sphere's quads split into triangles
//! at random (rings of 4 to 8), eight lanes still took 1.10 ms against 1.66.

use std::ops::{Add, BitAnd, Div, Mul, Sub};

use glam::Vec3;

/// A vector of `LANES` f32 lanes with the operations the kernel needs.
pub trait Wide:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self> + BitAnd<Output = Self>
{
    const LANES: usize;
    const ZERO: Self;
    fn splat(v: f32) -> Self;
    /// The first `LANES` values of `s`.
    fn load(s: &[f32]) -> Self;
    /// Writes the lanes to `out[..LANES]`.
    fn store(self, out: &mut [f32]);
    fn sqrt(self) -> Self;
    /// Lane mask `self > other`.
    fn gt(self, other: Self) -> Self;
    /// Lane mask "finite".
    fn finite(self) -> Self;
    /// Lanes of a comparison mask as bits (lane `l` is bit `l`).
    fn to_bits(self) -> u32;
    /// `[x, y, z]` lanes of the points `x[index[l]]`.
    ///
    /// # Safety
    /// `index` has `LANES` entries, each below `x.len()`.
    unsafe fn gather_xyz(x: &[Vec3], index: &[u32]) -> [Self; 3];
    /// Per lane, the power of two that brings the largest of `|a|, |b|, |c|`
    /// into [1, 2) (see [`crate::pyramid::project::normalising_power_of_two`]).
    fn normalising_power_of_two(a: Self, b: Self, c: Self) -> Self;
    /// `[x, y, z]` lanes of `LANES` consecutive points.
    fn load_points(p: &[Vec3]) -> [Self; 3];
    /// Stores `[x, y, z]` lanes as `LANES` consecutive points.
    fn store_points(v: [Self; 3], p: &mut [Vec3]);
}

pub use simd::*;

#[cfg(target_arch = "x86_64")]
mod simd {
    #![allow(unused_unsafe)]
    use std::arch::x86_64::*;
    use std::ops::{Add, BitAnd, Div, Mul, Sub};

    use glam::Vec3;

    use super::Wide;
    use crate::pyramid::project::{EXPONENT, REFLECTED_EXPONENT};

    // `row` reads a point as 16 bytes from its first float.
    const _: () = assert!(std::mem::size_of::<Vec3>() == 12);

    /// Point `x[i]` as `x y z ?`: one 16-byte load, except for the last
    /// point of `x`, which has no fourth float after it to over-read.
    ///
    /// # Safety
    /// `i < x.len()`.
    #[inline(always)]
    unsafe fn row(x: &[Vec3], i: u32) -> __m128 {
        let i = i as usize;
        if i < x.len() - 1 {
            // Vec3 is three packed f32; x[i + 1] exists, so 16 bytes are in bounds.
            unsafe { _mm_loadu_ps(x.as_ptr().add(i) as *const f32) }
        } else {
            let p = unsafe { *x.get_unchecked(i) };
            unsafe { _mm_setr_ps(p.x, p.y, p.z, 0.0) }
        }
    }

    /// Four f32 lanes (SSE2, part of every x86-64 CPU).
    #[derive(Clone, Copy, Debug)]
    pub struct F4(__m128);

    impl Wide for F4 {
        const LANES: usize = 4;
        const ZERO: F4 = F4(unsafe { std::mem::transmute::<[f32; 4], __m128>([0.0; 4]) });

        #[inline(always)]
        fn splat(v: f32) -> F4 {
            F4(unsafe { _mm_set1_ps(v) })
        }
        #[inline(always)]
        fn load(s: &[f32]) -> F4 {
            let s = &s[..4];
            F4(unsafe { _mm_loadu_ps(s.as_ptr()) })
        }
        #[inline(always)]
        fn store(self, out: &mut [f32]) {
            let out = &mut out[..4];
            unsafe { _mm_storeu_ps(out.as_mut_ptr(), self.0) }
        }
        #[inline(always)]
        fn sqrt(self) -> F4 {
            F4(unsafe { _mm_sqrt_ps(self.0) })
        }
        #[inline(always)]
        fn gt(self, other: F4) -> F4 {
            F4(unsafe { _mm_cmpgt_ps(self.0, other.0) })
        }
        /// `x − x == 0` fails exactly for ±∞ and NaN.
        #[inline(always)]
        fn finite(self) -> F4 {
            F4(unsafe { _mm_cmpeq_ps(_mm_sub_ps(self.0, self.0), _mm_setzero_ps()) })
        }
        #[inline(always)]
        fn to_bits(self) -> u32 {
            unsafe { _mm_movemask_ps(self.0) as u32 }
        }
        /// One 16-byte load per point and a 4×3 transpose, instead of twelve
        /// scalar loads and their inserts (the gathers are most of the
        /// kernel's work).
        #[inline(always)]
        unsafe fn gather_xyz(x: &[Vec3], index: &[u32]) -> [F4; 3] {
            let index = &index[..4];
            let (r0, r1, r2, r3) = unsafe { (row(x, index[0]), row(x, index[1]), row(x, index[2]), row(x, index[3])) };
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
        #[inline(always)]
        fn normalising_power_of_two(a: F4, b: F4, c: F4) -> F4 {
            unsafe {
                let exponent = _mm_castsi128_ps(_mm_set1_epi32(EXPONENT as i32));
                // Exponent fields are non-negative floats: their float maximum is the integer one.
                let e = _mm_max_ps(
                    _mm_max_ps(_mm_and_ps(a.0, exponent), _mm_and_ps(b.0, exponent)),
                    _mm_and_ps(c.0, exponent),
                );
                let bits = _mm_sub_epi32(_mm_set1_epi32(REFLECTED_EXPONENT as i32), _mm_castps_si128(e));
                F4(_mm_castsi128_ps(bits))
            }
        }
        /// Three 16-byte loads and a transpose.
        #[inline(always)]
        fn load_points(p: &[Vec3]) -> [F4; 3] {
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
        /// The inverse of [`F4::load_points`].
        #[inline(always)]
        fn store_points([x, y, z]: [F4; 3], p: &mut [Vec3]) {
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

    /// Eight f32 lanes (AVX2). Only valid inside a function compiled with
    /// `#[target_feature(enable = "avx2")]`, called after checking that the
    /// CPU has it: its methods are inlined into that function, where the AVX
    /// instructions are allowed.
    #[derive(Clone, Copy, Debug)]
    pub struct F8(__m256);

    impl Wide for F8 {
        const LANES: usize = 8;
        const ZERO: F8 = F8(unsafe { std::mem::transmute::<[f32; 8], __m256>([0.0; 8]) });

        #[inline(always)]
        fn splat(v: f32) -> F8 {
            F8(unsafe { _mm256_set1_ps(v) })
        }
        #[inline(always)]
        fn load(s: &[f32]) -> F8 {
            let s = &s[..8];
            F8(unsafe { _mm256_loadu_ps(s.as_ptr()) })
        }
        #[inline(always)]
        fn store(self, out: &mut [f32]) {
            let out = &mut out[..8];
            unsafe { _mm256_storeu_ps(out.as_mut_ptr(), self.0) }
        }
        #[inline(always)]
        fn sqrt(self) -> F8 {
            F8(unsafe { _mm256_sqrt_ps(self.0) })
        }
        /// The predicate of SSE's `_mm_cmpgt_ps` (ordered, signalling).
        #[inline(always)]
        fn gt(self, other: F8) -> F8 {
            F8(unsafe { _mm256_cmp_ps::<_CMP_GT_OS>(self.0, other.0) })
        }
        #[inline(always)]
        fn finite(self) -> F8 {
            F8(unsafe { _mm256_cmp_ps::<_CMP_EQ_OQ>(_mm256_sub_ps(self.0, self.0), _mm256_setzero_ps()) })
        }
        #[inline(always)]
        fn to_bits(self) -> u32 {
            unsafe { _mm256_movemask_ps(self.0) as u32 }
        }
        /// [`F4::gather_xyz`] with lanes 0–3 in the low half and 4–7 in the
        /// high half: AVX shuffles work within each half, so the same
        /// transpose serves both.
        #[inline(always)]
        unsafe fn gather_xyz(x: &[Vec3], index: &[u32]) -> [F8; 3] {
            let index = &index[..8];
            let pair = |l: usize| unsafe { _mm256_set_m128(row(x, index[l + 4]), row(x, index[l])) };
            let (r0, r1, r2, r3) = (pair(0), pair(1), pair(2), pair(3));
            unsafe {
                let xy01 = _mm256_unpacklo_ps(r0, r1);
                let xy23 = _mm256_unpacklo_ps(r2, r3);
                let zw01 = _mm256_unpackhi_ps(r0, r1);
                let zw23 = _mm256_unpackhi_ps(r2, r3);
                [
                    F8(_mm256_shuffle_ps::<0b01_00_01_00>(xy01, xy23)),
                    F8(_mm256_shuffle_ps::<0b11_10_11_10>(xy01, xy23)),
                    F8(_mm256_shuffle_ps::<0b01_00_01_00>(zw01, zw23)),
                ]
            }
        }
        #[inline(always)]
        fn normalising_power_of_two(a: F8, b: F8, c: F8) -> F8 {
            unsafe {
                let exponent = _mm256_castsi256_ps(_mm256_set1_epi32(EXPONENT as i32));
                let e = _mm256_max_ps(
                    _mm256_max_ps(_mm256_and_ps(a.0, exponent), _mm256_and_ps(b.0, exponent)),
                    _mm256_and_ps(c.0, exponent),
                );
                let bits = _mm256_sub_epi32(_mm256_set1_epi32(REFLECTED_EXPONENT as i32), _mm256_castps_si256(e));
                F8(_mm256_castsi256_ps(bits))
            }
        }
        #[inline(always)]
        fn load_points(p: &[Vec3]) -> [F8; 3] {
            let (low, high) = (F4::load_points(&p[..4]), F4::load_points(&p[4..8]));
            std::array::from_fn(|c| F8(unsafe { _mm256_set_m128(high[c].0, low[c].0) }))
        }
        #[inline(always)]
        fn store_points(v: [F8; 3], p: &mut [Vec3]) {
            let low = v.map(|v| F4(unsafe { _mm256_castps256_ps128(v.0) }));
            let high = v.map(|v| F4(unsafe { _mm256_extractf128_ps::<1>(v.0) }));
            F4::store_points(low, &mut p[..4]);
            F4::store_points(high, &mut p[4..8]);
        }
    }

    macro_rules! op {
        ($type:ident, $trait:ident, $method:ident, $intrinsic:ident) => {
            impl $trait for $type {
                type Output = $type;
                #[inline(always)]
                fn $method(self, rhs: $type) -> $type {
                    $type(unsafe { $intrinsic(self.0, rhs.0) })
                }
            }
        };
    }
    op!(F4, Add, add, _mm_add_ps);
    op!(F4, Sub, sub, _mm_sub_ps);
    op!(F4, Mul, mul, _mm_mul_ps);
    op!(F4, Div, div, _mm_div_ps);
    op!(F4, BitAnd, bitand, _mm_and_ps);
    op!(F8, Add, add, _mm256_add_ps);
    op!(F8, Sub, sub, _mm256_sub_ps);
    op!(F8, Mul, mul, _mm256_mul_ps);
    op!(F8, Div, div, _mm256_div_ps);
    op!(F8, BitAnd, bitand, _mm256_and_ps);
}

#[cfg(not(target_arch = "x86_64"))]
mod simd {
    use std::ops::{Add, BitAnd, Div, Mul, Sub};

    use glam::Vec3;

    use super::Wide;

    /// Four f32 lanes as a plain array (the compiler vectorises it where it can).
    #[derive(Clone, Copy, Debug)]
    pub struct F4([f32; 4]);

    const TRUE: f32 = f32::from_bits(u32::MAX);

    impl Wide for F4 {
        const LANES: usize = 4;
        const ZERO: F4 = F4([0.0; 4]);

        #[inline(always)]
        fn splat(v: f32) -> F4 {
            F4([v; 4])
        }
        #[inline(always)]
        fn load(s: &[f32]) -> F4 {
            F4([s[0], s[1], s[2], s[3]])
        }
        #[inline(always)]
        fn store(self, out: &mut [f32]) {
            out[..4].copy_from_slice(&self.0);
        }
        #[inline(always)]
        fn sqrt(self) -> F4 {
            F4(self.0.map(f32::sqrt))
        }
        #[inline(always)]
        fn gt(self, other: F4) -> F4 {
            F4(std::array::from_fn(|l| if self.0[l] > other.0[l] { TRUE } else { 0.0 }))
        }
        #[inline(always)]
        fn finite(self) -> F4 {
            F4(self.0.map(|v| if v.is_finite() { TRUE } else { 0.0 }))
        }
        #[inline(always)]
        fn to_bits(self) -> u32 {
            (0..4).map(|l| ((self.0[l].to_bits() != 0) as u32) << l).sum()
        }
        #[inline(always)]
        unsafe fn gather_xyz(x: &[Vec3], index: &[u32]) -> [F4; 3] {
            let p: [Vec3; 4] = std::array::from_fn(|l| unsafe { *x.get_unchecked(index[l] as usize) });
            [F4(p.map(|p| p.x)), F4(p.map(|p| p.y)), F4(p.map(|p| p.z))]
        }
        #[inline(always)]
        fn normalising_power_of_two(a: F4, b: F4, c: F4) -> F4 {
            F4(std::array::from_fn(|l| {
                crate::pyramid::project::normalising_power_of_two(Vec3::new(a.0[l], b.0[l], c.0[l]))
            }))
        }
        #[inline(always)]
        fn load_points(p: &[Vec3]) -> [F4; 3] {
            let p = &p[..4];
            [F4(std::array::from_fn(|l| p[l].x)), F4(std::array::from_fn(|l| p[l].y)), F4(std::array::from_fn(|l| p[l].z))]
        }
        #[inline(always)]
        fn store_points([x, y, z]: [F4; 3], p: &mut [Vec3]) {
            for (l, p) in p[..4].iter_mut().enumerate() {
                *p = Vec3::new(x.0[l], y.0[l], z.0[l]);
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
