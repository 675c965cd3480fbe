//! `terl cluster up|down`: the local cluster from the CLI. `up` runs `deploy/local-cluster.sh`
//! (one launcher, so the script and the CLI cannot drift apart); `down [RUN_ID]` sends SIGTERM to
//! that run's launcher (`runs/<id>/launcher.pid`, or `runs/.cluster.pid` for the last one
//! started), which stops and waits for every process of its run.

use std::path::PathBuf;
use std::process::{Command, ExitCode};

use anyhow::{Context, Result};
use clap::Subcommand;

#[derive(Debug, Subcommand)]
pub enum ClusterCommand {
    /// Start learner, selector and actors in the foreground (Ctrl-C or `terl cluster down` stops).
    Up {
        /// Run file (default deploy/configs/mt10.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Actor processes (default: cores - 1, at least 1).
        #[arg(long)]
        actors: Option<usize>,
        /// Further launcher options (see deploy/local-cluster.sh --help).
        #[arg(last = true)]
        rest: Vec<String>,
    },
    /// Stop a running local cluster: the run RUN_ID (its launcher's `runs/<id>/launcher.pid`),
    /// or without it the cluster started last (`runs/.cluster.pid`). Other runs are not touched.
    Down {
        /// Run id of the cluster to stop.
        run_id: Option<String>,
        /// Folder of run folders.
        #[arg(long, default_value = "runs")]
        runs_root: std::path::PathBuf,
    },
}

pub fn run(cmd: ClusterCommand) -> Result<ExitCode> {
    match cmd {
        ClusterCommand::Up {
            config,
            actors,
            rest,
        } => {
            let mut launcher = Command::new("deploy/local-cluster.sh");
            if let Some(c) = config {
                launcher.arg("--config").arg(c);
            }
            if let Some(n) = actors {
                launcher.arg("--actors").arg(n.to_string());
            }
            let status = launcher.args(rest).status().context(
                "cannot run deploy/local-cluster.sh (run terl from the repository root)",
            )?;
            Ok(if status.success() {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            })
        }
        ClusterCommand::Down { run_id, runs_root } => {
            let pid_file = match &run_id {
                Some(id) => {
                    anyhow::ensure!(
                        !id.is_empty() && !id.contains('/') && id != "." && id != "..",
                        "bad run id {id:?}"
                    );
                    runs_root.join(id).join("launcher.pid")
                }
                None => runs_root.join(".cluster.pid"),
            };
            let pid_file = pid_file.display().to_string();
            let pid = std::fs::read_to_string(&pid_file)
                .with_context(|| format!("no running cluster ({pid_file} not found)"))?;
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
                 killed); its services stop by themselves when it dies"
            );
            let ok = Command::new("kill")
                .args(["-TERM", pid])
                .status()?
                .success();
            anyhow::ensure!(
                ok,
                "cluster launcher {pid} is not running (stale {pid_file}?)"
            );
            eprintln!("sent SIGTERM to the cluster launcher (pid {pid}); it stops every process");
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// Whether process `pid` is a running `deploy/local-cluster.sh` (a launcher's pid file outlives
/// a launcher killed with SIGKILL, and its pid may be reused by anything).
pub(crate) fn is_launcher(pid: &str) -> bool {
    std::fs::read(format!("/proc/{pid}/cmdline"))
        .is_ok_and(|c| String::from_utf8_lossy(&c).contains("local-cluster.sh"))
}
