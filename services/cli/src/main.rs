//! `terl`: the command line of the terl system (the parser and subcommands are in the library).

#![warn(missing_docs)]

use clap::Parser;
use terl_cli::Cli;

fn main() -> std::process::ExitCode {
    end_quietly_on_a_closed_stdout();
    terl_runtime::init_tracing_with_default("warn");
    let cli = Cli::parse();
    match terl_cli::run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", chain(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes joined by ": ", like `{:#}`, but a cause whose text its parent
/// already ends with (a message that quotes its source, such as an OS error) is said once.
fn chain(e: &anyhow::Error) -> String {
    let mut text = String::new();
    let mut last = String::new();
    for cause in e.chain() {
        let message = cause.to_string();
        if !text.is_empty() {
            if last.ends_with(&message) {
                continue;
            }
            text.push_str(": ");
        }
        text.push_str(&message);
        last = message;
    }
    text
}

/// A closed pipe on stdout (`terl … | head`) ends the process as it does any Unix tool (killed
/// by SIGPIPE, nothing on stderr) instead of a panic in `println!` (exit 101).
///
/// SIGPIPE itself stays ignored (Rust's default) for the whole run: a socket whose peer went
/// away must be an error the command reports (a TLS server closing a plaintext client's
/// connection), and Rust's vectored socket writes (`writev`, used by hyper) do not pass
/// `MSG_NOSIGNAL`, so with SIGPIPE's default action such a peer killed `terl` without a word.
/// Only when printing to stdout fails with a broken pipe does the process restore the default
/// action and raise SIGPIPE.
fn end_quietly_on_a_closed_stdout() {
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let message = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if message.starts_with("failed printing to stdout") && message.contains("Broken pipe") {
            sigpipe::reset();
            let _ = nix::sys::signal::raise(nix::sys::signal::Signal::SIGPIPE);
        }
        default_hook(info);
    }));
}
