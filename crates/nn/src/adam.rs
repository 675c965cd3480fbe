//! Adam over a flat parameter vector, numerically the same as `torch.optim.Adam` (no weight decay).

use crate::error::NnError;
use crate::scalar::Float;
use crate::tensors::{Tensor, TensorFile};

/// Adam hyper-parameters (PyTorch defaults except the learning rate, which callers choose).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamConfig {
    /// Learning rate (PyTorch's `lr`).
    pub lr: f64,
    /// Decay rate of the first-moment (mean) estimate (PyTorch's `betas[0]`, default 0.9).
    pub beta1: f64,
    /// Decay rate of the second-moment (uncentred variance) estimate (PyTorch's `betas[1]`,
    /// default 0.999).
    pub beta2: f64,
    /// Added to the bias-corrected `sqrt(v_hat)` in the denominator for stability (PyTorch's
    /// `eps`, default 1e-8).
    pub eps: f64,
}

impl AdamConfig {
    /// PyTorch's defaults with the given learning rate.
    pub fn with_lr(lr: f64) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

/// Global-norm gradient clipping (`optax.clip_by_global_norm`, PyTorch's
/// `clip_grad_norm_`): with `n = sqrt(Σ_k Σ_i g_ki²)` over all `groups`, every gradient is
/// scaled by `max_norm / n` when `n > max_norm` and left alone otherwise. Returns `n` (the norm
/// before clipping, accumulated in f64). A non-finite norm leaves the gradients untouched (the
/// caller's finiteness check rejects them). `max_norm` must be positive.
pub fn clip_global_norm<T: Float>(groups: &mut [&mut [T]], max_norm: f64) -> f64 {
    let norm = groups
        .iter()
        .flat_map(|g| g.iter())
        .map(|v| {
            let v = v.f64();
            v * v
        })
        .sum::<f64>()
        .sqrt();
    if norm.is_finite() && norm > max_norm {
        let scale = T::of(max_norm / norm);
        for g in groups.iter_mut() {
            g.iter_mut().for_each(|v| *v *= scale);
        }
    }
    norm
}

/// The constants of one Adam step.
#[derive(Clone, Copy)]
struct AdamStep<T> {
    b1: T,
    b2: T,
    one_b1: T,
    one_b2: T,
    step_size: T,
    bias2_sqrt: T,
    eps: T,
}

/// One Adam step's loop over all parameters.
struct AdamKernel<'a, T> {
    k: AdamStep<T>,
    params: &'a mut [T],
    grads: &'a [T],
    m: &'a mut [T],
    v: &'a mut [T],
}

impl<T: Float> crate::simd::Kernel for AdamKernel<'_, T> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        let Self {
            k,
            params,
            grads,
            m,
            v,
        } = self;
        let AdamStep {
            b1,
            b2,
            one_b1,
            one_b2,
            step_size,
            bias2_sqrt,
            eps,
        } = k;
        for (((p, &g), m), v) in params.iter_mut().zip(grads).zip(m).zip(v) {
            *m = b1 * *m + one_b1 * g;
            *v = b2 * *v + one_b2 * g * g;
            let denom = (*v).sqrt() / bias2_sqrt + eps;
            *p -= step_size * (*m / denom);
        }
    }
}

/// Adam state (first and second moments, step count) for one flat parameter vector.
#[derive(Clone, Debug)]
pub struct Adam<T> {
    /// Hyper-parameters used by every [`Adam::step`]; may be changed between steps.
    pub config: AdamConfig,
    m: Vec<T>,
    v: Vec<T>,
    step: u64,
}

impl<T: Float> Adam<T> {
    /// Fresh state for `len` parameters.
    pub fn new(len: usize, config: AdamConfig) -> Self {
        Self {
            config,
            m: vec![T::of(0.0); len],
            v: vec![T::of(0.0); len],
            step: 0,
        }
    }

    /// Number of steps taken so far.
    pub fn steps(&self) -> u64 {
        self.step
    }

    /// One Adam step: `params -= lr * m_hat / (sqrt(v_hat) + eps)`, in PyTorch's exact order of
    /// operations so the same inputs give the same rounding.
    pub fn step(&mut self, params: &mut [T], grads: &[T]) {
        assert_eq!(params.len(), self.m.len(), "Adam: parameter count changed");
        assert_eq!(
            grads.len(),
            self.m.len(),
            "Adam: gradient count differs from parameters"
        );
        self.step += 1;
        let c = &self.config;
        let t = self.step as i32;
        let bias1 = 1.0 - c.beta1.powi(t);
        let bias2 = 1.0 - c.beta2.powi(t);
        let step_size = T::of(c.lr / bias1);
        let bias2_sqrt = T::of(bias2.sqrt());
        let (b1, b2) = (T::of(c.beta1), T::of(c.beta2));
        let (one_b1, one_b2) = (T::of(1.0 - c.beta1), T::of(1.0 - c.beta2));
        let eps = T::of(c.eps);
        let (m, v) = (&mut self.m[..], &mut self.v[..]);
        let k = AdamStep {
            b1,
            b2,
            one_b1,
            one_b2,
            step_size,
            bias2_sqrt,
            eps,
        };
        crate::simd::vectorized(AdamKernel {
            k,
            params,
            grads,
            m,
            v,
        });
    }

    /// The optimiser state as tensors `{prefix}.m`, `{prefix}.v` (flat) and `{prefix}.step`.
    pub fn export(&self, prefix: &str, out: &mut Vec<Tensor>) {
        out.push(Tensor::from_values(
            format!("{prefix}.m"),
            vec![self.m.len()],
            &self.m,
        ));
        out.push(Tensor::from_values(
            format!("{prefix}.v"),
            vec![self.v.len()],
            &self.v,
        ));
        out.push(Tensor::from_i64(
            format!("{prefix}.step"),
            vec![1],
            &[self.step as i64],
        ));
    }

    /// Restores state written by [`Adam::export`], checking shapes and dtypes.
    pub fn import(&mut self, prefix: &str, file: &TensorFile) -> Result<(), NnError> {
        let n = self.m.len();
        let m = file.values::<T>(&format!("{prefix}.m"), &[n])?;
        let v = file.values::<T>(&format!("{prefix}.v"), &[n])?;
        let step = file.i64_values(&format!("{prefix}.step"), &[1])?[0];
        if step < 0 {
            return Err(NnError::InvalidValue(format!(
                "{prefix}.step is negative ({step})"
            )));
        }
        self.m = m;
        self.v = v;
        self.step = step as u64;
        Ok(())
    }
}
