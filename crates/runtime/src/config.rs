//! The run file: which tasks, how many environments, the trainer and SAC settings, and how
//! the cluster splits the work. One TOML schema for `terl train` and the cluster services;
//! the `[cluster]` section is optional, so single-process configs keep working unchanged.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use terl_rl::guidance::GuidanceConfig;
use terl_rl::ptr::PtrConfig;
use terl_rl::train::TrainConfig;
use terl_rl::{SacConfig, TepConfig};

/// What the cluster trains: plain multi-task SAC, or SAC with PTR selection, the TEP planner
/// and guidance (the paper's TERL). Everything else is identical, so runs of the two are
/// comparable at equal budget.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Algorithm {
    /// Multi-task SAC alone (`"mtsac"`, the default).
    #[default]
    Mtsac,
    /// MTSAC plus PTR selection, the TEP planner and guidance (`"terl"`).
    Terl,
    /// SAC behind CARE's context-based encoder (`"care"`, [`terl_rl::care`]): the same
    /// learner, replay and heads as MTSAC, the input `[mixture of state encoders under task
    /// attention, task encoding]`; settings under `[sac.care]` (default: CARE's MT10 ones).
    Care,
}

impl Algorithm {
    /// Its name as in the run file (`algorithm = "..."`): `"mtsac"`, `"terl"` or `"care"`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Mtsac => "mtsac",
            Self::Terl => "terl",
            Self::Care => "care",
        }
    }
}

/// What the learner does when a checkpoint cannot be written (a full disk, a read-only folder):
/// either way the error is logged with the file and counted in status
/// (`checkpoint_failures`), and no half-written file is left under a checkpoint's name.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OnCheckpointError {
    /// Stop training with an error (exit code 1); the checkpoints written before are kept.
    #[default]
    Stop,
    /// Keep training and try again at the next checkpoint.
    Continue,
}

/// The run file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// A task set (`mt10`, `mt1-ind`, ...) or comma-separated task names.
    pub tasks: String,
    /// Training environments (spread round-robin over the tasks).
    pub num_envs: usize,
    /// Evaluation environments per task.
    #[serde(default = "one")]
    pub eval_envs_per_task: usize,
    /// Seed of the goal variations (50 per task).
    #[serde(default)]
    pub variation_seed: u64,
    /// Experiment name that `terl report` groups runs by (with the algorithm), e.g. `mt1-ind`
    /// for runs that each train one of the MT1-Ind tasks; unset: the `tasks` value.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub experiment: Option<String>,
    /// Name of this arm of a comparison within one experiment and algorithm (e.g. `before` and
    /// `after` of a change); `terl report` draws one line per algorithm and variant.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub variant: Option<String>,
    /// `"mtsac"` (default) or `"terl"` (cluster only: PTR selection, TEP, guidance).
    #[serde(default)]
    pub algorithm: Algorithm,
    /// The training schedule (`[train]`): env-step budget, warm-up, update ratio, replay capacity,
    /// evaluation, seed.
    #[serde(default)]
    pub train: TrainConfig,
    /// SAC hyper-parameters and network sizes (`[sac]`).
    #[serde(default)]
    pub sac: SacConfig,
    /// PTR selection in the selector (`algorithm = "terl"`).
    #[serde(default)]
    pub ptr: PtrConfig,
    /// The TEP planner trained by the learner (`algorithm = "terl"`); `obs_dim`/`act_dim` are
    /// set from the environment.
    #[serde(default)]
    pub tep: TepConfig,
    /// TERL guidance in the actors (`algorithm = "terl"`).
    #[serde(default)]
    pub guidance: GuidanceConfig,
    /// Distributed settings (ignored by the single-process trainer).
    #[serde(default)]
    pub cluster: ClusterConfig,
}

fn one() -> usize {
    1
}

/// How the learner, the selector and the actors share the run.
///
/// From `[train]` the cluster uses `total_env_steps` (the learner stops after receiving that
/// many transitions, writes its final checkpoint and exits 0; the launcher then stops the
/// cluster: equal budgets make MTSAC and TERL runs comparable; 0 trains until stopped),
/// `warmup_env_steps` (transitions before the first update; actors act randomly until the first
/// policy version arrives anyway), `replay_capacity_per_task`, `success_window`, `seed` and
/// `eval_every_env_steps`: every that many env steps received by the learner, the selector's
/// evaluator runs the latest policy version deterministically on `eval_episodes_per_task` goal
/// variations of every task (0: no in-run evaluation; `terl eval` evaluates a checkpoint
/// afterwards; an evaluation that outlasts the interval makes the evaluator skip the thresholds
/// it missed rather than queue them). `eval_episodes_per_env` and `stop_at_eval_success` are
/// single-process only.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClusterConfig {
    /// Environments in each actor (0: the run's `num_envs`).
    pub envs_per_actor: usize,
    /// Learner updates per inserted transition (update-to-data ratio). Unset: the
    /// single-process ratio, `train.updates_per_vec_step / num_envs`.
    pub samples_per_insert: Option<f64>,
    /// Slack of the rate limiter, in updates. Unset: `max(1, samples_per_insert)` times two
    /// transition batches, so a whole batch can always be inserted once training caught up.
    pub rate_error_buffer: Option<f64>,
    /// The learner publishes new policy weights every this many updates (and new planner
    /// weights with them, when TEP trained since).
    pub publish_every_updates: u64,
    /// `algorithm = "terl"`: the learner publishes the critics (for the selector's PTR
    /// scoring) at most every this many updates.
    pub critic_publish_every_updates: u64,
    /// Seconds between periodic checkpoints (0: only at shutdown and on request).
    pub checkpoint_every_secs: f64,
    /// Seconds (0 to 10) the learner spends at start, before it serves, timing a fresh copy of
    /// its networks updating back to back on a random batch (its standalone rate, as `terl
    /// bench sac` measures it), which `terl status` compares the in-cluster rate to; 0 skips it
    /// (no ratio is shown). The launcher waits that much longer for the learner to start.
    pub learner_calibrate_secs: f64,
    /// Periodic checkpoints (`checkpoints/update-*.safetensors`) kept, counting the ones earlier
    /// processes of the same run folder wrote (older ones are deleted).
    pub keep_checkpoints: usize,
    /// When a checkpoint cannot be written: `"stop"` (default) or `"continue"`.
    pub on_checkpoint_error: OnCheckpointError,
    /// How long an actor's send may wait for a full learner before giving up on that batch
    /// (counted and logged), seconds.
    pub block_timeout_secs: f64,
    /// Transition batches the learner's shared-memory queue holds before actors wait.
    pub buffer_batches: usize,
    /// In-run evaluation: episodes per task (episode k on goal variation k mod 50). Small by
    /// default so the evaluation does not starve the actors of a small machine; `terl eval`
    /// runs the full 50 on a checkpoint.
    pub eval_episodes_per_task: usize,
    /// In-run evaluation: worker threads of the evaluator (each steps its own environments).
    pub eval_threads: usize,
    /// In-run evaluation: environments the evaluator keeps per task and thread, episodes of a
    /// task stepped in lockstep (1..=10, default 10). They share their task's compiled model
    /// (~9 MB per task) and each adds ~0.4 MB for the whole run (`docs/results/env-memory/`);
    /// the MT50 run files keep 2 (`deploy/configs/mt50*.toml`). Results do not
    /// depend on it.
    pub eval_envs_per_task: usize,
    /// File holding the control-plane token (16 to 1024 visible ASCII characters; trailing
    /// whitespace ignored). Every gRPC call to the learner and the selector must then carry it,
    /// the weight stream included, and every terl client sends it. The `TERL_TOKEN`
    /// environment variable, when set, is used instead. A server bound to anything but a
    /// loopback address refuses to start without a token. Relative paths are relative to the
    /// working directory. The token is never logged.
    pub token_file: Option<PathBuf>,
    /// With a token: leave `GetStatus` of both services and `grpc.health.v1` readable without
    /// it (monitoring without the secret). Checkpoints, weights and reflection stay closed.
    pub status_without_token: bool,
    /// TLS certificate chain of the learner and selector servers (PEM); with `tls_key`, the
    /// servers speak TLS only. Needs `tls_ca` too, since the same run file configures the
    /// clients.
    pub tls_cert: Option<PathBuf>,
    /// Private key of `tls_cert` (PEM). Never logged.
    pub tls_key: Option<PathBuf>,
    /// CA certificate(s) (PEM) the clients (actors, the selector, `terl status`) verify the
    /// servers against; setting it makes the clients use TLS. The system's roots are not used.
    pub tls_ca: Option<PathBuf>,
    /// Name the clients expect in the server certificate, instead of the host they dial (e.g.
    /// `learner.cluster` when dialling an IP address that is not in the certificate).
    pub tls_domain: Option<String>,
    /// Largest gRPC message, MiB, of the learner's server and of the actors' and selector's
    /// weight streams. Every weights message the run's networks produce (policy; with
    /// `algorithm = "terl"` also both critics and the planner's F and AN) must fit:
    /// [`RunConfig::check_weight_messages`] refuses the run at start-up otherwise.
    pub max_message_mib: usize,
    /// What carries transitions and episodes: `"shm"` (iceoryx2 shared memory, every process
    /// on one host; the default) or `"zenoh"` (between hosts over QUIC, TLS 1.3; see `zenoh`).
    pub transport: terl_transport::TransportKind,
    /// `transport = "zenoh"`: the session of every process (`mode` = `"peer"` or
    /// `"client"`, `listen` and `connect` endpoints such as `quic/10.0.0.1:7447`). Each
    /// service's `--zenoh-listen`/`--zenoh-connect` replace the lists for that process.
    pub zenoh: terl_transport::ZenohConfig,
    /// `algorithm = "terl"`: the learner stops (final checkpoint, exit 0, as at the budget) once
    /// the planner gate is open for every task of the run and the TEP buffer holds at least this
    /// many selected transitions of each task: stage 1 of the paper's two-stage pipeline, where
    /// each MT1-Ind task trains until its planner data is usable (`deploy/experiments/run.sh
    /// terl-pipeline`). `train.total_env_steps` stays the cap. 0 (default): off.
    pub stop_at_planner_samples_per_task: u64,
    /// The same run file, seed and learner thread count (`[sac] threads`; "auto" counts the
    /// machine's cores) give the same run bit for bit, whatever the machine's load:
    /// transitions enter replay in rounds of one batch per actor, in actor order; updates run at
    /// fixed transition counts; and an actor's policy version is fixed by its transition count,
    /// `policy_lag_rounds` behind (see [`crate::Lockstep`]). Needs `algorithm = "mtsac"` and
    /// actors with fixed ids; a learner restarted with `--resume` is refused. Default: false
    /// (asynchronous: the rate limiter keeps the update-to-data ratio on average).
    pub reproducible: bool,
    /// `reproducible = true`: rounds (one 64-transition batch per actor) the acting policy
    /// lags the transitions sent, so actors step ahead while the learner learns; 0 (default):
    /// the publication period, `⌈publish_every_updates / (actors·64·samples_per_insert)⌉`.
    pub policy_lag_rounds: u64,
}

/// Longest duration any flag or run-file key in seconds accepts (about 116 days): beyond it a
/// value is a typo, and `Duration::from_secs_f64` would panic near 1.8e19 s.
pub const MAX_SECONDS: f64 = 1e7;

/// Parses a flag value in seconds: finite, > 0 and ≤ [`MAX_SECONDS`] (a clap `value_parser`:
/// the error names the range, clap names the flag and exits 2).
pub fn parse_seconds(text: &str) -> Result<f64, String> {
    let v: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if v.is_finite() && v > 0.0 && v <= MAX_SECONDS {
        Ok(v)
    } else {
        Err(format!("{text} s is not in (0, {MAX_SECONDS:e}] s"))
    }
}

/// Largest `cluster.policy_lag_rounds`: 4096 rounds are 262,144 transitions per actor, far
/// beyond any useful staleness.
pub const MAX_POLICY_LAG_ROUNDS: u64 = 4096;

/// Largest `cluster.learner_calibrate_secs`.
pub const MAX_LEARNER_CALIBRATE_SECS: f64 = 10.0;

/// Largest `cluster.max_message_mib`: gRPC frames a message with a 32-bit length.
pub const MAX_MESSAGE_MIB_LIMIT: usize = 4095;

/// Largest `num_envs` and `cluster.envs_per_actor`: every environment holds a MuJoCo data
/// arena (~0.4 MB beyond the first of its task), so 1024 per process is ~0.5 GB; MT50 needs 50.
pub const MAX_NUM_ENVS: usize = 1024;

/// Largest `train.replay_capacity_per_task`: the replay buffer is allocated up front, ~330
/// bytes per transition, so 10M per task is 3.3 GB per task (the paper uses 1M).
pub const MAX_REPLAY_CAPACITY_PER_TASK: usize = 10_000_000;

/// Most replay transitions over all tasks (~16.5 GB): the paper's MT50 (50 tasks × 1M).
pub const MAX_REPLAY_TRANSITIONS: usize = 50_000_000;

/// Largest `sac.batch_size` (the paper's MT10 batch is 1280, this project's workstation 256).
pub const MAX_BATCH_SIZE: usize = 65_536;

/// Largest episode, evaluation and window counts (`train.eval_episodes_per_env`,
/// `train.success_window`, `cluster.eval_episodes_per_task`): each is held or run in full.
pub const MAX_EPISODE_COUNT: usize = 100_000;

/// Largest `cluster.buffer_batches`: batches of 64 transitions (~21 KB each) queued per actor
/// in shared memory or a Zenoh credit window.
pub const MAX_BUFFER_BATCHES: usize = 4096;

/// Largest `cluster.eval_threads`.
pub const MAX_EVAL_THREADS: usize = 256;

impl Default for ClusterConfig {
    fn default() -> Self {
        Self {
            envs_per_actor: 0,
            samples_per_insert: None,
            rate_error_buffer: None,
            publish_every_updates: 100,
            critic_publish_every_updates: 1000,
            checkpoint_every_secs: 300.0,
            learner_calibrate_secs: 1.0,
            keep_checkpoints: 3,
            on_checkpoint_error: OnCheckpointError::Stop,
            block_timeout_secs: 30.0,
            buffer_batches: 8,
            eval_episodes_per_task: 10,
            eval_threads: 1,
            eval_envs_per_task: crate::eval::BATCH,
            token_file: None,
            status_without_token: false,
            tls_cert: None,
            tls_key: None,
            tls_ca: None,
            tls_domain: None,
            max_message_mib: 64,
            transport: terl_transport::TransportKind::Shm,
            zenoh: terl_transport::ZenohConfig::default(),
            stop_at_planner_samples_per_task: 0,
            reproducible: false,
            policy_lag_rounds: 0,
        }
    }
}

impl RunConfig {
    /// A process's own Zenoh endpoints (`--zenoh-listen`, `--zenoh-connect`): a non-empty
    /// list replaces the run file's `[cluster.zenoh]` one; an empty one keeps it.
    pub fn override_zenoh_endpoints(&mut self, listen: Vec<String>, connect: Vec<String>) {
        if !listen.is_empty() {
            self.cluster.zenoh.listen = listen;
        }
        if !connect.is_empty() {
            self.cluster.zenoh.connect = connect;
        }
    }

    /// The run file's `[sac]` completed for Meta-World: observation and action widths
    /// (`terl_sim::OBS_DIM`, `ACTION_DIM`) and `num_tasks`, the length of the run's task list
    /// (the width of the task one-hot). The one place the SAC dimensions are filled in.
    pub fn sac_config(&self, num_tasks: usize) -> SacConfig {
        SacConfig {
            obs_dim: terl_sim::OBS_DIM,
            act_dim: terl_sim::ACTION_DIM,
            num_tasks,
            ..self.sac.clone()
        }
    }
}

/// The value of the `TERL_TOKEN` environment variable, if set and not empty (what the service
/// binaries pass to [`ClusterConfig::server_security`] / [`ClusterConfig::client_security`]).
pub fn token_from_env() -> Option<String> {
    // A value that is not UTF-8 is passed on (lossily) rather than taken for unset, so the
    // token check refuses it by name instead of a token file silently winning.
    std::env::var_os(terl_wire::TOKEN_ENV)
        .map(|v| v.to_string_lossy().into_owned())
        .filter(|v| !v.is_empty())
}

impl ClusterConfig {
    /// The control-plane token: `env_token` (the `TERL_TOKEN` value) when given, else the
    /// content of `token_file`, else none. Errors name the source, never the value.
    pub fn token(&self, env_token: Option<String>) -> Result<Option<terl_wire::Token>> {
        if let Some(value) = env_token {
            return Ok(Some(terl_wire::Token::new(value, terl_wire::TOKEN_ENV)?));
        }
        match &self.token_file {
            Some(path) => Ok(Some(
                terl_wire::Token::from_file(path).context("cluster.token_file")?,
            )),
            None => Ok(None),
        }
    }

    /// What the learner's and selector's servers enforce: the token, `status_without_token`
    /// and TLS from `tls_cert`/`tls_key` (read now; unreadable files are an error).
    pub fn server_security(&self, env_token: Option<String>) -> Result<terl_wire::ServerSecurity> {
        let tls = match (&self.tls_cert, &self.tls_key) {
            (Some(cert), Some(key)) => Some(
                terl_wire::ServerTls::from_files(cert, key)
                    .context("cluster.tls_cert / cluster.tls_key")?,
            ),
            (None, None) => None,
            _ => anyhow::bail!("cluster.tls_cert and cluster.tls_key must be set together"),
        };
        anyhow::ensure!(
            tls.is_some() || self.tls_ca.is_none(),
            "cluster.tls_ca is set, so every client of this run speaks TLS, but this server has \
             no cluster.tls_cert / cluster.tls_key: it would serve plaintext that no actor or \
             selector could reach; set both (or remove cluster.tls_ca)"
        );
        Ok(terl_wire::ServerSecurity {
            token: self.token(env_token)?,
            status_without_token: self.status_without_token,
            tls,
        })
    }

    /// What every client of the run sends and trusts: the token and, with `tls_ca`, TLS
    /// verified against that CA (and `tls_domain`).
    pub fn client_security(&self, env_token: Option<String>) -> Result<terl_wire::ClientSecurity> {
        let tls = match &self.tls_ca {
            Some(ca) => Some(
                terl_wire::ClientTls::from_file(ca, self.tls_domain.clone())
                    .context("cluster.tls_ca")?,
            ),
            None => None,
        };
        Ok(terl_wire::ClientSecurity {
            token: self.token(env_token)?,
            tls,
        })
    }
}

impl ClusterConfig {
    /// The shared-memory / Zenoh transport of run `run_id` with `num_actors` actors, as every
    /// service opens it: `buffer_batches`, `block_timeout_secs`, `transport` and `zenoh` from
    /// this section, defaults otherwise.
    pub fn transport_config(
        &self,
        run_id: impl Into<String>,
        num_actors: usize,
    ) -> terl_transport::TransportConfig {
        terl_transport::TransportConfig {
            buffer_batches: self.buffer_batches,
            block_timeout: std::time::Duration::from_secs_f64(self.block_timeout_secs),
            transport: self.transport,
            zenoh: self.zenoh.clone(),
            ..terl_transport::TransportConfig::new(run_id, num_actors)
        }
    }

    /// [`ClusterConfig::transport_config`] as a service opens it: with the control-plane
    /// token (`env_token`, the `TERL_TOKEN` value, else `token_file`) as the Zenoh sessions'
    /// shared secret when there is one, so every session of the run authenticates, and with
    /// `tls_ca`, `tls_cert` and `tls_key` as the files of Zenoh's `quic/` endpoints; Zenoh
    /// endpoints beyond loopback need both ([`terl_transport::ZenohConfig::check_locked`]).
    ///
    /// # Errors
    /// The token cannot be read or is malformed (the source is named, never the value).
    pub fn service_transport_config(
        &self,
        run_id: impl Into<String>,
        num_actors: usize,
        env_token: Option<String>,
    ) -> Result<terl_transport::TransportConfig> {
        let mut config = self.transport_config(run_id, num_actors);
        if let Some(token) = self.token(env_token)? {
            config.zenoh.secret = Some(terl_transport::ZenohSecret::new(token.expose())?);
        }
        config.zenoh.tls = terl_transport::ZenohTls {
            ca: self.tls_ca.clone(),
            cert: self.tls_cert.clone(),
            key: self.tls_key.clone(),
        };
        Ok(config)
    }

    /// `max_message_mib` in bytes.
    pub fn max_message_bytes(&self) -> usize {
        self.max_message_mib << 20
    }
}

/// Per-tensor bound on what a weights message adds besides the values: name, shape, field tags
/// and lengths.
const TENSOR_OVERHEAD_BYTES: u64 = 128;
/// Bound on the message's own fields (kind, versions, tensor count).
const MESSAGE_OVERHEAD_BYTES: u64 = 64;

/// Upper bound on the encoded size of a weights message holding MLPs with these layer widths
/// (input, hidden…, output each): 4 bytes per `f32` parameter plus a bound per tensor (weight
/// and bias per layer). `None` if it overflows `u64`.
fn mlp_message_bytes(nets: &[Vec<usize>]) -> Option<u64> {
    nets.iter().try_fold(MESSAGE_OVERHEAD_BYTES, |acc, sizes| {
        sizes.windows(2).try_fold(acc, |acc, w| {
            let (i, o) = (w[0] as u64, w[1] as u64);
            let params = i.checked_mul(o)?.checked_add(o)?;
            acc.checked_add(params.checked_mul(4)?)?
                .checked_add(2 * TENSOR_OVERHEAD_BYTES)
        })
    })
}

/// One MLP's layer widths: `input`, the hidden widths, `output`.
fn widths(input: usize, hidden: &[usize], output: usize) -> Vec<usize> {
    let mut w = vec![input];
    w.extend_from_slice(hidden);
    w.push(output);
    w
}

impl RunConfig {
    /// Reads and checks a run file.
    #[allow(clippy::too_many_lines)] // one check per run-file section, in file order
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read config {}", path.display()))?;
        let mut cfg: Self =
            toml::from_str(&text).with_context(|| format!("invalid config {}", path.display()))?;
        match (cfg.algorithm, &cfg.sac.care) {
            (Algorithm::Care, None) => cfg.sac.care = Some(terl_rl::CareConfig::default()),
            (Algorithm::Care, Some(_)) => {}
            (other, Some(_)) => anyhow::bail!(
                "[sac.care] is set but algorithm = \"{}\": CARE's encoder needs \
                 algorithm = \"care\"",
                other.as_str()
            ),
            (_, None) => {}
        }
        anyhow::ensure!(
            (1..=MAX_NUM_ENVS).contains(&cfg.num_envs),
            "num_envs must be in 1..={MAX_NUM_ENVS} (got {})",
            cfg.num_envs
        );
        anyhow::ensure!(
            (1..=crate::eval::BATCH).contains(&cfg.eval_envs_per_task),
            "eval_envs_per_task must be in 1..={} (got {})",
            crate::eval::BATCH,
            cfg.eval_envs_per_task
        );
        let t = &cfg.train;
        anyhow::ensure!(
            (1..=MAX_REPLAY_CAPACITY_PER_TASK).contains(&t.replay_capacity_per_task),
            "train.replay_capacity_per_task must be in 1..={MAX_REPLAY_CAPACITY_PER_TASK} (got {}): \
             the replay buffer is allocated up front",
            t.replay_capacity_per_task
        );
        let num_tasks = crate::resolve_tasks(&cfg.tasks).map_or(1, |t| t.len());
        let replay = t.replay_capacity_per_task.saturating_mul(num_tasks);
        anyhow::ensure!(
            replay <= MAX_REPLAY_TRANSITIONS,
            "train.replay_capacity_per_task × {num_tasks} tasks is {replay} transitions; at most \
             {MAX_REPLAY_TRANSITIONS} in all (~330 bytes each, allocated up front)"
        );
        for (key, v) in [
            ("train.eval_episodes_per_env", t.eval_episodes_per_env),
            ("train.success_window", t.success_window),
            (
                "cluster.eval_episodes_per_task",
                cfg.cluster.eval_episodes_per_task,
            ),
        ] {
            anyhow::ensure!(
                v <= MAX_EPISODE_COUNT,
                "{key} must be at most {MAX_EPISODE_COUNT} (got {v})"
            );
        }
        anyhow::ensure!(
            t.success_window > 0,
            "train.success_window must be at least 1"
        );
        anyhow::ensure!(
            t.stop_at_eval_success
                .is_none_or(|v| v.is_finite() && (0.0..=1.0).contains(&v)),
            "train.stop_at_eval_success must be in [0, 1]"
        );
        anyhow::ensure!(
            (1..=MAX_BATCH_SIZE).contains(&cfg.sac.batch_size),
            "sac.batch_size must be in 1..={MAX_BATCH_SIZE} (got {})",
            cfg.sac.batch_size
        );
        anyhow::ensure!(
            cfg.cluster.envs_per_actor <= MAX_NUM_ENVS,
            "cluster.envs_per_actor must be at most {MAX_NUM_ENVS} (got {})",
            cfg.cluster.envs_per_actor
        );
        anyhow::ensure!(
            cfg.cluster.buffer_batches <= MAX_BUFFER_BATCHES,
            "cluster.buffer_batches must be at most {MAX_BUFFER_BATCHES} (got {})",
            cfg.cluster.buffer_batches
        );
        anyhow::ensure!(
            cfg.cluster.eval_threads <= MAX_EVAL_THREADS,
            "cluster.eval_threads must be at most {MAX_EVAL_THREADS} (got {})",
            cfg.cluster.eval_threads
        );
        let c = &cfg.cluster;
        let ratio = cfg.samples_per_insert();
        anyhow::ensure!(
            ratio.is_finite() && ratio > 0.0,
            "the update-to-data ratio must be finite and > 0, got {ratio}: it is \
             cluster.samples_per_insert when set, else train.updates_per_vec_step / num_envs \
             ({} / {})",
            cfg.train.updates_per_vec_step,
            cfg.num_envs
        );
        anyhow::ensure!(
            c.publish_every_updates > 0,
            "cluster.publish_every_updates must be at least 1"
        );
        anyhow::ensure!(
            c.checkpoint_every_secs.is_finite()
                && (0.0..=MAX_SECONDS).contains(&c.checkpoint_every_secs),
            "cluster.checkpoint_every_secs must be in [0, {MAX_SECONDS:e}] (0: off)"
        );
        anyhow::ensure!(
            c.learner_calibrate_secs.is_finite()
                && (0.0..=MAX_LEARNER_CALIBRATE_SECS).contains(&c.learner_calibrate_secs),
            "cluster.learner_calibrate_secs must be between 0 and {MAX_LEARNER_CALIBRATE_SECS} \
             (got {})",
            c.learner_calibrate_secs
        );
        anyhow::ensure!(
            c.block_timeout_secs.is_finite()
                && c.block_timeout_secs > 0.0
                && c.block_timeout_secs <= MAX_SECONDS,
            "cluster.block_timeout_secs must be in (0, {MAX_SECONDS:e}]"
        );
        anyhow::ensure!(c.buffer_batches > 0, "cluster.buffer_batches must be ≥ 1");
        anyhow::ensure!(
            c.eval_episodes_per_task > 0,
            "cluster.eval_episodes_per_task must be ≥ 1 (train.eval_every_env_steps = 0 turns \
             in-run evaluation off)"
        );
        anyhow::ensure!(c.eval_threads > 0, "cluster.eval_threads must be ≥ 1");
        anyhow::ensure!(
            (1..=crate::eval::BATCH).contains(&c.eval_envs_per_task),
            "cluster.eval_envs_per_task must be in 1..={}",
            crate::eval::BATCH
        );
        anyhow::ensure!(
            c.tls_cert.is_some() == c.tls_key.is_some(),
            "cluster.tls_cert and cluster.tls_key must be set together"
        );
        anyhow::ensure!(
            c.tls_cert.is_none() || c.tls_ca.is_some(),
            "cluster.tls_cert is set but cluster.tls_ca is not: the run's clients (actors, \
             selector, terl status) need the CA to verify the TLS servers"
        );
        anyhow::ensure!(
            (1..=MAX_MESSAGE_MIB_LIMIT).contains(&c.max_message_mib),
            "cluster.max_message_mib must be in 1..={MAX_MESSAGE_MIB_LIMIT}"
        );
        anyhow::ensure!(
            c.stop_at_planner_samples_per_task == 0 || cfg.algorithm == Algorithm::Terl,
            "cluster.stop_at_planner_samples_per_task needs algorithm = \"terl\" (an MTSAC run \
             has no planner)"
        );
        anyhow::ensure!(
            !c.reproducible || cfg.algorithm != Algorithm::Terl,
            "cluster.reproducible = true needs algorithm = \"mtsac\" or \"care\": TERL's \
             selected samples reach the learner from the selector asynchronously"
        );
        if let Some(care) = &cfg.sac.care {
            care.validate()
                .map_err(|e| anyhow::anyhow!("[sac.care] in {}: {e}", path.display()))?;
            if care.context == terl_rl::CareContext::TaskEmbeddings {
                if let Ok(tasks) = crate::resolve_tasks(&cfg.tasks) {
                    if let Some(t) = tasks
                        .iter()
                        .find(|t| terl_rl::care::task_embedding(t).is_none())
                    {
                        anyhow::bail!(
                            "[sac.care] context = \"task_embeddings\": task `{t}` has no \
                             published description embedding (use context = \"one_hot\")"
                        );
                    }
                }
            }
        }
        // The networks as the run's processes build them (sizes bounded, so that a huge width
        // is refused here rather than aborting a process on allocation).
        if let Ok(tasks) = crate::resolve_tasks(&cfg.tasks) {
            cfg.sac_config(tasks.len())
                .validate()
                .map_err(|e| anyhow::anyhow!("[sac] in {}: {e}", path.display()))?;
        }
        anyhow::ensure!(
            c.policy_lag_rounds <= MAX_POLICY_LAG_ROUNDS,
            "cluster.policy_lag_rounds must be at most {MAX_POLICY_LAG_ROUNDS} (got {})",
            c.policy_lag_rounds
        );
        c.zenoh
            .validate()
            .with_context(|| format!("[cluster.zenoh] in {}", path.display()))?;
        cfg.ptr
            .validate()
            .with_context(|| format!("[ptr] in {}", path.display()))?;
        cfg.tep
            .validate()
            .with_context(|| format!("[tep] in {}", path.display()))?;
        anyhow::ensure!(
            cfg.guidance.sigma.is_finite() && (0.0..=1.0).contains(&cfg.guidance.sigma),
            "guidance.sigma must be in [0, 1]"
        );
        cfg.guidance
            .validate()
            .map_err(|e| anyhow::anyhow!("[guidance]: {e}"))?;
        Ok(cfg)
    }

    /// Upper bounds on the encoded size, bytes, of each weights message the learner publishes
    /// for a run of `num_tasks` tasks: `policy` (the policy MLP, `obs + tasks` inputs, two
    /// outputs per action dimension), and with `algorithm = "terl"` `critic` (both Q networks)
    /// and `planner` (TEP's F and AN). `u64::MAX` stands for a size that overflows.
    pub fn weight_message_bytes(&self, num_tasks: usize) -> Vec<(&'static str, u64)> {
        let sac = &self.sac;
        let front = match &sac.care {
            Some(c) => c.front_dim(),
            None => sac.obs_dim.saturating_add(num_tasks),
        };
        let policy = widths(front, &sac.policy_hidden, sac.act_dim.saturating_mul(2));
        // CARE's policy message also carries the experts, the actor's attention, the task
        // encoder (two tensors each per layer) and the context table.
        let care_extra = sac.care.as_ref().map_or(0u64, |c| {
            let values = c
                .policy_num_params(sac.obs_dim, num_tasks)
                .map_or(u64::MAX, |n| n as u64);
            let layers = (c.num_experts * (c.expert_hidden.len() + 1)
                + c.gate_hidden.len()
                + 1
                + c.context_hidden.len()
                + 1) as u64;
            values
                .saturating_mul(4)
                .saturating_add((2 * layers + 1) * TENSOR_OVERHEAD_BYTES)
        });
        let critic = widths(
            sac.obs_dim
                .saturating_add(num_tasks)
                .saturating_add(sac.act_dim),
            &sac.critic_hidden,
            1,
        );
        // TEP's obs/act dims are set from the environment, which is the SAC's.
        let (obs, act) = (sac.obs_dim, sac.act_dim);
        let f = widths(
            obs.saturating_mul(2).saturating_add(act),
            &self.tep.f_hidden,
            1,
        );
        let an = widths(obs.saturating_mul(2), &self.tep.an_hidden, act);
        let mut out = vec![("policy", vec![policy])];
        if self.algorithm == Algorithm::Terl {
            out.push(("critic", vec![critic.clone(), critic]));
            out.push(("planner", vec![f, an]));
        }
        // The planner message also carries the guidance gate and the goal library.
        let gate_bytes = (num_tasks as u64)
            .saturating_mul(terl_rl::guidance::GOAL_LIBRARY_PER_TASK as u64)
            .saturating_mul(4 * (obs as u64 + 1))
            .saturating_add(4 * num_tasks as u64)
            .saturating_add(3 * TENSOR_OVERHEAD_BYTES);
        out.into_iter()
            .map(|(kind, nets)| {
                let bytes = mlp_message_bytes(&nets).unwrap_or(u64::MAX);
                let extra = match kind {
                    "planner" => gate_bytes,
                    "policy" => care_extra,
                    _ => 0,
                };
                (kind, bytes.saturating_add(extra))
            })
            .collect()
    }

    /// Refuses a run whose weights messages ([`Self::weight_message_bytes`]) would not fit the
    /// gRPC message limit `[cluster] max_message_mib`: the error names the message, its size
    /// and the run-file key with the value that would make it fit.
    pub fn check_weight_messages(&self, num_tasks: usize) -> Result<()> {
        let limit = self.cluster.max_message_bytes() as u64;
        for (kind, bytes) in self.weight_message_bytes(num_tasks) {
            if bytes > limit {
                let need = bytes.div_ceil(1 << 20);
                anyhow::ensure!(
                    need <= MAX_MESSAGE_MIB_LIMIT as u64,
                    "the run's {kind} weights message would be about {need} MiB, more than gRPC \
                     can carry ({MAX_MESSAGE_MIB_LIMIT} MiB): use smaller networks"
                );
                anyhow::bail!(
                    "the run's {kind} weights message would be about {need} MiB, over the gRPC \
                     message limit of {} MiB: set `max_message_mib = {need}` (or more) under \
                     [cluster] in the run file, or use smaller networks",
                    self.cluster.max_message_mib
                );
            }
        }
        Ok(())
    }

    /// Environments per actor.
    pub fn envs_per_actor(&self) -> usize {
        if self.cluster.envs_per_actor == 0 {
            self.num_envs
        } else {
            self.cluster.envs_per_actor
        }
    }

    /// The learner's update-to-data ratio.
    pub fn samples_per_insert(&self) -> f64 {
        self.cluster
            .samples_per_insert
            .unwrap_or(self.train.updates_per_vec_step / self.num_envs as f64)
    }

    /// The rate limiter's slack for transition batches of `batch` transitions.
    pub fn rate_error_buffer(&self, batch: usize) -> f64 {
        self.cluster
            .rate_error_buffer
            .unwrap_or(self.samples_per_insert().max(1.0) * 2.0 * batch as f64)
    }

    /// The task (index into the run's task list) of each environment of actor `actor_id` of
    /// `num_actors`, each asking for `envs_per_actor` environments.
    ///
    /// Every task gets the same number of environments over the whole cluster, for any actor
    /// count: replay samples tasks in equal shares, so unequal environment counts would replay
    /// some tasks' data more often than others'. The cluster's total, `num_actors ×
    /// envs_per_actor`, is rounded up to a multiple of the task count (`k` environments per
    /// task); environment slot `g` of the cluster steps task `g / k` (so an actor holds few
    /// distinct tasks), and actor `a` takes slots `⌊a·M/N⌋ .. ⌊(a+1)·M/N⌋` of the `M` slots, so
    /// actors differ by at most one environment and each has at least one.
    pub fn actor_env_tasks(
        num_tasks: usize,
        actor_id: usize,
        num_actors: usize,
        envs_per_actor: usize,
    ) -> Vec<usize> {
        let (t, n) = (num_tasks.max(1), num_actors.max(1));
        let requested = n * envs_per_actor.max(1);
        let per_task = requested.div_ceil(t);
        let slots = per_task * t;
        let (start, end) = (actor_id * slots / n, (actor_id + 1) * slots / n);
        (start..end.min(slots)).map(|g| g / per_task).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_task_gets_the_same_number_of_environments_for_any_actor_count() {
        for num_tasks in [1, 2, 10, 20, 45, 50] {
            for envs_per_actor in [1, 3, 10] {
                for num_actors in 1..=16 {
                    let mut per_task = vec![0usize; num_tasks];
                    let mut total = 0;
                    for a in 0..num_actors {
                        let mine =
                            RunConfig::actor_env_tasks(num_tasks, a, num_actors, envs_per_actor);
                        assert!(!mine.is_empty(), "actor {a} of {num_actors} has no env");
                        assert!(mine.len() <= envs_per_actor + num_tasks.div_ceil(num_actors));
                        for t in mine {
                            per_task[t] += 1;
                            total += 1;
                        }
                    }
                    let k = per_task[0];
                    assert!(
                        per_task.iter().all(|&c| c == k),
                        "{num_tasks} tasks, {num_actors} actors × {envs_per_actor}: {per_task:?}"
                    );
                    let requested = num_actors * envs_per_actor;
                    assert!(total >= requested && total < requested + num_tasks);
                }
            }
        }
        // The old rule gave tasks 0–4 twice the environments of tasks 5–9 here.
        let counts = (0..15).fold(vec![0; 10], |mut c, a| {
            for t in RunConfig::actor_env_tasks(10, a, 15, 10) {
                c[t] += 1;
            }
            c
        });
        assert_eq!(counts, vec![15; 10]);
        // One actor keeps the single-process layout: one environment per task.
        assert_eq!(
            RunConfig::actor_env_tasks(10, 0, 1, 10),
            (0..10).collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_nan_or_negative_update_to_data_ratio_is_refused_naming_its_keys() {
        let dir = tempfile::tempdir().unwrap();
        for (extra, ok) in [
            ("[train]\nupdates_per_vec_step = nan\n", false),
            ("[train]\nupdates_per_vec_step = -1.0\n", false),
            ("[cluster]\nsamples_per_insert = 0.0\n", false),
            ("[train]\nupdates_per_vec_step = 2.0\n", true),
        ] {
            let path = dir.path().join("r.toml");
            std::fs::write(&path, format!("tasks = \"mt10\"\nnum_envs = 10\n{extra}")).unwrap();
            match RunConfig::load(&path) {
                Ok(_) => assert!(ok, "{extra} accepted"),
                Err(e) => {
                    let e = format!("{e:#}");
                    assert!(!ok, "{extra} refused: {e}");
                    assert!(
                        e.contains("train.updates_per_vec_step")
                            && e.contains("samples_per_insert"),
                        "{e}"
                    );
                }
            }
        }
    }

    /// Every duration key of `[cluster]` with extreme values: refused naming the key (never a
    /// panic later in `Duration::from_secs_f64`), and the longest accepted value converts.
    #[test]
    fn extreme_durations_are_refused_naming_the_key() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.toml");
        for key in [
            "checkpoint_every_secs",
            "block_timeout_secs",
            "learner_calibrate_secs",
        ] {
            for v in ["1e300", "inf", "-inf", "nan", "-1.0", "1.8e19", "1e7"] {
                std::fs::write(
                    &path,
                    format!("tasks = \"mt10\"\nnum_envs = 10\n[cluster]\n{key} = {v}\n"),
                )
                .unwrap();
                let accepted = v == "1e7" && key != "learner_calibrate_secs";
                match RunConfig::load(&path) {
                    Ok(cfg) => {
                        assert!(accepted, "{key} = {v} accepted");
                        let _ = std::time::Duration::from_secs_f64(
                            cfg.cluster
                                .checkpoint_every_secs
                                .max(cfg.cluster.block_timeout_secs),
                        );
                    }
                    Err(e) => {
                        let e = format!("{e:#}");
                        assert!(!accepted, "{key} = {v} refused: {e}");
                        assert!(e.contains(key), "{key} = {v}: {e}");
                    }
                }
            }
        }
        for (text, ok) in [
            ("5", true),
            ("1e7", true),
            ("1e300", false),
            ("inf", false),
            ("nan", false),
            ("0", false),
            ("-0", false),
            ("-1", false),
            ("x", false),
        ] {
            assert_eq!(parse_seconds(text).is_ok(), ok, "{text}");
        }
    }

    #[test]
    fn eval_envs_per_task_outside_one_to_ten_is_refused_naming_the_key() {
        let dir = tempfile::tempdir().unwrap();
        for (value, ok) in [(0, false), (1, true), (10, true), (11, false)] {
            let path = dir.path().join(format!("e{value}.toml"));
            std::fs::write(
                &path,
                format!(
                    "tasks = \"mt10\"\nnum_envs = 10\n[cluster]\neval_envs_per_task = {value}\n"
                ),
            )
            .unwrap();
            match RunConfig::load(&path) {
                Ok(c) => {
                    assert!(ok, "{value} accepted");
                    assert_eq!(c.cluster.eval_envs_per_task, value);
                }
                Err(e) => {
                    assert!(!ok, "{value} refused: {e:#}");
                    assert!(
                        format!("{e:#}").contains("cluster.eval_envs_per_task"),
                        "{e:#}"
                    );
                }
            }
        }
    }

    #[test]
    fn single_process_configs_still_parse() {
        let text = "tasks = \"reach-v3\"\nnum_envs = 4\n[train]\nupdates_per_vec_step = 2.0\n";
        let cfg: RunConfig = toml::from_str(text).unwrap();
        assert_eq!(cfg.cluster, ClusterConfig::default());
        assert_eq!(cfg.envs_per_actor(), 4);
        assert!((cfg.samples_per_insert() - 0.5).abs() < 1e-12);
        assert!(cfg.rate_error_buffer(64) >= 1.0);
        assert_eq!(cfg.cluster.transport, terl_transport::TransportKind::Shm);
    }

    #[test]
    fn zenoh_transport_keys_parse_and_command_line_endpoints_replace_them() {
        let text = "tasks = \"reach-v3\"\nnum_envs = 4\n[cluster]\ntransport = \"zenoh\"\n\
                    [cluster.zenoh]\nmode = \"client\"\nconnect = [\"tcp/10.0.0.1:7447\"]\n";
        let mut cfg: RunConfig = toml::from_str(text).unwrap();
        assert_eq!(cfg.cluster.transport, terl_transport::TransportKind::Zenoh);
        assert_eq!(cfg.cluster.zenoh.mode, terl_transport::ZenohMode::Client);
        assert_eq!(cfg.cluster.zenoh.connect, ["tcp/10.0.0.1:7447"]);
        cfg.override_zenoh_endpoints(vec![], vec!["tcp/10.0.0.2:7447".into()]);
        assert_eq!(cfg.cluster.zenoh.connect, ["tcp/10.0.0.2:7447"]);
        assert!(cfg.cluster.zenoh.listen.is_empty());
        let bad = text.replace("transport = \"zenoh\"", "transport = \"carrier-pigeon\"");
        let err = toml::from_str::<RunConfig>(&bad).unwrap_err().to_string();
        assert!(err.contains("carrier-pigeon"), "{err}");
    }
}

#[cfg(test)]
mod message_limit_tests {
    use super::*;

    fn run_file(extra: &str) -> RunConfig {
        let text = format!("tasks = \"mt10\"\nnum_envs = 10\nalgorithm = \"terl\"\n{extra}");
        let dir = std::env::temp_dir().join(format!("terl-msg-limit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!("{:x}.toml", extra.len()));
        std::fs::write(&path, text).unwrap();
        let cfg = RunConfig::load(&path);
        std::fs::remove_file(&path).unwrap();
        cfg.unwrap()
    }

    #[test]
    fn weights_larger_than_the_message_limit_are_refused_naming_the_key() {
        // The paper-size networks fit the default limit with room to spare.
        let paper =
            run_file("[sac]\npolicy_hidden = [400, 400, 400]\ncritic_hidden = [400, 400, 400]\n");
        paper.check_weight_messages(10).unwrap();
        let sizes = paper.weight_message_bytes(10);
        assert_eq!(
            sizes.iter().map(|s| s.0).collect::<Vec<_>>(),
            ["policy", "critic", "planner"]
        );
        // The policy: (39 + 10)·400 + 400 + 2·(400·400 + 400) + 400·8 + 8 parameters.
        let params = 49 * 400 + 400 + 2 * (400 * 400 + 400) + 400 * 8 + 8;
        let policy = sizes[0].1;
        assert!(
            policy >= 4 * params && policy <= 4 * params + 2048,
            "{policy}"
        );

        // 3×4096 critics: two of them, about 2 × 33.8 M parameters, 258 MiB.
        let big = run_file("[sac]\ncritic_hidden = [4096, 4096, 4096]\n");
        let e = big.check_weight_messages(10).unwrap_err().to_string();
        assert!(
            e.contains("critic") && e.contains("max_message_mib = 258") && e.contains("[cluster]"),
            "{e}"
        );
        // Raising the key as the error says makes the same run acceptable.
        let raised = run_file(
            "[sac]\ncritic_hidden = [4096, 4096, 4096]\n[cluster]\nmax_message_mib = 258\n",
        );
        raised.check_weight_messages(10).unwrap();
        // MTSAC publishes only the policy: the big critics do not count.
        let mut mtsac = big.clone();
        mtsac.algorithm = Algorithm::Mtsac;
        mtsac.check_weight_messages(10).unwrap();
        // Sizes that overflow are refused too, not wrapped around.
        let mut huge = paper.clone();
        huge.sac.policy_hidden = vec![usize::MAX, usize::MAX];
        let e = huge.check_weight_messages(10).unwrap_err().to_string();
        assert!(e.contains("smaller networks"), "{e}");
    }
    #[test]
    fn every_service_opens_the_transport_the_cluster_section_describes() {
        let cfg = run_file(
            "[cluster]\nbuffer_batches = 9\nblock_timeout_secs = 2.5\ntransport = \"zenoh\"\n\
             [cluster.zenoh]\nconnect = [\"tcp/10.0.0.1:7447\"]\n",
        );
        let t = cfg.cluster.transport_config("run-a", 3);
        assert_eq!((t.run_id.as_str(), t.num_actors), ("run-a", 3));
        assert_eq!(t.buffer_batches, 9);
        assert_eq!(t.block_timeout, std::time::Duration::from_millis(2500));
        assert_eq!(t.transport, terl_transport::TransportKind::Zenoh);
        assert_eq!(t.zenoh.connect, ["tcp/10.0.0.1:7447"]);
        // Everything the section does not set keeps the transport's defaults.
        let defaults = terl_transport::TransportConfig::new("run-a", 3);
        assert_eq!(t.buffer_episodes, defaults.buffer_episodes);
        assert_eq!(t.buffer_selected, defaults.buffer_selected);
    }

    #[test]
    fn a_service_s_zenoh_session_takes_the_token_and_the_run_s_tls_files() {
        let cfg = run_file(
            "[cluster]\ntransport = \"zenoh\"\ntls_ca = \"t/ca.pem\"\ntls_cert = \"t/cert.pem\"\n\
             tls_key = \"t/key.pem\"\n[cluster.zenoh]\nconnect = [\"quic/10.0.0.1:7447\"]\n",
        );
        // The run file alone does not admit the endpoint: no token.
        let plain = cfg.cluster.transport_config("run-a", 1);
        assert!(plain.zenoh.check_locked().is_err());
        let t = cfg
            .cluster
            .service_transport_config("run-a", 1, Some("service-token-0123456789".into()))
            .unwrap();
        assert!(t.zenoh.secret.is_some());
        assert_eq!(t.zenoh.tls.ca.as_deref(), Some(Path::new("t/ca.pem")));
        assert_eq!(t.zenoh.tls.cert.as_deref(), Some(Path::new("t/cert.pem")));
        assert_eq!(t.zenoh.tls.key.as_deref(), Some(Path::new("t/key.pem")));
        t.zenoh.check_locked().unwrap();
        // Plain TCP beyond loopback stays refused, token and files or not.
        let mut tcp = t.clone();
        tcp.zenoh.connect = vec!["tcp/10.0.0.1:7447".into()];
        assert!(tcp.zenoh.check_locked().is_err());
    }
}
