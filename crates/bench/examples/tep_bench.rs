//! `cargo run --release -p terl-bench --example tep_bench -- --batch 1024 --threads 2 --seconds 5`
//! prints one JSON object on one line (`deploy/bench/compare_tep.sh` collects them): the update
//! part of `terl bench tep`, with its flags ([`terl_bench::args::TepUpdateArgs`]), on
//! Meta-World's widths. `terl bench tep` adds the actor-side guidance overhead, which needs
//! MuJoCo.

use clap::Parser;
use terl_bench::args::TepUpdateArgs;
use terl_bench::tep::tep_bench;

/// TEP update throughput, one JSON line.
#[derive(Debug, Parser)]
#[command(name = "tep_bench")]
struct Cli {
    #[command(flatten)]
    args: TepUpdateArgs,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let config = Cli::parse()
        .args
        .config(terl_sim::OBS_DIM, terl_sim::ACTION_DIM)?;
    let report = tep_bench(&config)?;
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}
