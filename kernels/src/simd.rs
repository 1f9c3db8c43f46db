//! Minimal vector types for the kernels: a value type with lane-wise +, -, *, load and store.
//!
//! `f64` and `f32` themselves are one-lane vectors (scalar remainder loops, non-AVX fallback);
//! [`F64x4`] and [`F32x8`] wrap AVX registers and are only used inside functions compiled with
//! `#[target_feature(enable = "avx2,fma")]` after run-time detection. Lane-wise IEEE add, sub, mul and
//! fused multiply-add give the same bits as the scalar operations (`mul_add` for the fused ones), so a
//! cell's result never depends on its lane.

use crate::real::Real;
use std::ops::{Add, Mul, Sub};

/// A SIMD vector of `LANES` values of `S`.
pub trait Vector: Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> {
    /// Element type.
    type S: Real;
    /// Number of lanes.
    const LANES: usize;
    /// All lanes set to `s`.
    fn splat(s: Self::S) -> Self;
    /// Unaligned load of `LANES` consecutive values.
    ///
    /// # Safety
    /// `p .. p + LANES` must be readable.
    unsafe fn load(p: *const Self::S) -> Self;
    /// Unaligned store of `LANES` consecutive values.
    ///
    /// # Safety
    /// `p .. p + LANES` must be writable.
    unsafe fn store(self, p: *mut Self::S);
    /// Load for a step whose first `n` lanes (`n < LANES`) are used: the other lanes hold whatever
    /// follows in memory.
    ///
    /// # Safety
    /// `p .. p + LANES` must be readable.
    unsafe fn load_first(p: *const Self::S, n: usize) -> Self;
    /// Store of the first `n` lanes (`n < LANES`) to `p ..`: the values past them are read and written
    /// back unchanged (a blend, which AVX2 does faster than a masked store on AMD cores).
    ///
    /// # Safety
    /// `p .. p + LANES` must be readable and writable, and no other thread may access them meanwhile.
    unsafe fn store_first(self, p: *mut Self::S, n: usize);
    /// The first `n` lanes (`n < LANES`) kept, the others set to zero.
    fn keep_first(self, n: usize) -> Self;
    /// `self * a + b`, fused (one rounding) when `FMA`, else a multiply and an add.
    fn madd<const FMA: bool>(self, a: Self, b: Self) -> Self;
    /// `b - self * a`, fused (one rounding) when `FMA`, else a multiply and a subtract.
    fn nmadd<const FMA: bool>(self, a: Self, b: Self) -> Self;
    /// Lane-wise maximum (which of the two is returned for NaN is unspecified).
    fn max(self, o: Self) -> Self;
    /// Largest lane, widened to f64.
    fn hmax(self) -> f64;
    /// Whether any lane is non-zero (NaN counts as non-zero).
    fn any_nonzero(self) -> bool;
}

macro_rules! scalar_vector {
    ($t:ty) => {
        impl Vector for $t {
            type S = $t;
            const LANES: usize = 1;
            #[inline(always)]
            fn splat(s: $t) -> Self {
                s
            }
            #[inline(always)]
            unsafe fn load(p: *const $t) -> Self {
                *p
            }
            #[inline(always)]
            unsafe fn store(self, p: *mut $t) {
                *p = self
            }
            #[inline(always)]
            unsafe fn load_first(_p: *const $t, _n: usize) -> Self {
                // n < LANES = 1: no lane is loaded.
                0.0
            }
            #[inline(always)]
            unsafe fn store_first(self, _p: *mut $t, _n: usize) {}
            #[inline(always)]
            fn keep_first(self, _n: usize) -> Self {
                0.0
            }
            #[inline(always)]
            fn madd<const FMA: bool>(self, a: Self, b: Self) -> Self {
                if FMA {
                    self.mul_add(a, b)
                } else {
                    self * a + b
                }
            }
            #[inline(always)]
            fn nmadd<const FMA: bool>(self, a: Self, b: Self) -> Self {
                if FMA {
                    (-self).mul_add(a, b)
                } else {
                    b - self * a
                }
            }
            #[inline(always)]
            fn max(self, o: Self) -> Self {
                if o > self {
                    o
                } else {
                    self
                }
            }
            #[inline(always)]
            fn hmax(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn any_nonzero(self) -> bool {
                self != 0.0
            }
        }
    };
}
scalar_vector!(f64);
scalar_vector!(f32);

#[cfg(target_arch = "x86_64")]
pub use avx::{F32x8, F64x4};

#[cfg(target_arch = "x86_64")]
mod avx {
    use super::Vector;
    use std::arch::x86_64::*;
    use std::ops::{Add, Mul, Sub};

    /// Four all-ones lanes then four zero lanes: the four lanes from index 4 − n hold n ones first.
    static MASK64: [i64; 8] = [-1, -1, -1, -1, 0, 0, 0, 0];
    /// The same for eight f32 lanes.
    static MASK32: [i32; 16] = [-1, -1, -1, -1, -1, -1, -1, -1, 0, 0, 0, 0, 0, 0, 0, 0];

    /// Four f64 lanes in an AVX register. Only construct inside AVX2-enabled code.
    #[derive(Clone, Copy)]
    pub struct F64x4(__m256d);
    /// Eight f32 lanes in an AVX register. Only construct inside AVX2-enabled code.
    #[derive(Clone, Copy)]
    pub struct F32x8(__m256);

    macro_rules! avx_vector {
        ($v:ident, $t:ty, $n:expr, $reg:ty, $add:ident, $sub:ident, $mul:ident, $max:ident, $set1:ident,
         $loadu:ident, $storeu:ident, $cmpneq:ident, $movemask:ident, $zero:ident, $fmadd:ident,
         $fnmadd:ident, $mask_table:ident, $blendv:ident, $and:ident,
         $from_int:ident) => {
            impl $v {
                /// The mask with the high bit of the first `n` lanes set.
                #[inline(always)]
                unsafe fn mask(n: usize) -> __m256i {
                    debug_assert!(n < $n);
                    _mm256_loadu_si256($mask_table.as_ptr().add($n - n) as *const __m256i)
                }
            }
            impl Add for $v {
                type Output = $v;
                #[inline(always)]
                fn add(self, o: $v) -> $v {
                    // SAFETY: values of this type only exist inside AVX-enabled code.
                    unsafe { $v($add(self.0, o.0)) }
                }
            }
            impl Sub for $v {
                type Output = $v;
                #[inline(always)]
                fn sub(self, o: $v) -> $v {
                    // SAFETY: as above.
                    unsafe { $v($sub(self.0, o.0)) }
                }
            }
            impl Mul for $v {
                type Output = $v;
                #[inline(always)]
                fn mul(self, o: $v) -> $v {
                    // SAFETY: as above.
                    unsafe { $v($mul(self.0, o.0)) }
                }
            }
            impl Vector for $v {
                type S = $t;
                const LANES: usize = $n;
                #[inline(always)]
                fn splat(s: $t) -> Self {
                    // SAFETY: as above.
                    unsafe { $v($set1(s)) }
                }
                #[inline(always)]
                unsafe fn load(p: *const $t) -> Self {
                    $v($loadu(p))
                }
                #[inline(always)]
                unsafe fn store(self, p: *mut $t) {
                    $storeu(p, self.0)
                }
                #[inline(always)]
                unsafe fn load_first(p: *const $t, _n: usize) -> Self {
                    $v($loadu(p))
                }
                #[inline(always)]
                unsafe fn store_first(self, p: *mut $t, n: usize) {
                    let old = $loadu(p);
                    $storeu(p, $blendv(old, self.0, $from_int(Self::mask(n))))
                }
                #[inline(always)]
                fn keep_first(self, n: usize) -> Self {
                    // SAFETY: as above.
                    unsafe { $v($and(self.0, $from_int(Self::mask(n)))) }
                }
                #[inline(always)]
                fn madd<const FMA: bool>(self, a: Self, b: Self) -> Self {
                    if FMA {
                        // SAFETY: FMA kernels are only entered after run-time detection of FMA.
                        unsafe { $v($fmadd(self.0, a.0, b.0)) }
                    } else {
                        self * a + b
                    }
                }
                #[inline(always)]
                fn nmadd<const FMA: bool>(self, a: Self, b: Self) -> Self {
                    if FMA {
                        // SAFETY: as above.
                        unsafe { $v($fnmadd(self.0, a.0, b.0)) }
                    } else {
                        b - self * a
                    }
                }
                #[inline(always)]
                fn max(self, o: Self) -> Self {
                    // SAFETY: as above.
                    unsafe { $v($max(self.0, o.0)) }
                }
                #[inline(always)]
                fn hmax(self) -> f64 {
                    let mut a = [0.0 as $t; $n];
                    // SAFETY: `a` holds exactly $n values.
                    unsafe { $storeu(a.as_mut_ptr(), self.0) };
                    a.iter().fold(f64::MIN, |m, &x| m.max(x as f64))
                }
                #[inline(always)]
                fn any_nonzero(self) -> bool {
                    // SAFETY: as above. NEQ_UQ is true for NaN lanes.
                    unsafe { $movemask($cmpneq::<_CMP_NEQ_UQ>(self.0, $zero())) != 0 }
                }
            }
        };
    }
    avx_vector!(
        F64x4,
        f64,
        4,
        __m256d,
        _mm256_add_pd,
        _mm256_sub_pd,
        _mm256_mul_pd,
        _mm256_max_pd,
        _mm256_set1_pd,
        _mm256_loadu_pd,
        _mm256_storeu_pd,
        _mm256_cmp_pd,
        _mm256_movemask_pd,
        _mm256_setzero_pd,
        _mm256_fmadd_pd,
        _mm256_fnmadd_pd,
        MASK64,
        _mm256_blendv_pd,
        _mm256_and_pd,
        _mm256_castsi256_pd
    );
    avx_vector!(
        F32x8,
        f32,
        8,
        __m256,
        _mm256_add_ps,
        _mm256_sub_ps,
        _mm256_mul_ps,
        _mm256_max_ps,
        _mm256_set1_ps,
        _mm256_loadu_ps,
        _mm256_storeu_ps,
        _mm256_cmp_ps,
        _mm256_movemask_ps,
        _mm256_setzero_ps,
        _mm256_fmadd_ps,
        _mm256_fnmadd_ps,
        MASK32,
        _mm256_blendv_ps,
        _mm256_and_ps,
        _mm256_castsi256_ps
    );
}
