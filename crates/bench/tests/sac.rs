//! The SAC update benchmark runs end to end and counts FLOPs consistently (no timing floors:
//! the numbers are the benchmark's output).

#[test]
fn the_benchmark_runs_and_counts_flops_consistently() {
    let cfg = terl_bench::sac::SacBenchConfig {
        obs_dim: 12,
        hidden: 32,
        layers: 2,
        batch: 64,
        threads: 1,
        seconds: 0.2,
        num_tasks: 3,
        ..Default::default()
    };
    let report = terl_bench::sac::sac_bench(&cfg).unwrap();
    assert!(report.updates >= 3 && report.updates_per_s > 0.0);
    assert!(report.gemm_gflops > 0.0 && report.inference_batch8_us > 0.0);
    let sac: terl_rl::Sac<f32> = terl_rl::Sac::new(cfg.sac_config().unwrap()).unwrap();
    assert_eq!(report.flops_per_update, sac.update_flops(cfg.batch));
    let json = serde_json::to_string(&report).unwrap();
    assert!(json.contains("\"updates_per_s\""));
}
