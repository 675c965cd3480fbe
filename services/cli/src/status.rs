//! `terl status`: one snapshot of a running cluster from the learner's and the selector's
//! `GetStatus`, as a table or JSON (`--json`, for scripts and tests).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Args;
use terl_wire::{ClientOptions, ClientSecurity, ClientTls, LearnerStatus, SelectorStatus, Token};

#[derive(Debug, Args)]
pub struct StatusArgs {
    /// Learner gRPC address. Without it (and without --run): the cluster the launcher started
    /// last (`runs/.cluster.run`), else 127.0.0.1:50051.
    #[arg(long)]
    pub addr: Option<String>,
    /// Selector gRPC address (same default rule; else 127.0.0.1:50052).
    #[arg(long)]
    pub selector_addr: Option<String>,
    /// Print JSON ({"learner": ..., "selector": ... or null}).
    #[arg(long)]
    pub json: bool,
    /// Seconds to wait for each server.
    #[arg(long, default_value_t = 5.0, value_parser = terl_runtime::parse_seconds)]
    pub timeout: f64,
    /// File holding the control-plane token (the run's `cluster.token_file`); without it the
    /// TERL_TOKEN environment variable is sent, if set.
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    /// CA certificate (PEM) to verify TLS servers with (the run's `cluster.tls_ca`); makes the
    /// connection TLS.
    #[arg(long)]
    pub tls_ca: Option<PathBuf>,
    /// Name expected in the servers' certificate instead of the dialled host
    /// (`cluster.tls_domain`).
    #[arg(long, requires = "tls_ca")]
    pub tls_domain: Option<String>,
    /// A launcher's run folder (runs/<id>): the addresses come from its learner.addr and
    /// selector.addr, and the launcher's processes (alive or not) and restarts are shown too.
    #[arg(long, value_name = "RUN_DIR")]
    pub run: Option<std::path::PathBuf>,
}

/// One process of a launcher's run (`runs/<id>/pids`).
#[derive(Debug, serde::Serialize)]
struct Process {
    role: String,
    pid: u32,
    alive: bool,
    /// CPU use over the half second `terl status` watched it, in cores (all its threads).
    cpu_cores: Option<f64>,
    /// Resident set size, in MB (10^6 bytes).
    rss_mb: Option<f64>,
}

/// What the launcher's files say about a run's processes.
#[derive(Debug, Default, serde::Serialize)]
struct Launcher {
    processes: Vec<Process>,
    /// `restart=<time> role=<role> exit_code=<code>` lines of `cluster.txt`, in order.
    restarts: Vec<String>,
    resumed: Vec<String>,
}

/// A launcher file's text, if it is a regular file of at most 1 MiB (a FIFO or device in its
/// place would block or flood the status).
fn launcher_file(path: &std::path::Path) -> String {
    let regular = std::fs::metadata(path).is_ok_and(|m| m.is_file() && m.len() <= 1 << 20);
    if regular {
        std::fs::read_to_string(path).unwrap_or_default()
    } else {
        String::new()
    }
}

fn read_launcher(run: &std::path::Path) -> Launcher {
    let processes = launcher_file(&run.join("pids"))
        .lines()
        .filter_map(|l| {
            let (role, pid) = l.split_once(' ')?;
            let pid: u32 = pid.trim().parse().ok()?;
            // A learner, selector or actor that has not exited (a zombie has).
            let alive = crate::cluster::launcher::is_service(pid)
                && terl_runtime::process::usage(Some(pid)).is_ok_and(|u| !u.exited);
            Some(Process {
                role: role.to_string(),
                pid,
                alive,
                cpu_cores: None,
                rss_mb: None,
            })
        })
        .collect();
    let info = launcher_file(&run.join("cluster.txt"));
    let pick = |prefix: &str| -> Vec<String> {
        info.lines()
            .filter_map(|l| l.strip_prefix(prefix))
            .map(str::to_string)
            .collect()
    };
    Launcher {
        processes,
        restarts: pick("restart="),
        resumed: pick("resumed="),
    }
}

/// How long `terl status` watches the run's processes to tell their CPU use.
const USAGE_WINDOW: Duration = Duration::from_millis(500);

/// Fills in the CPU use and memory of the launcher's live processes (on this host).
fn measure(l: &mut Launcher) {
    // A pid listed twice (a damaged file) is measured and counted once.
    let mut seen = std::collections::HashSet::new();
    let live: Vec<&mut Process> = l
        .processes
        .iter_mut()
        .filter(|p| p.alive && seen.insert(p.pid))
        .collect();
    let pids: Vec<u32> = live.iter().map(|p| p.pid).collect();
    for (p, got) in live
        .into_iter()
        .zip(terl_runtime::process::sample(&pids, USAGE_WINDOW))
    {
        if let Some((cores, rss)) = got {
            p.cpu_cores = Some(cores);
            p.rss_mb = Some(rss as f64 / 1e6);
        }
    }
}

/// Which side limits the run, from the share of its wall time the learner spends in updates
/// (`updates_per_second / busy_updates_per_second`): near 1 the learner is always updating and
/// the actors wait on the update-to-data ratio; well below, the learner waits for transitions.
fn bound_by(update_share: f64) -> &'static str {
    if update_share >= 0.9 {
        "learner-bound: more actors would only wait; more learner threads ([sac] threads) or \
         a lower update-to-data ratio would speed the run"
    } else if update_share >= 0.6 {
        "balanced: the learner updates most of the time and the actors keep up"
    } else {
        "actor-bound: the learner waits for transitions; more actors (--actors N) would \
         feed it"
    }
}

/// The machine line: cores, what the cluster's processes use of them, and which side limits
/// the run.
fn print_machine(learner: &LearnerStatus, launcher: Option<&Launcher>) {
    let cores = terl_runtime::process::machine_cores();
    let mut used = String::new();
    if let Some(l) = launcher {
        let parts: Vec<(String, f64)> = l
            .processes
            .iter()
            .filter_map(|p| Some((p.role.clone(), p.cpu_cores?)))
            .collect();
        if !parts.is_empty() {
            let total: f64 = parts.iter().map(|(_, c)| c).sum();
            let each: Vec<String> = parts.iter().map(|(r, c)| format!("{r} {c:.2}")).collect();
            used = format!(
                "; the cluster uses {total:.2} of them ({:.0} %: {})",
                100.0 * total / cores as f64,
                each.join(", ")
            );
        }
    }
    let verdict = if learner.busy_updates_per_second > 0.0 {
        let share = (learner.updates_per_second / learner.busy_updates_per_second).min(1.0);
        format!(
            "; the learner updates {:.0} % of the time: {}",
            100.0 * share,
            bound_by(share)
        )
    } else {
        String::new()
    };
    println!("machine   {cores} cores{used}{verdict}");
}

fn print_launcher(l: &Launcher) {
    let procs: Vec<String> = l
        .processes
        .iter()
        .map(|p| {
            let usage = match (p.cpu_cores, p.rss_mb) {
                (Some(c), Some(m)) => format!(", {:.0} % CPU, {m:.0} MB", 100.0 * c),
                _ => String::new(),
            };
            format!(
                "{} {} ({}{usage})",
                p.role,
                p.pid,
                if p.alive { "alive" } else { "gone" }
            )
        })
        .collect();
    println!(
        "processes {}  restarts {}{}",
        procs.join("  "),
        l.restarts.len(),
        l.resumed
            .last()
            .map(|r| format!("  resumed by the launcher at {r}"))
            .unwrap_or_default()
    );
    for r in l.restarts.iter().rev().take(5).rev() {
        println!("restarted {r}");
    }
}

impl StatusArgs {
    /// The token (`--token-file`, else TERL_TOKEN) and TLS trust (`--tls-ca`) to connect with.
    /// Without either flag, a launcher's run folder supplies its own settings: the
    /// `[cluster]` token_file / tls_ca / tls_domain of `RUN_DIR/config.toml`.
    pub fn client_options(&self, run_dir: Option<&std::path::Path>) -> Result<ClientOptions> {
        if self.token_file.is_none() && self.tls_ca.is_none() {
            if let Some(config) = run_dir
                .map(|d| d.join("config.toml"))
                .filter(|c| c.is_file())
            {
                let run = terl_runtime::RunConfig::load(&config)?;
                let security = run
                    .cluster
                    .client_security(terl_runtime::token_from_env())
                    .with_context(|| format!("the run's settings in {}", config.display()))?;
                return Ok(ClientOptions::secured(security));
            }
        }
        let token = match &self.token_file {
            Some(path) => Some(Token::from_file(path)?),
            None => terl_runtime::token_from_env()
                .map(|v| Token::new(v, terl_wire::TOKEN_ENV))
                .transpose()?,
        };
        let tls = self
            .tls_ca
            .as_deref()
            .map(|ca| ClientTls::from_file(ca, self.tls_domain.clone()))
            .transpose()?;
        Ok(ClientOptions::secured(ClientSecurity { token, tls }))
    }
}

/// The hint for a call whose connection the server closed.
const CLOSED_HINT: &str = "the connection closed: if the server uses TLS, give its CA \
     (--tls-ca, or cluster.tls_ca in the run file with --run RUN_DIR)";

/// What a failed status call most likely means: a server that answered and refused the
/// client's token, or (for a plaintext client) one that closed the connection because it
/// speaks TLS. `None` when the error says nothing more (nothing listens, a timeout).
fn diagnosis(e: &anyhow::Error, tls: bool) -> Option<&'static str> {
    if let Some(status) = e.chain().find_map(|c| c.downcast_ref::<tonic::Status>()) {
        return match status.code() {
            tonic::Code::Unauthenticated => Some(
                "it answers but refused this client's token: give the run's token (TERL_TOKEN \
                 or --token-file; with --run RUN_DIR the run file's token_file is used)",
            ),
            // What a closed connection looks like to a call: cancelled, unavailable, or an
            // unknown transport error (a broken pipe); not a server's own internal error.
            tonic::Code::Unavailable | tonic::Code::Cancelled if !tls => Some(CLOSED_HINT),
            tonic::Code::Unknown if !tls && status.message().contains("transport error") => {
                Some(CLOSED_HINT)
            }
            _ => None,
        };
    }
    None
}

async fn learner_status(addr: &str, options: ClientOptions) -> Result<LearnerStatus> {
    let mut client = terl_wire::connect_learner_with(addr, options).await?;
    Ok(client.status().await?)
}

async fn selector_status(addr: &str, options: ClientOptions) -> Result<SelectorStatus> {
    let mut client = terl_wire::connect_selector_with(addr, options).await?;
    Ok(client.status().await?)
}

fn percent(rate: f64) -> String {
    format!("{:.0}%", 100.0 * rate)
}

#[allow(clippy::too_many_lines)] // one table row after another, in reading order
fn print_table(learner: &LearnerStatus, selector: Result<&SelectorStatus, &anyhow::Error>) {
    let l = learner;
    println!(
        "learner   run {}  up {:.0}s  updates {} ({:.0}/s)  env steps {}  policy v{}  replay {}/{}  staleness mean {:.0} max {}  rejected {}",
        l.run_id, l.uptime_seconds, l.updates, l.updates_per_second, l.env_steps_total,
        l.policy_version, l.replay_size, l.replay_capacity, l.staleness_mean, l.staleness_max,
        l.rejected_batches
    );
    if l.standalone_updates_per_second > 0.0 {
        let busy = if l.busy_updates_per_second > 0.0 {
            format!(
                "{:.2}x its standalone rate ({:.1} updates/s while updating, {:.1} alone)",
                l.update_speed_ratio, l.busy_updates_per_second, l.standalone_updates_per_second
            )
        } else {
            format!(
                "standalone {:.1} updates/s; no update yet",
                l.standalone_updates_per_second
            )
        };
        println!(
            "speed     {busy}  longest staging round {:.2} ms",
            l.staging_max_ms
        );
    }
    if !l.resumed_from.is_empty() {
        println!(
            "resumed   from {} (update {}); replay refilled since then",
            l.resumed_from, l.resumed_at_update
        );
    }
    if l.checkpoint_failures > 0 {
        println!(
            "WARNING   {} checkpoint(s) could not be written (see the learner's log)",
            l.checkpoint_failures
        );
    }
    for a in &l.actors {
        let host = if a.host.is_empty() {
            String::new()
        } else {
            format!("  on {} ({})", a.host, a.address)
        };
        println!(
            "actor {:<3} env steps {:>10} ({:>6.0}/s)  acts with policy v{}  last seen {:.1}s ago  dropped: {} transitions ({} batches), {} episodes{host}",
            a.actor_id, a.env_steps, a.env_steps_per_second, a.policy_version, a.seconds_since_seen,
            a.transitions_dropped, a.transition_batches_dropped, a.episodes_dropped
        );
    }
    println!(
        "dropped   {} transitions ({} batches) never reached the learner, {} episodes not delivered to every receiver, {} selected samples ({} batches) (a receiver stayed full for longer than cluster.block_timeout_secs)",
        l.transitions_dropped, l.transition_batches_dropped, l.episodes_dropped,
        l.selected_samples_dropped, l.selected_batches_dropped
    );
    if l.transition_batches_missed > 0 {
        println!(
            "lost      {} transition batches in transit (a connection to an actor's host closed with them in flight)",
            l.transition_batches_missed
        );
    }
    let tasks: Vec<String> = l
        .task_success
        .iter()
        .map(|t| format!("{} {} ({})", t.task, percent(t.success_rate), t.episodes))
        .collect();
    let window = l.task_success.iter().map(|t| t.episodes).max().unwrap_or(0);
    println!(
        "train success (stochastic policy, last {window} training episodes/task; episodes in parentheses)  {}",
        tasks.join("  ")
    );
    if l.algorithm == "terl" {
        let guidance: Vec<String> = l
            .task_success
            .iter()
            .map(|t| {
                let mut s = format!("{} {}", t.task, percent(t.guidance_rate));
                if let Some(p) = t.guidance_probability {
                    s.push_str(&format!(" σ^N {p:.3}"));
                }
                if let Some(r) = t.not_improving_rate {
                    s.push_str(&format!(" f≥f' {} of {}", percent(r), t.compared_steps));
                }
                if let Some(g) = t.action_gap {
                    s.push_str(&format!(" ‖AN−π‖ {g:.2}"));
                }
                s
            })
            .collect();
        println!(
            "tep       planner v{}  updates {}  buffer {}/{}  loss F {:.3} AN {:.3}  target {:.2}  distance {:.2}  selected {} (after a success {})  guided steps {}",
            l.planner_version, l.tep_updates, l.tep_buffer_size, l.tep_buffer_capacity,
            l.tep_f_loss, l.tep_an_loss, l.tep_target_mean, l.tep_goal_distance_mean,
            l.selected_samples, l.tep_after_success, l.guided_steps
        );
        println!(
            "guidance  guided share (σ^N where the planner may act, share of f_t ≥ f_t-1 of the compared steps, mean ‖AN−π‖ of guided steps)  {}",
            guidance.join("  |  ")
        );
        let p = &l.planner;
        println!(
            "planner   F terms step {:.3} goal {:.3} symmetry {:.3}  AN bc {:.3}  mean gap {:.1}",
            p.step_loss, p.goal_loss, p.symmetry_loss, p.an_bc_loss, p.gap_mean
        );
        let gate: Vec<String> = p
            .tasks
            .iter()
            .map(|t| {
                let rho = t
                    .spearman
                    .map_or_else(|| "ρ –".to_string(), |r| format!("ρ {r:.2}"));
                let mark = if t.validated {
                    format!("guided since TEP update {}", t.validated_at_tep_update)
                } else {
                    "not guided".to_string()
                };
                format!(
                    "{} {rho} ({} held out, {} in buffer) {mark}",
                    t.task, t.held_out_trajectories, t.tep_transitions
                )
            })
            .collect();
        println!("gate      {}", gate.join("  |  "));
    }
    match selector {
        Ok(s) => {
            let tasks: Vec<String> = s
                .task_success
                .iter()
                .map(|t| format!("{} {} ({})", t.task, percent(t.success_rate), t.episodes))
                .collect();
            println!(
                "selector  episodes {} (never received {}, dropped by actors {})  selected {}  [{}]",
                s.episodes_seen,
                s.episodes_missed,
                s.episodes_dropped,
                s.selected_samples,
                tasks.join("  ")
            );
            if s.priority.scored > 0 {
                let p = &s.priority;
                println!(
                    "priority  scored {}  mean {:.3} (GAE part {:.3}, entropy part {:.3})  min {:.3}  max {:.3}  selection threshold {:.3}  critic v{}",
                    p.scored,
                    p.mean,
                    p.gae_part_mean,
                    p.entropy_part_mean,
                    p.min,
                    p.max,
                    p.selection_threshold,
                    s.critic_version
                );
            }
        }
        Err(e) => println!("selector  unreachable: {e:#}"),
    }
    if let Ok(Some(e)) = selector.map(|s| s.last_eval.as_ref()) {
        let tasks: Vec<String> = e
            .tasks
            .iter()
            .map(|t| format!("{} {}", t.task, percent(t.success_rate)))
            .collect();
        println!(
            "eval success (deterministic policy, {} episodes/task) at env steps {}, policy v{}: mean {}  [{}]  return {:.1}  ({:.1} s wall, {:.1} s CPU)",
            e.episodes_per_task,
            e.env_steps,
            e.policy_version,
            percent(e.mean_success_rate),
            tasks.join("  "),
            e.mean_return,
            e.wall_seconds,
            e.cpu_seconds
        );
    }
}

/// The launcher of a run folder: `Some(pid)` if `launcher.pid` names a live launcher
/// (`terl cluster up`, which `deploy/local-cluster.sh` runs), `Err` with a clear message if the file is there but that process is
/// gone (the launcher was killed: its services stopped with it), `None` without the file (not
/// started by the launcher, or stopped cleanly).
fn live_launcher(run: &std::path::Path) -> Result<Option<u32>> {
    let file = run.join("launcher.pid");
    let Ok(text) = std::fs::read_to_string(&file) else {
        return Ok(None);
    };
    let pid: Option<u32> = text.trim().parse().ok();
    let alive = pid.is_some_and(|pid| crate::cluster::is_launcher(&pid.to_string()));
    anyhow::ensure!(
        alive,
        "no cluster is running in {}: its launcher (pid {}) is gone, and its services stop \
         with it; start one with ./deploy/local-cluster.sh (--resume {} continues this run), or \
         ask a server with --addr",
        run.display(),
        text.trim(),
        run.display()
    );
    Ok(pid)
}

/// The run folder of the cluster the launcher started last in `runs/` (`runs/.cluster.run`):
/// `Ok(None)` if there is none, an error if its launcher is gone (killed with SIGKILL, which
/// leaves the file behind).
fn last_started_run() -> Result<Option<std::path::PathBuf>> {
    let Ok(dir) = std::fs::read_to_string("runs/.cluster.run") else {
        return Ok(None);
    };
    let dir = std::path::PathBuf::from(dir.trim());
    match live_launcher(&dir)? {
        Some(_) => Ok(Some(dir)),
        None => anyhow::bail!(
            "no cluster is running: the last one started here, in {dir}, has stopped (its \
             launcher removed launcher.pid); `terl report {dir}` summarises it, \
             ./deploy/local-cluster.sh --resume {dir} continues it",
            dir = dir.display()
        ),
    }
}

/// A service's address from `<run>/<name>.addr` (a regular text file of at most 1 MiB).
fn read_addr(dir: &std::path::Path, name: &str) -> Result<String> {
    let path = dir.join(format!("{name}.addr"));
    match std::fs::metadata(&path) {
        Err(_) => anyhow::bail!(
            "{} not found: is {} the folder of a running cluster?",
            path.display(),
            dir.display()
        ),
        // A FIFO or device in its place would block or flood the status.
        Ok(m) if !m.is_file() || m.len() > 1 << 20 => anyhow::bail!(
            "{} is not an address file (not a regular file of at most 1 MiB)",
            path.display()
        ),
        Ok(_) => {}
    }
    let text = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    match String::from_utf8(text) {
        Ok(t) => Ok(t.trim().to_string()),
        Err(_) => anyhow::bail!("{} is not an address file (not text)", path.display()),
    }
}

pub fn run(args: StatusArgs) -> Result<ExitCode> {
    // `--run` of a folder without launcher.pid: a run not started by the launcher, or one
    // whose launcher stopped (its address files stay); a failed connection then says so.
    let mut no_launcher = None;
    let run_dir = match (&args.run, &args.addr) {
        (Some(dir), _) => {
            if live_launcher(dir)?.is_none() {
                no_launcher = Some(dir.clone());
            }
            Some(dir.clone())
        }
        (None, None) => last_started_run()?,
        (None, Some(_)) => None,
    };
    let read = read_addr;
    let (addr, selector_addr, launcher) = match &run_dir {
        Some(dir) => (
            args.addr.clone().map_or_else(|| read(dir, "learner"), Ok)?,
            args.selector_addr
                .clone()
                .map_or_else(|| read(dir, "selector"), Ok)?,
            Some({
                let mut l = read_launcher(dir);
                measure(&mut l);
                l
            }),
        ),
        None => (
            args.addr
                .clone()
                .unwrap_or_else(|| terl_wire::DEFAULT_LEARNER_ADDR.to_string()),
            args.selector_addr
                .clone()
                .unwrap_or_else(|| terl_wire::DEFAULT_SELECTOR_ADDR.to_string()),
            None,
        ),
    };
    let defaulted = run_dir.is_none() && args.addr.is_none();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let timeout = Duration::from_secs_f64(args.timeout.max(0.1));
    let options = args.client_options(run_dir.as_deref())?;
    let tls = options.security.tls.is_some();
    runtime.block_on(async {
        let learner = tokio::time::timeout(timeout, learner_status(&addr, options.clone()))
            .await
            .unwrap_or_else(|_| Err(anyhow::anyhow!("timed out")));
        let why_learner = learner.as_ref().err().and_then(|e| diagnosis(e, tls));
        let learner = learner.with_context(|| {
            if let Some(why) = why_learner {
                format!("learner at {addr}: {why}")
            } else if defaulted {
                format!(
                    "no cluster found: there is no runs/.cluster.run here and nothing \
                         answers at {addr}; start one with ./deploy/local-cluster.sh, or give \
                         --run RUN_DIR or --addr"
                )
            } else if let Some(dir) = &no_launcher {
                format!(
                    "learner at {addr} (no launcher runs in {}: it has no launcher.pid, \
                         so this may be a stopped run)",
                    dir.display()
                )
            } else {
                format!("learner at {addr}")
            }
        })?;
        // A stopped run's address files stay behind; another run may serve there now.
        if let Some(dir) = &run_dir {
            let folder = dir.file_name().map(|n| n.to_string_lossy().into_owned());
            // A launcher's run folder is named by its run id (services started by hand may
            // use any --run-dir).
            if args.addr.is_none()
                && dir.join("cluster.txt").is_file()
                && folder.as_deref().is_some_and(|f| f != learner.run_id)
                && !learner.run_id.is_empty()
            {
                anyhow::bail!(
                    "the learner at {addr} serves run {}, not {}: {} is a stopped run whose \
                     address another run uses now (give that run's folder, or --addr)",
                    learner.run_id,
                    folder.unwrap_or_default(),
                    dir.display()
                );
            }
        }
        let selector = tokio::time::timeout(timeout, selector_status(&selector_addr, options))
            .await
            .unwrap_or_else(|_| Err(anyhow::anyhow!("timed out")))
            .map_err(|e| match diagnosis(&e, tls) {
                Some(why) => e.context(format!("selector at {selector_addr}: {why}")),
                None => e.context(format!("selector at {selector_addr}")),
            });
        if args.json {
            let value = serde_json::json!({
                "learner": learner,
                "selector": selector.as_ref().ok(),
                "launcher": launcher,
            });
            println!("{}", serde_json::to_string(&value)?);
        } else {
            print_table(&learner, selector.as_ref());
            print_machine(&learner, launcher.as_ref());
            if let Some(l) = &launcher {
                print_launcher(l);
            }
        }
        Ok(ExitCode::SUCCESS)
    })
}
