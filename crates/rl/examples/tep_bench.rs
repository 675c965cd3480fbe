//! `cargo run --release -p terl-rl --example tep_bench -- --batch 1024 --threads 2 --seconds 5`
//! prints one JSON object (the CLI's `terl bench tep` calls the same library function and adds
//! the actor-side guidance overhead, which needs MuJoCo).

use terl_rl::bench_tep::{tep_bench, TepBenchConfig};

fn main() {
    let mut cfg = TepBenchConfig::default();
    let args: Vec<String> = std::env::args().skip(1).collect();
    for pair in args.chunks(2) {
        let [flag, value] = pair else {
            eprintln!("flags take one value each");
            std::process::exit(2);
        };
        let parse = |v: &str| {
            v.parse::<usize>()
                .unwrap_or_else(|_| panic!("{flag}: not a number: {v}"))
        };
        match flag.as_str() {
            "--obs-dim" => cfg.obs_dim = parse(value),
            "--act-dim" => cfg.act_dim = parse(value),
            "--hidden" => cfg.hidden = parse(value),
            "--layers" => cfg.layers = parse(value),
            "--batch" => cfg.batch = parse(value),
            "--threads" => cfg.threads = parse(value),
            "--seconds" => cfg.seconds = value.parse().expect("--seconds: not a number"),
            other => {
                eprintln!("unknown flag {other}");
                std::process::exit(2);
            }
        }
    }
    match tep_bench(&cfg) {
        Ok(report) => println!(
            "{}",
            serde_json::to_string(&report).expect("report serialises")
        ),
        Err(e) => {
            eprintln!("bench failed: {e}");
            std::process::exit(1);
        }
    }
}
