//! Every flag of `terl`, `terl-learner`, `terl-actor` and `terl-selector` that takes a number,
//! found by walking the real clap command trees (a new flag is covered without being listed
//! here), parsed with extreme values (±0, subnormals, ±1e300, ±inf, NaN, u64::MAX and one
//! more, negatives, empty) and with random ones (proptest): clap never panics, a refused value
//! is refused with the flag named (exit code 2), and an accepted one is bounded — finite, not
//! negative and at most 10^12 — except seeds and process ids, whose whole range is meaningful.
//! A value outside a flag's range is refused while clap parses, before anything runs
//! (`terl_runtime::flags`).

use std::any::TypeId;
use std::panic::AssertUnwindSafe;

use clap::CommandFactory;
use proptest::prelude::*;

/// One numeric flag: the command path to it (binary name, subcommands) and its long name.
#[derive(Debug, Clone)]
struct Flag {
    path: Vec<String>,
    long: String,
    command: clap::Command,
}

impl Flag {
    /// Seeds take any value of their type; `terl cluster up --restarts` and
    /// `--restart-backoff` saturate (a count beyond the type means "always restart", a
    /// backoff beyond it the longest backoff, 60 s), so no value of them is unbounded.
    fn full_range(&self) -> bool {
        self.long.contains("seed") || ["restarts", "restart-backoff"].contains(&self.long.as_str())
    }
}

fn numeric(t: &clap::builder::ValueParser) -> bool {
    let id = t.type_id();
    [
        TypeId::of::<u8>(),
        TypeId::of::<u16>(),
        TypeId::of::<u32>(),
        TypeId::of::<u64>(),
        TypeId::of::<usize>(),
        TypeId::of::<i32>(),
        TypeId::of::<i64>(),
        TypeId::of::<f32>(),
        TypeId::of::<f64>(),
    ]
    .into_iter()
    .any(|n| id == n)
}

fn walk(cmd: &clap::Command, path: &[String], root: &clap::Command, out: &mut Vec<Flag>) {
    for a in cmd.get_arguments() {
        let Some(long) = a.get_long() else { continue };
        if a.get_action().takes_values() && numeric(a.get_value_parser()) {
            out.push(Flag {
                path: path.to_vec(),
                long: long.to_string(),
                command: root.clone(),
            });
        }
    }
    for s in cmd.get_subcommands() {
        let mut p = path.to_vec();
        p.push(s.get_name().to_string());
        walk(s, &p, root, out);
    }
}

fn flags() -> Vec<Flag> {
    let mut out = vec![];
    for (name, cmd) in [
        ("terl", terl_cli::Cli::command()),
        ("terl-learner", terl_learner::args::Args::command()),
        ("terl-actor", terl_actor::args::Args::command()),
        ("terl-selector", terl_selector::args::Args::command()),
    ] {
        let cmd = cmd.name(name);
        walk(&cmd, &[name.to_string()], &cmd, &mut out);
    }
    out
}

/// Largest value an accepted numeric flag may hold (`terl_runtime::flags::MAX_STEPS`).
const BOUND: f64 = 1e12;

/// Parses `--flag=value` in the flag's command; panics (fails the test) if clap panics, if a
/// refusal does not name the flag, or if an accepted value is unbounded.
fn check(flag: &Flag, value: &str) {
    let mut argv = flag.path.clone();
    argv.push(format!("--{}={value}", flag.long));
    let cmd = flag.command.clone();
    let parsed = std::panic::catch_unwind(AssertUnwindSafe(|| cmd.try_get_matches_from(&argv)))
        .unwrap_or_else(|_| panic!("clap panicked on {argv:?}"));
    let refused = match &parsed {
        Ok(_) => false,
        Err(e) => matches!(
            e.kind(),
            clap::error::ErrorKind::ValueValidation | clap::error::ErrorKind::InvalidValue
        ),
    };
    if refused {
        let e = parsed.unwrap_err();
        assert_eq!(e.exit_code(), 2, "{argv:?}");
        let text = e.to_string();
        assert!(
            text.contains(&format!("--{}", flag.long)),
            "{argv:?} refused without naming the flag: {text}"
        );
        return;
    }
    // Accepted (or stopped later for another reason, such as a missing required argument:
    // the value itself passed).
    if flag.full_range() {
        return;
    }
    let v: f64 = value
        .trim()
        .parse()
        .unwrap_or_else(|_| panic!("{argv:?}: accepted, but {value:?} is not a number"));
    assert!(
        v.is_finite() && (0.0..=BOUND).contains(&v),
        "{argv:?}: {value} accepted, which is not a bounded value (want finite, in [0, {BOUND:e}])"
    );
}

const EXTREMES: &[&str] = &[
    "0",
    "-0",
    "0.0",
    "1",
    "5e-324",
    "2.2e-308",
    "1e300",
    "-1e300",
    "inf",
    "-inf",
    "infinity",
    "nan",
    "NaN",
    "18446744073709551615",
    "18446744073709551616",
    "9223372036854775807",
    "-9223372036854775808",
    "4294967296",
    "1e19",
    "-1",
    "",
    " ",
];

#[test]
fn every_numeric_flag_refuses_or_bounds_extreme_values_without_a_panic() {
    let flags = flags();
    // The walk finds the flags (a broken walk would pass vacuously).
    assert!(
        flags.len() >= 60,
        "only {} numeric flags found",
        flags.len()
    );
    eprintln!("{} numeric flags", flags.len());
    for long in [
        "num-actors",
        "threads",
        "episodes-per-task",
        "seconds",
        "timeout",
    ] {
        assert!(flags.iter().any(|f| f.long == long), "--{long} not found");
    }
    for flag in &flags {
        for value in EXTREMES {
            check(flag, value);
        }
    }
}

/// Numbers as a user or a script might write them.
fn number_text() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<u64>().prop_map(|v| v.to_string()),
        any::<i64>().prop_map(|v| v.to_string()),
        any::<f64>().prop_map(|v| v.to_string()),
        any::<f64>().prop_map(|v| format!("{v:e}")),
        any::<u128>().prop_map(|v| v.to_string()),
        (0u32..40).prop_map(|e| format!("1e{e}")),
        (0u64..100_000).prop_map(|v| v.to_string()),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 512,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]
    #[test]
    fn random_numbers_in_numeric_flags_are_refused_or_bounded(
        pick in any::<prop::sample::Index>(),
        value in number_text(),
    ) {
        let flags = flags();
        check(&flags[pick.index(flags.len())], &value);
    }
}
