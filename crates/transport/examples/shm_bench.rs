//! Prints `shm_throughput` reports as JSON: `cargo run --release -p terl-transport
//! --example shm_bench -- [PUBLISHERS] [SECONDS]` (default: 1 and 3 publishers, 3 s).

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let seconds: f64 = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(3.0);
    let counts: Vec<usize> = match args.first() {
        Some(n) => vec![n.parse()?],
        None => vec![1, 3],
    };
    for publishers in counts {
        let report = terl_transport::bench::shm_throughput(publishers, seconds)?;
        println!("{}", serde_json::to_string_pretty(&report)?);
    }
    Ok(())
}
