//! Forward-only `f32` MLP for a few rows per call (actors: one row per environment).
//!
//! Small batches are a different GEMM regime from training: every weight is read once per call
//! for only a few rows, and a general GEMM's packing and blocking cost more than the products
//! (faer at 8 rows of a 512-wide layer runs at about half its 4-row rate per row). Each weight is
//! therefore stored pre-packed in panels of two vectors' width of output columns (`panel[k][j] =
//! W[p·P + j][k]`, zero-padded; `P` = 32 with AVX-512, 16 otherwise), which a register-blocked
//! kernel streams once per call: with AVX-512 8 rows × 2 vectors of accumulators (16 of its 32
//! registers), with AVX2 4 rows × 2 (8 of 16), one FMA per weight and row. Without either
//! instruction set the same panels go through faer. The instruction set is chosen at run time
//! ([`InstructionSet::detect`]) or given ([`SmallBatchMlp::with_instruction_set`]).

use faer::linalg::matmul::matmul;
use faer::traits::pulp::{Simd, WithSimd};
use faer::{Accum, MatMut, MatRef, Par};
use terl_nn::{Activation, InstructionSet, Mlp, MlpSpec};

#[derive(Clone, Debug)]
pub(crate) struct SmallBatchMlp {
    sizes: Vec<usize>,
    activations: Vec<Activation>,
    /// Per layer, the weight packed in panels: `out_pad(l) / panel` blocks of `[in, panel]`.
    panels: Vec<Vec<f32>>,
    biases: Vec<Vec<f32>>,
    /// The input rows.
    input: Vec<f32>,
    /// Per layer, outputs of up to `max_rows` rows, `out_pad(l)` columns each.
    outs: Vec<Vec<f32>>,
    /// The network's output rows without padding.
    result: Vec<f32>,
    max_rows: usize,
    isa: InstructionSet,
    /// Output columns per weight panel: two vectors of `isa` (16 without a vector kernel).
    panel: usize,
}

fn padded(n: usize, to: usize) -> usize {
    n.div_ceil(to) * to
}

impl SmallBatchMlp {
    /// A network of `spec`'s shape holding `net`'s weights (same shape), with the best
    /// instruction set of this processor.
    pub(crate) fn new(spec: &MlpSpec, net: &Mlp<f32>, max_rows: usize) -> Self {
        Self::with_instruction_set(spec, net, max_rows, InstructionSet::detect())
            .expect("the detected instruction set is available")
    }

    /// Like [`SmallBatchMlp::new`] with the kernel of `isa`; `None` if this processor lacks it.
    pub(crate) fn with_instruction_set(
        spec: &MlpSpec,
        net: &Mlp<f32>,
        max_rows: usize,
        isa: InstructionSet,
    ) -> Option<Self> {
        if !isa.is_available() {
            return None;
        }
        let panel = 2 * isa.f32_lanes().max(8);
        let sizes = net.sizes().to_vec();
        let layers = sizes.len() - 1;
        let mut activations = vec![spec.hidden_activation; layers];
        activations[layers - 1] = spec.output_activation;
        let rows = max_rows;
        let mut m = Self {
            panels: sizes
                .windows(2)
                .map(|w| vec![0.0; w[0] * padded(w[1], panel)])
                .collect(),
            biases: sizes[1..].iter().map(|&o| vec![0.0; o]).collect(),
            input: vec![0.0; rows * sizes[0]],
            outs: sizes[1..]
                .iter()
                .map(|&o| vec![0.0; rows * padded(o, panel)])
                .collect(),
            result: vec![0.0; max_rows * sizes[layers]],
            sizes,
            activations,
            max_rows,
            isa,
            panel,
        };
        m.load(net);
        Some(m)
    }

    /// The instruction set of the kernel.
    pub(crate) fn instruction_set(&self) -> InstructionSet {
        self.isa
    }

    /// Copies (and packs) `net`'s weights.
    pub(crate) fn load(&mut self, net: &Mlp<f32>) {
        assert_eq!(net.sizes(), self.sizes, "network shape changed");
        let width = self.panel;
        for l in 0..self.sizes.len() - 1 {
            let (n_in, n_out) = (self.sizes[l], self.sizes[l + 1]);
            let w = &net.params[net.weight_range(l)];
            for (p, panel) in self.panels[l].chunks_exact_mut(n_in * width).enumerate() {
                for (k, row) in panel.chunks_exact_mut(width).enumerate() {
                    for (j, v) in row.iter_mut().enumerate() {
                        let o = p * width + j;
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
        let width = self.panel;
        for l in 0..layers {
            let (n_in, n_out) = (self.sizes[l], self.sizes[l + 1]);
            let out_pad = padded(n_out, width);
            let (before, rest) = self.outs.split_at_mut(l);
            let (x, x_stride) = if l == 0 {
                (&self.input[..rows * n0], n0)
            } else {
                let stride = padded(n_in, width);
                (&before[l - 1][..rows * stride], stride)
            };
            let y = &mut rest[0][..rows * out_pad];
            let product = Panels {
                x,
                x_stride,
                n_in,
                panels: &self.panels[l],
                width,
                y,
                y_stride: out_pad,
            };
            product.run(self.isa);
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
        let out_pad = padded(n_out, width);
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

/// `y[r][p·P + j] = Σ_k x[r][k] · panel_p[k][j]` for all rows and panels (`P` = `width`).
struct Panels<'a> {
    x: &'a [f32],
    x_stride: usize,
    n_in: usize,
    panels: &'a [f32],
    width: usize,
    y: &'a mut [f32],
    y_stride: usize,
}

impl Panels<'_> {
    /// Runs the product with `isa`'s kernel (which the caller checked is available).
    fn run(self, isa: InstructionSet) {
        match isa {
            #[cfg(target_arch = "x86_64")]
            InstructionSet::Avx512 => {
                let simd = faer::traits::pulp::x86::V4::try_new().expect("AVX-512 is available");
                Simd::vectorize(simd, PanelKernel::<8>(self));
            }
            #[cfg(target_arch = "x86_64")]
            InstructionSet::Avx2 => {
                let simd = faer::traits::pulp::x86::V3::try_new().expect("AVX2 is available");
                Simd::vectorize(simd, PanelKernel::<4>(self));
            }
            _ => self.through_faer(),
        }
    }

    /// The same product through faer, one GEMM per panel.
    fn through_faer(self) {
        let Self {
            x,
            x_stride,
            n_in,
            panels,
            width,
            y,
            y_stride,
        } = self;
        let rows = x.len() / x_stride;
        let xm = MatRef::from_row_major_slice(x, rows, x_stride).subcols(0, n_in);
        let mut ym = MatMut::from_row_major_slice_mut(y, rows, y_stride);
        for (p, panel) in panels.chunks_exact(n_in * width).enumerate() {
            matmul(
                ym.as_mut().subcols_mut(p * width, width),
                Accum::Replace,
                xm,
                MatRef::from_row_major_slice(panel, n_in, width),
                1.0f32,
                Par::Seq,
            );
        }
    }
}

/// The register-blocked kernel: `R` rows at a time, two vectors of columns per panel.
struct PanelKernel<'a, const R: usize>(Panels<'a>);

impl<const R: usize> WithSimd for PanelKernel<'_, R> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let Panels {
            x,
            x_stride,
            n_in,
            panels,
            width,
            y,
            y_stride,
        } = self.0;
        assert_eq!(
            S::F32_LANES * 2,
            width,
            "panels packed for another vector width"
        );
        let rows = x.len() / x_stride;
        let full = rows - rows % R;
        for (p, panel) in panels.chunks_exact(n_in * width).enumerate() {
            let (w, _) = S::as_simd_f32s(panel);
            let y = &mut *y;
            let col = p * width;
            for g in (0..full).step_by(R) {
                row_block::<S, R>(simd, w, x, x_stride, n_in, g, y, y_stride, col);
            }
            let at = (x, x_stride, n_in, full, col);
            match rows - full {
                0 => {}
                1 => tail::<S, 1>(simd, w, at, y, y_stride),
                2 => tail::<S, 2>(simd, w, at, y, y_stride),
                3 => tail::<S, 3>(simd, w, at, y, y_stride),
                4 => tail::<S, 4>(simd, w, at, y, y_stride),
                5 => tail::<S, 5>(simd, w, at, y, y_stride),
                6 => tail::<S, 6>(simd, w, at, y, y_stride),
                r => {
                    // R is at most 8, so at most 7 rows are left.
                    debug_assert_eq!(r, 7);
                    tail::<S, 7>(simd, w, at, y, y_stride)
                }
            }
        }
    }
}

/// [`row_block`] for the last rows of a panel (`at` = x, x_stride, n_in, first row, column).
#[inline(always)]
fn tail<S: Simd, const R: usize>(
    simd: S,
    w: &[S::f32s],
    at: (&[f32], usize, usize, usize, usize),
    y: &mut [f32],
    y_stride: usize,
) {
    let (x, x_stride, n_in, g, col) = at;
    row_block::<S, R>(simd, w, x, x_stride, n_in, g, y, y_stride, col);
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
        let out = &mut y[(g + r) * y_stride + col..][..2 * S::F32_LANES];
        let (o, _) = S::as_mut_simd_f32s(out);
        o[0] = a[0];
        o[1] = a[1];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use terl_nn::MlpCache;

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
            assert_eq!(small.instruction_set(), InstructionSet::detect());
            let mut cache = MlpCache::new(&net, 8);
            for rows in [1, 2, 3, 5, 7, 8] {
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

    /// Every instruction set this processor has (AVX-512, AVX2, the faer path) gives the same
    /// outputs as an `f64` reference within `f32` rounding, at widths that are and are not
    /// multiples of the panel and at every row count up to 16 (full and partial row blocks).
    #[test]
    fn every_instruction_set_matches_an_f64_reference() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let spec = MlpSpec {
            input: 49,
            hidden: vec![400, 37, 64],
            output: 8,
            hidden_activation: Activation::Relu,
            output_activation: Activation::Identity,
        };
        let net: Mlp<f32> = Mlp::new(&spec, &mut rng);
        let mut wide: Mlp<f64> = Mlp::new(&spec, &mut rng);
        wide.params = net.params.iter().map(|&v| f64::from(v)).collect();
        let mut reference = MlpCache::new(&wide, 16);
        let mut ran = Vec::new();
        for isa in InstructionSet::ALL {
            let Some(mut small) = SmallBatchMlp::with_instruction_set(&spec, &net, 16, isa) else {
                continue;
            };
            ran.push(isa);
            for rows in 1..=16 {
                let x: Vec<f32> = (0..rows * 49).map(|_| rng.gen_range(-2.0..2.0)).collect();
                for (d, &v) in reference.input_mut(0..rows).iter_mut().zip(&x) {
                    *d = f64::from(v);
                }
                wide.forward(&mut reference, rows, Par::Seq);
                let got = small.forward(&x, rows);
                for (a, &b) in got.iter().zip(reference.output(0..rows)) {
                    let err = (f64::from(*a) - b).abs();
                    assert!(
                        err <= 1e-4 * (1.0 + b.abs()),
                        "{isa}, {rows} rows: {a} vs {b}"
                    );
                }
            }
        }
        assert!(ran.contains(&InstructionSet::detect()) && ran.contains(&InstructionSet::Portable));
    }
}
