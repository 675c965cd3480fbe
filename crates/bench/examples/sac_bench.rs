//! `cargo run --release -p terl-bench --example sac_bench -- --hidden 400 --layers 3 --batch 1280
//! --threads 2 --seconds 5` prints one JSON object on one line (`deploy/bench/compare_sac.sh`
//! collects them). Same flags as `terl bench sac` ([`terl_bench::args::SacArgs`]), which prints
//! the same report indented.

use clap::Parser;
use terl_bench::args::SacArgs;
use terl_bench::sac::sac_bench;

/// SAC update throughput, one JSON line.
#[derive(Debug, Parser)]
#[command(name = "sac_bench")]
struct Cli {
    #[command(flatten)]
    args: SacArgs,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let config = Cli::parse().args.config()?;
    let report = sac_bench(&config)?;
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}
