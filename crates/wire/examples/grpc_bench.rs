//! Runs the gRPC benchmarks and prints their JSON reports:
//! `cargo run --release -p terl-wire --example grpc_bench -- [stream SECONDS] [broadcast SUBSCRIBERS VERSIONS]`
//! (no arguments: both, 3 s of streaming and 8 subscribers × 50 versions).

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: f64| args.get(i).and_then(|a| a.parse().ok()).unwrap_or(default);
    let which = args.first().map(String::as_str).unwrap_or("all");
    if which == "stream" || which == "all" {
        let report = terl_wire::bench::grpc_transition_stream(arg(1, 3.0))?;
        println!("{}", serde_json::to_string_pretty(&report)?);
    }
    if which == "broadcast" || which == "all" {
        let report =
            terl_wire::bench::broadcast_latency(arg(1, 8.0) as usize, arg(2, 50.0) as u64)?;
        println!("{}", serde_json::to_string_pretty(&report)?);
    }
    Ok(())
}
