//! SAC update throughput against the machine's GEMM rate, and small-batch inference latency.
//!
//! [`sac_bench`] times full updates (critics, actor, temperatures, targets) on a fixed random
//! batch, counts the FLOPs of the update's GEMMs ([`Sac::update_flops`]), and in the same run
//! times the same GEMM shapes alone, issued the way the update issues them (the policy's GEMMs
//! split across threads, the two critics' GEMMs side by side). `achieved_gflops / gemm_gflops`
//! is then the fraction of the update spent in useful GEMM work. `deploy/bench/sac_torch.py`
//! prints the same fields for PyTorch.

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::time::Instant;
use terl_rl::{Policy, Sac, SacConfig, SacError};

/// What to measure. `obs_dim` is the policy's input width, observation plus one-hot task id
/// (49 = Meta-World's 39 + MT10's 10 tasks).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SacBenchConfig {
    /// Policy input width: observation plus one-hot task id.
    pub obs_dim: usize,
    /// Action width.
    pub act_dim: usize,
    /// Width of every hidden layer (policy and critics).
    pub hidden: usize,
    /// Number of hidden layers.
    pub layers: usize,
    /// Minibatch rows per update.
    pub batch: usize,
    /// Threads of the update's GEMMs (a rayon pool of this size, and [`SacConfig::threads`]).
    pub threads: usize,
    /// Seconds of timed updates (the GEMM and inference measurements add about half of that).
    pub seconds: f64,
    /// Tasks in the one-hot part of `obs_dim`.
    pub num_tasks: usize,
}

impl Default for SacBenchConfig {
    fn default() -> Self {
        Self {
            obs_dim: 49,
            act_dim: 4,
            hidden: 400,
            layers: 3,
            batch: 1280,
            threads: 2,
            seconds: 5.0,
            num_tasks: 10,
        }
    }
}

/// Measured numbers (the same fields as the PyTorch script's JSON).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SacBenchReport {
    /// Which implementation produced the numbers: `"terl-rust-faer"` here,
    /// `"pytorch-<version>-cpu"` from `deploy/bench/sac_torch.py`.
    pub implementation: String,
    /// SIMD level the GEMMs and the small-batch kernels ran with (`avx512`, `avx2`,
    /// `portable`; chosen at run time, [`terl_nn::InstructionSet::detect`]).
    #[serde(default)]
    pub instruction_set: String,
    /// What was measured.
    pub config: SacBenchConfig,
    /// Updates timed.
    pub updates: u64,
    /// Updates per second, timed alternately with the bare GEMMs.
    pub updates_per_s: f64,
    /// Milliseconds per update (`1000 / updates_per_s`).
    pub update_ms: f64,
    /// FLOPs of the GEMMs of one update.
    pub flops_per_update: u64,
    /// GFLOP/s the update's GEMMs reach inside the update (`flops_per_update · updates_per_s`).
    pub achieved_gflops: f64,
    /// GFLOP/s of the same GEMM shapes alone, issued as the update issues them.
    pub gemm_gflops: f64,
    /// `achieved_gflops / gemm_gflops`.
    pub gemm_efficiency: f64,
    /// GFLOP/s of a 1024³ GEMM with the same threads (the machine's large-GEMM rate).
    pub gemm_square_gflops: f64,
    /// Mean latency of one stochastic `Policy::act` on 8 observations (one thread).
    pub inference_batch8_us: f64,
    /// CARE's update at the same head sizes, batch and threads (its MT10 encoder settings,
    /// [`terl_rl::CareConfig::default`]), timed alternately with MTSAC's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub care: Option<CareRate>,
}

/// CARE's update rate beside MTSAC's, both timed in the same alternating slices.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CareRate {
    /// CARE updates per second.
    pub updates_per_s: f64,
    /// MTSAC updates per second in the same slices.
    pub mtsac_updates_per_s: f64,
    /// `updates_per_s / mtsac_updates_per_s`.
    pub relative_to_mtsac: f64,
}

impl SacBenchConfig {
    /// The learner configuration this benchmark runs.
    pub fn sac_config(&self) -> Result<SacConfig, SacError> {
        if self.obs_dim <= self.num_tasks {
            return Err(SacError::Config(format!(
                "obs_dim {} must exceed num_tasks {} (it includes the one-hot task id)",
                self.obs_dim, self.num_tasks
            )));
        }
        Ok(SacConfig {
            obs_dim: self.obs_dim - self.num_tasks,
            act_dim: self.act_dim,
            num_tasks: self.num_tasks,
            policy_hidden: vec![self.hidden; self.layers],
            critic_hidden: vec![self.hidden; self.layers],
            batch_size: self.batch,
            threads: self.threads,
            ..Default::default()
        })
    }
}

/// Runs the benchmark.
pub fn sac_bench(config: &SacBenchConfig) -> Result<SacBenchReport, SacError> {
    let cfg = config.sac_config()?;
    let mut sac: Sac<f32> = Sac::new(cfg.clone())?;
    let batch = random_batch(&cfg, 0);

    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(config.threads.max(1))
        .build()
        .map_err(|e| SacError::Config(format!("cannot start {} threads: {e}", config.threads)))?;
    let mut plan = GemmPlan::for_update(&cfg);
    let flops = sac.update_flops(cfg.batch_size);
    assert_eq!(plan.flops(), flops, "the GEMM plan must mirror the update");
    for _ in 0..2 {
        sac.update(&batch)?;
    }
    pool.install(|| plan.run());

    // Their ratio is what `gemm_efficiency` reports.
    let rates = alternate(
        config.seconds,
        &pool,
        || sac.update(&batch).map(drop),
        || plan.run(),
    )?;
    let (updates, updates_per_s) = (rates.updates, rates.updates_per_s);
    let achieved_gflops = flops as f64 * updates_per_s / 1e9;
    let gemm_gflops = flops as f64 * rates.gemm_runs_per_s / 1e9;
    let gemm_square_gflops = pool.install(|| {
        square_gemm_gflops(
            1024,
            config.threads,
            (config.seconds / 10.0).clamp(0.2, 1.0),
        )
    });
    let inference_batch8_us =
        inference_latency_us(&sac, 8, (config.seconds / 10.0).clamp(0.2, 1.0))?;
    let care = care_rate(&cfg, &mut sac, &batch, config.seconds / 2.0)?;

    Ok(SacBenchReport {
        implementation: "terl-rust-faer".to_string(),
        instruction_set: terl_nn::InstructionSet::detect().to_string(),
        config: config.clone(),
        updates,
        updates_per_s,
        update_ms: 1e3 / updates_per_s,
        flops_per_update: flops,
        achieved_gflops,
        gemm_gflops,
        gemm_efficiency: achieved_gflops / gemm_gflops,
        gemm_square_gflops,
        inference_batch8_us,
        care: Some(care),
    })
}

/// CARE's and MTSAC's update rates at the same sizes, timed in alternating slices for
/// `seconds` each (at least 3 updates each).
fn care_rate(
    cfg: &SacConfig,
    mtsac: &mut Sac<f32>,
    batch: &terl_rl::Batch,
    seconds: f64,
) -> Result<CareRate, SacError> {
    let mut care = terl_rl::sac::timing_learner(&SacConfig {
        care: Some(terl_rl::CareConfig::default()),
        ..cfg.clone()
    })?;
    care.update(batch)?;
    let slice = (seconds / 10.0).clamp(0.05, 0.5);
    let timed = |sac: &mut Sac<f32>, spent: &mut f64, n: &mut u64| -> Result<(), SacError> {
        let start = Instant::now();
        loop {
            sac.update(batch)?;
            *n += 1;
            if start.elapsed().as_secs_f64() >= slice {
                break;
            }
        }
        *spent += start.elapsed().as_secs_f64();
        Ok(())
    };
    let (mut care_s, mut care_n, mut mtsac_s, mut mtsac_n) = (0.0, 0u64, 0.0, 0u64);
    while care_s < seconds || care_n < 3 || mtsac_n < 3 {
        timed(&mut care, &mut care_s, &mut care_n)?;
        timed(mtsac, &mut mtsac_s, &mut mtsac_n)?;
    }
    let (c, m) = (care_n as f64 / care_s, mtsac_n as f64 / mtsac_s);
    Ok(CareRate {
        updates_per_s: c,
        mtsac_updates_per_s: m,
        relative_to_mtsac: c / m,
    })
}

/// Updates and their bare GEMMs, timed alternately (see [`alternate`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Alternated {
    pub updates: u64,
    pub updates_per_s: f64,
    pub gemm_runs_per_s: f64,
}

/// Runs `update` and `gemms` (on `pool`) alternately in short slices until `seconds` of
/// updates (and at least 3) are done, so both see the same background load on a shared
/// machine; the GEMM slices are half as long.
pub(crate) fn alternate(
    seconds: f64,
    pool: &rayon::ThreadPool,
    mut update: impl FnMut() -> Result<(), SacError>,
    mut gemms: impl FnMut() + Send,
) -> Result<Alternated, SacError> {
    let slice = (seconds / 10.0).clamp(0.05, 0.5);
    let (mut update_s, mut updates, mut gemm_s, mut gemm_runs) = (0.0f64, 0u64, 0.0f64, 0u64);
    while update_s < seconds || updates < 3 {
        let start = Instant::now();
        loop {
            update()?;
            updates += 1;
            if start.elapsed().as_secs_f64() >= slice {
                break;
            }
        }
        update_s += start.elapsed().as_secs_f64();
        let start = Instant::now();
        pool.install(|| loop {
            gemms();
            gemm_runs += 1;
            if start.elapsed().as_secs_f64() >= slice / 2.0 {
                break;
            }
        });
        gemm_s += start.elapsed().as_secs_f64();
    }
    Ok(Alternated {
        updates,
        updates_per_s: updates as f64 / update_s,
        gemm_runs_per_s: gemm_runs as f64 / gemm_s,
    })
}

pub use terl_rl::sac::random_batch;

fn inference_latency_us(sac: &Sac<f32>, rows: usize, seconds: f64) -> Result<f64, SacError> {
    let cfg = sac.config();
    let mut policy = Policy::new(sac.policy_spec(), rows);
    policy.set_params(&sac.policy_net().params, 0)?;
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let obs: Vec<f32> = (0..rows * cfg.obs_dim)
        .map(|_| rng.gen_range(-1.0..1.0))
        .collect();
    let tasks: Vec<usize> = (0..rows).map(|i| i % cfg.num_tasks).collect();
    let mut actions = vec![0.0; rows * cfg.act_dim];
    for _ in 0..10 {
        policy.act(&obs, &tasks, false, &mut rng, &mut actions)?;
    }
    let start = Instant::now();
    let mut calls = 0u64;
    while start.elapsed().as_secs_f64() < seconds {
        for _ in 0..10 {
            policy.act(&obs, &tasks, false, &mut rng, &mut actions)?;
        }
        calls += 10;
    }
    Ok(start.elapsed().as_secs_f64() * 1e6 / calls as f64)
}

pub(crate) fn square_gemm_gflops(n: usize, threads: usize, seconds: f64) -> f64 {
    let a = vec![0.5f32; n * n];
    let b = vec![0.25f32; n * n];
    let mut c = vec![0.0f32; n * n];
    let par = terl_nn::par_for_threads(threads);
    let mut run = || {
        matmul(
            MatMut::from_row_major_slice_mut(&mut c, n, n),
            Accum::Replace,
            MatRef::from_row_major_slice(&a, n, n),
            MatRef::from_row_major_slice(&b, n, n).transpose(),
            1.0f32,
            par,
        )
    };
    run();
    let start = Instant::now();
    let mut runs = 0u64;
    while start.elapsed().as_secs_f64() < seconds || runs < 2 {
        run();
        runs += 1;
    }
    2.0 * (n * n * n) as f64 * runs as f64 / start.elapsed().as_secs_f64() / 1e9
}

/// One GEMM of the update, in the layout the update uses.
#[derive(Debug)]
pub(crate) enum GemmKind {
    /// `y [rows, out] = x [rows, in] · wᵀ`
    Forward,
    /// `dw [out, in] = dzᵀ · x`
    WeightGrad,
    /// `dx [rows, cols] = dz [rows, out] · w[:, cols]`
    InputGrad { cols: usize },
}

#[derive(Debug)]
pub(crate) struct GemmOp {
    kind: GemmKind,
    rows: usize,
    n_in: usize,
    n_out: usize,
    a: Vec<f32>,
    b: Vec<f32>,
    c: Vec<f32>,
}

impl GemmOp {
    pub(crate) fn new(kind: GemmKind, rows: usize, n_in: usize, n_out: usize) -> Self {
        let (a, b, c) = match kind {
            GemmKind::Forward => (rows * n_in, n_out * n_in, rows * n_out),
            GemmKind::WeightGrad => (rows * n_out, rows * n_in, n_out * n_in),
            GemmKind::InputGrad { .. } => (rows * n_out, n_out * n_in, rows * n_in),
        };
        Self {
            kind,
            rows,
            n_in,
            n_out,
            a: vec![0.01; a],
            b: vec![0.02; b],
            c: vec![0.0; c],
        }
    }

    pub(crate) fn flops(&self) -> u64 {
        let inner = match self.kind {
            GemmKind::InputGrad { cols } => cols,
            _ => self.n_in,
        };
        2 * (self.rows * inner * self.n_out) as u64
    }

    pub(crate) fn run(&mut self, par: Par) {
        let (r, i, o) = (self.rows, self.n_in, self.n_out);
        match self.kind {
            GemmKind::Forward => matmul(
                MatMut::from_row_major_slice_mut(&mut self.c, r, o),
                Accum::Replace,
                MatRef::from_row_major_slice(&self.a, r, i),
                MatRef::from_row_major_slice(&self.b, o, i).transpose(),
                1.0f32,
                par,
            ),
            GemmKind::WeightGrad => matmul(
                MatMut::from_row_major_slice_mut(&mut self.c, o, i),
                Accum::Replace,
                MatRef::from_row_major_slice(&self.a, r, o).transpose(),
                MatRef::from_row_major_slice(&self.b, r, i),
                1.0f32,
                par,
            ),
            GemmKind::InputGrad { cols } => matmul(
                MatMut::from_row_major_slice_mut(&mut self.c, r, i).subcols_mut(0, cols),
                Accum::Replace,
                MatRef::from_row_major_slice(&self.a, r, o),
                MatRef::from_row_major_slice(&self.b, o, i).subcols(0, cols),
                1.0f32,
                par,
            ),
        }
    }
}

/// The GEMMs of one SAC update (see `Sac::compute_gradients`), grouped as the update runs them.
#[derive(Debug)]
struct GemmPlan {
    threads: usize,
    policy: Vec<GemmOp>,
    critics: [Vec<GemmOp>; 2],
}

impl GemmPlan {
    fn for_update(cfg: &SacConfig) -> Self {
        let b = cfg.batch_size;
        let sizes = |input: usize, hidden: &[usize], output: usize| {
            let mut s = vec![input];
            s.extend_from_slice(hidden);
            s.push(output);
            s
        };
        let p = sizes(cfg.policy_input(), &cfg.policy_hidden, 2 * cfg.act_dim);
        let mut policy = Vec::new();
        for w in p.windows(2) {
            policy.push(GemmOp::new(GemmKind::Forward, 2 * b, w[0], w[1]));
        }
        for (l, w) in p.windows(2).enumerate().rev() {
            policy.push(GemmOp::new(GemmKind::WeightGrad, b, w[0], w[1]));
            if l > 0 {
                policy.push(GemmOp::new(
                    GemmKind::InputGrad { cols: w[0] },
                    b,
                    w[0],
                    w[1],
                ));
            }
        }
        let q = sizes(cfg.critic_input(), &cfg.critic_hidden, 1);
        let critic = || {
            let mut ops = Vec::new();
            for w in q.windows(2) {
                ops.push(GemmOp::new(GemmKind::Forward, b, w[0], w[1]));
            }
            for w in q.windows(2) {
                ops.push(GemmOp::new(GemmKind::Forward, 2 * b, w[0], w[1]));
            }
            for (l, w) in q.windows(2).enumerate().rev() {
                ops.push(GemmOp::new(GemmKind::WeightGrad, b, w[0], w[1]));
                if l > 0 {
                    ops.push(GemmOp::new(
                        GemmKind::InputGrad { cols: w[0] },
                        b,
                        w[0],
                        w[1],
                    ));
                }
            }
            for (l, w) in q.windows(2).enumerate().rev() {
                let cols = if l > 0 { w[0] } else { cfg.act_dim };
                ops.push(GemmOp::new(GemmKind::InputGrad { cols }, b, w[0], w[1]));
            }
            ops
        };
        Self {
            threads: cfg.threads,
            policy,
            critics: [critic(), critic()],
        }
    }

    fn flops(&self) -> u64 {
        self.policy
            .iter()
            .chain(self.critics.iter().flatten())
            .map(GemmOp::flops)
            .sum()
    }

    fn run(&mut self) {
        let par = terl_nn::par_for_threads(self.threads);
        for op in &mut self.policy {
            op.run(par);
        }
        let [c1, c2] = &mut self.critics;
        if self.threads > 1 {
            rayon::join(
                || c1.iter_mut().for_each(|op| op.run(Par::Seq)),
                || c2.iter_mut().for_each(|op| op.run(Par::Seq)),
            );
        } else {
            c1.iter_mut()
                .chain(c2.iter_mut())
                .for_each(|op| op.run(Par::Seq));
        }
    }
}
