//! `terl cluster up`: the local cluster's launcher. Starts one learner, one selector and N
//! actors (the service binaries next to `terl`), waits until the learner and the selector answer
//! `grpc.health.v1`, restarts a process that dies (the learner and selector with `--resume` on
//! the address they had), prints `terl status` every 5 s and, when it stops, one summary line:
//! why, the worst exit code of any process and the run folder.
//!
//! Files (read by `terl status`, `terl cluster down|clean`, deploy/soak.sh and the tests):
//! `RUNS/<id>/launcher.pid` (this process), `RUNS/<id>/pids` (`<role> <pid>` per line),
//! `RUNS/<id>/{learner,selector}.addr` (written by the services), `RUNS/<id>/cluster.txt`
//! (`key=value` lines: the start, resumes and restarts), `RUNS/.cluster.pid` and
//! `RUNS/.cluster.run` (the launcher started last). A lock per run id in
//! `$TMPDIR/terl-run-locks/<id>.lock` is held while the launcher lives.
//!
//! Exit codes: 0 when the learner finished its budget or `terl cluster down` stopped the run,
//! 1 when a process could not start or died too often, 2 for bad options, 128 + n on signal n
//! (SIGINT, SIGTERM). The services get `--parent-pid` and stop by themselves if the launcher
//! is killed.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Args;
use nix::fcntl::{Flock, FlockArg};
use tokio::signal::unix::{signal, Signal, SignalKind};

/// Written by `terl cluster down` into the run folder before it signals the launcher: the stop
/// was asked for, so the launcher exits 0.
pub(crate) const DOWN_MARKER: &str = "launcher.down";

/// A process that exits with an error this soon after its start is not restarted.
const MIN_UPTIME: Duration = Duration::from_secs(10);
/// How long a learner or selector may take to write its address, and then to answer health.
const START_LIMIT: Duration = Duration::from_secs(30);
/// Between two looks at the processes (and two `terl status` prints).
const TICK: Duration = Duration::from_secs(5);
/// The longest wait before a restart.
const MAX_BACKOFF_SECS: u64 = 60;
/// How long a stopping process may take after SIGTERM (the learner writes its final
/// checkpoint: ~11 MB at 3×256, well under a second) before the launcher sends SIGKILL.
const STOP_GRACE: Duration = Duration::from_secs(60);

/// The options of `deploy/local-cluster.sh` (see its header for the long version).
#[derive(Debug, Args)]
#[command(args_override_self = true)]
pub struct UpArgs {
    /// Run file (default deploy/configs/mt10.toml; quick checks: deploy/configs/cluster-smoke.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Actor processes (default: cores - 1, at least 1).
    #[arg(long, value_parser = actor_count)]
    pub actors: Option<usize>,
    /// Run id, 1 to 64 characters of A-Z a-z 0-9 . _ - (default: <config name>-<date>-<time>).
    #[arg(long, value_parser = run_id_arg)]
    pub run_id: Option<String>,
    /// With algorithm = "terl": start the planner's buffer from an earlier run's
    /// runs/<id>/tep-dataset.mcap (repeat to load several).
    #[arg(long, value_name = "MCAP")]
    pub tep_dataset: Vec<PathBuf>,
    /// Learner gRPC address (default 127.0.0.1:0: a free port, written to runs/<id>/learner.addr).
    #[arg(long)]
    pub learner_addr: Option<String>,
    /// Selector gRPC address (default 127.0.0.1:0).
    #[arg(long)]
    pub selector_addr: Option<String>,
    /// Folder of run folders (default runs). `terl cluster down` looks in runs/ unless given the
    /// same `--runs-root`; `terl status` finds the run with `--run DIR/<id>`.
    #[arg(long)]
    pub runs_root: Option<PathBuf>,
    /// Continue the run in RUN_DIR after any stop: its config, run id, TEP datasets, actor
    /// count and addresses.
    #[arg(long, value_name = "RUN_DIR")]
    pub resume: Option<PathBuf>,
    /// Restart a process that dies up to N times per process (0: a death stops the cluster).
    #[arg(long, default_value = "3", value_name = "N", value_parser = restart_count)]
    pub restarts: u32,
    /// Wait before a restart, doubled for each further restart of the same process, at most 60 s.
    #[arg(long, default_value = "2", value_name = "SECS", value_parser = backoff_seconds)]
    pub restart_backoff: u64,
    /// Accepted for deploy/local-cluster.sh, which builds unless given it; `terl` never builds.
    #[arg(long)]
    pub no_build: bool,
}

/// Prints a usage error as the launcher script did and returns exit code 2.
fn usage(msg: impl std::fmt::Display) -> Result<ExitCode> {
    eprintln!("{msg}");
    Ok(ExitCode::from(2))
}

/// `date -Iseconds`: local time with its UTC offset, e.g. `2026-12-01T08:15:02+01:00`.
fn iso_now() -> String {
    chrono::Local::now()
        .format("%Y-%m-%dT%H:%M:%S%:z")
        .to_string()
}

fn valid_run_id(id: &str) -> bool {
    (1..=64).contains(&id.len())
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'))
        && id != "."
        && id != ".."
}

/// Local actors per core the launcher starts at most (`--actors`).
pub const MAX_ACTORS_PER_CORE: usize = 4;
/// Local actors the launcher starts at most on any machine (`--actors`).
pub const MAX_LOCAL_ACTORS: usize = 256;

/// The most local actors `--actors` accepts here: [`MAX_ACTORS_PER_CORE`] per core, at most
/// [`MAX_LOCAL_ACTORS`]. An actor steps its environments on one core; more than a few per core
/// only share the cores and add memory.
pub fn max_local_actors() -> usize {
    (MAX_ACTORS_PER_CORE * terl_runtime::process::available_cores()).min(MAX_LOCAL_ACTORS)
}

fn all_digits(s: &str, nonzero_first: bool) -> bool {
    !s.is_empty() && s.chars().all(|c| c.is_ascii_digit()) && !(nonzero_first && s.starts_with('0'))
}

/// `--actors`: a positive whole number without leading zeros (the machine's limit is checked
/// once the options are resolved, [`max_local_actors`]).
fn actor_count(s: &str) -> std::result::Result<usize, String> {
    if !all_digits(s, true) {
        return Err("must be a positive integer".into());
    }
    match s.parse::<usize>() {
        Ok(n) if n <= MAX_LOCAL_ACTORS => Ok(n),
        _ => Err(format!(
            "must be at most {MAX_LOCAL_ACTORS} local actors (the launcher's limit on any \
             machine; at most {MAX_ACTORS_PER_CORE} per core)"
        )),
    }
}

/// `--run-id`: see [`valid_run_id`].
fn run_id_arg(s: &str) -> std::result::Result<String, String> {
    if valid_run_id(s) {
        Ok(s.to_string())
    } else {
        Err("must be 1 to 64 characters of A-Z a-z 0-9 . _ - (not . or ..)".into())
    }
}

/// `--restarts`: a whole number; a larger one than `u32` holds means "always restart".
fn restart_count(s: &str) -> std::result::Result<u32, String> {
    if !all_digits(s, false) {
        return Err("must be a non-negative integer".into());
    }
    Ok(s.parse().unwrap_or(u32::MAX))
}

/// `--restart-backoff`: whole seconds; a larger one than `u64` holds waits the longest backoff.
fn backoff_seconds(s: &str) -> std::result::Result<u64, String> {
    if !all_digits(s, false) {
        return Err("must be a whole number of seconds".into());
    }
    Ok(s.parse().unwrap_or(MAX_BACKOFF_SECS))
}

/// The lock file of a run id: `${TMPDIR:-/tmp}/terl-run-locks/<id>.lock`.
fn lock_path(run_id: &str) -> PathBuf {
    let tmp = std::env::var_os("TMPDIR")
        .filter(|t| !t.is_empty())
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/tmp"));
    tmp.join("terl-run-locks").join(format!("{run_id}.lock"))
}

/// Takes the run id's lock without waiting: `Ok(None)` if another process holds it. The file
/// is opened close-on-exec, so no child keeps the lock after the launcher is gone.
fn lock_run_id(run_id: &str) -> Result<Option<Flock<File>>> {
    let path = lock_path(run_id);
    let dir = path.parent().expect("lock file has a folder");
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let file = std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(&path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    match Flock::lock(file, FlockArg::LockExclusiveNonblock) {
        Ok(lock) => Ok(Some(lock)),
        Err((_, e)) if e == nix::errno::Errno::EWOULDBLOCK => Ok(None),
        Err((_, e)) => Err(anyhow::anyhow!("cannot lock {}: {e}", path.display())),
    }
}

/// Whether a launcher holds the lock of `run_id` (tries it, and lets go at once).
pub(crate) fn run_id_locked(run_id: &str) -> Result<bool> {
    if !lock_path(run_id).exists() {
        return Ok(false);
    }
    Ok(lock_run_id(run_id)?.is_none())
}

fn cmdline(pid: u32) -> Option<Vec<String>> {
    let raw = std::fs::read(format!("/proc/{pid}/cmdline")).ok()?;
    let mut args: Vec<String> = raw
        .split(|&b| b == 0)
        .map(|a| String::from_utf8_lossy(a).into_owned())
        .collect();
    if args.last().is_some_and(String::is_empty) {
        args.pop();
    }
    Some(args)
}

const SERVICES: [&str; 3] = ["terl-learner", "terl-selector", "terl-actor"];

/// Whether `pid` is a running learner, selector or actor.
pub(crate) fn is_service(pid: u32) -> bool {
    cmdline(pid).is_some_and(|args| {
        args.first()
            .is_some_and(|a| SERVICES.iter().any(|s| a.ends_with(s)))
    })
}

/// The running learner, selector and actor processes of run `run_id` (`--run-id <id>` on
/// their command line), except this process: a killed launcher's services, or ones started by
/// hand.
pub(crate) fn run_processes(run_id: &str) -> Vec<u32> {
    let me = std::process::id();
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    let mut pids: Vec<u32> = dir
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter(|&pid| pid != me)
        .filter(|&pid| {
            cmdline(pid).is_some_and(|args| {
                let Some(at) = args
                    .iter()
                    .position(|a| SERVICES.iter().any(|s| a.ends_with(s)))
                else {
                    return false;
                };
                args[at + 1..]
                    .windows(2)
                    .any(|w| w[0] == "--run-id" && w[1] == run_id)
            })
        })
        .collect();
    pids.sort_unstable();
    pids
}

/// What the options resolve to.
#[derive(Debug)]
struct Plan {
    config: PathBuf,
    run_id: String,
    runs_root: PathBuf,
    actors: usize,
    learner_addr: String,
    selector_addr: String,
    tep_datasets: Vec<PathBuf>,
    resume: bool,
    restarts: u32,
    backoff: u64,
}

/// Whether `resume` is a launcher's run folder the run can continue from; the reason if not.
fn resumable(resume: &Path) -> std::result::Result<(), String> {
    for file in [resume.join("config.toml"), resume.join("cluster.txt")] {
        if !file.is_file() {
            return Err(format!(
                "--resume: {} not found (not a launcher's run folder)",
                file.display()
            ));
        }
    }
    // Without a checkpoint the learner starts again from update 0; beside the logs of the
    // earlier start that would make one folder hold two runs (reports would join them).
    let has_checkpoint = std::fs::read_dir(resume.join("checkpoints")).is_ok_and(|d| {
        d.filter_map(|e| e.ok())
            .any(|e| e.path().extension().is_some_and(|x| x == "safetensors"))
    });
    let has_logs = ["episodes.mcap", "metrics.mcap", "eval.mcap"]
        .iter()
        .any(|f| resume.join(f).exists());
    if !has_checkpoint && has_logs {
        return Err(format!(
            "--resume: {} holds logs but no checkpoint, so the run cannot continue where it \
             stopped (starting it again would put two runs in one folder): remove the folder to \
             start over, or start a new --run-id",
            resume.display()
        ));
    }
    Ok(())
}

/// Refuses more local actors than this machine can run; `from_run` is the run's cluster.txt when
/// `--resume` took the count from it (the message then names that file, not `--actors`).
fn local_actor_count_fits(
    actors: usize,
    from_run: Option<&Path>,
) -> std::result::Result<(), String> {
    let most = max_local_actors();
    if actors <= most {
        return Ok(());
    }
    let asked = match from_run {
        // Resuming on a smaller machine: the count came from the run, not from the user.
        Some(info) => format!(
            "{} says actors={actors} (give --actors to resume with fewer), which",
            info.display()
        ),
        None => format!("--actors {actors}"),
    };
    Err(format!(
        "{asked} is more than this machine can run: at most {most} local actors \
         ({MAX_ACTORS_PER_CORE} per core, at most {MAX_LOCAL_ACTORS}; each holds its \
         environments, ~50-150 MB); actors on other hosts join over Zenoh (docs/cluster.md)"
    ))
}

/// The options checked and resolved as the launcher script did (same messages); `Err(code)`
/// after printing a usage error.
fn plan(args: UpArgs) -> std::result::Result<Plan, Result<ExitCode>> {
    let (restarts, backoff) = (args.restarts, args.restart_backoff);
    let mut config = args
        .config
        .clone()
        .unwrap_or_else(|| PathBuf::from("deploy/configs/mt10.toml"));
    let mut run_id = args.run_id.clone();
    let mut runs_root = args.runs_root.clone().unwrap_or_else(|| "runs".into());
    let mut tep_datasets = args.tep_dataset.clone();
    let mut actors = args.actors;
    // Where the actor count came from when --resume read it from the run's cluster.txt.
    let mut actors_from_run: Option<PathBuf> = None;
    let mut learner_addr = args.learner_addr.clone();
    let mut selector_addr = args.selector_addr.clone();
    if let Some(resume) = &args.resume {
        // `runs/<id>/` and `runs/<id>` are the same run.
        let text = resume.to_string_lossy();
        let resume = PathBuf::from(match text.trim_end_matches('/') {
            "" => "/",
            t => t,
        });
        if args.config.is_some() || args.run_id.is_some() || !args.tep_dataset.is_empty() {
            return Err(usage(
                "--resume takes the run's own config, run id and TEP datasets; drop \
                 --config/--run-id/--tep-dataset",
            ));
        }
        config = resume.join("config.toml");
        if let Err(why) = resumable(&resume) {
            return Err(usage(why));
        }
        run_id = Some(
            resume
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
        );
        runs_root = match resume.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        // The TEP datasets the run started from, and its actor count and addresses unless given.
        let info = std::fs::read_to_string(resume.join("cluster.txt")).unwrap_or_default();
        for line in info.lines() {
            if let Some(d) = line.strip_prefix("tep_dataset=") {
                tep_datasets.push(d.into());
            } else if let Some(n) = line.strip_prefix("actors=") {
                if actors.is_none() {
                    match actor_count(n) {
                        Ok(n) => {
                            actors = Some(n);
                            actors_from_run = Some(resume.join("cluster.txt"));
                        }
                        Err(_) => {
                            return Err(usage(format!(
                                "--resume: {} says actors={n}, not a positive integer: give \
                                 --actors",
                                resume.join("cluster.txt").display()
                            )))
                        }
                    }
                }
            } else if let Some(a) = line.strip_prefix("learner_addr=") {
                learner_addr.get_or_insert_with(|| a.to_string());
            } else if let Some(a) = line.strip_prefix("selector_addr=") {
                selector_addr.get_or_insert_with(|| a.to_string());
            }
        }
    }
    let actors = actors.unwrap_or_else(|| {
        let cores = std::thread::available_parallelism().map_or(2, usize::from);
        cores.saturating_sub(1).max(1)
    });
    if !config.is_file() {
        return Err(usage(format!("config not found: {}", config.display())));
    }
    // The services would refuse a bad run file one by one after the launcher had written the run
    // folder; refuse it here, before anything is started or written.
    let checked = terl_runtime::RunConfig::load(&config)
        .and_then(|run| terl_runtime::resolve_tasks(&run.tasks).map(drop));
    if let Err(e) = checked {
        return Err(usage(format!("run file {}: {e:#}", config.display())));
    }
    if let Some(d) = tep_datasets.iter().find(|d| !d.is_file()) {
        return Err(usage(format!("TEP dataset not found: {}", d.display())));
    }
    if let Err(why) = local_actor_count_fits(actors, actors_from_run.as_deref()) {
        return Err(usage(why));
    }
    let run_id = run_id.unwrap_or_else(|| {
        let name = config
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let stem = match name.strip_suffix(".toml") {
            Some(s) if !s.is_empty() => s.to_string(),
            _ => name,
        };
        format!("{stem}-{}", chrono::Local::now().format("%Y%m%d-%H%M%S"))
    });
    if !valid_run_id(&run_id) {
        return Err(usage(format!(
            "--run-id must be 1 to 64 characters of A-Z a-z 0-9 . _ - (got \"{run_id}\")"
        )));
    }
    Ok(Plan {
        config,
        run_id,
        runs_root,
        actors,
        learner_addr: learner_addr.unwrap_or_else(|| "127.0.0.1:0".into()),
        selector_addr: selector_addr.unwrap_or_else(|| "127.0.0.1:0".into()),
        tep_datasets,
        resume: args.resume.is_some(),
        restarts,
        backoff,
    })
}

/// `terl cluster up`: runs the cluster until it stops; the exit code says why (module docs).
pub fn up(args: UpArgs) -> Result<ExitCode> {
    let plan = match plan(args) {
        Ok(p) => p,
        Err(code) => return code,
    };
    // Shared-memory service names carry the run id machine-wide: a second cluster with the id
    // of a live one (even in another runs root, or orphans of a killed launcher) would mix with
    // it. The lock refuses a second launcher even when both start in the same instant; the
    // process search catches services still running (a killed launcher's, or ones started by
    // hand).
    let Some(lock) = lock_run_id(&plan.run_id)? else {
        return usage(format!(
            "run id {id} is in use by another launcher or its processes (lock {lock}): stop \
             it, or choose another --run-id",
            id = plan.run_id,
            lock = lock_path(&plan.run_id).display()
        ));
    };
    let live = run_processes(&plan.run_id);
    if !live.is_empty() {
        let pids: Vec<String> = live.iter().map(u32::to_string).collect();
        return usage(format!(
            "run id {} is in use by running processes ({}): stop them, or choose another \
             --run-id",
            plan.run_id,
            pids.join(" ")
        ));
    }
    // A fresh run never writes into another run's folder: its checkpoint rotation would delete
    // that run's checkpoints, its logs would continue that run's numbering, and a later
    // --resume could continue from either run's checkpoint.
    let out = plan.runs_root.join(&plan.run_id);
    if !plan.resume && holds_files(&out) {
        let (what, resume) = match std::fs::symlink_metadata(&out) {
            Ok(m) if m.is_dir() && std::fs::read_dir(&out).is_err() => {
                ("is a folder this user cannot read", false)
            }
            Ok(m) if m.is_dir() => ("already holds files (a run's, or others)", true),
            Ok(m) if m.file_type().is_symlink() => ("is a link, not a folder", false),
            Ok(_) => ("is a file, not a folder", false),
            Err(e) => {
                return usage(format!(
                    "{} cannot be used as the run folder: {e} (is --runs-root a folder?)",
                    out.display()
                ))
            }
        };
        let resume = if resume {
            format!(
                "continue a stopped run there with --resume {}, ",
                out.display()
            )
        } else {
            String::new()
        };
        return usage(format!(
            "{} {what}: a fresh run needs a new or empty folder; {resume}remove it, or choose \
             another --run-id",
            out.display()
        ));
    }
    let bin = std::env::current_exe()
        .context("cannot find the terl binary")?
        .parent()
        .context("the terl binary has no folder")?
        .to_path_buf();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    // Every child is spawned from this (the main) thread: the services' --parent-pid death
    // signal follows the thread that started them.
    let code = runtime.block_on(async {
        let signals = Signals::new()?;
        let mut launcher = Launcher::prepare(plan, bin, signals)?;
        launcher.run().await
    });
    drop(lock);
    code
}

/// Whether `dir` exists and is anything but an empty folder (a file, a link or a folder with
/// entries): an unreadable path counts as holding files.
pub(crate) fn holds_files(dir: &Path) -> bool {
    match std::fs::symlink_metadata(dir) {
        Err(e) => e.kind() != std::io::ErrorKind::NotFound,
        Ok(m) if m.is_dir() => std::fs::read_dir(dir).map_or(true, |mut d| d.next().is_some()),
        Ok(_) => true,
    }
}

/// SIGINT and SIGTERM, recorded; the launcher looks at them between its steps.
struct Signals {
    int: Signal,
    term: Signal,
    got: Option<i32>,
}

impl Signals {
    fn new() -> Result<Self> {
        Ok(Self {
            int: signal(SignalKind::interrupt()).context("cannot handle SIGINT")?,
            term: signal(SignalKind::terminate()).context("cannot handle SIGTERM")?,
            got: None,
        })
    }

    /// Sleeps `d` unless a signal arrives (or arrived before); returns whether one did.
    async fn nap(&mut self, d: Duration) -> bool {
        if self.got.is_some() {
            return true;
        }
        tokio::select! {
            biased;
            _ = self.int.recv() => self.got = Some(nix::sys::signal::Signal::SIGINT as i32),
            _ = self.term.recv() => self.got = Some(nix::sys::signal::Signal::SIGTERM as i32),
            _ = tokio::time::sleep(d) => {}
        }
        self.got.is_some()
    }

    /// Whether a signal has arrived, without waiting.
    async fn interrupted(&mut self) -> bool {
        self.nap(Duration::ZERO).await
    }
}

/// One service process of the run.
#[derive(Debug)]
struct Proc {
    child: Child,
    started: Instant,
}

/// How a run ended: the summary's reason and the launcher's exit code.
struct Ending {
    reason: String,
    code: u8,
}

struct Launcher {
    plan: Plan,
    bin: PathBuf,
    out: PathBuf,
    signals: Signals,
    /// Running processes by role (learner, selector, actor-<i>).
    procs: BTreeMap<String, Proc>,
    restarts_of: BTreeMap<String, u32>,
    worst: i32,
    security: terl_wire::ClientOptions,
    /// Extra time the learner may take to write its address (its calibration).
    learner_extra: Duration,
}

/// The shell's exit code of a process: its code, or 128 + the signal that ended it.
fn shell_code(status: ExitStatus) -> i32 {
    use std::os::unix::process::ExitStatusExt;
    status
        .code()
        .or_else(|| status.signal().map(|s| 128 + s))
        .unwrap_or(1)
}

/// The roles in the order they start and are looked at.
fn role_order(role: &str) -> (u8, usize) {
    match role {
        "learner" => (0, 0),
        "selector" => (1, 0),
        r => (
            2,
            r.strip_prefix("actor-")
                .and_then(|i| i.parse().ok())
                .unwrap_or(usize::MAX),
        ),
    }
}

impl Launcher {
    /// Writes the run folder's files (config copy, cluster.txt, pid files).
    fn prepare(plan: Plan, bin: PathBuf, signals: Signals) -> Result<Self> {
        let out = plan.runs_root.join(&plan.run_id);
        let created = !out.exists();
        std::fs::create_dir_all(&out)
            .with_context(|| format!("cannot create {}", out.display()))?;
        // A full filesystem: nothing would start, and every file written now would be cut.
        if let Some(free) = full_disk(&out) {
            if created {
                let _ = std::fs::remove_dir(&out);
            }
            anyhow::bail!(
                "the run folder's filesystem is full ({free} bytes free in {}): free space, then \
                 start again{}",
                out.display(),
                if plan.resume { " with --resume" } else { "" }
            );
        }
        let info = out.join("cluster.txt");
        if !plan.resume {
            std::fs::copy(&plan.config, out.join("config.toml")).with_context(|| {
                format!("cannot copy {} to {}", plan.config.display(), out.display())
            })?;
            let mut text = format!(
                "run_id={}\nconfig={}\nactors={}\nlearner_addr={}\nselector_addr={}\n",
                plan.run_id,
                plan.config.display(),
                plan.actors,
                plan.learner_addr,
                plan.selector_addr
            );
            for d in &plan.tep_datasets {
                text.push_str(&format!("tep_dataset={}\n", d.display()));
            }
            text.push_str(&format!("started={}\n", iso_now()));
            std::fs::write(&info, text)
                .with_context(|| format!("cannot write {}", info.display()))?;
        } else {
            append_line(
                &info,
                &format!("resumed={} actors={}", iso_now(), plan.actors),
            )?;
            let has_checkpoint = std::fs::read_dir(out.join("checkpoints")).is_ok_and(|d| {
                d.filter_map(|e| e.ok())
                    .any(|e| e.path().extension().is_some_and(|x| x == "safetensors"))
            });
            if !has_checkpoint {
                eprintln!(
                    "[cluster] warning: {}/checkpoints holds no checkpoint: the learner starts \
                     this run again from update 0",
                    out.display()
                );
            }
        }
        let me = format!("{}\n", std::process::id());
        let _ = std::fs::remove_file(out.join(DOWN_MARKER));
        for (path, text) in [
            (plan.runs_root.join(".cluster.pid"), me.clone()),
            (
                plan.runs_root.join(".cluster.run"),
                format!("{}\n", out.display()),
            ),
            (out.join("launcher.pid"), me),
        ] {
            std::fs::write(&path, text)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        // The run's token and TLS trust, for the health checks (the services refuse a config
        // that is wrong; then the check is moot).
        let run = terl_runtime::RunConfig::load(&out.join("config.toml")).ok();
        let security = run
            .as_ref()
            .and_then(|run| {
                run.cluster
                    .client_security(terl_runtime::token_from_env())
                    .ok()
            })
            .map(terl_wire::ClientOptions::secured)
            .unwrap_or_default();
        // The learner times itself before it writes its address (at most a few updates past
        // `learner_calibrate_secs`): give it that much longer, three times over.
        let learner_extra = run.map_or(Duration::ZERO, |run| {
            Duration::from_secs_f64(
                3.0 * run
                    .cluster
                    .learner_calibrate_secs
                    .clamp(0.0, terl_runtime::MAX_LEARNER_CALIBRATE_SECS),
            )
        });
        Ok(Self {
            plan,
            bin,
            out,
            signals,
            procs: BTreeMap::new(),
            restarts_of: BTreeMap::new(),
            worst: 0,
            security,
            learner_extra,
        })
    }

    fn write_pids(&self) {
        let mut roles: Vec<&String> = self.procs.keys().collect();
        roles.sort_by_key(|r| role_order(r));
        let text: String = roles
            .iter()
            .map(|r| format!("{r} {}\n", self.procs[*r].child.id()))
            .collect();
        let path = self.out.join("pids");
        if let Err(e) = std::fs::write(&path, text) {
            eprintln!("[cluster] warning: cannot write {}: {e}", path.display());
        }
    }

    /// Starts (or restarts: `again`) the process of `role`. Logs append, so a restart keeps
    /// the earlier process's log above its own.
    fn start(&mut self, role: &str, again: bool) -> Result<()> {
        let p = &self.plan;
        let (binary, mut args): (&str, Vec<String>) = match role {
            "learner" => {
                let mut a = vec![
                    "--addr".to_string(),
                    p.learner_addr.clone(),
                    "--run-dir".into(),
                    self.out.display().to_string(),
                ];
                for d in &p.tep_datasets {
                    a.extend(["--tep-dataset".to_string(), d.display().to_string()]);
                }
                ("terl-learner", a)
            }
            "selector" => (
                "terl-selector",
                vec![
                    "--addr".to_string(),
                    p.selector_addr.clone(),
                    "--run-dir".into(),
                    self.out.display().to_string(),
                    "--learner-addr".into(),
                    p.learner_addr.clone(),
                ],
            ),
            actor => (
                "terl-actor",
                vec![
                    "--actor-id".to_string(),
                    actor.trim_start_matches("actor-").to_string(),
                    "--learner-addr".into(),
                    p.learner_addr.clone(),
                ],
            ),
        };
        if (p.resume || again) && role_order(role).0 < 2 {
            args.push("--resume".into());
        }
        let log_path = self.out.join(format!("{role}.log"));
        let log = std::fs::OpenOptions::new()
            .append(true)
            .create(true)
            .open(&log_path)
            .with_context(|| format!("cannot open {}", log_path.display()))?;
        let exe = self.bin.join(binary);
        let child = Command::new(&exe)
            .args([
                "--config".to_string(),
                self.out.join("config.toml").display().to_string(),
                "--run-id".into(),
                p.run_id.clone(),
                "--num-actors".into(),
                p.actors.to_string(),
                "--parent-pid".into(),
                std::process::id().to_string(),
            ])
            .args(&args)
            // Services print errors without a backtrace (panics still follow RUST_BACKTRACE).
            .env("RUST_LIB_BACKTRACE", "0")
            .stdin(Stdio::null())
            .stderr(log)
            .spawn()
            .with_context(|| format!("cannot start {}", exe.display()))?;
        self.procs.insert(
            role.to_string(),
            Proc {
                child,
                started: Instant::now(),
            },
        );
        self.write_pids();
        Ok(())
    }

    /// The last lines of a role's log (its error), indented.
    fn last_error(&self, role: &str) {
        let text =
            std::fs::read_to_string(self.out.join(format!("{role}.log"))).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        for line in &lines[lines.len().saturating_sub(8)..] {
            eprintln!("    {line}");
        }
    }

    /// Waits until `role` has written its address and answers health; its address. `Err`
    /// with the ending if it did not start (or a signal came).
    async fn wait_ready(&mut self, role: &str) -> std::result::Result<String, Ending> {
        let addr_file = self.out.join(format!("{role}.addr"));
        let service = if role == "learner" {
            terl_wire::LEARNER_SERVICE
        } else {
            terl_wire::SELECTOR_SERVICE
        };
        let mut phase_start = Instant::now();
        let mut addr: Option<String> = None;
        loop {
            if self.signals.interrupted().await {
                return Err(self.interrupted());
            }
            let exit = self.procs.get_mut(role).map(|p| p.child.try_wait());
            if role == "learner" && matches!(exit, Some(Ok(Some(status))) if status.success()) {
                // A learner resumed on a finished run says so and exits at once.
                return Err(Ending {
                    reason: format!(
                        "the learner exited 0 before serving: the run is finished (see {}/learner.log)",
                        self.out.display()
                    ),
                    code: 0,
                });
            }
            if !matches!(exit, Some(Ok(None))) {
                break;
            }
            match &addr {
                None => {
                    if let Ok(text) = std::fs::read_to_string(&addr_file) {
                        if !text.trim().is_empty() {
                            addr = Some(text.trim().to_string());
                            phase_start = Instant::now();
                            continue;
                        }
                    }
                }
                Some(a) => {
                    let check = terl_wire::check_health(a, service, &self.security);
                    if let Ok(Ok(true)) = tokio::time::timeout(Duration::from_secs(2), check).await
                    {
                        return Ok(a.clone());
                    }
                }
            }
            let limit = if role == "learner" && addr.is_none() {
                START_LIMIT + self.learner_extra
            } else {
                START_LIMIT
            };
            if phase_start.elapsed() > limit {
                break;
            }
            self.signals.nap(Duration::from_millis(100)).await;
        }
        eprintln!(
            "[cluster] {role} did not start; the end of {}/{role}.log:",
            self.out.display()
        );
        self.last_error(role);
        Err(Ending {
            reason: format!("the {role} did not start"),
            code: 1,
        })
    }

    fn interrupted(&self) -> Ending {
        let sig = self.signals.got.unwrap_or(0);
        if self.out.join(DOWN_MARKER).exists() {
            Ending {
                reason: format!("interrupted (signal {sig}, by terl cluster down)"),
                code: 0,
            }
        } else {
            Ending {
                reason: format!("interrupted (signal {sig})"),
                code: (128 + sig).clamp(0, 255) as u8,
            }
        }
    }

    /// Starts the cluster and watches it until it ends; then stops every process.
    async fn run(&mut self) -> Result<ExitCode> {
        let ending = self.start_and_watch().await;
        let code = ending.code;
        self.stop(&ending.reason);
        Ok(ExitCode::from(code))
    }

    async fn start_and_watch(&mut self) -> Ending {
        for f in ["learner.addr", "selector.addr"] {
            let _ = std::fs::remove_file(self.out.join(f));
        }
        if let Err(e) = self.start("learner", false) {
            return self.cannot_start(e);
        }
        // A restarted learner or selector binds the address the first one got (port 0
        // resolved), so actors and the selector find it again.
        match self.wait_ready("learner").await {
            Ok(a) => self.plan.learner_addr = a,
            Err(end) => return end,
        }
        // The selector follows the learner's weights (PTR scoring with algorithm = "terl").
        if let Err(e) = self.start("selector", false) {
            return self.cannot_start(e);
        }
        match self.wait_ready("selector").await {
            Ok(a) => self.plan.selector_addr = a,
            Err(end) => return end,
        }
        for i in 0..self.plan.actors {
            if let Err(e) = self.start(&format!("actor-{i}"), false) {
                return self.cannot_start(e);
            }
        }
        eprintln!(
            "[cluster] run {} {}: learner {}, selector {}, {} actor(s); logs in {}/. Ctrl-C stops.",
            self.plan.run_id,
            if self.plan.resume {
                "resumed"
            } else {
                "started"
            },
            self.plan.learner_addr,
            self.plan.selector_addr,
            self.plan.actors,
            self.out.display()
        );
        loop {
            if self.signals.nap(TICK).await {
                return self.interrupted();
            }
            let mut roles: Vec<String> = self.procs.keys().cloned().collect();
            roles.sort_by_key(|r| role_order(r));
            for role in roles {
                if self.signals.interrupted().await {
                    return self.interrupted();
                }
                if let Some(end) = self.look_at(&role).await {
                    return end;
                }
            }
            if self.signals.interrupted().await {
                return self.interrupted();
            }
            eprintln!("---- {}", chrono::Local::now().format("%H:%M:%S"));
            let _ = std::io::stderr().flush();
            let _ = Command::new(self.bin.join("terl"))
                .arg("status")
                .arg("--run")
                .arg(&self.out)
                .stdin(Stdio::null())
                .stdout(stderr_stdio())
                .status();
        }
    }

    fn cannot_start(&self, e: anyhow::Error) -> Ending {
        let reason = format!("{e:#}");
        eprintln!("[cluster] {reason}");
        Ending { reason, code: 1 }
    }

    /// Looks at the process of `role`: `None` if it runs or was restarted, the ending if the
    /// cluster must stop.
    async fn look_at(&mut self, role: &str) -> Option<Ending> {
        let proc = self.procs.get_mut(role)?;
        let status = match proc.child.try_wait() {
            Ok(None) => return None,
            Ok(Some(s)) => s,
            Err(e) => {
                eprintln!("[cluster] cannot wait for {role}: {e}");
                return None;
            }
        };
        let pid = proc.child.id();
        let started = proc.started;
        self.procs.remove(role);
        self.write_pids();
        let code = shell_code(status);
        self.worst = self.worst.max(code);
        if role == "learner" && code == 0 {
            let reason = "the learner finished (its budget or stop condition reached)".to_string();
            eprintln!("[cluster] {reason}; stopping the cluster");
            return Some(Ending { reason, code: 0 });
        }
        let n = self.restarts_of.get(role).copied().unwrap_or(0);
        // A full disk: the process's own error may not have reached its log (written to the
        // same filesystem), and a restart would fail the same way.
        if let Some(free) = full_disk(&self.out) {
            let reason = format!(
                "{role} (pid {pid}) exited with code {code} and the run folder's filesystem is \
                 full ({free} bytes free in {}): free space, then continue with --resume {}",
                self.out.display(),
                self.out.display()
            );
            eprintln!("[cluster] {reason}; stopping the cluster");
            self.last_error(role);
            return Some(Ending { reason, code: 1 });
        }
        // An error exit (not a signal, not a panic) within seconds of a start is a start-up
        // failure that a restart would repeat (a changed config, no checkpoint the run can
        // use, a full disk with on_checkpoint_error = "stop"): stop, and say why.
        if (code == 1 || code == 2) && started.elapsed() < MIN_UPTIME {
            let reason = format!(
                "{role} (pid {pid}) exited with code {code} within {}s of its start, a failure \
                 a restart would repeat",
                MIN_UPTIME.as_secs()
            );
            eprintln!(
                "[cluster] {reason}; stopping the cluster. The end of {}/{role}.log:",
                self.out.display()
            );
            self.last_error(role);
            return Some(Ending { reason, code: 1 });
        }
        if n >= self.plan.restarts {
            let reason = format!(
                "{role} (pid {pid}) exited with code {code} after {n} restart(s) (limit \
                 --restarts {})",
                self.plan.restarts
            );
            eprintln!(
                "[cluster] {reason}; stopping the cluster (logs in {}/)",
                self.out.display()
            );
            return Some(Ending { reason, code: 1 });
        }
        let wait_s = 1u64
            .checked_shl(n)
            .and_then(|m| self.plan.backoff.checked_mul(m))
            .unwrap_or(u64::MAX)
            .min(MAX_BACKOFF_SECS);
        self.restarts_of.insert(role.to_string(), n + 1);
        eprintln!(
            "[cluster] {role} (pid {pid}) exited with code {code}; restart {} of {} in {wait_s}s",
            n + 1,
            self.plan.restarts
        );
        let info = self.out.join("cluster.txt");
        if let Err(e) = append_line(
            &info,
            &format!("restart={} role={role} exit_code={code}", iso_now()),
        ) {
            eprintln!("[cluster] warning: {e:#}");
        }
        if self.signals.nap(Duration::from_secs(wait_s)).await {
            return Some(self.interrupted());
        }
        if let Err(e) = self.start(role, true) {
            return Some(self.cannot_start(e));
        }
        None
    }

    /// SIGTERM to every process, then waits for each, [`STOP_GRACE`] at most before SIGKILL;
    /// removes the launcher's files and prints the summary line.
    fn stop(&mut self, reason: &str) {
        eprintln!("[cluster] stopping {} processes", self.procs.len());
        let signal = |proc: &Proc, sig| {
            if let Ok(pid) = i32::try_from(proc.child.id()) {
                let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid), sig);
            }
        };
        for proc in self.procs.values() {
            signal(proc, nix::sys::signal::Signal::SIGTERM);
        }
        let deadline = Instant::now() + STOP_GRACE;
        let mut failed = Vec::new();
        for (role, mut proc) in std::mem::take(&mut self.procs) {
            let status = loop {
                match proc.child.try_wait() {
                    Ok(Some(status)) => break Some(status),
                    Ok(None) if Instant::now() < deadline => {
                        std::thread::sleep(Duration::from_millis(50));
                    }
                    Ok(None) => {
                        eprintln!(
                            "[cluster] {role} did not stop within {} s of SIGTERM: SIGKILL",
                            STOP_GRACE.as_secs()
                        );
                        signal(&proc, nix::sys::signal::Signal::SIGKILL);
                        break proc.child.wait().ok();
                    }
                    Err(_) => break None,
                }
            };
            if let Some(status) = status {
                let code = shell_code(status);
                self.worst = self.worst.max(code);
                if code != 0 {
                    failed.push(format!("{role} ({code})"));
                }
            }
        }
        // A process that failed while stopping on a full disk (the learner's final checkpoint
        // did not fit): say so, as for a failure during the run.
        if let Some(free) = full_disk(&self.out) {
            if !failed.is_empty() {
                eprintln!(
                    "[cluster] {} exited with an error while stopping, and the run folder's \
                     filesystem is full ({free} bytes free in {}): the final checkpoint may not \
                     have been written (the newest periodic one is kept); free space, then \
                     continue with --resume {}",
                    failed.join(", "),
                    self.out.display(),
                    self.out.display()
                );
                if failed.iter().any(|f| f.starts_with("learner")) {
                    self.last_error("learner");
                }
            }
        }
        for f in ["launcher.pid", "pids", DOWN_MARKER] {
            let _ = std::fs::remove_file(self.out.join(f));
        }
        let last = self.plan.runs_root.join(".cluster.pid");
        if std::fs::read_to_string(&last).is_ok_and(|p| p.trim() == std::process::id().to_string())
        {
            let _ = std::fs::remove_file(&last);
            let _ = std::fs::remove_file(self.plan.runs_root.join(".cluster.run"));
        }
        eprintln!(
            "[cluster] stopped: {reason} (worst exit code {}; run folder {})",
            self.worst,
            self.out.display()
        );
    }
}

/// Below this many free bytes the run folder's filesystem counts as full (a checkpoint, a
/// metrics chunk or a log line would not fit).
const FULL_DISK_BYTES: u64 = 1 << 20;

/// The bytes still free on the filesystem of `dir` when it counts as full (fewer than
/// [`FULL_DISK_BYTES`] an unprivileged process may write, by `statvfs`); `None` when it is not
/// full or cannot be asked.
fn full_disk(dir: &Path) -> Option<u64> {
    let st = nix::sys::statvfs::statvfs(dir).ok()?;
    Some(st.blocks_available().saturating_mul(st.fragment_size())).filter(|&b| b < FULL_DISK_BYTES)
}

fn append_line(path: &Path, line: &str) -> Result<()> {
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    writeln!(f, "{line}").with_context(|| format!("cannot write {}", path.display()))
}

/// This process's stderr as a child's stdout (`terl status` prints to the launcher's stderr).
fn stderr_stdio() -> Stdio {
    use std::os::fd::AsFd;
    std::io::stderr()
        .as_fd()
        .try_clone_to_owned()
        .map(Stdio::from)
        .unwrap_or_else(|_| Stdio::inherit())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_ids_follow_the_services_rule() {
        for ok in ["a", "mt10-20260101-120000", "x.y_z-1", &"a".repeat(64)] {
            assert!(valid_run_id(ok), "{ok}");
        }
        for bad in ["", ".", "..", "a/b", "bk(p", "a b", &"a".repeat(65)] {
            assert!(!valid_run_id(bad), "{bad}");
        }
    }

    #[test]
    fn exit_codes_are_the_shells() {
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(shell_code(ExitStatus::from_raw(3 << 8)), 3);
        assert_eq!(shell_code(ExitStatus::from_raw(9)), 137);
        assert_eq!(shell_code(ExitStatus::from_raw(15)), 143);
    }

    #[test]
    fn roles_sort_learner_selector_then_actors_by_number() {
        let mut roles = vec!["actor-10", "selector", "actor-2", "learner", "actor-0"];
        roles.sort_by_key(|r| role_order(r));
        assert_eq!(
            roles,
            ["learner", "selector", "actor-0", "actor-2", "actor-10"]
        );
    }
}
