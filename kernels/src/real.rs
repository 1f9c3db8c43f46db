//! The floating-point storage types a block can use (`fluid.precision`): f64 (default) and f32.

use std::fmt::Debug;
use std::ops::{Add, AddAssign, Div, Mul, Neg, Sub};

/// A storage and compute precision for PDFs. Implemented for `f64` and `f32` only.
///
/// Kernels are written once over `Real` and lane arrays `[T; L]`; every operation is an IEEE operation
/// without contraction, so a vector lane and the scalar remainder loop produce identical bits.
pub trait Real:
    Copy
    + Send
    + Sync
    + Default
    + Debug
    + PartialOrd
    + 'static
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
{
    /// Additive identity.
    const ZERO: Self;
    /// Multiplicative identity.
    const ONE: Self;
    /// Elements per 32-byte (AVX) vector: 4 for f64, 8 for f32.
    const LANES: usize;
    /// Name used in summaries and tables ("f64" or "f32").
    const NAME: &'static str;
    /// Size in bytes.
    const BYTES: usize;
    /// Rounds an f64 to this type (round-to-nearest).
    fn from_f64(v: f64) -> Self;
    /// Widens to f64 (exact).
    fn to_f64(self) -> f64;
    /// The raw IEEE bits, zero-extended to 64 bits (for checksums).
    fn bits(self) -> u64;
    /// The value of raw IEEE bits (the low [`Real::BYTES`] bytes of `bits`): the inverse of
    /// [`Real::bits`].
    fn from_bits(bits: u64) -> Self;
    /// `max` that propagates the larger of two ordered values (NaN handled by the caller).
    fn max_of(self, o: Self) -> Self;
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const LANES: usize = 4;
    const NAME: &'static str = "f64";
    const BYTES: usize = 8;
    #[inline(always)]
    fn from_f64(v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn bits(self) -> u64 {
        self.to_bits()
    }
    #[inline(always)]
    fn from_bits(bits: u64) -> Self {
        f64::from_bits(bits)
    }
    #[inline(always)]
    fn max_of(self, o: Self) -> Self {
        if o > self {
            o
        } else {
            self
        }
    }
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const LANES: usize = 8;
    const NAME: &'static str = "f32";
    const BYTES: usize = 4;
    #[inline(always)]
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn bits(self) -> u64 {
        self.to_bits() as u64
    }
    #[inline(always)]
    fn from_bits(bits: u64) -> Self {
        f32::from_bits(bits as u32)
    }
    #[inline(always)]
    fn max_of(self, o: Self) -> Self {
        if o > self {
            o
        } else {
            self
        }
    }
}
