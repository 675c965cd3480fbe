//! Dense neural networks on faer, written for reinforcement-learning updates.
//!
//! Why this crate exists: SAC spends its time in a handful of small-to-medium GEMMs per update.
//! A general autograd framework pays per-operation overhead that dominates at these sizes, so the
//! networks here are plain multilayer perceptrons with hand-written backward passes over explicit
//! caches. Every matrix is batch-major and row-major (PyTorch's layout), so one layer over one
//! batch is one GEMM into a preallocated buffer, and bias + activation are fused into one pass.
//!
//! What it owns:
//! - [`Mlp`]: parameters in one flat vector (per layer `weight [out, in]` then `bias [out]`),
//!   forward/backward over an [`MlpCache`], PyTorch `nn.Linear` initialisation;
//! - [`Adam`]: PyTorch-equivalent Adam with bias correction over a flat parameter vector;
//! - [`gaussian`]: the tanh-squashed Gaussian policy head (reparameterised sample, log-prob with
//!   the tanh correction, backward);
//! - [`tensors`]: safetensors (de)serialisation of named tensors with shape/dtype validation;
//! - [`gradcheck`]: the error measure of the gradient checks against finite differences.
//!
//! Everything is generic over [`Float`] (`f32` for training, `f64` for gradient checks).

#![warn(missing_docs)]

pub mod adam;
pub mod error;
pub mod gaussian;
pub mod gradcheck;
pub mod mlp;
pub mod scalar;
pub mod simd;
pub mod tensors;

pub use adam::{clip_global_norm, Adam, AdamConfig};
pub use error::NnError;
pub use mlp::{Activation, Init, InputGrad, Mlp, MlpCache, MlpSpec};
pub use scalar::Float;
pub use simd::{clear_upper_state, InstructionSet};
pub use tensors::{Dtype, Tensor, TensorFile};

/// faer's parallelism setting for a thread count: sequential for 0 or 1, rayon otherwise.
///
/// With more than one thread the caller must run inside a rayon pool that has at least that many
/// threads (the global pool does on a machine with that many cores).
pub fn par_for_threads(threads: usize) -> faer::Par {
    if threads <= 1 {
        faer::Par::Seq
    } else {
        faer::Par::rayon(threads)
    }
}
