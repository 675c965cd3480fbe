//! Ranges of the command-line flags that count, size or seed something, checked by clap while
//! it parses (`value_parser = flags::count(..)`): a value outside its range exits with code 2
//! and an error that names the flag and the range, before anything runs. Durations in seconds
//! use [`crate::parse_seconds`]. The run file's keys have their own ranges in
//! [`crate::RunConfig::load`]; these are the same where a flag and a key mean the same thing.

use clap::builder::RangedU64ValueParser;

/// Most actor processes one run takes (`--num-actors` of the services): each sizes a
/// publisher slot of every stream. `terl cluster up --actors` is bounded further by the
/// machine's cores.
pub const MAX_ACTORS: u64 = 1024;
/// Largest process id Linux hands out (`PID_MAX_LIMIT`, 2^22).
pub const MAX_PID: u64 = 1 << 22;
/// Most worker threads a flag asks for (evaluation, planner training, benchmarks).
pub const MAX_THREADS: u64 = 256;
/// Most environments one benchmark or probe steps at once (as `num_envs` in a run file).
pub const MAX_ENVS: u64 = crate::config::MAX_NUM_ENVS as u64;
/// Most episodes per task a command runs or writes (as the run file's episode counts).
pub const MAX_EPISODES: u64 = crate::config::MAX_EPISODE_COUNT as u64;
/// Most publishers or subscribers a transport benchmark opens.
pub const MAX_BENCH_PEERS: u64 = 256;
/// Most weight versions a broadcast benchmark publishes.
pub const MAX_VERSIONS: u64 = 1_000_000;
/// Most trajectories a planner evaluation holds out.
pub const MAX_HOLD_OUT: u64 = 1_000_000;
/// Most (state, goal) pairs a planner evaluation draws per trajectory.
pub const MAX_PAIRS: u64 = 1_000_000;
/// Most updates or env steps a command runs (10^12: years of this machine's rate).
pub const MAX_STEPS: u64 = 1_000_000_000_000;

/// A count in `1..=max`, as the flag's own integer type (`usize`, `u64`, `u32`).
pub fn count<T>(max: u64) -> RangedU64ValueParser<T>
where
    T: TryFrom<u64> + Clone + Send + Sync + 'static,
    <T as TryFrom<u64>>::Error: std::error::Error + Send + Sync + 'static,
{
    RangedU64ValueParser::<T>::new().range(1..=max)
}

/// A count in `0..=max` where 0 means none or off (the flag's help says which).
pub fn count_or_zero<T>(max: u64) -> RangedU64ValueParser<T>
where
    T: TryFrom<u64> + Clone + Send + Sync + 'static,
    <T as TryFrom<u64>>::Error: std::error::Error + Send + Sync + 'static,
{
    RangedU64ValueParser::<T>::new().range(0..=max)
}

/// Largest tolerance or noise scale a flag takes.
pub const MAX_SCALE: f64 = 1e6;

/// A tolerance or noise scale: finite and in `[0, MAX_SCALE]` (not-a-number would make every
/// comparison false, so a check with it could never fail).
pub fn parse_scale(text: &str) -> Result<f64, String> {
    let v: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number"))?;
    if v.is_finite() && (0.0..=MAX_SCALE).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{text} is not in [0, {MAX_SCALE:e}]"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[arg(long, value_parser = count::<usize>(8), default_value_t = 2)]
        envs: usize,
        #[arg(long, value_parser = count_or_zero::<u32>(500), default_value_t = 0)]
        after: u32,
        #[arg(long, value_parser = parse_scale, default_value_t = 0.1)]
        tol: f64,
    }

    fn parse(args: &[&str]) -> Result<Cli, clap::Error> {
        Cli::try_parse_from(std::iter::once("t").chain(args.iter().copied()))
    }

    #[test]
    fn values_in_range_parse_and_the_rest_name_the_flag() {
        let c = parse(&["--envs", "8", "--after", "0", "--tol", "0"]).unwrap();
        assert_eq!((c.envs, c.after, c.tol), (8, 0, 0.0));
        for (flag, v) in [
            ("--envs", "0"),
            ("--envs", "9"),
            ("--envs", "18446744073709551615"),
            ("--envs", "18446744073709551616"),
            ("--envs", "-1"),
            ("--envs", "1e3"),
            ("--after", "501"),
            ("--tol", "nan"),
            ("--tol", "inf"),
            ("--tol", "-0.5"),
            ("--tol", "1e300"),
        ] {
            let e = parse(&[&format!("{flag}={v}")]).unwrap_err();
            assert_eq!(e.exit_code(), 2);
            assert!(e.to_string().contains(flag), "{flag} {v}: {e}");
        }
    }
}
