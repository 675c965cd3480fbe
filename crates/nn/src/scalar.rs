//! The element type of networks: `f32` for training and inference, `f64` for gradient checks,
//! and the element types of stored tensors ([`Dtype`]). `tensors` builds on this module, not the
//! other way round.

use faer::traits::RealField;
use std::fmt::{Debug, Display};

/// Element types used by this project's tensors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dtype {
    /// 32-bit IEEE 754 float (safetensors `F32`).
    F32,
    /// 64-bit IEEE 754 float (safetensors `F64`).
    F64,
    /// 64-bit signed integer (safetensors `I64`), used for step counters.
    I64,
}

impl Dtype {
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            Dtype::F32 => 4,
            Dtype::F64 | Dtype::I64 => 8,
        }
    }
}

impl std::fmt::Display for Dtype {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = match self {
            Dtype::F32 => "F32",
            Dtype::F64 => "F64",
            Dtype::I64 => "I64",
        };
        f.write_str(s)
    }
}

/// A real floating-point type faer can multiply, with the few math functions the layers need.
pub trait Float:
    RealField
    + Copy
    + Default
    + Send
    + Sync
    + Debug
    + Display
    + PartialOrd
    + std::ops::Neg<Output = Self>
    + 'static
{
    /// The safetensors dtype of this type.
    const DTYPE: Dtype;
    /// Converts from `f64` (rounding for `f32`).
    fn of(x: f64) -> Self;
    /// Converts to `f64`.
    fn f64(self) -> f64;
    /// Converts from `f32`.
    fn of_f32(x: f32) -> Self;
    /// Converts to `f32` (rounding for `f64`).
    fn f32(self) -> f32;
    /// `e^self`.
    fn exp(self) -> Self;
    /// Natural logarithm.
    fn ln(self) -> Self;
    /// Hyperbolic tangent.
    fn tanh(self) -> Self;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// The larger of `self` and `other` (the other one if either is NaN, like `f32::max`).
    fn max(self, other: Self) -> Self;
    /// The smaller of `self` and `other` (the other one if either is NaN, like `f32::min`).
    fn min(self, other: Self) -> Self;
    /// Neither infinite nor NaN.
    fn is_finite(self) -> bool;
    /// `ln(1 + e^x)` without overflow.
    fn softplus(self) -> Self {
        let zero = Self::of(0.0);
        let m = if self > zero { self } else { zero };
        m + ((-m).exp() + (self - m).exp()).ln()
    }
    /// Appends the little-endian bytes of `self`.
    fn write_le(self, out: &mut Vec<u8>);
    /// Reads one value from little-endian bytes (`bytes.len()` must be the type's size).
    fn read_le(bytes: &[u8]) -> Self;
}

macro_rules! impl_float {
    ($t:ty, $dtype:expr) => {
        impl Float for $t {
            const DTYPE: Dtype = $dtype;
            #[inline(always)]
            fn of(x: f64) -> Self {
                x as $t
            }
            #[inline(always)]
            fn f64(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn of_f32(x: f32) -> Self {
                x as $t
            }
            #[inline(always)]
            fn f32(self) -> f32 {
                self as f32
            }
            #[inline(always)]
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            #[inline(always)]
            fn ln(self) -> Self {
                <$t>::ln(self)
            }
            #[inline(always)]
            fn tanh(self) -> Self {
                <$t>::tanh(self)
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn max(self, other: Self) -> Self {
                <$t>::max(self, other)
            }
            #[inline(always)]
            fn min(self, other: Self) -> Self {
                <$t>::min(self, other)
            }
            #[inline(always)]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
            fn write_le(self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
            fn read_le(bytes: &[u8]) -> Self {
                let mut b = [0u8; std::mem::size_of::<$t>()];
                b.copy_from_slice(bytes);
                <$t>::from_le_bytes(b)
            }
        }
    };
}

impl_float!(f32, Dtype::F32);
impl_float!(f64, Dtype::F64);
