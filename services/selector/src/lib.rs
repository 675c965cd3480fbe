//! The selector service: receives every finished episode the actors send over shared memory,
//! keeps per-task success-rate windows (the gate PTR selection opens at 85 %) and episode
//! statistics, and serves them in `GetStatus`. Priority scoring and the selected-sample stream
//! to the learner arrive with the PTR issue; the statistics here are what that gate reads.

use std::collections::VecDeque;
use std::future::Future;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use terl_transport::{EpisodeSummary, ShmTransport, TransportConfig};
use terl_wire::{SelectorBackend, SelectorStatus, TaskSuccess};
use tonic::Status;

/// Everything the selector needs to start.
pub type SelectorConfig = terl_runtime::ServiceConfig;

/// Per-task episode statistics: a rolling success window plus running totals.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TaskEpisodes {
    pub window: VecDeque<bool>,
    pub episodes: u64,
    pub successes: u64,
    pub return_sum: f64,
    pub length_sum: u64,
}

/// What the selector knows about the run's episodes.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeStats {
    tasks: Vec<String>,
    window_len: usize,
    per_task: Vec<TaskEpisodes>,
    episodes_seen: u64,
    /// Episodes naming a task outside the run's task list (a misconfigured actor).
    rejected: u64,
}

impl EpisodeStats {
    pub fn new(tasks: Vec<String>, window_len: usize) -> Self {
        let per_task = vec![TaskEpisodes::default(); tasks.len()];
        Self {
            tasks,
            window_len: window_len.max(1),
            per_task,
            episodes_seen: 0,
            rejected: 0,
        }
    }

    /// Records one finished episode.
    pub fn record(&mut self, task: usize, success: bool, episode_return: f64, length: u32) {
        let Some(t) = self.per_task.get_mut(task) else {
            self.rejected += 1;
            return;
        };
        self.episodes_seen += 1;
        if t.window.len() == self.window_len {
            t.window.pop_front();
        }
        t.window.push_back(success);
        t.episodes += 1;
        t.successes += u64::from(success);
        if episode_return.is_finite() {
            t.return_sum += episode_return;
        }
        t.length_sum += u64::from(length);
    }

    pub fn per_task(&self) -> &[TaskEpisodes] {
        &self.per_task
    }

    /// Success rate over each task's window.
    pub fn task_success(&self) -> Vec<TaskSuccess> {
        self.tasks
            .iter()
            .zip(&self.per_task)
            .map(|(task, t)| TaskSuccess {
                task: task.clone(),
                success_rate: if t.window.is_empty() {
                    0.0
                } else {
                    t.window.iter().filter(|&&s| s).count() as f64 / t.window.len() as f64
                },
                episodes: t.window.len() as u64,
            })
            .collect()
    }
}

#[derive(Debug)]
struct Shared {
    started: Instant,
    run_id: String,
    stats: Mutex<EpisodeStats>,
    stop: AtomicBool,
}

#[derive(Debug)]
struct Backend(Arc<Shared>);

impl SelectorBackend for Backend {
    async fn status(&self) -> Result<SelectorStatus, Status> {
        let stats = self
            .0
            .stats
            .lock()
            .map_err(|_| Status::internal("stats lock poisoned"))?;
        Ok(SelectorStatus {
            run_id: self.0.run_id.clone(),
            uptime_seconds: self.0.started.elapsed().as_secs_f64(),
            episodes_seen: stats.episodes_seen,
            task_success: stats.task_success(),
            ..SelectorStatus::default()
        })
    }
}

fn receive_loop(config: &SelectorConfig, shared: &Shared) -> anyhow::Result<()> {
    let transport_config = TransportConfig::new(config.run_id.clone(), config.num_actors);
    let transport = ShmTransport::open(transport_config, "selector")?;
    let mut episodes = transport.shm_source::<EpisodeSummary>()?;
    let mut last_log = Instant::now();
    while !shared.stop.load(Ordering::Relaxed) {
        let mut got = 0;
        while let Some(()) = episodes.try_receive_with(|e| {
            if let Ok(mut stats) = shared.stats.lock() {
                stats.record(
                    usize::from(e.task),
                    e.succeeded(),
                    f64::from(e.episode_return),
                    e.length,
                );
            }
        })? {
            got += 1;
        }
        if last_log.elapsed() >= Duration::from_secs(10) {
            last_log = Instant::now();
            if let Ok(stats) = shared.stats.lock() {
                tracing::info!(episodes = stats.episodes_seen, "progress");
            }
        }
        if got == 0 {
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    Ok(())
}

/// Runs the selector until `shutdown` completes or receiving fails.
pub async fn run(
    config: SelectorConfig,
    shutdown: impl Future<Output = ()> + Send,
) -> anyhow::Result<()> {
    let tasks = terl_runtime::resolve_tasks(&config.run.tasks)?
        .into_iter()
        .map(str::to_owned)
        .collect();
    let listener = terl_wire::bind(config.addr)
        .await
        .with_context(|| format!("cannot listen on {}", config.addr))?;
    let addr = listener.local_addr()?;
    let addr_file = terl_runtime::write_addr_file(&config.run_dir, "selector", addr)?;
    tracing::info!(%addr, file = %addr_file.display(), run_id = %config.run_id, "selector listening");
    let shared = Arc::new(Shared {
        started: Instant::now(),
        run_id: config.run_id.clone(),
        stats: Mutex::new(EpisodeStats::new(tasks, config.run.train.success_window)),
        stop: AtomicBool::new(false),
    });
    let (done_tx, mut done_rx) = tokio::sync::watch::channel(false);
    let receiver = {
        let shared = Arc::clone(&shared);
        std::thread::Builder::new()
            .name("episodes".into())
            .spawn(move || {
                let result = receive_loop(&config, &shared);
                let _ = done_tx.send(true);
                result
            })?
    };
    let stop_serving = async {
        tokio::select! {
            () = shutdown => {}
            _ = done_rx.wait_for(|done| *done) => tracing::warn!("episode receiver stopped"),
        }
    };
    let served =
        terl_wire::serve_selector(listener, Backend(Arc::clone(&shared)), stop_serving).await;
    shared.stop.store(true, Ordering::Relaxed);
    let received = tokio::task::spawn_blocking(move || receiver.join())
        .await?
        .map_err(|_| anyhow::anyhow!("episode receiver panicked"))?;
    served.context("gRPC server")?;
    received
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_roll_and_unknown_tasks_are_counted() {
        let mut s = EpisodeStats::new(vec!["a".into(), "b".into()], 2);
        s.record(0, true, 10.0, 500);
        s.record(0, false, 5.0, 500);
        s.record(0, false, 5.0, 500);
        s.record(1, true, 1.0, 500);
        s.record(7, true, 1.0, 500);
        let ts = s.task_success();
        assert_eq!((ts[0].success_rate, ts[0].episodes), (0.0, 2));
        assert_eq!((ts[1].success_rate, ts[1].episodes), (1.0, 1));
        assert_eq!(s.per_task()[0].episodes, 3);
        assert_eq!(s.episodes_seen, 4);
        assert_eq!(s.rejected, 1);
    }
}
