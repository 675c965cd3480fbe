//! Which SIMD instruction set the kernels run with.
//!
//! faer's GEMMs (through its `nightly` feature: `pulp/x86-v4`, `gemm/x86-v4`) and terl's
//! small-batch inference kernel both choose at run time: AVX-512 (x86-64-v4) where the processor
//! has it, else AVX2 + FMA (x86-64-v3), else portable code. One binary serves every x86-64
//! machine; [`InstructionSet::detect`] says which path this one takes, and benchmarks report it.

use std::fmt;

/// A SIMD level of the kernels, best first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum InstructionSet {
    /// x86-64-v4: 512-bit vectors, 16 `f32` lanes (avx512f/bw/cd/dq/vl).
    Avx512,
    /// x86-64-v3: 256-bit vectors, 8 `f32` lanes, fused multiply-add.
    Avx2,
    /// No vector kernel of terl's own; faer's portable (or non-x86 SIMD) code.
    Portable,
}

impl InstructionSet {
    /// Every level, best first.
    pub const ALL: [InstructionSet; 3] = [Self::Avx512, Self::Avx2, Self::Portable];

    /// The best level this processor supports (what faer's GEMMs use too).
    pub fn detect() -> Self {
        Self::ALL
            .into_iter()
            .find(|isa| isa.is_available())
            .unwrap_or(Self::Portable)
    }

    /// Whether this processor can run kernels of this level.
    pub fn is_available(self) -> bool {
        match self {
            #[cfg(target_arch = "x86_64")]
            Self::Avx512 => faer::traits::pulp::x86::V4::try_new().is_some(),
            #[cfg(target_arch = "x86_64")]
            Self::Avx2 => faer::traits::pulp::x86::V3::try_new().is_some(),
            #[cfg(not(target_arch = "x86_64"))]
            Self::Avx512 | Self::Avx2 => false,
            Self::Portable => true,
        }
    }

    /// `f32` lanes of one vector (1 for portable code).
    pub fn f32_lanes(self) -> usize {
        match self {
            Self::Avx512 => 16,
            Self::Avx2 => 8,
            Self::Portable => 1,
        }
    }

    /// `"avx512"`, `"avx2"` or `"portable"`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Avx512 => "avx512",
            Self::Avx2 => "avx2",
            Self::Portable => "portable",
        }
    }
}

/// Clears the upper halves of this thread's vector registers (`vzeroupper`) when the processor
/// has AVX; a no-op otherwise.
///
/// faer's x86 GEMM micro-kernels are generated assembly that returns with the upper register
/// state dirty. Code compiled for baseline x86-64 (SSE encoding: all of terl's scalar loops)
/// and glibc's libm (VEX encoding) then pay a state transition on every switch between the
/// two: measured here, `f32::exp` took 230 ns instead of 4.7 ns after an AVX-512 GEMM, which
/// made the tanh-Gaussian head of a SAC update at 2×256/256 a sixth of the update. Call it after
/// a GEMM and before scalar work on the same thread ([`crate::Mlp`] does after each of its
/// GEMMs). Costs a few cycles.
#[inline]
pub fn clear_upper_state() {
    #[cfg(target_arch = "x86_64")]
    if let Some(simd) = faer::traits::pulp::x86::V3::try_new() {
        simd.avx._mm256_zeroupper();
    }
}

/// An element-wise loop to run through [`vectorized`]; `run` must be `#[inline(always)]`.
pub(crate) trait Kernel {
    type Output;
    fn run(self) -> Self::Output;
}

struct Dispatch<K>(K);

impl<K: Kernel> faer::traits::pulp::WithSimd for Dispatch<K> {
    type Output = K::Output;

    #[inline(always)]
    fn with_simd<S: faer::traits::pulp::Simd>(self, _simd: S) -> K::Output {
        self.0.run()
    }
}

/// Runs `kernel` compiled for the best instruction set of this processor (pulp's run-time
/// dispatch), so its loops (bias + activation, Adam, Polyak averaging) are auto-vectorised with
/// 512- or 256-bit registers instead of baseline SSE, and return with the upper register state
/// clean. The chain `with_simd` → [`Kernel::run`] is `#[inline(always)]` end to end, so the
/// loops are compiled inside pulp's target-feature function (a closure would not reliably be
/// inlined there and would run as baseline code: measured). Floating-point results are
/// bit-identical to the scalar loops (Rust never reassociates or contracts into FMA).
#[inline(always)]
pub(crate) fn vectorized<K: Kernel>(kernel: K) -> K::Output {
    faer::traits::pulp::Arch::new().dispatch(Dispatch(kernel))
}

impl fmt::Display for InstructionSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detection_agrees_with_the_standard_library() {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            let avx512 = has!("avx512f")
                && has!("avx512bw")
                && has!("avx512cd")
                && has!("avx512dq")
                && has!("avx512vl");
            assert_eq!(InstructionSet::Avx512.is_available(), avx512);
            let avx2 = has!("avx2") && has!("fma");
            assert_eq!(InstructionSet::Avx2.is_available(), avx2);
            if avx512 {
                assert_eq!(InstructionSet::detect(), InstructionSet::Avx512);
            }
        }
        assert!(InstructionSet::Portable.is_available());
    }
}
