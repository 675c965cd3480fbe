//! The gRPC benchmarks run end to end and produce sane, serialisable reports (no timing floors:
//! the numbers are the benchmark's output).

use terl_bench::grpc::{broadcast_latency_async, grpc_transition_stream_async};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn transition_stream_bench_counts_every_transition() {
    let report = grpc_transition_stream_async(0.5, 64).await.unwrap();
    println!("{}", serde_json::to_string_pretty(&report).unwrap());
    assert_eq!(report.malformed_batches, 0);
    assert_eq!(report.transitions, report.batches * 64);
    assert!(report.transitions_per_second > 1000.0, "{report:?}");
    assert_eq!(report.payload_bytes_per_transition, 348);
}

/// Every version reaches every subscriber and the report is complete. Latency is a benchmark
/// number (`terl bench broadcast`), not a test floor: it depends on the machine and its load.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn broadcast_reaches_eight_subscribers() {
    let report = broadcast_latency_async(8, 30).await.unwrap();
    println!("{}", serde_json::to_string_pretty(&report).unwrap());
    assert_eq!(report.samples, 8 * 30);
    assert_eq!(report.parameters, 344_008);
    assert_eq!(report.skipped, 0);
    assert!(report.latency_ms_p50 > 0.0 && report.latency_ms_p50 <= report.latency_ms_p95);
}
