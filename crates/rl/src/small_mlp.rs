//! Forward-only `f32` MLP for a few rows per call (actors: one row per environment).
//!
//! Small batches are a different GEMM regime from training: every weight is read once per call
//! for only a few rows, and a general GEMM's packing and blocking cost more than the products
//! (faer at 8 rows of a 512-wide layer runs at about half its 4-row rate per row). Each weight is
//! therefore stored pre-packed in panels of [`PANEL`] output columns (`panel[k][j] = W[p·PANEL +
//! j][k]`, zero-padded), which a register-blocked kernel streams once per call: 4 rows × 16
//! columns of accumulators, one FMA per weight and row. Without 8-lane `f32` SIMD (AVX2) the
//! same panels go through faer.

use faer::linalg::matmul::matmul;
use faer::traits::pulp::{self, Simd, WithSimd};
use faer::{Accum, MatMut, MatRef, Par};
use terl_nn::{Activation, Mlp, MlpSpec};

/// Output columns per weight panel (two 8-lane vectors).
const PANEL: usize = 16;
/// Rows per register block of the kernel.
const ROW_BLOCK: usize = 4;

#[derive(Clone, Debug)]
pub(crate) struct SmallBatchMlp {
    sizes: Vec<usize>,
    activations: Vec<Activation>,
    /// Per layer, the weight packed in panels: `out_pad(l) / PANEL` blocks of `[in, PANEL]`.
    panels: Vec<Vec<f32>>,
    biases: Vec<Vec<f32>>,
    /// The input rows.
    input: Vec<f32>,
    /// Per layer, outputs of up to `max_rows` rows, `out_pad(l)` columns each.
    outs: Vec<Vec<f32>>,
    /// The network's output rows without padding.
    result: Vec<f32>,
    max_rows: usize,
    arch: pulp::Arch,
}

fn padded(n: usize, to: usize) -> usize {
    n.div_ceil(to) * to
}

impl SmallBatchMlp {
    /// A network of `spec`'s shape holding `net`'s weights (same shape).
    pub(crate) fn new(spec: &MlpSpec, net: &Mlp<f32>, max_rows: usize) -> Self {
        let sizes = net.sizes().to_vec();
        let layers = sizes.len() - 1;
        let mut activations = vec![spec.hidden_activation; layers];
        activations[layers - 1] = spec.output_activation;
        let rows = max_rows;
        let mut m = Self {
            panels: sizes
                .windows(2)
                .map(|w| vec![0.0; w[0] * padded(w[1], PANEL)])
                .collect(),
            biases: sizes[1..].iter().map(|&o| vec![0.0; o]).collect(),
            input: vec![0.0; rows * sizes[0]],
            outs: sizes[1..]
                .iter()
                .map(|&o| vec![0.0; rows * padded(o, PANEL)])
                .collect(),
            result: vec![0.0; max_rows * sizes[layers]],
            sizes,
            activations,
            max_rows,
            arch: pulp::Arch::new(),
        };
        m.load(net);
        m
    }

    /// Copies (and packs) `net`'s weights.
    pub(crate) fn load(&mut self, net: &Mlp<f32>) {
        assert_eq!(net.sizes(), self.sizes, "network shape changed");
        for l in 0..self.sizes.len() - 1 {
            let (n_in, n_out) = (self.sizes[l], self.sizes[l + 1]);
            let w = &net.params[net.weight_range(l)];
            for (p, panel) in self.panels[l].chunks_exact_mut(n_in * PANEL).enumerate() {
                for (k, row) in panel.chunks_exact_mut(PANEL).enumerate() {
                    for (j, v) in row.iter_mut().enumerate() {
                        let o = p * PANEL + j;
                        *v = if o < n_out { w[o * n_in + k] } else { 0.0 };
                    }
                }
            }
            self.biases[l].copy_from_slice(&net.params[net.bias_range(l)]);
        }
    }

    pub(crate) fn max_rows(&self) -> usize {
        self.max_rows
    }

    /// Forward pass over `rows` rows of `input` (`rows × sizes[0]`); returns the output rows.
    pub(crate) fn forward(&mut self, input: &[f32], rows: usize) -> &[f32] {
        assert!(
            rows <= self.max_rows,
            "{rows} rows exceed {}",
            self.max_rows
        );
        assert_eq!(input.len(), rows * self.sizes[0], "input of the wrong size");
        let n0 = self.sizes[0];
        self.input[..rows * n0].copy_from_slice(input);
        let layers = self.sizes.len() - 1;
        for l in 0..layers {
            let (n_in, n_out) = (self.sizes[l], self.sizes[l + 1]);
            let out_pad = padded(n_out, PANEL);
            let (before, rest) = self.outs.split_at_mut(l);
            let (x, x_stride) = if l == 0 {
                (&self.input[..rows * n0], n0)
            } else {
                let stride = padded(n_in, PANEL);
                (&before[l - 1][..rows * stride], stride)
            };
            let y = &mut rest[0][..rows * out_pad];
            let kernel = PanelKernel {
                x,
                x_stride,
                n_in,
                panels: &self.panels[l],
                y,
                y_stride: out_pad,
            };
            if !self.arch.dispatch(kernel) {
                faer_panels(x, x_stride, n_in, &self.panels[l], y, out_pad);
            }
            let bias = &self.biases[l];
            let rows_y = y.chunks_exact_mut(out_pad).map(|r| &mut r[..n_out]);
            match self.activations[l] {
                Activation::Identity => rows_y.for_each(|r| {
                    r.iter_mut().zip(bias).for_each(|(v, &b)| *v += b);
                }),
                // `if s < 0 { 0 } else { s }` keeps NaN visible (as `Mlp::forward` does).
                Activation::Relu => rows_y.for_each(|r| {
                    r.iter_mut().zip(bias).for_each(|(v, &b)| {
                        let s = *v + b;
                        *v = if s < 0.0 { 0.0 } else { s };
                    });
                }),
                Activation::Tanh => rows_y.for_each(|r| {
                    r.iter_mut()
                        .zip(bias)
                        .for_each(|(v, &b)| *v = (*v + b).tanh());
                }),
                Activation::Softplus => rows_y.for_each(|r| {
                    r.iter_mut()
                        .zip(bias)
                        .for_each(|(v, &b)| *v = terl_nn::Float::softplus(*v + b));
                }),
            }
        }
        let n_out = self.sizes[layers];
        let out_pad = padded(n_out, PANEL);
        let y = &self.outs[layers - 1];
        for (dst, src) in self.result[..rows * n_out]
            .chunks_exact_mut(n_out)
            .zip(y.chunks_exact(out_pad))
        {
            dst.copy_from_slice(&src[..n_out]);
        }
        &self.result[..rows * n_out]
    }
}

/// `y[r][p·PANEL + j] = Σ_k x[r][k] · panel_p[k][j]` for all rows and panels. Returns `false` (nothing written) unless the SIMD width is 8 `f32` lanes.
struct PanelKernel<'a> {
    x: &'a [f32],
    x_stride: usize,
    n_in: usize,
    panels: &'a [f32],
    y: &'a mut [f32],
    y_stride: usize,
}

impl WithSimd for PanelKernel<'_> {
    type Output = bool;

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> bool {
        if S::F32_LANES * 2 != PANEL {
            return false;
        }
        let Self {
            x,
            x_stride,
            n_in,
            panels,
            y,
            y_stride,
        } = self;
        let rows = x.len() / x_stride;
        let full = rows - rows % ROW_BLOCK;
        for (p, panel) in panels.chunks_exact(n_in * PANEL).enumerate() {
            let (w, _) = S::as_simd_f32s(panel);
            let y = &mut *y;
            let col = p * PANEL;
            for g in (0..full).step_by(ROW_BLOCK) {
                row_block::<S, ROW_BLOCK>(simd, w, x, x_stride, n_in, g, y, y_stride, col);
            }
            match rows - full {
                1 => row_block::<S, 1>(simd, w, x, x_stride, n_in, full, y, y_stride, col),
                2 => row_block::<S, 2>(simd, w, x, x_stride, n_in, full, y, y_stride, col),
                3 => row_block::<S, 3>(simd, w, x, x_stride, n_in, full, y, y_stride, col),
                _ => {}
            }
        }
        true
    }
}

/// Rows `g..g + R` of one panel: `R × 2` vector accumulators over all `n_in` inputs.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn row_block<S: Simd, const R: usize>(
    simd: S,
    w: &[S::f32s],
    x: &[f32],
    x_stride: usize,
    n_in: usize,
    g: usize,
    y: &mut [f32],
    y_stride: usize,
    col: usize,
) {
    let xr: [&[f32]; R] = std::array::from_fn(|r| &x[(g + r) * x_stride..][..n_in]);
    let zero = simd.splat_f32s(0.0);
    let mut acc = [[zero; 2]; R];
    for (k, w) in w.chunks_exact(2).enumerate() {
        let (w0, w1) = (w[0], w[1]);
        for (a, xr) in acc.iter_mut().zip(&xr) {
            let b = simd.splat_f32s(xr[k]);
            a[0] = simd.mul_add_f32s(b, w0, a[0]);
            a[1] = simd.mul_add_f32s(b, w1, a[1]);
        }
    }
    for (r, a) in acc.iter().enumerate() {
        let out = &mut y[(g + r) * y_stride + col..][..PANEL];
        let (o, _) = S::as_mut_simd_f32s(out);
        o[0] = a[0];
        o[1] = a[1];
    }
}

/// [`PanelKernel`] through faer, one GEMM per panel (for machines without 8-lane SIMD).
fn faer_panels(
    x: &[f32],
    x_stride: usize,
    n_in: usize,
    panels: &[f32],
    y: &mut [f32],
    y_stride: usize,
) {
    let rows = x.len() / x_stride;
    let xm = MatRef::from_row_major_slice(x, rows, x_stride).subcols(0, n_in);
    let mut ym = MatMut::from_row_major_slice_mut(y, rows, y_stride);
    for (p, panel) in panels.chunks_exact(n_in * PANEL).enumerate() {
        matmul(
            ym.as_mut().subcols_mut(p * PANEL, PANEL),
            Accum::Replace,
            xm,
            MatRef::from_row_major_slice(panel, n_in, PANEL),
            1.0f32,
            Par::Seq,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use terl_nn::MlpCache;

    /// The faer fallback gives the same products as the kernel.
    fn faer_matches(spec: &MlpSpec, net: &Mlp<f32>, rows: usize) -> bool {
        let small = SmallBatchMlp::new(spec, net, rows);
        let (n_in, n_out) = (net.sizes()[0], padded(net.sizes()[1], PANEL));
        let x: Vec<f32> = (0..rows * n_in).map(|i| (i % 7) as f32 - 3.0).collect();
        let (mut a, mut b) = (vec![0.0; rows * n_out], vec![0.0; rows * n_out]);
        faer_panels(&x, n_in, n_in, &small.panels[0], &mut a, n_out);
        let kernel = PanelKernel {
            x: &x,
            x_stride: n_in,
            n_in,
            panels: &small.panels[0],
            y: &mut b,
            y_stride: n_out,
        };
        if !pulp::Arch::new().dispatch(kernel) {
            return true;
        }
        a.iter()
            .zip(&b)
            .all(|(a, b)| (a - b).abs() <= 1e-5 * (1.0 + a.abs()))
    }

    #[test]
    fn matches_the_training_network() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for (hidden_activation, output_activation) in [
            (Activation::Relu, Activation::Identity),
            (Activation::Relu, Activation::Tanh),
            (Activation::Relu, Activation::Softplus),
        ] {
            let spec = MlpSpec {
                input: 13,
                hidden: vec![40, 24, 17],
                output: 3,
                hidden_activation,
                output_activation,
            };
            let net: Mlp<f32> = Mlp::new(&spec, &mut rng);
            let mut small = SmallBatchMlp::new(&spec, &net, 8);
            let mut cache = MlpCache::new(&net, 8);
            for rows in [1, 2, 3, 5, 7, 8] {
                assert!(faer_matches(&spec, &net, rows));
                let x: Vec<f32> = (0..rows * 13).map(|_| rng.gen_range(-2.0..2.0)).collect();
                cache.input_mut(0..rows).copy_from_slice(&x);
                net.forward(&mut cache, rows, Par::Seq);
                let want = cache.output(0..rows).to_vec();
                let got = small.forward(&x, rows);
                for (a, b) in got.iter().zip(&want) {
                    assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{a} vs {b}");
                }
            }
        }
    }
}
