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
    /// Learner gRPC address.
    #[arg(long, default_value = terl_wire::DEFAULT_LEARNER_ADDR)]
    pub addr: String,
    /// Selector gRPC address.
    #[arg(long, default_value = terl_wire::DEFAULT_SELECTOR_ADDR)]
    pub selector_addr: String,
    /// Print JSON ({"learner": ..., "selector": ... or null}).
    #[arg(long)]
    pub json: bool,
    /// Seconds to wait for each server.
    #[arg(long, default_value_t = 5.0)]
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
}

impl StatusArgs {
    /// The token (`--token-file`, else TERL_TOKEN) and TLS trust (`--tls-ca`) to connect with.
    pub fn client_options(&self) -> Result<ClientOptions> {
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

fn print_table(learner: &LearnerStatus, selector: Result<&SelectorStatus, &anyhow::Error>) {
    let l = learner;
    println!(
        "learner   run {}  up {:.0}s  updates {} ({:.0}/s)  env steps {}  policy v{}  replay {}/{}  staleness mean {:.0} max {}  rejected {}",
        l.run_id, l.uptime_seconds, l.updates, l.updates_per_second, l.env_steps_total,
        l.policy_version, l.replay_size, l.replay_capacity, l.staleness_mean, l.staleness_max,
        l.rejected_batches
    );
    for a in &l.actors {
        println!(
            "actor {:<3} env steps {:>10} ({:>6.0}/s)  acts with policy v{}  last seen {:.1}s ago",
            a.actor_id, a.env_steps, a.env_steps_per_second, a.policy_version, a.seconds_since_seen
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
            .map(|t| format!("{} {}", t.task, percent(t.guidance_rate)))
            .collect();
        println!(
            "tep       planner v{}  updates {}  buffer {}/{}  loss F {:.3} AN {:.3}  target {:.2}  distance {:.2}  selected {}  guided steps {}",
            l.planner_version, l.tep_updates, l.tep_buffer_size, l.tep_buffer_capacity,
            l.tep_f_loss, l.tep_an_loss, l.tep_target_mean, l.tep_goal_distance_mean,
            l.selected_samples, l.guided_steps
        );
        println!("guidance  {}", guidance.join("  "));
    }
    match selector {
        Ok(s) => {
            let tasks: Vec<String> = s
                .task_success
                .iter()
                .map(|t| format!("{} {} ({})", t.task, percent(t.success_rate), t.episodes))
                .collect();
            println!(
                "selector  episodes {}  selected {}  [{}]",
                s.episodes_seen,
                s.selected_samples,
                tasks.join("  ")
            );
            if s.priority.scored > 0 {
                let p = &s.priority;
                println!(
                    "priority  scored {}  mean {:.3}  min {:.3}  max {:.3}  selection threshold {:.3}  critic v{}",
                    p.scored, p.mean, p.min, p.max, p.selection_threshold, s.critic_version
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

pub fn run(args: StatusArgs) -> Result<ExitCode> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let timeout = Duration::from_secs_f64(args.timeout.max(0.1));
    let options = args.client_options()?;
    runtime.block_on(async {
        let learner = tokio::time::timeout(timeout, learner_status(&args.addr, options.clone()))
            .await
            .unwrap_or_else(|_| Err(anyhow::anyhow!("timed out")))
            .with_context(|| format!("learner at {}", args.addr))?;
        let selector = tokio::time::timeout(timeout, selector_status(&args.selector_addr, options))
            .await
            .unwrap_or_else(|_| Err(anyhow::anyhow!("timed out")))
            .with_context(|| format!("selector at {}", args.selector_addr));
        if args.json {
            let value = serde_json::json!({
                "learner": learner,
                "selector": selector.as_ref().ok(),
            });
            println!("{}", serde_json::to_string(&value)?);
        } else {
            print_table(&learner, selector.as_ref());
        }
        Ok(ExitCode::SUCCESS)
    })
}
