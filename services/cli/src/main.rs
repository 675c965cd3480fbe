//! `terl`: the command line of the terl system (the parser and subcommands are in the library).

#![warn(missing_docs)]

use clap::Parser;
use terl_cli::Cli;

fn main() -> std::process::ExitCode {
    // A closed pipe (`terl … | head`) ends the process as it does any Unix tool, instead of a
    // panic in `println!` (exit 101). Sockets are unaffected: Rust sends with MSG_NOSIGNAL.
    sigpipe::reset();
    terl_runtime::init_tracing_with_default("warn");
    let cli = Cli::parse();
    match terl_cli::run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
