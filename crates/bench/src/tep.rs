//! TEP update throughput against the machine's GEMM rate, and small-batch planner latency.
//!
//! [`tep_bench`] times full [`Tep::update`]s (F loss, AN loss, both Adam steps, both Polyak
//! targets) on a fixed random batch, counts the FLOPs of the update's GEMMs
//! ([`Tep::update_flops`]), and in the same run times the same GEMM shapes alone, issued in the
//! update's order with the update's threads. `achieved_gflops / gemm_gflops` is the fraction of
//! the update spent in useful GEMM work. `deploy/bench/tep_torch.py` prints the same fields for
//! PyTorch.
//!
//! The actor-side cost of guidance needs real environments and lives in the CLI (`terl bench
//! tep`), which fills [`TepBenchReport::guidance`] with a [`GuidanceOverhead`].

use crate::sac::{alternate, square_gemm_gflops, GemmKind, GemmOp};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::time::Instant;
use terl_rl::{Planner, SacError, Tep, TepBatch, TepConfig};

/// What to measure: the planner's networks (F: `2·obs_dim + act_dim → hidden^layers → 1`, AN:
/// `2·obs_dim → hidden^layers → act_dim`), the batch and the update's threads.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TepBenchConfig {
    /// Observation width of `s` and `s'` (39 in Meta-World).
    pub obs_dim: usize,
    /// Action width (4 in Meta-World).
    pub act_dim: usize,
    /// Width of every hidden layer (F and AN).
    pub hidden: usize,
    /// Number of hidden layers.
    pub layers: usize,
    /// Minibatch rows per update.
    pub batch: usize,
    /// Threads of the update's GEMMs ([`TepConfig::threads`]).
    pub threads: usize,
    /// Seconds of timed updates (the GEMM and latency measurements add about half of that).
    pub seconds: f64,
}

impl Default for TepBenchConfig {
    fn default() -> Self {
        Self {
            obs_dim: 39,
            act_dim: 4,
            hidden: 512,
            layers: 3,
            batch: 1024,
            threads: 2,
            seconds: 5.0,
        }
    }
}

impl TepBenchConfig {
    /// The planner configuration this benchmark runs (validated).
    pub fn tep_config(&self) -> Result<TepConfig, SacError> {
        if self.hidden == 0 || self.layers == 0 {
            return Err(SacError::Config(
                "tep bench hidden and layers must be positive".into(),
            ));
        }
        if !(self.seconds > 0.0 && self.seconds.is_finite()) {
            return Err(SacError::Config(format!(
                "tep bench seconds {} must be positive and finite",
                self.seconds
            )));
        }
        let cfg = TepConfig {
            obs_dim: self.obs_dim,
            act_dim: self.act_dim,
            f_hidden: vec![self.hidden; self.layers],
            an_hidden: vec![self.hidden; self.layers],
            batch_size: self.batch,
            threads: self.threads,
            ..Default::default()
        };
        cfg.validate()?;
        Ok(cfg)
    }
}

/// Actor step time with and without guidance (measured by the CLI on real environments).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GuidanceOverhead {
    /// Environments stepped together by the actor.
    pub num_envs: usize,
    /// Meta-World v3 names of the actor's tasks (the policy's one-hot spans all of them).
    pub tasks: Vec<String>,
    /// Policy hidden widths.
    pub policy_hidden: Vec<usize>,
    /// Alternating rounds (with / without) the medians are taken over.
    pub rounds: usize,
    /// Median time of one actor step (`Policy::act` + `VecEnv::step` for all envs), in µs.
    pub step_us_without: f64,
    /// The same with guidance as the actor runs it ([`terl_rl::guidance::BatchGuidance`]) at the
    /// start of guidance (`N = 0`, `σ^N = 1`: F on every row, AN on the guided ones).
    pub step_us_with: f64,
    /// Median over rounds of `(with − without) / without`.
    pub guidance_overhead_ratio: f64,
    /// Fraction of steps that executed the planner's action (random weights: not meaningful
    /// for learning, only a check that the path runs).
    pub guided_fraction: f64,
    /// Finished episodes `N` of the decayed variant.
    pub decayed_episodes: u64,
    /// `σ^N` of the decayed variant.
    pub decayed_probability: f64,
    /// Median step time with guidance after `decayed_episodes` episodes: F only where a
    /// decision can use it (about `2σ^N` of the rows).
    pub step_us_with_decayed: f64,
    /// Median over rounds of `(with_decayed − without) / without`.
    pub guidance_overhead_ratio_decayed: f64,
    /// `guided_fraction` of the decayed variant.
    pub guided_fraction_decayed: f64,
}

/// Measured numbers (the same fields as the PyTorch script's JSON, plus `guidance`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TepBenchReport {
    /// Which implementation produced the numbers: `"terl-rust-faer"` here,
    /// `"pytorch-<version>-cpu"` from `deploy/bench/tep_torch.py`.
    pub implementation: String,
    /// SIMD level the GEMMs and the small-batch kernels ran with (`avx512`, `avx2`,
    /// `portable`; chosen at run time, [`terl_nn::InstructionSet::detect`]).
    #[serde(default)]
    pub instruction_set: String,
    /// What was measured.
    pub config: TepBenchConfig,
    /// TEP updates timed.
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
    /// Mean latency of `Planner::reach` + `Planner::actions` on 8 rows (one thread), in µs.
    pub planner_batch8_us: f64,
    /// Actor-side guidance cost, when measured (`terl bench tep`).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub guidance: Option<GuidanceOverhead>,
}

/// A batch of `cfg.batch_size` random rows, values in `[-1, 1)`.
pub fn random_tep_batch(cfg: &TepConfig, seed: u64) -> TepBatch {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (od, ad) = (cfg.obs_dim, cfg.act_dim);
    let mut batch = TepBatch::with_capacity(cfg.batch_size, od, ad);
    let mut draw = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect() };
    for i in 0..cfg.batch_size {
        let (s, a, s1, g) = (draw(od), draw(ad), draw(od), draw(od));
        batch.push(&s, &a, &s1, &g, 2 + (i % 50) as u32);
    }
    batch
}

/// The GEMMs of one TEP update in the order `Tep::update` issues them (see its module docs).
fn update_gemms(cfg: &TepConfig) -> Vec<GemmOp> {
    let b = cfg.batch_size;
    let sizes = |input: usize, hidden: &[usize], output: usize| {
        let mut s = vec![input];
        s.extend_from_slice(hidden);
        s.push(output);
        s
    };
    let f = sizes(cfg.f_input(), &cfg.f_hidden, 1);
    let an = sizes(cfg.an_input(), &cfg.an_hidden, cfg.act_dim);
    let mut ops = Vec::new();
    let forward = |ops: &mut Vec<GemmOp>, s: &[usize], rows: usize| {
        for w in s.windows(2) {
            ops.push(GemmOp::new(GemmKind::Forward, rows, w[0], w[1]));
        }
    };
    // Backward over `rows`: weight gradients if `params`, input gradients of the hidden layers,
    // and `first_cols` columns of input gradient at layer 0 (none if 0).
    let backward =
        |ops: &mut Vec<GemmOp>, s: &[usize], rows: usize, params: bool, first_cols: usize| {
            for (l, w) in s.windows(2).enumerate().rev() {
                if params {
                    ops.push(GemmOp::new(GemmKind::WeightGrad, rows, w[0], w[1]));
                }
                let cols = if l > 0 { w[0] } else { first_cols };
                if cols > 0 {
                    ops.push(GemmOp::new(GemmKind::InputGrad { cols }, rows, w[0], w[1]));
                }
            }
        };
    forward(&mut ops, &an, b); // ÃN
    forward(&mut ops, &f, b); // F̃
    forward(&mut ops, &an, b); // AN
    forward(&mut ops, &f, 4 * b); // the four stacked F evaluations
    backward(&mut ops, &f, 3 * b, true, 0); // F loss
    backward(&mut ops, &f, b, false, cfg.act_dim); // AN loss through F's action input
    backward(&mut ops, &an, b, true, 0); // AN parameters
    ops
}

/// Runs the benchmark (without the guidance part; see [`GuidanceOverhead`]).
pub fn tep_bench(config: &TepBenchConfig) -> Result<TepBenchReport, SacError> {
    let cfg = config.tep_config()?;
    let mut tep: Tep<f32> = Tep::new(cfg.clone())?;
    let batch = random_tep_batch(&cfg, 0);

    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(config.threads)
        .build()
        .map_err(|e| SacError::Config(format!("cannot start {} threads: {e}", config.threads)))?;
    let mut gemms = update_gemms(&cfg);
    let flops = tep.update_flops(cfg.batch_size);
    let plan_flops: u64 = gemms.iter().map(GemmOp::flops).sum();
    assert_eq!(plan_flops, flops, "the GEMM plan must mirror the update");
    let par = terl_nn::par_for_threads(config.threads);
    let mut run_gemms = || gemms.iter_mut().for_each(|op| op.run(par));
    for _ in 0..2 {
        tep.update(&batch)?;
    }
    pool.install(&mut run_gemms);

    let rates = alternate(
        config.seconds,
        &pool,
        || tep.update(&batch).map(drop),
        run_gemms,
    )?;
    let (updates, updates_per_s) = (rates.updates, rates.updates_per_s);
    let achieved_gflops = flops as f64 * updates_per_s / 1e9;
    let gemm_gflops = flops as f64 * rates.gemm_runs_per_s / 1e9;
    let short = (config.seconds / 10.0).clamp(0.2, 1.0);
    let gemm_square_gflops = pool.install(|| square_gemm_gflops(1024, config.threads, short));
    let mut planner = tep.planner(8);
    let planner_batch8_us = planner_latency_us(&mut planner, &cfg, 8, short);

    Ok(TepBenchReport {
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
        planner_batch8_us,
        guidance: None,
    })
}

/// Mean time of `reach` + `actions` on `rows` random rows (the planner's own thread).
fn planner_latency_us(planner: &mut Planner, cfg: &TepConfig, rows: usize, seconds: f64) -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let (od, ad) = (cfg.obs_dim, cfg.act_dim);
    let mut draw = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect() };
    let (obs, goals, actions) = (draw(rows * od), draw(rows * od), draw(rows * ad));
    let (mut f, mut an) = (vec![0.0; rows], vec![0.0; rows * ad]);
    let mut call = || {
        planner.reach(&obs, &goals, &actions, &mut f);
        planner.actions(&obs, &goals, &mut an);
    };
    for _ in 0..10 {
        call();
    }
    let start = Instant::now();
    let mut calls = 0u64;
    while start.elapsed().as_secs_f64() < seconds || calls < 10 {
        for _ in 0..10 {
            call();
        }
        calls += 10;
    }
    start.elapsed().as_secs_f64() * 1e6 / calls as f64
}

/// Median of `v` (NaN if empty).
pub fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> TepBenchConfig {
        TepBenchConfig {
            obs_dim: 6,
            act_dim: 2,
            hidden: 16,
            layers: 2,
            batch: 32,
            threads: 1,
            seconds: 0.1,
        }
    }

    #[test]
    fn invalid_arguments_are_rejected() {
        for bad in [
            TepBenchConfig {
                batch: 0,
                ..small()
            },
            TepBenchConfig {
                threads: 0,
                ..small()
            },
            TepBenchConfig {
                hidden: 0,
                ..small()
            },
            TepBenchConfig {
                layers: 0,
                ..small()
            },
            TepBenchConfig {
                seconds: 0.0,
                ..small()
            },
            TepBenchConfig {
                seconds: f64::NAN,
                ..small()
            },
            TepBenchConfig {
                obs_dim: 0,
                ..small()
            },
        ] {
            assert!(
                matches!(tep_bench(&bad), Err(SacError::Config(_))),
                "{bad:?} accepted"
            );
        }
    }

    #[test]
    fn the_gemm_plan_counts_the_update_flops() {
        for threads in [1, 2] {
            let cfg = TepBenchConfig {
                threads,
                ..TepBenchConfig::default()
            }
            .tep_config()
            .unwrap();
            let tep: Tep<f32> = Tep::new(cfg.clone()).unwrap();
            let plan: u64 = update_gemms(&cfg).iter().map(GemmOp::flops).sum();
            assert_eq!(plan, tep.update_flops(cfg.batch_size));
        }
    }

    #[test]
    fn a_short_run_reports_consistent_numbers() {
        for threads in [1, 2] {
            let cfg = TepBenchConfig { threads, ..small() };
            let r = tep_bench(&cfg).unwrap();
            assert!(r.updates >= 3 && r.updates_per_s > 0.0);
            assert!((r.update_ms - 1e3 / r.updates_per_s).abs() < 1e-9 * r.update_ms.max(1.0));
            let tep: Tep<f32> = Tep::new(cfg.tep_config().unwrap()).unwrap();
            assert_eq!(r.flops_per_update, tep.update_flops(cfg.batch));
            let achieved = r.flops_per_update as f64 * r.updates_per_s / 1e9;
            assert!((r.achieved_gflops - achieved).abs() <= 1e-9 * achieved);
            assert!(r.gemm_gflops > 0.0 && r.gemm_square_gflops > 0.0);
            assert!((r.gemm_efficiency - r.achieved_gflops / r.gemm_gflops).abs() < 1e-12);
            assert!(r.planner_batch8_us > 0.0 && r.guidance.is_none());
            let json = serde_json::to_string(&r).unwrap();
            assert!(json.contains("\"updates_per_s\"") && !json.contains("guidance"));
            let back: TepBenchReport = serde_json::from_str(&json).unwrap();
            assert_eq!(back.config, cfg);
        }
    }

    #[test]
    fn median_of_odd_even_and_empty() {
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 2.0, 3.0]), 2.5);
        assert!(median(vec![]).is_nan());
    }
}
