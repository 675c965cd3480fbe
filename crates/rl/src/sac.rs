//! The MTSAC learner: twin Q critics with Polyak targets, a tanh-Gaussian policy and one learned
//! temperature per task, all on an observation with the one-hot task id appended.
//!
//! One update ([`Sac::update`]) computes all three losses from the parameters as they were at the
//! start of the update, then steps all optimisers and the targets:
//!
//! - critics: `y = r + γ·(1 − terminated)·(min_k Q̄_k(s', a') − α_task·log π(a'|s'))`,
//!   `L_Q = mean (Q_1(s,a) − y)² + mean (Q_2(s,a) − y)²`, `a' ~ π(·|s')`;
//! - actor: `L_π = mean (α_task·log π(ã|s) − min_k Q_k(s, ã))`, `ã ~ π(·|s)` reparameterised;
//! - temperature: `L_α = mean (−ln α_task · (log π(ã|s) + H̄))` with `H̄ = −|A|` by default.
//!
//! Computing every loss before any step is what lets a non-finite loss or gradient stop the
//! update with all weights untouched. It also lets the policy run `s'` and `s` as one stacked
//! GEMM per layer, and each critic run `(s, a)` and `(s, ã)` as one: fewer, larger GEMMs. With
//! more than one thread the two critics run concurrently (each with sequential GEMMs), which
//! beats splitting small GEMMs across cores.

use crate::batch::Batch;
use crate::care::{self, CareEncoder};
use crate::config::SacConfig;
use crate::error::SacError;
use crate::names;
use crate::policy::PolicySpec;
use faer::Par;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use terl_nn::tensors::{save_file, Tensor, TensorFile};
use terl_nn::{
    clear_upper_state, clip_global_norm, gaussian, par_for_threads, Activation, Adam, Float,
    InputGrad, Mlp, MlpCache, MlpSpec,
};

/// Losses and diagnostics of one update (names follow cleanrl's metric names).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct UpdateStats {
    /// Mean squared TD error of critic 1 against the clipped double-Q soft target
    /// `r + γ (1 − terminated) (min_k Q'_k(s', a') − α log π(a'|s'))`.
    pub qf1_loss: f64,
    /// The same for critic 2.
    pub qf2_loss: f64,
    /// Mean of `α log π(ã|s) − min_k Q_k(s, ã)` over the batch.
    pub actor_loss: f64,
    /// Mean of `−ln α_task · (log π(ã|s) + target_entropy)` over the batch (per-task
    /// temperature).
    pub alpha_loss: f64,
    /// Mean of `Q_1(s, a)` over the batch.
    pub qf1_mean: f64,
    /// Mean `log π(ã|s)` over the batch (minus the policy entropy estimate).
    pub log_prob_mean: f64,
    /// Mean temperature over the batch's rows.
    pub alpha_mean: f64,
    /// Global norm of the policy gradient before clipping.
    #[serde(default)]
    pub actor_grad_norm: f64,
    /// Global norm of both critics' gradients together, before clipping.
    #[serde(default)]
    pub critic_grad_norm: f64,
}

/// One critic with its target, optimiser, gradient and activation buffers.
#[derive(Debug)]
struct Critic<T> {
    net: Mlp<T>,
    target: Mlp<T>,
    adam: Adam<T>,
    grads: Vec<T>,
    /// Rows `0..B`: `(s, a)`; rows `B..2B`: `(s, ã)`.
    cache: MlpCache<T>,
    /// Rows `0..B`: `(s', a')` for the target network.
    target_cache: MlpCache<T>,
}

/// Multi-task SAC: networks, optimiser state, update buffers, counters.
#[derive(Debug)]
pub struct Sac<T: Float = f32> {
    config: SacConfig,
    policy: Mlp<T>,
    policy_adam: Adam<T>,
    policy_grads: Vec<T>,
    /// Rows `0..B`: `s'`; rows `B..2B`: `s`.
    policy_cache: MlpCache<T>,
    critics: [Critic<T>; 2],
    log_alpha: Vec<T>,
    alpha_adam: Adam<T>,
    alpha_grads: Vec<T>,
    rng: ChaCha8Rng,
    pool: Option<rayon::ThreadPool>,
    // Per-update buffers, sized for the batch capacity.
    eps: Vec<T>,
    pi_actions: Vec<T>,
    log_prob: Vec<T>,
    alpha_rows: Vec<T>,
    targets: Vec<T>,
    d_actions: Vec<T>,
    d_log_prob: Vec<T>,
    /// CARE's encoder in front of the heads (`config.care`).
    care: Option<CareEncoder<T>>,
    /// CARE: gradient of the critics' loss w.r.t. their front, `[B, front_dim]`, both summed.
    d_front: Vec<T>,
    /// CARE: gradient of the actor's loss w.r.t. the mixture part of its input, `[B, F]`.
    d_features: Vec<T>,
    updates: u64,
    rejected_batches: u64,
}

fn policy_spec(cfg: &SacConfig) -> MlpSpec {
    MlpSpec {
        input: cfg.policy_input(),
        hidden: cfg.policy_hidden.clone(),
        output: 2 * cfg.act_dim,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Identity,
    }
}

fn critic_spec(cfg: &SacConfig) -> MlpSpec {
    MlpSpec {
        input: cfg.critic_input(),
        hidden: cfg.critic_hidden.clone(),
        output: 1,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Identity,
    }
}

/// Writes `[obs, one_hot(task)]` (and `action` if given) into one input row.
#[inline]
fn write_input<T: Float>(
    row: &mut [T],
    obs: &[f32],
    task: usize,
    num_tasks: usize,
    action: Option<&[T]>,
) {
    let (o, rest) = row.split_at_mut(obs.len());
    for (d, &s) in o.iter_mut().zip(obs) {
        *d = T::of_f32(s);
    }
    let (onehot, act) = rest.split_at_mut(num_tasks);
    onehot.fill(T::of(0.0));
    onehot[task] = T::of(1.0);
    if let Some(a) = action {
        act.copy_from_slice(a);
    }
}

impl<T: Float> Critic<T> {
    fn new(cfg: &SacConfig, rng: &mut ChaCha8Rng) -> Self {
        let net = Mlp::new_with(&critic_spec(cfg), cfg.init_for(true), rng);
        let b = cfg.batch_size;
        Self {
            target: net.clone(),
            adam: Adam::new(net.num_params(), cfg.adam(cfg.critic_lr)),
            grads: vec![T::of(0.0); net.num_params()],
            cache: MlpCache::new(&net, 2 * b),
            target_cache: MlpCache::new(&net, b),
            net,
        }
    }

    /// Fills rows `0..B` with `(s, a)` of the batch and runs the critic on them (needs no
    /// policy output, so it can run while the policy does).
    fn forward_replay(&mut self, cfg: &SacConfig, batch: &Batch, care: Option<&[T]>, par: Par) {
        let (b, od, a, nt) = (batch.len(), cfg.obs_dim, cfg.act_dim, cfg.num_tasks);
        let w = cfg.critic_input();
        let cin = self.cache.input_mut(0..b);
        if let Some(front) = care {
            let p = cfg.policy_input();
            for i in 0..b {
                let row = &mut cin[i * w..(i + 1) * w];
                row[..p].copy_from_slice(&front[i * p..(i + 1) * p]);
                for (d, &s) in row[p..].iter_mut().zip(&batch.actions[i * a..(i + 1) * a]) {
                    *d = T::of_f32(s);
                }
            }
            self.net.forward_rows(&mut self.cache, 0..b, par);
            return;
        }
        for i in 0..b {
            let task = batch.task_ids[i] as usize;
            let row = &mut cin[i * w..(i + 1) * w];
            write_input(row, &batch.obs[i * od..(i + 1) * od], task, nt, None);
            for (d, &s) in row[od + nt..]
                .iter_mut()
                .zip(&batch.actions[i * a..(i + 1) * a])
            {
                *d = T::of_f32(s);
            }
        }
        self.net.forward_rows(&mut self.cache, 0..b, par);
    }

    /// Fills inputs and runs the target on `(s', a')` and the critic on `(s, ã)` (rows
    /// `B..2B`), with `a'` and `ã` the policy's samples `pi_actions` (rows `0..B` and `B..2B`).
    fn forward_policy(
        &mut self,
        cfg: &SacConfig,
        batch: &Batch,
        pi_actions: &[T],
        care: Option<(&[T], &[T])>,
        par: Par,
    ) {
        let (b, od, a, nt) = (batch.len(), cfg.obs_dim, cfg.act_dim, cfg.num_tasks);
        let w = cfg.critic_input();
        if let Some((critic, target)) = care {
            // CARE: the target reads the target encoder's front on s', the critic its own on s.
            let p = cfg.policy_input();
            let tin = self.target_cache.input_mut(0..b);
            for i in 0..b {
                let row = &mut tin[i * w..(i + 1) * w];
                row[..p].copy_from_slice(&target[i * p..(i + 1) * p]);
                row[p..].copy_from_slice(&pi_actions[i * a..(i + 1) * a]);
            }
            self.target.forward(&mut self.target_cache, b, par);
            let cin = self.cache.input_mut(b..2 * b);
            for i in 0..b {
                let row = &mut cin[i * w..(i + 1) * w];
                row[..p].copy_from_slice(&critic[i * p..(i + 1) * p]);
                row[p..].copy_from_slice(&pi_actions[(b + i) * a..(b + i + 1) * a]);
            }
            self.net.forward_rows(&mut self.cache, b..2 * b, par);
            return;
        }
        let tin = self.target_cache.input_mut(0..b);
        for i in 0..b {
            let task = batch.task_ids[i] as usize;
            let next_obs = &batch.next_obs[i * od..(i + 1) * od];
            write_input(
                &mut tin[i * w..(i + 1) * w],
                next_obs,
                task,
                nt,
                Some(&pi_actions[i * a..(i + 1) * a]),
            );
        }
        self.target.forward(&mut self.target_cache, b, par);
        let cin = self.cache.input_mut(b..2 * b);
        for i in 0..b {
            let task = batch.task_ids[i] as usize;
            write_input(
                &mut cin[i * w..(i + 1) * w],
                &batch.obs[i * od..(i + 1) * od],
                task,
                nt,
                Some(&pi_actions[(b + i) * a..(b + i + 1) * a]),
            );
        }
        self.net.forward_rows(&mut self.cache, b..2 * b, par);
    }

    /// Critic-loss parameter gradients from rows `0..B` and the actor's action gradients from
    /// rows `B..2B` (gradient of the loss w.r.t. the outputs already written by the caller).
    fn backward(&mut self, cfg: &SacConfig, b: usize, par: Par) {
        // With CARE the critics' loss also flows into the encoder through the front columns.
        let front = match cfg.care {
            Some(_) => InputGrad::Cols(0..cfg.policy_input()),
            None => InputGrad::None,
        };
        self.net
            .backward(&mut self.cache, 0..b, Some(&mut self.grads), front, par);
        let acts = cfg.policy_input()..cfg.critic_input();
        self.net
            .backward(&mut self.cache, b..2 * b, None, InputGrad::Cols(acts), par);
    }

    fn step(&mut self, tau: T) {
        self.adam.step(&mut self.net.params, &self.grads);
        self.target.polyak_from(&self.net, tau);
    }
}

/// Runs `f` on both critics, concurrently when a pool is present.
fn both<T: Float>(critics: &mut [Critic<T>; 2], parallel: bool, f: impl Fn(&mut Critic<T>) + Sync) {
    let [c1, c2] = critics;
    if parallel {
        // A pool thread may come back dirty from a GEMM micro-kernel (see
        // `terl_nn::clear_upper_state`).
        rayon::join(
            || {
                clear_upper_state();
                f(c1)
            },
            || {
                clear_upper_state();
                f(c2)
            },
        );
    } else {
        f(c1);
        f(c2);
    }
}

impl<T: Float> Sac<T> {
    /// Builds networks (seeded by `config.seed`), optimisers and all update buffers.
    ///
    /// # Errors
    /// An invalid config, or CARE with task-embedding context (its context table needs the
    /// task names: [`Sac::for_tasks`]).
    pub fn new(config: SacConfig) -> Result<Self, SacError> {
        Self::with_context(config, None)
    }

    /// Like [`Sac::new`] for the tasks `tasks` (in task-id order): with CARE the context table
    /// is built from their names ([`care::context_table`]); MTSAC ignores the names.
    ///
    /// # Errors
    /// [`Sac::new`]'s, a task count other than `num_tasks`, or a task without a published
    /// embedding.
    pub fn for_tasks(config: SacConfig, tasks: &[String]) -> Result<Self, SacError> {
        let table = match &config.care {
            Some(care) => {
                if tasks.len() != config.num_tasks {
                    return Err(SacError::Config(format!(
                        "{} task names for num_tasks {}",
                        tasks.len(),
                        config.num_tasks
                    )));
                }
                Some(care::context_table(care, tasks)?)
            }
            None => None,
        };
        Self::with_context(config, table.as_deref())
    }

    /// Like [`Sac::new`] with CARE's context table given (`[num_tasks, context_dim]`; `None`
    /// builds the one-hot table, the only one that needs no task names).
    pub fn with_context(config: SacConfig, context: Option<&[f32]>) -> Result<Self, SacError> {
        config.validate()?;
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        let policy = Mlp::new_with(&policy_spec(&config), config.init_for(false), &mut rng);
        let critics = [
            Critic::new(&config, &mut rng),
            Critic::new(&config, &mut rng),
        ];
        let care = match &config.care {
            None => None,
            Some(cc) => {
                let one_hot;
                let table = match (context, cc.context) {
                    (Some(t), _) => t,
                    (None, care::CareContext::OneHot) => {
                        one_hot = care::context_table(
                            cc,
                            &(0..config.num_tasks)
                                .map(|t| t.to_string())
                                .collect::<Vec<_>>(),
                        )?;
                        &one_hot[..]
                    }
                    (None, care::CareContext::TaskEmbeddings) => {
                        return Err(SacError::Config(
                            "care with context = \"task_embeddings\" needs the task names \
                             (Sac::for_tasks) or a context table"
                                .into(),
                        ))
                    }
                };
                Some(CareEncoder::new(&config, table, &mut rng)?)
            }
        };
        let pool = if config.threads > 1 {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(config.threads)
                .thread_name(|i| format!("sac-update-{i}"))
                .build()
                .map_err(|e| {
                    SacError::Config(format!(
                        "cannot start {} update threads: {e}",
                        config.threads
                    ))
                })?;
            Some(pool)
        } else {
            None
        };
        let (b, a, nt) = (config.batch_size, config.act_dim, config.num_tasks);
        let zeros = |n: usize| vec![T::of(0.0); n];
        Ok(Self {
            policy_adam: Adam::new(policy.num_params(), config.adam(config.actor_lr)),
            policy_grads: zeros(policy.num_params()),
            policy_cache: MlpCache::new(&policy, 2 * b),
            policy,
            critics,
            log_alpha: vec![T::of(config.initial_log_alpha); nt],
            alpha_adam: Adam::new(nt, config.adam(config.alpha_lr)),
            alpha_grads: zeros(nt),
            rng,
            pool,
            eps: zeros(2 * b * a),
            pi_actions: zeros(2 * b * a),
            log_prob: zeros(2 * b),
            alpha_rows: zeros(b),
            targets: zeros(b),
            d_actions: zeros(b * a),
            d_log_prob: zeros(b),
            d_front: zeros(if care.is_some() {
                b * config.policy_input()
            } else {
                0
            }),
            d_features: zeros(config.care.as_ref().map_or(0, |c| b * c.feature_dim)),
            care,
            updates: 0,
            rejected_batches: 0,
            config,
        })
    }

    /// The hyper-parameters this agent was built with.
    pub fn config(&self) -> &SacConfig {
        &self.config
    }

    /// Updates applied so far.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Batches rejected for non-finite values so far.
    pub fn rejected_batches(&self) -> u64 {
        self.rejected_batches
    }

    /// Per-task `ln α`.
    pub fn log_alpha(&self) -> &[T] {
        &self.log_alpha
    }

    /// Mutable per-task `ln α`; the temperature optimiser's state is left as is.
    pub fn log_alpha_mut(&mut self) -> &mut [T] {
        &mut self.log_alpha
    }

    /// The policy network (outputs mean and log-std of the tanh-squashed Gaussian).
    pub fn policy_net(&self) -> &Mlp<T> {
        &self.policy
    }

    /// Mutable policy network (its parameters; the Adam state is left as is).
    pub fn policy_net_mut(&mut self) -> &mut Mlp<T> {
        &mut self.policy
    }

    /// Critic `k` (0 or 1).
    pub fn critic_net(&self, k: usize) -> &Mlp<T> {
        &self.critics[k].net
    }

    /// Mutable critic `k` (0 or 1); its target and Adam state are left as is.
    pub fn critic_net_mut(&mut self, k: usize) -> &mut Mlp<T> {
        &mut self.critics[k].net
    }

    /// Target critic `k` (0 or 1).
    pub fn target_net(&self, k: usize) -> &Mlp<T> {
        &self.critics[k].target
    }

    /// Gradients of the last [`Sac::compute_gradients`]: policy, critic 0, critic 1, `ln α`.
    pub fn gradients(&self) -> (&[T], &[T], &[T], &[T]) {
        (
            &self.policy_grads,
            &self.critics[0].grads,
            &self.critics[1].grads,
            &self.alpha_grads,
        )
    }

    /// CARE's attention over its state encoders after the last update's forward pass: the
    /// critics' and the actor's, each `[num_tasks, num_experts]` (rows sum to one). `None`
    /// without CARE.
    pub fn care_attention(&self) -> Option<(&[T], &[T])> {
        self.care
            .as_ref()
            .map(|c| (c.critic_attention(), c.actor_attention()))
    }

    /// CARE's network `net` (`None` without CARE or for an expert index out of range); its
    /// optimiser state and target are left as they are.
    pub fn care_net_mut(&mut self, net: care::CareNet) -> Option<&mut Mlp<T>> {
        self.care.as_mut().and_then(|c| c.net_mut(net))
    }

    /// The gradient of CARE's network `net` from the last [`Sac::compute_gradients`] (after
    /// [`Sac::update`], clipped): experts, critics' attention and task encoder from the
    /// critics' loss, the actor's attention from the actor's loss.
    pub fn care_gradient(&self, net: care::CareNet) -> Option<&[T]> {
        self.care.as_ref().and_then(|c| c.gradient(net))
    }

    /// The shape of the policy, for building an inference [`crate::Policy`].
    pub fn policy_spec(&self) -> PolicySpec {
        PolicySpec::from_config(&self.config)
    }

    /// One full update: reject a non-finite batch (counted), draw the sampling noise, compute
    /// all losses and gradients, and only if all are finite step the critics, the policy, the
    /// temperatures and the targets.
    pub fn update(&mut self, batch: &Batch) -> Result<UpdateStats, SacError> {
        self.check_batch(batch)?;
        if let Err(e) = batch.check_finite() {
            self.rejected_batches += 1;
            return Err(e);
        }
        self.resample_noise(batch.len());
        let pool = self.pool.take();
        let result = match &pool {
            Some(pool) => pool.install(|| self.compute_and_apply(batch)),
            None => self.compute_and_apply(batch),
        };
        self.pool = pool;
        result
    }

    fn compute_and_apply(&mut self, batch: &Batch) -> Result<UpdateStats, SacError> {
        let mut stats = self.compute_gradients_inner(batch)?;
        (stats.actor_grad_norm, stats.critic_grad_norm) = self.clip_gradients();
        self.apply_gradients();
        Ok(stats)
    }

    /// Clips the policy gradient and the critics' joint gradient to `max_grad_norm` (global
    /// norm; nothing when it is 0) and returns both norms before clipping.
    fn clip_gradients(&mut self) -> (f64, f64) {
        let max = self.config.max_grad_norm;
        let bound = if max > 0.0 { max } else { f64::INFINITY };
        if self.care.is_some() {
            return self.clip_care_gradients(bound);
        }
        let actor = clip_global_norm(&mut [&mut self.policy_grads[..]], bound);
        let [c1, c2] = &mut self.critics;
        let critic = clip_global_norm(&mut [&mut c1.grads[..], &mut c2.grads[..]], bound);
        (actor, critic)
    }

    /// [`Self::clip_gradients`] with CARE: the actor's group also holds the actor's attention,
    /// the critics' group the experts, the critics' attention and the task encoder.
    fn clip_care_gradients(&mut self, bound: f64) -> (f64, f64) {
        let care = self.care.as_mut().expect("called with CARE");
        let actor =
            (care::sq_norm(&self.policy_grads) + care::sq_norm(care.actor_grads_mut())).sqrt();
        let [c1, c2] = &mut self.critics;
        let critic =
            (care::sq_norm(&c1.grads) + care::sq_norm(&c2.grads) + care.critic_grad_sq_norm())
                .sqrt();
        if actor.is_finite() && actor > bound {
            let scale = T::of(bound / actor);
            self.policy_grads.iter_mut().for_each(|v| *v *= scale);
            care.actor_grads_mut().iter_mut().for_each(|v| *v *= scale);
        }
        if critic.is_finite() && critic > bound {
            let scale = T::of(bound / critic);
            c1.grads.iter_mut().for_each(|v| *v *= scale);
            c2.grads.iter_mut().for_each(|v| *v *= scale);
            care.scale_critic_grads(scale);
        }
        (actor, critic)
    }

    fn check_batch(&self, batch: &Batch) -> Result<(), SacError> {
        let c = &self.config;
        if batch.obs_dim != c.obs_dim || batch.act_dim != c.act_dim {
            return Err(SacError::Shape(format!(
                "batch has obs/act dims {}/{}, config {}/{}",
                batch.obs_dim, batch.act_dim, c.obs_dim, c.act_dim
            )));
        }
        if batch.is_empty() || batch.len() > c.batch_size {
            return Err(SacError::Shape(format!(
                "batch of {} rows; capacity is {}",
                batch.len(),
                c.batch_size
            )));
        }
        batch.check_shape(c.num_tasks)
    }

    /// Draws new reparameterisation noise for `rows` rows (`s'` then `s`).
    pub fn resample_noise(&mut self, rows: usize) {
        let n = 2 * rows * self.config.act_dim;
        gaussian::fill_standard_normal(&mut self.rng, &mut self.eps[..n]);
    }

    /// Computes losses and gradients with the current noise, without changing any parameter
    /// (for gradient checks and diagnostics; [`Sac::update`] is the training entry point).
    pub fn compute_gradients(&mut self, batch: &Batch) -> Result<UpdateStats, SacError> {
        self.check_batch(batch)?;
        batch.check_finite()?;
        let pool = self.pool.take();
        let result = match &pool {
            Some(pool) => pool.install(|| self.compute_gradients_inner(batch)),
            None => self.compute_gradients_inner(batch),
        };
        self.pool = pool;
        result
    }

    #[allow(clippy::too_many_lines)] // one SAC update's forward and backward passes in order (critics, policy, temperature), as in the reference implementation
    fn compute_gradients_inner(&mut self, batch: &Batch) -> Result<UpdateStats, SacError> {
        let cfg = &self.config;
        let (b, od, a, nt) = (batch.len(), cfg.obs_dim, cfg.act_dim, cfg.num_tasks);
        let threads = cfg.threads;
        let parallel = threads > 1;
        let par = par_for_threads(threads);
        let inv_b = T::of(1.0 / b as f64);
        let gamma = T::of(cfg.gamma);
        let target_entropy = T::of(cfg.target_entropy());

        // Policy on s' (rows 0..B) and s (rows B..2B), then reparameterised samples.
        let pw = cfg.policy_input();
        let pin = self.policy_cache.input_mut(0..2 * b);
        if let Some(care) = &mut self.care {
            care.forward(&batch.obs, &batch.next_obs, &batch.task_ids, par);
            pin.copy_from_slice(&care.front_policy[..2 * b * pw]);
        }
        for i in (0..b).filter(|_| self.care.is_none()) {
            let task = batch.task_ids[i] as usize;
            write_input(
                &mut pin[i * pw..(i + 1) * pw],
                &batch.next_obs[i * od..(i + 1) * od],
                task,
                nt,
                None,
            );
            write_input(
                &mut pin[(b + i) * pw..(b + i + 1) * pw],
                &batch.obs[i * od..(i + 1) * od],
                task,
                nt,
                None,
            );
        }
        // The policy on s' and s while the critics run on (s, a) of the batch (on one thread
        // each with a pool: the three are independent).
        let critic_par = if parallel { Par::Seq } else { par };
        let care_critic = self.care.as_ref().map(|c| &c.front_critic[..b * pw]);
        if parallel {
            let (policy, policy_cache, critics) =
                (&self.policy, &mut self.policy_cache, &mut self.critics);
            rayon::join(
                || {
                    clear_upper_state();
                    policy.forward(policy_cache, 2 * b, Par::Seq);
                },
                || {
                    clear_upper_state();
                    both(critics, false, |c| {
                        c.forward_replay(cfg, batch, care_critic, Par::Seq)
                    });
                },
            );
        } else {
            self.policy.forward(&mut self.policy_cache, 2 * b, par);
            both(&mut self.critics, false, |c| {
                c.forward_replay(cfg, batch, care_critic, par)
            });
        }
        let (eps, pi_actions, log_prob) = (
            &self.eps[..2 * b * a],
            &mut self.pi_actions[..2 * b * a],
            &mut self.log_prob[..2 * b],
        );
        gaussian::sample(
            self.policy_cache.output(0..2 * b),
            eps,
            a,
            pi_actions,
            log_prob,
        );
        for i in 0..b {
            self.alpha_rows[i] = self.log_alpha[batch.task_ids[i] as usize].exp();
        }

        // Both critics: targets on (s', a'), critics on (s, ã).
        let pi_actions = &self.pi_actions[..2 * b * a];
        let care_fronts = self
            .care
            .as_ref()
            .map(|c| (&c.front_critic[..b * pw], &c.front_target[..b * pw]));
        both(&mut self.critics, parallel, |c| {
            c.forward_policy(cfg, batch, pi_actions, care_fronts, critic_par)
        });

        // Targets and the gradients of all losses w.r.t. the critic outputs.
        let mut stats = UpdateStats::default();
        for i in 0..b {
            let q_next = self.critics[0].target_cache.output(i..i + 1)[0]
                .min(self.critics[1].target_cache.output(i..i + 1)[0]);
            let soft = q_next - self.alpha_rows[i] * self.log_prob[i];
            let not_done = T::of(1.0) - T::of_f32(batch.terminated[i]);
            self.targets[i] = T::of_f32(batch.rewards[i]) + gamma * not_done * soft;
        }
        let mut critic_losses = [0.0f64; 2];
        for (k, critic) in self.critics.iter_mut().enumerate() {
            let (q, dq) = critic.cache.output_and_grad_mut(0..b);
            let mut loss = 0.0f64;
            for i in 0..b {
                let err = q[i] - self.targets[i];
                loss += (err * err).f64();
                dq[i] = T::of(2.0) * err * inv_b;
            }
            critic_losses[k] = loss / b as f64;
            if k == 0 {
                stats.qf1_mean = q.iter().map(|v| v.f64()).sum::<f64>() / b as f64;
            }
        }
        let mut actor_loss = 0.0f64;
        {
            let [c1, c2] = &mut self.critics;
            let (q1, d1) = c1.cache.output_and_grad_mut(b..2 * b);
            let (q2, d2) = c2.cache.output_and_grad_mut(b..2 * b);
            for i in 0..b {
                let first = q1[i] <= q2[i];
                let q_min = if first { q1[i] } else { q2[i] };
                actor_loss += (self.alpha_rows[i] * self.log_prob[b + i] - q_min).f64();
                d1[i] = if first { -inv_b } else { T::of(0.0) };
                d2[i] = if first { T::of(0.0) } else { -inv_b };
            }
        }
        stats.qf1_loss = critic_losses[0];
        stats.qf2_loss = critic_losses[1];
        stats.actor_loss = actor_loss / b as f64;
        self.alpha_grads.fill(T::of(0.0));
        let mut alpha_loss = 0.0f64;
        for i in 0..b {
            let task = batch.task_ids[i] as usize;
            let slack = self.log_prob[b + i] + target_entropy;
            alpha_loss -= (self.log_alpha[task] * slack).f64();
            self.alpha_grads[task] -= slack * inv_b;
        }
        stats.alpha_loss = alpha_loss / b as f64;
        stats.log_prob_mean =
            self.log_prob[b..2 * b].iter().map(|v| v.f64()).sum::<f64>() / b as f64;
        stats.alpha_mean = self.alpha_rows[..b].iter().map(|v| v.f64()).sum::<f64>() / b as f64;
        for (loss, value) in [
            ("qf1", stats.qf1_loss),
            ("qf2", stats.qf2_loss),
            ("actor", stats.actor_loss),
            ("alpha", stats.alpha_loss),
        ] {
            if !value.is_finite() {
                return Err(SacError::NonFiniteLoss { loss, value });
            }
        }

        // Backward: critics (parameters from the critic loss, actions from the actor loss).
        both(&mut self.critics, parallel, |c| {
            c.backward(cfg, b, critic_par)
        });
        let act_cols = pw..cfg.critic_input();
        let qw = cfg.critic_input();
        self.care_backward_critic(batch, par);
        for i in 0..b {
            let g1 = &self.critics[0].cache.grad_input(b + i..b + i + 1)[act_cols.clone()];
            let g2 = &self.critics[1].cache.grad_input(b + i..b + i + 1)[act_cols.clone()];
            debug_assert_eq!(g1.len() + pw, qw);
            for j in 0..a {
                self.d_actions[i * a + j] = g1[j] + g2[j];
            }
            self.d_log_prob[i] = self.alpha_rows[i] * inv_b;
        }
        let (head, d_head) = self.policy_cache.output_and_grad_mut(b..2 * b);
        gaussian::sample_backward(
            head,
            &self.eps[b * a..2 * b * a],
            &self.pi_actions[b * a..2 * b * a],
            &self.d_actions[..b * a],
            &self.d_log_prob[..b],
            a,
            d_head,
        );
        // With CARE the actor's loss also trains the actor's attention (through the mixture
        // columns; the experts' outputs and the task encoding are detached for the actor).
        let features = self.config.care.as_ref().map_or(0, |c| c.feature_dim);
        let policy_input_grad = if features > 0 {
            InputGrad::Cols(0..features)
        } else {
            InputGrad::None
        };
        self.policy.backward(
            &mut self.policy_cache,
            b..2 * b,
            Some(&mut self.policy_grads),
            policy_input_grad,
            par,
        );
        self.care_backward_actor(batch, par);

        for (network, g) in [
            ("policy", &self.policy_grads),
            ("critic 1", &self.critics[0].grads),
            ("critic 2", &self.critics[1].grads),
            ("log alpha", &self.alpha_grads),
        ] {
            if !g.iter().all(|v| v.is_finite()) {
                return Err(SacError::NonFiniteGradient { network });
            }
        }
        if let Some(network) = self.care.as_ref().and_then(|c| c.non_finite_gradient()) {
            return Err(SacError::NonFiniteGradient { network });
        }
        Ok(stats)
    }

    /// CARE: the critics' loss into the encoder, from both critics' gradients w.r.t. their
    /// front columns (rows `0..B`, written by [`Critic::backward`]).
    fn care_backward_critic(&mut self, batch: &Batch, par: Par) {
        let Some(care) = &mut self.care else { return };
        let (b, pw) = (batch.len(), self.config.policy_input());
        for i in 0..b {
            let g1 = &self.critics[0].cache.grad_input(i..i + 1)[..pw];
            let g2 = &self.critics[1].cache.grad_input(i..i + 1)[..pw];
            for ((d, &x), &y) in self.d_front[i * pw..(i + 1) * pw]
                .iter_mut()
                .zip(g1)
                .zip(g2)
            {
                *d = x + y;
            }
        }
        care.backward_critic(&batch.task_ids, &self.d_front[..b * pw], par);
    }

    /// CARE: the actor's loss into the actor's attention, from the policy's gradient w.r.t.
    /// the mixture columns of its input on `s` (rows `B..2B`).
    fn care_backward_actor(&mut self, batch: &Batch, par: Par) {
        let Some(care) = &mut self.care else { return };
        let (b, features) = (batch.len(), care.cfg.feature_dim);
        for i in 0..b {
            self.d_features[i * features..(i + 1) * features]
                .copy_from_slice(&self.policy_cache.grad_input(b + i..b + i + 1)[..features]);
        }
        care.backward_actor(&batch.task_ids, &self.d_features[..b * features], par);
    }

    /// Steps all optimisers with the gradients of the last computation and moves the targets.
    fn apply_gradients(&mut self) {
        let parallel = self.config.threads > 1;
        let tau = T::of(self.config.tau);
        let policy = &mut self.policy;
        let policy_adam = &mut self.policy_adam;
        let policy_grads = &self.policy_grads;
        let critics = &mut self.critics;
        if parallel {
            rayon::join(
                || both(critics, true, |c| c.step(tau)),
                || {
                    clear_upper_state();
                    policy_adam.step(&mut policy.params, policy_grads)
                },
            );
        } else {
            both(critics, false, |c| c.step(tau));
            policy_adam.step(&mut policy.params, policy_grads);
        }
        self.alpha_adam.step(&mut self.log_alpha, &self.alpha_grads);
        if let Some(care) = &mut self.care {
            care.step();
        }
        self.updates += 1;
    }

    /// FLOPs of the GEMMs of one update with `batch` rows (what the benchmark divides by time).
    pub fn update_flops(&self, batch: usize) -> u64 {
        let b = batch;
        let q = &self.critics[0].net;
        let policy = self.policy.forward_flops(2 * b) + self.policy.backward_flops(b, true, 0);
        let critic = q.forward_flops(b) // target on (s', a')
            + q.forward_flops(2 * b)
            + q.backward_flops(b, true, 0)
            + q.backward_flops(b, false, self.config.act_dim);
        policy + 2 * critic + self.care.as_ref().map_or(0, |c| c.update_flops(b))
    }

    /// Policy weights as flat `f32` in the [`Mlp`] layout (per layer `weight [out, in]`, bias),
    /// for broadcasting to actors ([`crate::Policy::set_params`]).
    pub fn policy_params_f32(&self) -> Vec<f32> {
        let mut out: Vec<f32> = self.policy.params.iter().map(|v| v.f32()).collect();
        if let Some(care) = &self.care {
            care.policy_params_f32(&mut out);
        }
        out
    }

    /// Policy weights as named `f32` tensors `policy.{layer}.weight|bias`.
    pub fn policy_tensors(&self) -> Vec<Tensor> {
        let mut out = Vec::new();
        let head: Vec<f32> = self.policy.params.iter().map(|v| v.f32()).collect();
        self.policy.export_values(names::POLICY, &head, &mut out);
        if let Some(care) = &self.care {
            care.policy_tensors(&mut out);
        }
        out
    }

    /// The two online critics as named `f32` tensors `qf{1,2}.{layer}.weight|bias` (qf1 first,
    /// each in the [`Mlp`] parameter order), for the selector's value estimates
    /// ([`crate::value::ValueEstimator::set_critics`] takes them concatenated).
    pub fn critic_tensors(&self) -> Vec<Tensor> {
        let mut out = Vec::new();
        for (k, c) in self.critics.iter().enumerate() {
            let as_f32: Vec<f32> = c.net.params.iter().map(|v| v.f32()).collect();
            c.net.export_values(names::CRITICS[k], &as_f32, &mut out);
        }
        out
    }

    /// All state of the learner as named tensors: networks, targets, Adam moments and steps,
    /// temperatures, counters. Metadata holds the config (TOML) and the noise generator state.
    pub fn checkpoint_tensors(&self) -> (Vec<Tensor>, BTreeMap<String, String>) {
        let mut t = Vec::new();
        self.policy.export(names::POLICY, &mut t);
        self.policy_adam.export("policy_adam", &mut t);
        for (k, c) in self.critics.iter().enumerate() {
            c.net.export(names::CRITICS[k], &mut t);
            c.target.export(&format!("qf{}_target", k + 1), &mut t);
            c.adam.export(&format!("qf{}_adam", k + 1), &mut t);
        }
        t.push(Tensor::from_values(
            "log_alpha",
            vec![self.log_alpha.len()],
            &self.log_alpha,
        ));
        self.alpha_adam.export("log_alpha_adam", &mut t);
        t.push(Tensor::from_i64(
            "counters",
            vec![2],
            &[self.updates as i64, self.rejected_batches as i64],
        ));
        if let Some(care) = &self.care {
            care.checkpoint_tensors(&mut t);
        }
        let mut meta = BTreeMap::new();
        meta.insert("format".to_string(), "pt".to_string());
        meta.insert("terl.sac_config".to_string(), self.config.to_toml());
        let seed: String = self
            .rng
            .get_seed()
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        meta.insert("terl.rng_seed".to_string(), seed);
        meta.insert(
            "terl.rng_word_pos".to_string(),
            self.rng.get_word_pos().to_string(),
        );
        (t, meta)
    }

    /// Restores state written by [`Sac::checkpoint_tensors`]. Shapes and dtypes must match this
    /// learner's config; on error nothing is changed.
    pub fn restore_checkpoint(&mut self, file: &TensorFile) -> Result<(), SacError> {
        let mut policy = self.policy.clone();
        policy.import(names::POLICY, file)?;
        let mut policy_adam = self.policy_adam.clone();
        policy_adam.import("policy_adam", file)?;
        let mut critics = Vec::new();
        for (k, c) in self.critics.iter().enumerate() {
            let (mut net, mut target, mut adam) = (c.net.clone(), c.target.clone(), c.adam.clone());
            net.import(names::CRITICS[k], file)?;
            target.import(&format!("qf{}_target", k + 1), file)?;
            adam.import(&format!("qf{}_adam", k + 1), file)?;
            critics.push((net, target, adam));
        }
        let log_alpha = file.values::<T>("log_alpha", &[self.log_alpha.len()])?;
        let mut alpha_adam = self.alpha_adam.clone();
        alpha_adam.import("log_alpha_adam", file)?;
        let counters = file.i64_values("counters", &[2])?;
        let care = match &self.care {
            Some(c) => Some(c.restore(file)?),
            None => None,
        };
        let rng = match (
            file.metadata.get("terl.rng_seed"),
            file.metadata.get("terl.rng_word_pos"),
        ) {
            (Some(seed), Some(pos)) => {
                let bytes: Vec<u8> = (0..seed.len() / 2)
                    .filter_map(|i| u8::from_str_radix(seed.get(2 * i..2 * i + 2)?, 16).ok())
                    .collect();
                let seed: [u8; 32] = bytes
                    .try_into()
                    .map_err(|_| SacError::Config("bad terl.rng_seed in checkpoint".into()))?;
                let pos: u128 = pos
                    .parse()
                    .map_err(|_| SacError::Config("bad terl.rng_word_pos in checkpoint".into()))?;
                let mut rng = ChaCha8Rng::from_seed(seed);
                rng.set_word_pos(pos);
                Some(rng)
            }
            _ => None,
        };
        self.policy = policy;
        self.policy_adam = policy_adam;
        for (c, (net, target, adam)) in self.critics.iter_mut().zip(critics) {
            c.net = net;
            c.target = target;
            c.adam = adam;
        }
        self.log_alpha = log_alpha;
        self.alpha_adam = alpha_adam;
        if care.is_some() {
            self.care = care;
        }
        self.updates = counters[0].max(0) as u64;
        self.rejected_batches = counters[1].max(0) as u64;
        if let Some(rng) = rng {
            self.rng = rng;
        }
        Ok(())
    }

    /// Saves a checkpoint as a safetensors file (the only file I/O of this crate, with
    /// [`Sac::load_checkpoint`]).
    pub fn save_checkpoint(&self, path: &Path) -> Result<(), SacError> {
        let (tensors, meta) = self.checkpoint_tensors();
        save_file(path, &tensors, &meta)?;
        Ok(())
    }

    /// Loads a checkpoint written by [`Sac::save_checkpoint`] into this learner.
    pub fn load_checkpoint(&mut self, path: &Path) -> Result<(), SacError> {
        let file = TensorFile::load(path)?;
        self.restore_checkpoint(&file)
    }
}

/// A batch of `cfg.batch_size` random rows: observations, next observations and actions uniform
/// in `[-1, 1)`, rewards in `[0, 1)`, nothing terminated, tasks `i mod num_tasks`. For
/// benchmarks and for timing a learner alone ([`standalone_update_rate`]).
pub fn random_batch(cfg: &SacConfig, seed: u64) -> Batch {
    use rand::Rng;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut batch = Batch::with_capacity(cfg.batch_size, cfg.obs_dim, cfg.act_dim);
    let mut obs = vec![0.0; cfg.obs_dim];
    let mut next = vec![0.0; cfg.obs_dim];
    let mut act = vec![0.0; cfg.act_dim];
    for i in 0..cfg.batch_size {
        obs.iter_mut().for_each(|v| *v = rng.gen_range(-1.0..1.0));
        next.iter_mut().for_each(|v| *v = rng.gen_range(-1.0..1.0));
        act.iter_mut().for_each(|v| *v = rng.gen_range(-1.0..1.0));
        batch.push(
            &obs,
            &act,
            rng.gen_range(0.0..1.0),
            &next,
            false,
            (i % cfg.num_tasks) as u32,
        );
    }
    batch
}

/// A learner of `config`'s shape for timing: with CARE, a context table of the right shape
/// whatever the tasks (the cost does not depend on its values).
pub fn timing_learner(config: &SacConfig) -> Result<Sac<f32>, SacError> {
    let table = config.care.as_ref().map(|c| {
        let n = config.num_tasks * c.context_dim(config.num_tasks);
        (0..n)
            .map(|i| ((i % 7) as f32) * 0.05)
            .collect::<Vec<f32>>()
    });
    Sac::with_context(config.clone(), table.as_deref())
}

/// Updates per second of a learner of `config`'s shape running alone: a fresh [`Sac`] (same
/// networks, batch size and update threads; its own thread pool) on a [`random_batch`]: one
/// warm-up update, then updates back to back until `seconds` have passed (at least one). This is
/// the rate `terl bench sac` reports for the same shapes, and what the learner compares its
/// in-cluster rate to. When the warm-up update alone takes `seconds` or more (very large
/// networks), its own duration is the measurement, so the whole call takes at most about
/// `max(one update, seconds + one update)` after building the networks.
///
/// # Errors
/// The config's validation errors, or a failed update (none is expected on random data).
pub fn standalone_update_rate(config: &SacConfig, seconds: f64) -> Result<f64, SacError> {
    let mut sac = timing_learner(config)?;
    let batch = random_batch(config, config.seed ^ 0x5ca1_ab1e);
    let warm_up = std::time::Instant::now();
    sac.update(&batch)?;
    let one = warm_up.elapsed().as_secs_f64();
    if one >= seconds {
        return Ok(1.0 / one.max(1e-9));
    }
    let start = std::time::Instant::now();
    let mut n = 0u32;
    while n == 0 || start.elapsed().as_secs_f64() < seconds {
        sac.update(&batch)?;
        n += 1;
    }
    Ok(f64::from(n) / start.elapsed().as_secs_f64())
}
