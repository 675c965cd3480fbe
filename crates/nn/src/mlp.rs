//! Multilayer perceptrons with hand-written, cache-based forward and backward passes.
//!
//! Layout: a batch is a row-major `rows × features` matrix (PyTorch's layout); layer `l` has a
//! row-major weight `[out, in]` followed by its bias `[out]` in one flat parameter vector, so the
//! optimiser, Polyak averaging and serialisation are single loops over contiguous memory. A layer
//! is one faer GEMM into a preallocated buffer followed by one fused bias + activation pass;
//! backward is one fused activation-derivative + bias-gradient pass and two GEMMs.

use crate::error::NnError;
use crate::scalar::Float;
use crate::simd::{clear_upper_state, Kernel};
use crate::tensors::{Tensor, TensorFile};
use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use rand::Rng;
use std::ops::Range;

/// Element-wise non-linearity after a layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Activation {
    /// `y = z` (no non-linearity).
    Identity,
    /// `y = max(0, z)`.
    Relu,
    /// `y = tanh(z)`.
    Tanh,
    /// `ln(1 + e^z)`: a smooth, non-negative output (for quantities that are ≥ 0 by definition,
    /// like the planner's step count F). Its derivative is written through the output,
    /// `σ(z) = 1 − e^{−y}`.
    Softplus,
}

/// Shape of an MLP: `input → hidden[0] → … → output`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MlpSpec {
    /// Width of the network input (features per row).
    pub input: usize,
    /// Widths of the hidden layers, first to last (may be empty).
    pub hidden: Vec<usize>,
    /// Width of the network output.
    pub output: usize,
    /// Activation after every hidden layer.
    pub hidden_activation: Activation,
    /// Activation after the output layer.
    pub output_activation: Activation,
}

impl MlpSpec {
    /// Number of parameters of a network of this shape (every layer's `weight [out, in]` and
    /// `bias [out]`, the length of [`Mlp::params`]), or `None` when it overflows `usize` (sizes
    /// read from an untrusted file).
    pub fn checked_num_params(&self) -> Option<usize> {
        let mut sizes = Vec::with_capacity(self.hidden.len() + 2);
        sizes.push(self.input);
        sizes.extend_from_slice(&self.hidden);
        sizes.push(self.output);
        sizes.windows(2).try_fold(0usize, |acc, w| {
            acc.checked_add(w[0].checked_mul(w[1])?.checked_add(w[1])?)
        })
    }
}

/// Which gradient w.r.t. the network input a backward pass computes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum InputGrad {
    /// None (the first layer's input gradient GEMM is skipped).
    None,
    /// All input columns.
    All,
    /// Only these input columns (for example the action part of a critic's input).
    Cols(Range<usize>),
}

/// How [`Mlp::new_with`] draws the initial parameters. Every draw is uniform in `±bound`
/// (a bound of 0 gives exact zeros), with `fan_in` the layer's input width.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Init {
    /// PyTorch's `nn.Linear` default: weights and biases in `±1/sqrt(fan_in)`.
    TorchDefault,
    /// He-uniform hidden layers (weights in `±sqrt(6/fan_in)`, JAX's `he_uniform`, biases
    /// zero) and a small output layer (weights and biases in `±head_bound`), as the Meta-World
    /// reference implementation (`metaworld_algorithms/rl/networks.py`: policy head
    /// `uniform(1e-3)`, Q head `uniform(3e-3)`).
    HeUniform {
        /// Bound of the output layer's weights and biases.
        head_bound: f64,
    },
}

impl Init {
    /// `(weight bound, bias bound)` of a layer with `fan_in` inputs.
    fn bounds(self, fan_in: usize, output_layer: bool) -> (f64, f64) {
        match self {
            Self::TorchDefault => {
                let b = 1.0 / (fan_in as f64).sqrt();
                (b, b)
            }
            Self::HeUniform { head_bound } if output_layer => (head_bound, head_bound),
            Self::HeUniform { .. } => ((6.0 / fan_in as f64).sqrt(), 0.0),
        }
    }
}

/// A dense MLP; parameters in one flat vector (see the module docs for the layout).
#[derive(Clone, Debug)]
pub struct Mlp<T> {
    sizes: Vec<usize>,
    activations: Vec<Activation>,
    offsets: Vec<usize>,
    /// All parameters: per layer `weight [out, in]` row-major, then `bias [out]`.
    pub params: Vec<T>,
}

/// Activations and gradients of one MLP for up to `capacity` rows, allocated once.
#[derive(Clone, Debug)]
pub struct MlpCache<T> {
    capacity: usize,
    sizes: Vec<usize>,
    input: Vec<T>,
    outs: Vec<Vec<T>>,
    grads: Vec<Vec<T>>,
    grad_input: Vec<T>,
}

impl<T: Float> Mlp<T> {
    /// A network initialised like PyTorch's `nn.Linear`: weights and biases uniform in
    /// `±1/sqrt(fan_in)` (what `kaiming_uniform_(a=sqrt(5))` reduces to). Same as
    /// [`Mlp::new_with`]`(spec, Init::TorchDefault, rng)`.
    pub fn new(spec: &MlpSpec, rng: &mut impl Rng) -> Self {
        Self::new_with(spec, Init::TorchDefault, rng)
    }

    /// A network initialised by `init` (see [`Init`]); parameters are drawn layer by layer,
    /// weights then bias, from `rng`.
    pub fn new_with(spec: &MlpSpec, init: Init, rng: &mut impl Rng) -> Self {
        let mut sizes = vec![spec.input];
        sizes.extend_from_slice(&spec.hidden);
        sizes.push(spec.output);
        assert!(
            sizes.iter().all(|&s| s > 0),
            "MLP layer sizes must be positive: {sizes:?}"
        );
        let layers = sizes.len() - 1;
        let mut activations = vec![spec.hidden_activation; layers];
        activations[layers - 1] = spec.output_activation;
        let mut offsets = Vec::with_capacity(layers);
        let mut total = 0;
        for l in 0..layers {
            offsets.push(total);
            total += sizes[l + 1] * sizes[l] + sizes[l + 1];
        }
        let mut params = Vec::with_capacity(total);
        for l in 0..layers {
            let (weight_bound, bias_bound) = init.bounds(sizes[l], l + 1 == layers);
            for k in 0..(sizes[l + 1] * sizes[l] + sizes[l + 1]) {
                let bound = if k < sizes[l + 1] * sizes[l] {
                    weight_bound
                } else {
                    bias_bound
                };
                let value = if bound > 0.0 {
                    rng.gen_range(-bound..bound)
                } else {
                    0.0
                };
                params.push(T::of(value));
            }
        }
        Self {
            sizes,
            activations,
            offsets,
            params,
        }
    }

    /// Layer widths `[input, hidden…, output]`.
    pub fn sizes(&self) -> &[usize] {
        &self.sizes
    }

    /// Number of dense layers (hidden layers + output layer).
    pub fn num_layers(&self) -> usize {
        self.sizes.len() - 1
    }

    /// Width of the network input.
    pub fn input_dim(&self) -> usize {
        self.sizes[0]
    }

    /// Width of the network output.
    pub fn output_dim(&self) -> usize {
        self.sizes[self.sizes.len() - 1]
    }

    /// Total number of parameters (length of [`Mlp::params`]).
    pub fn num_params(&self) -> usize {
        self.params.len()
    }

    /// Range of layer `l`'s weight in the flat parameter vector.
    pub fn weight_range(&self, l: usize) -> Range<usize> {
        let start = self.offsets[l];
        start..start + self.sizes[l + 1] * self.sizes[l]
    }

    /// Range of layer `l`'s bias in the flat parameter vector.
    pub fn bias_range(&self, l: usize) -> Range<usize> {
        let start = self.weight_range(l).end;
        start..start + self.sizes[l + 1]
    }

    fn weight(&self, l: usize) -> MatRef<'_, T> {
        MatRef::from_row_major_slice(
            &self.params[self.weight_range(l)],
            self.sizes[l + 1],
            self.sizes[l],
        )
    }

    /// Forward pass over the first `rows` rows of `cache`'s input (written by the caller with
    /// [`MlpCache::input_mut`]); the result is [`MlpCache::output`].
    pub fn forward(&self, cache: &mut MlpCache<T>, rows: usize, par: Par) {
        self.forward_rows(cache, 0..rows, par);
    }

    /// Forward pass over the cache rows `rows` only (the others keep what they hold), so two
    /// parts of one batch can be computed at different times, e.g. while another network runs.
    /// Each row's result is the same as from [`Mlp::forward`] over all rows (rows are
    /// independent; up to the GEMM's summation order).
    ///
    /// # Panics
    /// `rows` reaches past the cache's capacity, or the cache is of another network shape.
    pub fn forward_rows(&self, cache: &mut MlpCache<T>, rows: Range<usize>, par: Par) {
        assert_eq!(
            cache.sizes, self.sizes,
            "cache was built for another network shape"
        );
        assert!(
            rows.end <= cache.capacity,
            "rows up to {} exceed cache capacity {}",
            rows.end,
            cache.capacity
        );
        if rows.is_empty() {
            return;
        }
        let n = rows.len();
        for l in 0..self.num_layers() {
            let (n_in, n_out) = (self.sizes[l], self.sizes[l + 1]);
            let (before, rest) = cache.outs.split_at_mut(l);
            let x: &[T] = if l == 0 {
                &cache.input[rows.start * n_in..rows.end * n_in]
            } else {
                &before[l - 1][rows.start * n_in..rows.end * n_in]
            };
            let y = &mut rest[0][rows.start * n_out..rows.end * n_out];
            gemm(
                MatMut::from_row_major_slice_mut(y, n, n_out),
                MatRef::from_row_major_slice(x, n, n_in),
                self.weight(l).transpose(),
                par,
            );
            bias_activation(y, &self.params[self.bias_range(l)], self.activations[l]);
        }
    }

    /// Backward pass over `rows` of the last forward pass. The caller writes the loss gradient
    /// w.r.t. the output rows into [`MlpCache::grad_output_mut`] first (it is overwritten).
    ///
    /// With `param_grads`, the gradients of all parameters from these rows are *written* (not
    /// accumulated) into it, in the flat parameter layout. `input_grad` selects which input
    /// gradient to compute into [`MlpCache::grad_input`].
    #[allow(clippy::too_many_lines)] // the backward pass of every layer in order, each GEMM pair side by side
    pub fn backward(
        &self,
        cache: &mut MlpCache<T>,
        rows: Range<usize>,
        mut param_grads: Option<&mut [T]>,
        input_grad: InputGrad,
        par: Par,
    ) {
        assert_eq!(
            cache.sizes, self.sizes,
            "cache was built for another network shape"
        );
        assert!(
            rows.end <= cache.capacity && rows.start <= rows.end,
            "bad row range {rows:?}"
        );
        if let Some(g) = param_grads.as_deref() {
            assert_eq!(
                g.len(),
                self.params.len(),
                "gradient buffer has the wrong length"
            );
        }
        let n = rows.len();
        if n == 0 {
            if let Some(g) = param_grads {
                g.fill(T::of(0.0));
            }
            return;
        }
        for l in (0..self.num_layers()).rev() {
            let (n_in, n_out) = (self.sizes[l], self.sizes[l + 1]);
            let out_rows = rows.start * n_out..rows.end * n_out;
            let in_rows = rows.start * n_in..rows.end * n_in;
            let (g_before, g_rest) = cache.grads.split_at_mut(l);
            let dz = &mut g_rest[0][out_rows.clone()];
            let y = &cache.outs[l][out_rows];
            let x: &[T] = if l == 0 {
                &cache.input[in_rows.clone()]
            } else {
                &cache.outs[l - 1][in_rows.clone()]
            };
            let weight_grad = match param_grads.as_deref_mut() {
                Some(grads) => {
                    let (gw, gb) =
                        grads[self.offsets[l]..self.bias_range(l).end].split_at_mut(n_out * n_in);
                    activation_grad_with_bias(dz, y, gb, self.activations[l]);
                    Some(gw)
                }
                None => {
                    activation_grad(dz, y, self.activations[l]);
                    None
                }
            };
            let dz = MatRef::from_row_major_slice(&*dz, n, n_out);
            // dX = dZ · W (all columns, or the asked ones of the input layer).
            let (dx, cols) = if l > 0 {
                (
                    Some(MatMut::from_row_major_slice_mut(
                        &mut g_before[l - 1][in_rows.clone()],
                        n,
                        n_in,
                    )),
                    0..n_in,
                )
            } else {
                let cols = match &input_grad {
                    InputGrad::None => 0..0,
                    InputGrad::All => 0..n_in,
                    InputGrad::Cols(c) => c.clone(),
                };
                assert!(
                    cols.end <= n_in,
                    "input gradient columns {cols:?} out of range"
                );
                let dx = (!cols.is_empty()).then(|| {
                    MatMut::from_row_major_slice_mut(
                        &mut cache.grad_input[in_rows.clone()],
                        n,
                        n_in,
                    )
                });
                (dx, cols)
            };
            let weight = self.weight(l);
            let x = MatRef::from_row_major_slice(x, n, n_in);
            let input_grad_gemm = |dx: MatMut<'_, T>, par: Par| {
                gemm(
                    dx.subcols_mut(cols.start, cols.len()),
                    dz,
                    weight.subcols(cols.start, cols.len()),
                    par,
                );
            };
            let weight_grad_gemm = |gw: &mut [T], par: Par| {
                gemm(
                    MatMut::from_row_major_slice_mut(gw, n_out, n_in),
                    dz.transpose(),
                    x,
                    par,
                );
            };
            match (weight_grad, dx) {
                // Both GEMMs of the layer are independent: with threads to spare, each gets half
                // of them (on two threads, one each: better than splitting small GEMMs).
                (Some(gw), Some(dx)) => match par {
                    Par::Rayon(threads) if threads.get() >= 2 => {
                        let half = threads.get() / 2;
                        let (pw, px) = (
                            crate::par_for_threads(threads.get() - half),
                            crate::par_for_threads(half),
                        );
                        rayon::join(
                            || {
                                clear_upper_state();
                                weight_grad_gemm(gw, pw);
                            },
                            || {
                                clear_upper_state();
                                input_grad_gemm(dx, px);
                            },
                        );
                    }
                    _ => {
                        weight_grad_gemm(gw, par);
                        input_grad_gemm(dx, par);
                    }
                },
                (Some(gw), None) => weight_grad_gemm(gw, par),
                (None, Some(dx)) => input_grad_gemm(dx, par),
                (None, None) => {}
            }
        }
    }

    /// Polyak averaging `self ← (1 − tau)·self + tau·source` (PyTorch's order of operations).
    pub fn polyak_from(&mut self, source: &Mlp<T>, tau: T) {
        assert_eq!(
            self.sizes, source.sizes,
            "Polyak averaging between different shapes"
        );
        let keep = T::of(1.0) - tau;
        let (target, source) = (&mut self.params[..], &source.params[..]);
        crate::simd::vectorized(Polyak {
            target,
            source,
            keep,
            tau,
        });
    }

    /// FLOPs of a forward pass over `rows` rows (2 per multiply-add of the GEMMs).
    pub fn forward_flops(&self, rows: usize) -> u64 {
        (0..self.num_layers())
            .map(|l| 2 * (rows * self.sizes[l] * self.sizes[l + 1]) as u64)
            .sum()
    }

    /// FLOPs of a backward pass over `rows` rows with or without parameter gradients and with
    /// `input_cols` columns of input gradient.
    pub fn backward_flops(&self, rows: usize, param_grads: bool, input_cols: usize) -> u64 {
        let mut f = 0u64;
        for l in 0..self.num_layers() {
            let (i, o) = (self.sizes[l], self.sizes[l + 1]);
            if param_grads {
                f += 2 * (rows * i * o) as u64;
            }
            let dx_cols = if l == 0 { input_cols } else { i };
            f += 2 * (rows * dx_cols * o) as u64;
        }
        f
    }

    /// Weights as tensors `{prefix}.{l}.weight [out, in]` and `{prefix}.{l}.bias [out]` with `l`
    /// the number of the linear layer, so `torch.nn.Linear(in, out).load_state_dict` takes them
    /// as they are (a `torch.nn.Sequential` with activation modules in between numbers its
    /// linear layers 0, 2, 4, …; rename when loading into one).
    pub fn export(&self, prefix: &str, out: &mut Vec<Tensor>) {
        self.export_values(prefix, &self.params, out);
    }

    /// Like [`Mlp::export`] for another vector in the parameter layout (gradients, Adam moments),
    /// of any float type (e.g. `f32` copies of `f64` weights for the wire).
    pub fn export_values<U: Float>(&self, prefix: &str, values: &[U], out: &mut Vec<Tensor>) {
        assert_eq!(values.len(), self.params.len());
        for l in 0..self.num_layers() {
            let shape_w = vec![self.sizes[l + 1], self.sizes[l]];
            out.push(Tensor::from_values(
                format!("{prefix}.{l}.weight"),
                shape_w,
                &values[self.weight_range(l)],
            ));
            out.push(Tensor::from_values(
                format!("{prefix}.{l}.bias"),
                vec![self.sizes[l + 1]],
                &values[self.bias_range(l)],
            ));
        }
    }

    /// Loads weights written by [`Mlp::export`]; shapes and dtype must match exactly and values
    /// must be finite. On error `self` is unchanged.
    pub fn import(&mut self, prefix: &str, file: &TensorFile) -> Result<(), NnError> {
        let mut params = self.params.clone();
        self.import_values(prefix, file, &mut params)?;
        if let Some(bad) = params.iter().position(|v| !v.is_finite()) {
            return Err(NnError::InvalidValue(format!(
                "`{prefix}` has a non-finite weight at flat index {bad}"
            )));
        }
        self.params = params;
        Ok(())
    }

    /// Like [`Mlp::import`] into another vector in the parameter layout.
    pub fn import_values(
        &self,
        prefix: &str,
        file: &TensorFile,
        values: &mut [T],
    ) -> Result<(), NnError> {
        assert_eq!(values.len(), self.params.len());
        for l in 0..self.num_layers() {
            let w = file.get(
                &format!("{prefix}.{l}.weight"),
                &[self.sizes[l + 1], self.sizes[l]],
            )?;
            w.copy_into(&mut values[self.weight_range(l)])?;
            let b = file.get(&format!("{prefix}.{l}.bias"), &[self.sizes[l + 1]])?;
            b.copy_into(&mut values[self.bias_range(l)])?;
        }
        Ok(())
    }
}

impl<T: Float> MlpCache<T> {
    /// Buffers for `capacity` rows of `mlp`.
    pub fn new(mlp: &Mlp<T>, capacity: usize) -> Self {
        let sizes = mlp.sizes.clone();
        let zeros = |n: usize| vec![T::of(0.0); n];
        Self {
            capacity,
            input: zeros(capacity * sizes[0]),
            outs: sizes[1..].iter().map(|&s| zeros(capacity * s)).collect(),
            grads: sizes[1..].iter().map(|&s| zeros(capacity * s)).collect(),
            grad_input: zeros(capacity * sizes[0]),
            sizes,
        }
    }

    /// Maximum number of rows these buffers hold.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Input rows `rows` (row-major), to be filled before [`Mlp::forward`].
    pub fn input_mut(&mut self, rows: Range<usize>) -> &mut [T] {
        let w = self.sizes[0];
        &mut self.input[rows.start * w..rows.end * w]
    }

    /// Input rows as last written.
    pub fn input(&self, rows: Range<usize>) -> &[T] {
        let w = self.sizes[0];
        &self.input[rows.start * w..rows.end * w]
    }

    /// Output rows of the last forward pass.
    pub fn output(&self, rows: Range<usize>) -> &[T] {
        let w = self.sizes[self.sizes.len() - 1];
        &self.outs[self.outs.len() - 1][rows.start * w..rows.end * w]
    }

    /// Loss gradient w.r.t. output rows, to be filled before [`Mlp::backward`].
    pub fn grad_output_mut(&mut self, rows: Range<usize>) -> &mut [T] {
        let w = self.sizes[self.sizes.len() - 1];
        let last = self.grads.len() - 1;
        &mut self.grads[last][rows.start * w..rows.end * w]
    }

    /// Output rows and their gradient buffer together (for losses that need both).
    pub fn output_and_grad_mut(&mut self, rows: Range<usize>) -> (&[T], &mut [T]) {
        let w = self.sizes[self.sizes.len() - 1];
        let last = self.grads.len() - 1;
        let r = rows.start * w..rows.end * w;
        (&self.outs[last][r.clone()], &mut self.grads[last][r])
    }

    /// Input gradient rows of the last backward pass (only the columns it was asked for are
    /// meaningful).
    pub fn grad_input(&self, rows: Range<usize>) -> &[T] {
        let w = self.sizes[0];
        &self.grad_input[rows.start * w..rows.end * w]
    }
}

/// `dst ← lhs · rhs` (faer, overwriting), then [`clear_upper_state`] on this thread: faer's
/// micro-kernels return with the upper vector state dirty, and every scalar pass after a GEMM
/// would pay for it.
fn gemm<T: Float>(dst: MatMut<'_, T>, lhs: MatRef<'_, T>, rhs: MatRef<'_, T>, par: Par) {
    matmul(dst, Accum::Replace, lhs, rhs, T::of(1.0), par);
    clear_upper_state();
}

/// `y ← act(y + bias)` row by row, in one pass.
fn bias_activation<T: Float>(y: &mut [T], bias: &[T], act: Activation) {
    crate::simd::vectorized(BiasActivation { y, bias, act });
}

#[inline(always)]
fn bias_activation_loops<T: Float>(y: &mut [T], bias: &[T], act: Activation) {
    let zero = T::of(0.0);
    let rows = y.chunks_exact_mut(bias.len());
    match act {
        Activation::Identity => {
            rows.for_each(|r| r.iter_mut().zip(bias).for_each(|(v, &b)| *v += b))
        }
        // `if v < 0 { 0 } else { v }` keeps NaN visible instead of clamping it to zero.
        Activation::Relu => rows.for_each(|r| {
            r.iter_mut().zip(bias).for_each(|(v, &b)| {
                let s = *v + b;
                *v = if s < zero { zero } else { s };
            })
        }),
        Activation::Tanh => rows.for_each(|r| {
            r.iter_mut()
                .zip(bias)
                .for_each(|(v, &b)| *v = (*v + b).tanh())
        }),
        Activation::Softplus => rows.for_each(|r| {
            r.iter_mut()
                .zip(bias)
                .for_each(|(v, &b)| *v = (*v + b).softplus())
        }),
    }
}

/// `t ← t·keep + tau·s` element-wise.
struct Polyak<'a, T> {
    target: &'a mut [T],
    source: &'a [T],
    keep: T,
    tau: T,
}

impl<T: Float> Kernel for Polyak<'_, T> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        for (t, &s) in self.target.iter_mut().zip(self.source) {
            *t = *t * self.keep + self.tau * s;
        }
    }
}

/// [`bias_activation`]'s loops.
struct BiasActivation<'a, T> {
    y: &'a mut [T],
    bias: &'a [T],
    act: Activation,
}

impl<T: Float> Kernel for BiasActivation<'_, T> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        bias_activation_loops(self.y, self.bias, self.act);
    }
}

/// [`activation_grad`]'s loops.
struct ActivationGrad<'a, T> {
    dz: &'a mut [T],
    y: &'a [T],
    act: Activation,
}

impl<T: Float> Kernel for ActivationGrad<'_, T> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        activation_grad_loops(self.dz, self.y, self.act);
    }
}

/// [`activation_grad_with_bias`]'s loops.
struct ActivationGradWithBias<'a, T> {
    dz: &'a mut [T],
    y: &'a [T],
    db: &'a mut [T],
    act: Activation,
}

impl<T: Float> Kernel for ActivationGradWithBias<'_, T> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        activation_grad_with_bias_loops(self.dz, self.y, self.db, self.act);
    }
}

/// Softplus' derivative `σ(z)` from its output `y = ln(1 + e^z)`: `1 − e^{−y}`.
#[inline(always)]
fn softplus_grad<T: Float>(y: T) -> T {
    T::of(1.0) - (-y).exp()
}

/// `dz ← dy · act'(y)` in place, with `y` the activation output.
fn activation_grad<T: Float>(dz: &mut [T], y: &[T], act: Activation) {
    crate::simd::vectorized(ActivationGrad { dz, y, act });
}

#[inline(always)]
fn activation_grad_loops<T: Float>(dz: &mut [T], y: &[T], act: Activation) {
    let (zero, one) = (T::of(0.0), T::of(1.0));
    match act {
        Activation::Identity => {}
        Activation::Relu => dz
            .iter_mut()
            .zip(y)
            .for_each(|(d, &y)| *d = if y > zero { *d } else { zero }),
        Activation::Tanh => dz.iter_mut().zip(y).for_each(|(d, &y)| *d *= one - y * y),
        Activation::Softplus => dz
            .iter_mut()
            .zip(y)
            .for_each(|(d, &y)| *d *= softplus_grad(y)),
    }
}

/// [`activation_grad`] fused with the bias gradient `db = Σ_rows dz` (written, not accumulated).
fn activation_grad_with_bias<T: Float>(dz: &mut [T], y: &[T], db: &mut [T], act: Activation) {
    crate::simd::vectorized(ActivationGradWithBias { dz, y, db, act });
}

#[inline(always)]
fn activation_grad_with_bias_loops<T: Float>(dz: &mut [T], y: &[T], db: &mut [T], act: Activation) {
    let (zero, one) = (T::of(0.0), T::of(1.0));
    db.fill(zero);
    let width = db.len();
    for (dr, yr) in dz.chunks_exact_mut(width).zip(y.chunks_exact(width)) {
        match act {
            Activation::Identity => db.iter_mut().zip(dr.iter()).for_each(|(b, &d)| *b += d),
            Activation::Relu => {
                db.iter_mut()
                    .zip(dr.iter_mut())
                    .zip(yr)
                    .for_each(|((b, d), &y)| {
                        let g = if y > zero { *d } else { zero };
                        *d = g;
                        *b += g;
                    })
            }
            Activation::Tanh => {
                db.iter_mut()
                    .zip(dr.iter_mut())
                    .zip(yr)
                    .for_each(|((b, d), &y)| {
                        let g = *d * (one - y * y);
                        *d = g;
                        *b += g;
                    })
            }
            Activation::Softplus => {
                db.iter_mut()
                    .zip(dr.iter_mut())
                    .zip(yr)
                    .for_each(|((b, d), &y)| {
                        let g = *d * softplus_grad(y);
                        *d = g;
                        *b += g;
                    })
            }
        }
    }
}
