//! Command-line arguments shared by `terl bench sac`/`tep` (services/cli) and this crate's
//! examples (`sac_bench`, `tep_bench`), so both parse the same flags with the same defaults.

use clap::Args;

use crate::sac::SacBenchConfig;
use crate::tep::TepBenchConfig;

/// Arguments that cannot describe a benchmark run (a zero thread count, a non-positive
/// duration, ...). The message names the flag.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct ArgsError(pub String);

fn ensure(ok: bool, message: &str) -> Result<(), ArgsError> {
    if ok {
        Ok(())
    } else {
        Err(ArgsError(message.to_owned()))
    }
}

/// Longest benchmark accepted, in seconds (about 116 days; `Duration::from_secs_f64` panics
/// near 1.8e19 s).
pub const MAX_SECONDS: f64 = 1e7;

fn positive_seconds(seconds: f64) -> Result<(), ArgsError> {
    ensure(
        seconds > 0.0 && seconds <= MAX_SECONDS,
        "--seconds must be in (0, 1e7]",
    )
}

/// Update threads above this are refused (a benchmark of thousands of threads on a few cores
/// measures the scheduler, and never finishes).
pub const MAX_THREADS: usize = 256;

fn threads(threads: usize) -> Result<(), ArgsError> {
    ensure(
        (1..=MAX_THREADS).contains(&threads),
        "--threads must be between 1 and 256",
    )
}

/// Widest layer (input, output or hidden) and most tasks the benchmarks build.
pub const MAX_WIDTH: u64 = 16_384;
/// Deepest network (hidden layers) the benchmarks build.
pub const MAX_LAYERS: u64 = 64;
/// Largest minibatch (rows), as a run file's `batch_size`.
pub const MAX_BATCH: u64 = 65_536;

/// A count flag in `1..=max` (clap refuses the rest with the flag named, exit code 2).
fn count(max: u64) -> clap::builder::RangedU64ValueParser<usize> {
    clap::builder::RangedU64ValueParser::<usize>::new().range(1..=max)
}

/// `--seconds` as clap parses it: a number that [`positive_seconds`] accepts.
fn parse_seconds(text: &str) -> Result<f64, String> {
    let v: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    positive_seconds(v).map(|()| v).map_err(|e| e.0)
}

fn layers(layers: usize, hidden: usize) -> Result<(), ArgsError> {
    ensure(layers > 0, "--layers must be at least 1")?;
    ensure(hidden > 0, "--hidden must be at least 1")
}

/// Flags of the SAC update benchmark (`terl bench sac`); see [`SacBenchConfig`].
#[derive(Debug, Clone, PartialEq, Args)]
pub struct SacArgs {
    /// Policy input width: observation plus one-hot task id (39 + 10 for MT10).
    #[arg(long, value_parser = count(MAX_WIDTH), default_value_t = 49)]
    pub obs_dim: usize,
    /// Action width (4 in Meta-World).
    #[arg(long, value_parser = count(MAX_WIDTH), default_value_t = 4)]
    pub act_dim: usize,
    /// Width of every hidden layer.
    #[arg(long, value_parser = count(MAX_WIDTH), default_value_t = 400)]
    pub hidden: usize,
    /// Number of hidden layers.
    #[arg(long, value_parser = count(MAX_LAYERS), default_value_t = 3)]
    pub layers: usize,
    /// Minibatch rows per update.
    #[arg(long, value_parser = count(MAX_BATCH), default_value_t = 1280)]
    pub batch: usize,
    /// Threads of the update's GEMMs (1 to 256).
    #[arg(long, value_parser = count(MAX_THREADS as u64), default_value_t = 2)]
    pub threads: usize,
    /// Seconds of timed updates (the GEMM and inference measurements add about half of that).
    #[arg(long, value_parser = parse_seconds, default_value_t = 5.0)]
    pub seconds: f64,
    /// Tasks in the one-hot part of obs-dim.
    #[arg(long, value_parser = count(MAX_WIDTH), default_value_t = 10)]
    pub num_tasks: usize,
    /// Print the report as JSON (the only format: the report is JSON either way).
    #[arg(long)]
    pub json: bool,
}

impl SacArgs {
    /// The benchmark configuration of these flags.
    ///
    /// # Errors
    /// [`ArgsError`] for a non-positive or non-finite `--seconds`, `--threads` outside
    /// `1..=MAX_THREADS`, `--layers 0`, `--hidden 0`, or a `--num-tasks` not smaller than
    /// `--obs-dim`.
    pub fn config(&self) -> Result<SacBenchConfig, ArgsError> {
        positive_seconds(self.seconds)?;
        threads(self.threads)?;
        layers(self.layers, self.hidden)?;
        ensure(
            self.num_tasks < self.obs_dim,
            "--num-tasks must be smaller than --obs-dim (it is part of it)",
        )?;
        Ok(SacBenchConfig {
            obs_dim: self.obs_dim,
            act_dim: self.act_dim,
            hidden: self.hidden,
            layers: self.layers,
            batch: self.batch,
            threads: self.threads,
            seconds: self.seconds,
            num_tasks: self.num_tasks,
        })
    }
}

/// Flags of the TEP update measurement (`terl bench tep` adds the guidance flags); see
/// [`TepBenchConfig`]. Observation and action widths are Meta-World's unless a caller sets
/// them ([`TepUpdateArgs::config`]).
#[derive(Debug, Clone, PartialEq, Args)]
pub struct TepUpdateArgs {
    /// Minibatch rows per TEP update (at least 1).
    #[arg(long, value_parser = count(MAX_BATCH), default_value_t = 1024)]
    pub batch: usize,
    /// Threads of the update's GEMMs (1 to 256).
    #[arg(long, value_parser = count(MAX_THREADS as u64), default_value_t = 2)]
    pub threads: usize,
    /// Seconds of timed updates, and of each guidance variant.
    #[arg(long, value_parser = parse_seconds, default_value_t = 5.0)]
    pub seconds: f64,
    /// Width of every hidden layer of F and AN.
    #[arg(long, value_parser = count(MAX_WIDTH), default_value_t = 512)]
    pub hidden: usize,
    /// Number of hidden layers of F and AN.
    #[arg(long, value_parser = count(MAX_LAYERS), default_value_t = 3)]
    pub layers: usize,
}

impl TepUpdateArgs {
    /// The benchmark configuration of these flags for observations of `obs_dim` and actions of
    /// `act_dim` values (39 and 4 in Meta-World).
    ///
    /// # Errors
    /// [`ArgsError`] for a non-positive or non-finite `--seconds`, `--threads` outside
    /// `1..=MAX_THREADS`, `--layers 0`, `--hidden 0` or `--batch 0`.
    pub fn config(&self, obs_dim: usize, act_dim: usize) -> Result<TepBenchConfig, ArgsError> {
        positive_seconds(self.seconds)?;
        threads(self.threads)?;
        layers(self.layers, self.hidden)?;
        ensure(self.batch > 0, "--batch must be at least 1")?;
        Ok(TepBenchConfig {
            obs_dim,
            act_dim,
            hidden: self.hidden,
            layers: self.layers,
            batch: self.batch,
            threads: self.threads,
            seconds: self.seconds,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Sac {
        #[command(flatten)]
        args: SacArgs,
    }

    #[derive(Debug, Parser)]
    struct Tep {
        #[command(flatten)]
        args: TepUpdateArgs,
    }

    #[test]
    fn defaults_are_the_benchmarks_defaults() {
        let sac = Sac::parse_from(["sac"]).args.config().unwrap();
        assert_eq!(sac, SacBenchConfig::default());
        let tep = Tep::parse_from(["tep"]).args.config(39, 4).unwrap();
        assert_eq!(tep, TepBenchConfig::default());
    }

    #[test]
    fn flags_set_the_config() {
        let sac = Sac::parse_from([
            "sac",
            "--hidden",
            "256",
            "--layers",
            "2",
            "--batch",
            "256",
            "--threads",
            "1",
            "--seconds",
            "0.5",
            "--obs-dim",
            "41",
            "--num-tasks",
            "2",
            "--act-dim",
            "3",
        ])
        .args
        .config()
        .unwrap();
        assert_eq!(
            sac,
            SacBenchConfig {
                obs_dim: 41,
                act_dim: 3,
                hidden: 256,
                layers: 2,
                batch: 256,
                threads: 1,
                seconds: 0.5,
                num_tasks: 2,
            }
        );
        let tep = Tep::parse_from(["tep", "--batch", "64", "--threads", "1", "--seconds", "2"])
            .args
            .config(6, 2)
            .unwrap();
        assert_eq!((tep.batch, tep.threads, tep.seconds), (64, 1, 2.0));
        assert_eq!((tep.obs_dim, tep.act_dim), (6, 2));
    }

    #[test]
    fn nonsense_is_refused_with_the_flag_named() {
        let sac = |extra: &[&str]| {
            // Refused by clap while parsing (a range) or by `config` (a relation).
            let argv = ["sac"].iter().chain(extra).copied();
            match Sac::try_parse_from(argv) {
                Err(e) => e.to_string(),
                Ok(s) => s.args.config().unwrap_err().0,
            }
        };
        assert!(sac(&["--seconds", "0"]).contains("--seconds"));
        assert!(sac(&["--seconds", "inf"]).contains("--seconds"));
        assert!(sac(&["--threads", "0"]).contains("--threads"));
        assert!(sac(&["--threads", "257"]).contains("--threads"));
        assert!(sac(&["--layers", "0"]).contains("--layers"));
        assert!(sac(&["--hidden", "0"]).contains("--hidden"));
        assert!(sac(&["--num-tasks", "49"]).contains("--num-tasks"));
        assert!(sac(&["--hidden", "18446744073709551615"]).contains("--hidden"));
        assert!(sac(&["--batch", "1e9"]).contains("--batch"));
        let tep = |extra: &[&str]| {
            let argv = ["tep"].iter().chain(extra).copied();
            match Tep::try_parse_from(argv) {
                Err(e) => e.to_string(),
                Ok(t) => t.args.config(39, 4).unwrap_err().0,
            }
        };
        assert!(tep(&["--seconds=-1"]).contains("--seconds"));
        assert!(tep(&["--threads", "0"]).contains("--threads"));
        assert!(tep(&["--batch", "0"]).contains("--batch"));
        assert!(tep(&["--layers", "0"]).contains("--layers"));
        assert!(tep(&["--threads", "1000"]).contains("--threads"));
        // Unknown flags and missing values are clap's errors, not silently ignored.
        assert!(Sac::try_parse_from(["sac", "--hiden", "3"]).is_err());
        assert!(Tep::try_parse_from(["tep", "--batch"]).is_err());
    }
}
