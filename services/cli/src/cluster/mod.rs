//! `terl cluster up|down|clean`: the local cluster from the CLI. `up` is the launcher
//! (`deploy/local-cluster.sh` builds, then runs it; see [`launcher`]); `down [RUN_ID]`
//! sends SIGTERM to that run's launcher (`runs/<id>/launcher.pid`, or `runs/.cluster.pid` for the
//! last one started), which stops and waits for every process of its run; `clean RUN_ID` removes
//! the launcher files a killed launcher left behind.

pub mod launcher;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Subcommand;

use launcher::UpArgs;

#[derive(Debug, Subcommand)]
pub enum ClusterCommand {
    /// Start learner, selector and actors in the foreground (Ctrl-C or `terl cluster down`
    /// stops); the options of deploy/local-cluster.sh.
    Up(UpArgs),
    /// Stop a running local cluster: the run RUN_ID (its launcher's `runs/<id>/launcher.pid`),
    /// or without it the cluster started last (`runs/.cluster.pid`). Other runs are not touched.
    /// The launcher then exits 0.
    Down {
        /// Run id of the cluster to stop.
        run_id: Option<String>,
        /// Folder of run folders.
        #[arg(long, default_value = "runs")]
        runs_root: PathBuf,
    },
    /// Remove the launcher files of a stopped run RUN_ID (launcher.pid, pids, the *.addr files
    /// and, if they name this run, runs/.cluster.pid and runs/.cluster.run), e.g. after the
    /// launcher was killed with SIGKILL. Refuses while any process of the run is alive. Logs,
    /// checkpoints and the run's records stay.
    Clean {
        /// Run id of the stopped run.
        run_id: String,
        /// Folder of run folders.
        #[arg(long, default_value = "runs")]
        runs_root: PathBuf,
    },
}

pub fn run(cmd: ClusterCommand) -> Result<ExitCode> {
    match cmd {
        ClusterCommand::Up(args) => launcher::up(args),
        ClusterCommand::Down { run_id, runs_root } => down(run_id.as_deref(), &runs_root),
        ClusterCommand::Clean { run_id, runs_root } => clean(&run_id, &runs_root),
    }
}

fn check_run_id(id: &str) -> Result<()> {
    anyhow::ensure!(
        !id.is_empty() && !id.contains('/') && id != "." && id != "..",
        "bad run id {id:?}"
    );
    Ok(())
}

fn down(run_id: Option<&str>, runs_root: &Path) -> Result<ExitCode> {
    let (pid_file, run_dir) = match run_id {
        Some(id) => {
            check_run_id(id)?;
            let dir = runs_root.join(id);
            (dir.join("launcher.pid"), Some(dir))
        }
        None => (
            runs_root.join(".cluster.pid"),
            std::fs::read_to_string(runs_root.join(".cluster.run"))
                .ok()
                .map(|d| PathBuf::from(d.trim())),
        ),
    };
    let pid_file = pid_file.display().to_string();
    let pid = std::fs::read_to_string(&pid_file).with_context(|| {
        let hint = if runs_root == Path::new("runs") {
            " (a cluster started with --runs-root DIR: give `terl cluster down --runs-root DIR`)"
        } else {
            ""
        };
        format!("no running cluster ({pid_file} not found){hint}")
    })?;
    let pid = pid.trim();
    anyhow::ensure!(
        !pid.is_empty() && pid.chars().all(|c| c.is_ascii_digit()),
        "bad pid {pid:?} in {pid_file}"
    );
    // A launcher killed with SIGKILL leaves its pid file; the pid may since belong to
    // an unrelated process, which must not be signalled.
    anyhow::ensure!(
        is_launcher(pid),
        "no running cluster launcher has pid {pid} (stale {pid_file}: the launcher was \
         killed); its services stop by themselves when it dies (`terl cluster clean` removes \
         its files)"
    );
    let pid_n: i32 = pid.parse().context("pid out of range")?;
    // Tell the launcher that this stop was asked for (it then exits 0, not 143): a marker in
    // the run folder whose launcher.pid is this pid.
    if let Some(dir) = run_dir
        .filter(|d| std::fs::read_to_string(d.join("launcher.pid")).is_ok_and(|p| p.trim() == pid))
    {
        let marker = dir.join(launcher::DOWN_MARKER);
        std::fs::write(&marker, format!("{}\n", std::process::id()))
            .with_context(|| format!("cannot write {}", marker.display()))?;
    }
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(pid_n),
        nix::sys::signal::Signal::SIGTERM,
    )
    .with_context(|| format!("cluster launcher {pid} is not running (stale {pid_file}?)"))?;
    eprintln!("sent SIGTERM to the cluster launcher (pid {pid}); it stops every process");
    Ok(ExitCode::SUCCESS)
}

fn clean(run_id: &str, runs_root: &Path) -> Result<ExitCode> {
    check_run_id(run_id)?;
    let dir = runs_root.join(run_id);
    anyhow::ensure!(dir.is_dir(), "{} is not a run folder", dir.display());
    if let Ok(text) = std::fs::read_to_string(dir.join("launcher.pid")) {
        let pid = text.trim();
        anyhow::ensure!(
            !is_launcher(pid),
            "run {run_id} is running (launcher pid {pid}): stop it first with `terl cluster \
             down {run_id}`"
        );
    }
    let mut alive: Vec<u32> = launcher::run_processes(run_id);
    for line in std::fs::read_to_string(dir.join("pids"))
        .unwrap_or_default()
        .lines()
    {
        if let Some(pid) = line
            .split_once(' ')
            .and_then(|(_, p)| p.trim().parse::<u32>().ok())
        {
            if launcher::is_service(pid) && !alive.contains(&pid) {
                alive.push(pid);
            }
        }
    }
    anyhow::ensure!(
        alive.is_empty(),
        "run {run_id} still has running processes ({}): stop them first",
        alive
            .iter()
            .map(u32::to_string)
            .collect::<Vec<_>>()
            .join(" ")
    );
    anyhow::ensure!(
        !launcher::run_id_locked(run_id)?,
        "run {run_id} is in use by a launcher (its lock is held): stop it first with `terl \
         cluster down {run_id}`"
    );
    let mut removed = Vec::new();
    for name in [
        "launcher.pid",
        "pids",
        "learner.addr",
        "selector.addr",
        ".learner.addr.tmp",
        ".selector.addr.tmp",
        launcher::DOWN_MARKER,
    ] {
        let path = dir.join(name);
        if std::fs::remove_file(&path).is_ok() {
            removed.push(path);
        }
    }
    // The "last started" pointer, if it points at this run.
    let last = std::fs::read_to_string(runs_root.join(".cluster.run")).unwrap_or_default();
    if !last.trim().is_empty() && same_dir(Path::new(last.trim()), &dir) {
        for name in [".cluster.pid", ".cluster.run"] {
            let path = runs_root.join(name);
            if std::fs::remove_file(&path).is_ok() {
                removed.push(path);
            }
        }
    }
    if removed.is_empty() {
        eprintln!(
            "run {run_id}: no launcher files to remove in {}",
            dir.display()
        );
    } else {
        let names: Vec<String> = removed.iter().map(|p| p.display().to_string()).collect();
        eprintln!("run {run_id} cleaned: removed {}", names.join(", "));
    }
    Ok(ExitCode::SUCCESS)
}

fn same_dir(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    }
}

/// Whether process `pid` is a running cluster launcher: `terl cluster up` (which
/// `deploy/local-cluster.sh` becomes), or an older launcher script (a launcher's pid file
/// outlives a launcher killed with SIGKILL, and its pid may be reused by anything).
pub(crate) fn is_launcher(pid: &str) -> bool {
    let Ok(cmdline) = std::fs::read(format!("/proc/{pid}/cmdline")) else {
        return false;
    };
    let args: Vec<String> = cmdline
        .split(|&b| b == 0)
        .map(|a| String::from_utf8_lossy(a).into_owned())
        .collect();
    let terl_up = args.first().is_some_and(|a| {
        Path::new(a)
            .file_name()
            .is_some_and(|n| n == std::ffi::OsStr::new("terl"))
    }) && args.get(1).is_some_and(|a| a == "cluster")
        && args.get(2).is_some_and(|a| a == "up");
    terl_up || args.iter().any(|a| a.ends_with("local-cluster.sh"))
}
