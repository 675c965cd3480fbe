//! faer `f32` GEMM rate for the SAC update's shapes in several operand layouts, sequential and
//! on a rayon pool, against a plain column-major GEMM of the same size and the core's FMA peak.
//!   cargo run --release -p terl-nn --example gemm_rate -- [seconds_per_case] [rounds]
//!
//! The FMA peak line is the ceiling to compare against, not a vendor figure: a Zen 1 core (CPU
//! family 23, model 1) splits every 256-bit FMA into two 128-bit halves, so it retires 16 `f32`
//! FLOP per cycle (about 39 GFLOP/s at its clock), half of what a Zen 2 or later core does.
#![allow(clippy::too_many_lines)] // the benchmark's steps in order

use faer::linalg::matmul::matmul;
use faer::traits::pulp::{self, Simd, WithSimd};
use faer::{Accum, MatMut, MatRef, Par};
use std::time::Instant;

/// How the operands of `C [m×n] = A [m×k] · B [k×n]` are stored.
#[derive(Clone, Copy, Debug)]
enum Layout {
    /// All column-major (BLAS "NN").
    ColMajor,
    /// All row-major views.
    RowMajor,
    /// `mlp.rs` forward: row-major `A`, `B` the transpose of a row-major `[n×k]` weight.
    RowMajorBt,
    /// `mlp.rs` weight gradient: `A` the transpose of a row-major `[k×m]`, `B` row-major.
    RowMajorAt,
}

struct Case {
    m: usize,
    n: usize,
    k: usize,
    layout: Layout,
    a: Vec<f32>,
    b: Vec<f32>,
    c: Vec<f32>,
}

impl Case {
    fn new(m: usize, n: usize, k: usize, layout: Layout) -> Self {
        Self {
            m,
            n,
            k,
            layout,
            a: (0..m * k).map(|i| (i % 13) as f32 * 0.01).collect(),
            b: (0..k * n).map(|i| (i % 7) as f32 * 0.01).collect(),
            c: vec![0.0; m * n],
        }
    }

    fn run(&mut self, par: Par) {
        let (m, n, k) = (self.m, self.n, self.k);
        let (a, b) = match self.layout {
            Layout::ColMajor => (
                MatRef::from_column_major_slice(&self.a, m, k),
                MatRef::from_column_major_slice(&self.b, k, n),
            ),
            Layout::RowMajor => (
                MatRef::from_row_major_slice(&self.a, m, k),
                MatRef::from_row_major_slice(&self.b, k, n),
            ),
            Layout::RowMajorBt => (
                MatRef::from_row_major_slice(&self.a, m, k),
                MatRef::from_row_major_slice(&self.b, n, k).transpose(),
            ),
            Layout::RowMajorAt => (
                MatRef::from_row_major_slice(&self.a, k, m).transpose(),
                MatRef::from_row_major_slice(&self.b, k, n),
            ),
        };
        let c = match self.layout {
            Layout::ColMajor => MatMut::from_column_major_slice_mut(&mut self.c, m, n),
            _ => MatMut::from_row_major_slice_mut(&mut self.c, m, n),
        };
        matmul(c, Accum::Replace, a, b, 1.0f32, par);
    }

    fn flops(&self) -> f64 {
        2.0 * (self.m * self.n * self.k) as f64
    }
}

/// Independent FMA chains on 8-lane vectors: the core's FMA throughput.
struct FmaPeak {
    iters: usize,
}

impl WithSimd for FmaPeak {
    type Output = (f32, usize);

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> (f32, usize) {
        let x = simd.splat_f32s(std::hint::black_box(0.999_9));
        let y = simd.splat_f32s(std::hint::black_box(1e-4));
        let mut acc = [simd.splat_f32s(1.0); 12];
        for _ in 0..self.iters / 100 {
            for _ in 0..100 {
                for a in acc.iter_mut() {
                    *a = simd.mul_add_f32s(*a, x, y);
                }
            }
            acc = std::hint::black_box(acc);
        }
        let mut s = simd.splat_f32s(0.0);
        for a in acc {
            s = simd.add_f32s(s, a);
        }
        (simd.reduce_sum_f32s(s), S::F32_LANES)
    }
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seconds: f64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(0.3);
    let rounds: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);

    println!("pulp::Arch::new() = {:?}", pulp::Arch::new());
    #[cfg(target_arch = "x86_64")]
    println!(
        "detected: avx2={} fma={} avx512f={}",
        std::arch::is_x86_feature_detected!("avx2"),
        std::arch::is_x86_feature_detected!("fma"),
        std::arch::is_x86_feature_detected!("avx512f"),
    );

    // FMA peak of one core (measured in every round, next to the GEMMs, as the load varies).
    let fma_peak = |seconds: f64| {
        let iters = 1_000_000;
        let start = Instant::now();
        let mut runs = 0usize;
        let mut lanes = 0;
        while start.elapsed().as_secs_f64() < seconds {
            let (sum, l) = pulp::Arch::new().dispatch(FmaPeak { iters });
            std::hint::black_box(sum);
            lanes = l;
            runs += 1;
        }
        (
            2.0 * 12.0 * (lanes * iters * runs) as f64 / start.elapsed().as_secs_f64() / 1e9,
            lanes,
        )
    };
    let mut peak = Vec::new();
    let pool2 = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    // (label, m, n, k, layout)
    let shapes: Vec<(&str, usize, usize, usize, Layout)> = vec![
        ("square 1024 col-major", 1024, 1024, 1024, Layout::ColMajor),
        ("square 1024 row·rowT", 1024, 1024, 1024, Layout::RowMajorBt),
        (
            "fwd 1280x400x400 col-major",
            1280,
            400,
            400,
            Layout::ColMajor,
        ),
        (
            "fwd 1280x400x400 row-major",
            1280,
            400,
            400,
            Layout::RowMajor,
        ),
        (
            "fwd 1280x400x400 X·Wᵀ (mlp)",
            1280,
            400,
            400,
            Layout::RowMajorBt,
        ),
        (
            "fwd 2560x400x400 X·Wᵀ (mlp)",
            2560,
            400,
            400,
            Layout::RowMajorBt,
        ),
        (
            "dW 400x400x1280 dYᵀ·X (mlp)",
            400,
            400,
            1280,
            Layout::RowMajorAt,
        ),
        (
            "dW 400x400x1280 col-major",
            400,
            400,
            1280,
            Layout::ColMajor,
        ),
        (
            "dX 1280x400x400 dY·W (mlp)",
            1280,
            400,
            400,
            Layout::RowMajor,
        ),
        (
            "fwd 1280x400x49 X·Wᵀ (mlp)",
            1280,
            400,
            49,
            Layout::RowMajorBt,
        ),
        (
            "fwd 256x400x400 X·Wᵀ (mlp)",
            256,
            400,
            400,
            Layout::RowMajorBt,
        ),
        ("fwd 256x400x400 col-major", 256, 400, 400, Layout::ColMajor),
        (
            "dW 400x400x256 dYᵀ·X (mlp)",
            400,
            400,
            256,
            Layout::RowMajorAt,
        ),
        ("dX 256x400x400 dY·W (mlp)", 256, 400, 400, Layout::RowMajor),
        (
            "fwd 256x256x256 X·Wᵀ (mlp)",
            256,
            256,
            256,
            Layout::RowMajorBt,
        ),
        ("fwd 8x400x400 X·Wᵀ (mlp)", 8, 400, 400, Layout::RowMajorBt),
    ];
    let mut cases: Vec<(&str, Case)> = shapes
        .into_iter()
        .map(|(s, m, n, k, l)| (s, Case::new(m, n, k, l)))
        .collect();
    let pars = [("Seq", Par::Seq), ("rayon(2)", Par::rayon(2))];
    let mut results = vec![vec![Vec::new(); pars.len()]; cases.len()];
    let mut lanes = 0;
    for _ in 0..rounds {
        let (p, l) = fma_peak(seconds);
        peak.push(p);
        lanes = l;
        for (ci, (_, case)) in cases.iter_mut().enumerate() {
            for (pi, &(_, par)) in pars.iter().enumerate() {
                let mut go = || {
                    case.run(par);
                    let start = Instant::now();
                    let mut runs = 0u64;
                    while start.elapsed().as_secs_f64() < seconds || runs < 2 {
                        case.run(par);
                        runs += 1;
                    }
                    case.flops() * runs as f64 / start.elapsed().as_secs_f64() / 1e9
                };
                let r = if pi == 0 { go() } else { pool2.install(go) };
                results[ci][pi].push(r);
            }
        }
    }
    println!(
        "FMA peak, 1 core, {lanes} f32 lanes, 12 independent chains: median {:.1} GFLOP/s",
        median(&mut peak)
    );
    println!(
        "{:<32} {:>10} {:>10}   (median GFLOP/s over {rounds} rounds)",
        "case", pars[0].0, pars[1].0
    );
    for (ci, (label, _)) in cases.iter().enumerate() {
        println!(
            "{:<32} {:>10.1} {:>10.1}",
            label,
            median(&mut results[ci][0]),
            median(&mut results[ci][1])
        );
    }
}
