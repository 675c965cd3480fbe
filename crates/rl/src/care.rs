//! CARE, the context-based multi-task encoder (Sodhani, Zhang and Pineau, "Multi-Task
//! Reinforcement Learning with Context-based Representations", ICML 2021; reference code
//! `facebookresearch/mtrl`, agent `state_sac` with `encoder.type_to_select = moe` and
//! `moe.task_id_to_encoder_id_cfg.mode = attention`).
//!
//! In place of MTSAC's `[observation, one-hot task id]`, the SAC heads read
//! `[h(s, t), z_t]` (plus the action for a critic), with
//!
//! - `z_t = E(c_t)`: the **task encoder** `E` (an MLP) of the task's context `c_t`, by default
//!   the published RoBERTa embedding of the task's description (768 values, frozen, shipped in
//!   `crates/rl/data/care-task-embeddings.json`; mtrl applies a ReLU to it before `E`, so does
//!   this module), or the task's one-hot vector;
//! - `h(s, t) = Σ_k w_k(t)·e_k(s)`: a **mixture of k state encoders** `e_k` (MLPs of the
//!   observation) weighted by **attention** `w(t) = softmax(G(z_t) / temperature)`, `G` an MLP of
//!   the (detached) task encoding.
//!
//! As in mtrl: the critic and the actor share the experts `e_k` (tied weights) but each has its
//! own attention network `G`; the critics' loss trains the experts, the critics' attention and
//! the task encoder; the actor's loss trains only the actor head and the actor's attention (the
//! experts' outputs and `z_t` are detached for the actor). The target critics have their own
//! copies of the experts and the critics' attention, moved by Polyak averaging with
//! `encoder_tau` (0.05) while the heads move with `tau`; targets use the online task encoder.
//!
//! The task encoder and the attention depend on the task only, so they run once per update on
//! the `num_tasks` rows of the context table, not on the batch.

use crate::error::SacError;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::sync::OnceLock;
use terl_nn::tensors::{Tensor, TensorFile};
use terl_nn::{Activation, Adam, AdamConfig, Float, Init, InputGrad, Mlp, MlpCache, MlpSpec};

/// Length of one published task-description embedding (RoBERTa-small, mtrl's
/// `metadata/task_embedding/roberta_small`).
pub const EMBEDDING_DIM: usize = 768;

/// The published embeddings: `{"source", "dim", "tasks": {"reach-v3": [768 values], …}}`.
const EMBEDDINGS_JSON: &str = include_str!("../data/care-task-embeddings.json");

/// Where the task context `c_t` comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CareContext {
    /// The published RoBERTa embedding of the task's description (768 values; CARE's setting).
    /// Every Meta-World v3 task has one, so a policy can be asked for a task it never trained
    /// on (MT-Test zero-shot) through that task's embedding.
    #[default]
    TaskEmbeddings,
    /// The task's one-hot vector (`num_tasks` values): the documented alternative, without
    /// any knowledge of what the tasks are.
    OneHot,
}

/// CARE's settings (`[sac.care]` in a run file). Defaults are mtrl's published MT10 settings
/// (`docs_src/source/pages/tutorials/baseline.rst`, CARE: `num_experts = 4`;
/// `config/agent/components/metaworld_encoder.yaml`: experts of 2 layers, 50 hidden, feature 50,
/// attention MLP 2 layers of 50, temperature 1; `metaworld_multitask.yaml`: task encoder
/// output 50; `state_sac.yaml`: `encoder_tau = 0.05`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CareConfig {
    /// Number of state encoders `k` in the mixture (mtrl MT10: 4).
    pub num_experts: usize,
    /// Hidden widths of each state encoder (ReLU; mtrl: one hidden layer of 50).
    pub expert_hidden: Vec<usize>,
    /// Output width of each state encoder and of the mixture `h` (mtrl: 50).
    pub feature_dim: usize,
    /// The task context `c_t`.
    pub context: CareContext,
    /// Hidden widths of the task encoder `E` (ReLU). Default `[100, 50, 50, 50]`: mtrl's
    /// projection of the pretrained embedding (768 → 100 → 50, ReLU) followed by its trunk
    /// (`build_mlp(50, 50, 50, num_layers = 2)`), as one MLP.
    pub context_hidden: Vec<usize>,
    /// Width of the task encoding `z_t` (mtrl: 50).
    pub encoding_dim: usize,
    /// Hidden widths of each attention network `G` (ReLU; mtrl: 2 layers of 50).
    pub gate_hidden: Vec<usize>,
    /// Softmax temperature of the attention (mtrl: 1).
    pub temperature: f64,
    /// Polyak factor of the target critics' experts and attention (mtrl: `encoder_tau` 0.05).
    pub encoder_tau: f64,
}

impl Default for CareConfig {
    fn default() -> Self {
        Self {
            num_experts: 4,
            expert_hidden: vec![50],
            feature_dim: 50,
            context: CareContext::TaskEmbeddings,
            context_hidden: vec![100, 50, 50, 50],
            encoding_dim: 50,
            gate_hidden: vec![50, 50],
            temperature: 1.0,
            encoder_tau: 0.05,
        }
    }
}

impl CareConfig {
    /// Length of one context vector `c_t` for `num_tasks` tasks.
    pub fn context_dim(&self, num_tasks: usize) -> usize {
        match self.context {
            CareContext::TaskEmbeddings => EMBEDDING_DIM,
            CareContext::OneHot => num_tasks,
        }
    }

    /// Width of what the heads read before the action: `feature_dim + encoding_dim`.
    pub fn front_dim(&self) -> usize {
        self.feature_dim + self.encoding_dim
    }

    /// Checks sizes and ranges.
    pub fn validate(&self) -> Result<(), SacError> {
        let bad = |m: String| Err(SacError::Config(format!("care: {m}")));
        if self.num_experts == 0 || self.feature_dim == 0 || self.encoding_dim == 0 {
            return bad("num_experts, feature_dim and encoding_dim must be positive".into());
        }
        if self.num_experts > 1024 {
            return bad(format!("num_experts {} is above 1024", self.num_experts));
        }
        for (name, widths) in [
            ("expert_hidden", &self.expert_hidden),
            ("context_hidden", &self.context_hidden),
            ("gate_hidden", &self.gate_hidden),
        ] {
            if widths.contains(&0) {
                return bad(format!("{name} widths must be positive"));
            }
            if let Some(w) = widths.iter().find(|&&w| w > crate::limits::MAX_WIDTH) {
                return bad(format!(
                    "{name} width {w} is above {}",
                    crate::limits::MAX_WIDTH
                ));
            }
            if widths.len() > crate::limits::MAX_LAYERS {
                return bad(format!(
                    "{name} has more than {} layers",
                    crate::limits::MAX_LAYERS
                ));
            }
        }
        for (name, v) in [
            ("feature_dim", self.feature_dim),
            ("encoding_dim", self.encoding_dim),
        ] {
            if v > crate::limits::MAX_WIDTH {
                return bad(format!("{name} {v} is above {}", crate::limits::MAX_WIDTH));
            }
        }
        // The attention's logits are divided by the temperature in f32: far below mtrl's 1 they
        // overflow to inf and the softmax to NaN.
        if !(self.temperature.is_finite() && (1e-3..=1e3).contains(&self.temperature)) {
            return bad(format!(
                "temperature {} must be in [0.001, 1000] (mtrl: 1)",
                self.temperature
            ));
        }
        if !(0.0..=1.0).contains(&self.encoder_tau) {
            return bad(format!(
                "encoder_tau {} must be in [0, 1]",
                self.encoder_tau
            ));
        }
        Ok(())
    }

    /// Number of `f32` values a policy's CARE encoder carries (the experts, the actor's
    /// attention, the task encoder and the `[num_tasks, context_dim]` context table: the layout
    /// of `CareEncoder::policy_params_f32`), or `None` when it overflows `usize`.
    pub fn policy_num_params(&self, obs_dim: usize, num_tasks: usize) -> Option<usize> {
        self.expert_spec(obs_dim)
            .checked_num_params()?
            .checked_mul(self.num_experts)?
            .checked_add(self.gate_spec().checked_num_params()?)?
            .checked_add(self.task_encoder_spec(num_tasks).checked_num_params()?)?
            .checked_add(num_tasks.checked_mul(self.context_dim(num_tasks))?)
    }

    /// The task encoder `E`: context → encoding.
    pub fn task_encoder_spec(&self, num_tasks: usize) -> MlpSpec {
        relu_mlp(
            self.context_dim(num_tasks),
            &self.context_hidden,
            self.encoding_dim,
        )
    }

    /// An attention network `G`: encoding → one logit per expert.
    pub fn gate_spec(&self) -> MlpSpec {
        relu_mlp(self.encoding_dim, &self.gate_hidden, self.num_experts)
    }

    /// One state encoder `e_k`: observation → feature.
    pub fn expert_spec(&self, obs_dim: usize) -> MlpSpec {
        relu_mlp(obs_dim, &self.expert_hidden, self.feature_dim)
    }
}

fn relu_mlp(input: usize, hidden: &[usize], output: usize) -> MlpSpec {
    MlpSpec {
        input,
        hidden: hidden.to_vec(),
        output,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Identity,
    }
}

#[derive(Deserialize)]
struct EmbeddingFile {
    dim: usize,
    tasks: HashMap<String, Vec<f32>>,
}

fn embeddings() -> &'static HashMap<String, Vec<f32>> {
    static TABLE: OnceLock<HashMap<String, Vec<f32>>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let file: EmbeddingFile =
            serde_json::from_str(EMBEDDINGS_JSON).expect("the shipped embedding file parses");
        assert!(file
            .tasks
            .values()
            .all(|v| v.len() == file.dim && file.dim == EMBEDDING_DIM));
        file.tasks
    })
}

/// The published description embedding of a Meta-World v3 task (768 values), or `None` for a
/// name that has none.
pub fn task_embedding(task: &str) -> Option<&'static [f32]> {
    embeddings().get(task).map(Vec::as_slice)
}

/// The context table `[tasks.len(), context_dim]` (row-major) CARE encodes: per task its
/// embedding through a ReLU (mtrl's `Sequential(pretrained, ReLU, projection)`), or its
/// one-hot row.
///
/// # Errors
/// A task without a published embedding.
pub fn context_table(cfg: &CareConfig, tasks: &[String]) -> Result<Vec<f32>, SacError> {
    let nt = tasks.len();
    let dim = cfg.context_dim(nt);
    let mut out = vec![0.0f32; nt * dim];
    for (i, (row, task)) in out.chunks_exact_mut(dim).zip(tasks).enumerate() {
        match cfg.context {
            CareContext::OneHot => row[i] = 1.0,
            CareContext::TaskEmbeddings => {
                let e = task_embedding(task).ok_or_else(|| {
                    SacError::Config(format!(
                        "care: no published description embedding for task `{task}` (use \
                         context = \"one_hot\")"
                    ))
                })?;
                for (d, &v) in row.iter_mut().zip(e) {
                    *d = v.max(0.0);
                }
            }
        }
    }
    Ok(out)
}

/// `out[r] = softmax(logits[r] / temperature)` per row of `k` values.
pub fn softmax_rows<T: Float>(logits: &[T], k: usize, temperature: f64, out: &mut [T]) {
    let inv = T::of(1.0 / temperature);
    for (l, w) in logits.chunks_exact(k).zip(out.chunks_exact_mut(k)) {
        let m = l.iter().fold(T::of(f64::NEG_INFINITY), |a, &b| a.max(b));
        let mut sum = T::of(0.0);
        for (wi, &li) in w.iter_mut().zip(l) {
            *wi = ((li - m) * inv).exp();
            sum += *wi;
        }
        for wi in w.iter_mut() {
            *wi /= sum;
        }
    }
}

/// Gradient of the logits of [`softmax_rows`] from the gradient `dw` of its output `w`:
/// `dlogits = w ⊙ (dw − ⟨w, dw⟩) / temperature`.
pub fn softmax_backward<T: Float>(
    w: &[T],
    dw: &[T],
    k: usize,
    temperature: f64,
    dlogits: &mut [T],
) {
    let inv = T::of(1.0 / temperature);
    for ((w, dw), dl) in w
        .chunks_exact(k)
        .zip(dw.chunks_exact(k))
        .zip(dlogits.chunks_exact_mut(k))
    {
        let dot = w
            .iter()
            .zip(dw)
            .fold(T::of(0.0), |acc, (&a, &b)| acc + a * b);
        for ((d, &wi), &gi) in dl.iter_mut().zip(w).zip(dw) {
            *d = wi * (gi - dot) * inv;
        }
    }
}

/// `Σ g²` in f64.
pub(crate) fn sq_norm<T: Float>(g: &[T]) -> f64 {
    g.iter()
        .map(|v| {
            let v = v.f64();
            v * v
        })
        .sum()
}

/// A trained network with its optimiser, gradient and activation buffers.
#[derive(Clone, Debug)]
pub(crate) struct Trained<T> {
    pub(crate) net: Mlp<T>,
    adam: Adam<T>,
    pub(crate) grads: Vec<T>,
    pub(crate) cache: MlpCache<T>,
}

impl<T: Float> Trained<T> {
    fn new(spec: &MlpSpec, rows: usize, adam: AdamConfig, rng: &mut impl rand::Rng) -> Self {
        let net = Mlp::new_with(spec, Init::TorchDefault, rng);
        Self {
            adam: Adam::new(net.num_params(), adam),
            grads: vec![T::of(0.0); net.num_params()],
            cache: MlpCache::new(&net, rows),
            net,
        }
    }

    fn step(&mut self) {
        self.adam.step(&mut self.net.params, &self.grads);
    }

    /// Parameter gradients (written) from the output gradients already in `rows` of the cache.
    fn backward_params(&mut self, rows: std::ops::Range<usize>, par: faer::Par) {
        self.net.backward(
            &mut self.cache,
            rows,
            Some(&mut self.grads),
            InputGrad::None,
            par,
        );
    }

    /// An attention network's parameter gradients from the gradient `dw` of its softmax output
    /// `w` (`[rows, k]`).
    fn backward_attention(
        &mut self,
        w: &[T],
        dw: &[T],
        k: usize,
        temperature: f64,
        par: faer::Par,
    ) {
        let rows = w.len() / k;
        softmax_backward(w, dw, k, temperature, self.cache.grad_output_mut(0..rows));
        self.backward_params(0..rows, par);
    }

    fn export(&self, prefix: &str, out: &mut Vec<Tensor>) {
        self.net.export(prefix, out);
        self.adam.export(&format!("{prefix}_adam"), out);
    }

    fn import(&self, prefix: &str, file: &TensorFile) -> Result<Self, SacError> {
        let mut next = self.clone();
        next.net.import(prefix, file)?;
        next.adam.import(&format!("{prefix}_adam"), file)?;
        Ok(next)
    }
}

/// One of CARE's trained networks (for gradient checks and diagnostics).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CareNet {
    /// State encoder `k`.
    Expert(usize),
    /// The task encoder `E`.
    TaskEncoder,
    /// The critics' attention network.
    CriticAttention,
    /// The actor's attention network.
    ActorAttention,
}

/// Checkpoint and weight-message names of CARE's networks (see [`crate::names`]).
pub mod names {
    /// State encoder `k`: `care_expert{k}.{layer}.weight|bias`.
    pub fn expert(k: usize) -> String {
        format!("care_expert{k}")
    }
    /// Target copy of state encoder `k` (learner checkpoints only).
    pub fn target_expert(k: usize) -> String {
        format!("care_expert{k}_target")
    }
    /// The task encoder `E`.
    pub const TASK_ENCODER: &str = "care_task_encoder";
    /// The actor's attention network.
    pub const ACTOR_GATE: &str = "care_actor_gate";
    /// The critics' attention network.
    pub const CRITIC_GATE: &str = "care_critic_gate";
    /// Target copy of the critics' attention network (learner checkpoints only).
    pub const TARGET_GATE: &str = "care_critic_gate_target";
    /// The context table `[num_tasks, context_dim]`.
    pub const CONTEXT: &str = "care_context";
}

/// CARE's encoder side of one SAC learner: everything before the heads, forward and backward.
#[derive(Clone, Debug)]
pub(crate) struct CareEncoder<T> {
    pub(crate) cfg: CareConfig,
    obs_dim: usize,
    num_tasks: usize,
    /// `[num_tasks, context_dim]`.
    pub(crate) context: Vec<T>,
    pub(crate) task_encoder: Trained<T>,
    pub(crate) critic_gate: Trained<T>,
    pub(crate) actor_gate: Trained<T>,
    pub(crate) target_gate: Mlp<T>,
    target_gate_cache: MlpCache<T>,
    /// Rows `0..B`: `s'`; rows `B..2B`: `s`.
    pub(crate) experts: Vec<Trained<T>>,
    pub(crate) target_experts: Vec<Mlp<T>>,
    /// Rows `0..B`: `s'`.
    target_expert_caches: Vec<MlpCache<T>>,
    /// Attention per task `[num_tasks, k]`: critics, actor, target critics.
    w_critic: Vec<T>,
    w_actor: Vec<T>,
    w_target: Vec<T>,
    /// What the heads read before the action, `[rows, front_dim]`: the policy on `s'` (rows
    /// `0..B`) and `s` (rows `B..2B`); the critics on `s`; the target critics on `s'`.
    pub(crate) front_policy: Vec<T>,
    pub(crate) front_critic: Vec<T>,
    pub(crate) front_target: Vec<T>,
    // Backward scratch.
    dw: Vec<T>,
    dz: Vec<T>,
}

impl<T: Float> CareEncoder<T> {
    /// Networks for `sac.care` on `sac.num_tasks` tasks with `context`
    /// (`[num_tasks, context_dim]`), batches of up to `sac.batch_size` rows, Adam with the
    /// critics' learning rate (the actor's for the actor's attention); parameters drawn from
    /// `rng` (task encoder, critics' attention, actor's attention, then the experts).
    pub(crate) fn new(
        sac: &crate::SacConfig,
        context: &[f32],
        rng: &mut impl rand::Rng,
    ) -> Result<Self, SacError> {
        let cfg = sac
            .care
            .as_ref()
            .ok_or_else(|| SacError::Config("CARE encoder without [sac.care]".into()))?;
        let (obs_dim, num_tasks, batch) = (sac.obs_dim, sac.num_tasks, sac.batch_size);
        let (critic_adam, actor_adam) = (sac.adam(sac.critic_lr), sac.adam(sac.actor_lr));
        cfg.validate()?;
        let cd = cfg.context_dim(num_tasks);
        if context.len() != num_tasks * cd {
            return Err(SacError::Shape(format!(
                "care: context table has {} values, {num_tasks} tasks × {cd} expected",
                context.len()
            )));
        }
        if context.iter().any(|v| !v.is_finite()) {
            return Err(SacError::Shape(
                "care: context table has a non-finite value".into(),
            ));
        }
        let k = cfg.num_experts;
        let task_encoder = Trained::new(
            &cfg.task_encoder_spec(num_tasks),
            num_tasks,
            critic_adam,
            rng,
        );
        let critic_gate = Trained::new(&cfg.gate_spec(), num_tasks, critic_adam, rng);
        let actor_gate = Trained::new(&cfg.gate_spec(), num_tasks, actor_adam, rng);
        let experts: Vec<Trained<T>> = (0..k)
            .map(|_| Trained::new(&cfg.expert_spec(obs_dim), 2 * batch, critic_adam, rng))
            .collect();
        let target_experts: Vec<Mlp<T>> = experts.iter().map(|e| e.net.clone()).collect();
        let zeros = |n: usize| vec![T::of(0.0); n];
        let p = cfg.front_dim();
        Ok(Self {
            obs_dim,
            num_tasks,
            context: context.iter().map(|&v| T::of_f32(v)).collect(),
            target_gate: critic_gate.net.clone(),
            target_gate_cache: MlpCache::new(&critic_gate.net, num_tasks),
            target_expert_caches: target_experts
                .iter()
                .map(|e| MlpCache::new(e, batch))
                .collect(),
            task_encoder,
            critic_gate,
            actor_gate,
            experts,
            target_experts,
            w_critic: zeros(num_tasks * k),
            w_actor: zeros(num_tasks * k),
            w_target: zeros(num_tasks * k),
            front_policy: zeros(2 * batch * p),
            front_critic: zeros(batch * p),
            front_target: zeros(batch * p),
            dw: zeros(num_tasks * k),
            dz: zeros(num_tasks * cfg.encoding_dim),
            cfg: cfg.clone(),
        })
    }

    fn trained(&self, net: CareNet) -> Option<&Trained<T>> {
        match net {
            CareNet::Expert(k) => self.experts.get(k),
            CareNet::TaskEncoder => Some(&self.task_encoder),
            CareNet::CriticAttention => Some(&self.critic_gate),
            CareNet::ActorAttention => Some(&self.actor_gate),
        }
    }

    /// The network `net` (its parameters may be changed; optimiser and targets are not).
    pub(crate) fn net_mut(&mut self, net: CareNet) -> Option<&mut Mlp<T>> {
        match net {
            CareNet::Expert(k) => self.experts.get_mut(k).map(|e| &mut e.net),
            CareNet::TaskEncoder => Some(&mut self.task_encoder.net),
            CareNet::CriticAttention => Some(&mut self.critic_gate.net),
            CareNet::ActorAttention => Some(&mut self.actor_gate.net),
        }
    }

    /// The gradient of `net` from the last backward pass.
    pub(crate) fn gradient(&self, net: CareNet) -> Option<&[T]> {
        self.trained(net).map(|t| &t.grads[..])
    }

    /// The critics' attention `[num_tasks, k]` of the last [`Self::forward`].
    pub(crate) fn critic_attention(&self) -> &[T] {
        &self.w_critic
    }

    /// The actor's attention `[num_tasks, k]` of the last [`Self::forward`].
    pub(crate) fn actor_attention(&self) -> &[T] {
        &self.w_actor
    }

    /// Runs everything on a batch (`obs`, `next_obs`: `[b, obs_dim]`; `tasks`: `[b]`) and fills
    /// the three front buffers.
    pub(crate) fn forward(&mut self, obs: &[f32], next_obs: &[f32], tasks: &[u32], par: faer::Par) {
        let (b, od, nt, k) = (
            tasks.len(),
            self.obs_dim,
            self.num_tasks,
            self.cfg.num_experts,
        );
        let (f, zd, p) = (
            self.cfg.feature_dim,
            self.cfg.encoding_dim,
            self.cfg.front_dim(),
        );
        let temp = self.cfg.temperature;
        // Task side: E on the context table, then the three attentions.
        self.task_encoder
            .cache
            .input_mut(0..nt)
            .copy_from_slice(&self.context);
        self.task_encoder
            .net
            .forward(&mut self.task_encoder.cache, nt, par);
        let z = self.task_encoder.cache.output(0..nt);
        for (gate, cache, w) in [
            (
                &self.critic_gate.net,
                &mut self.critic_gate.cache,
                &mut self.w_critic,
            ),
            (
                &self.actor_gate.net,
                &mut self.actor_gate.cache,
                &mut self.w_actor,
            ),
            (
                &self.target_gate,
                &mut self.target_gate_cache,
                &mut self.w_target,
            ),
        ] {
            cache.input_mut(0..nt).copy_from_slice(z);
            gate.forward(cache, nt, par);
            softmax_rows(cache.output(0..nt), k, temp, w);
        }
        // State side: the experts on s' and s, the target experts on s'.
        for e in &mut self.experts {
            let input = e.cache.input_mut(0..2 * b);
            for (d, &s) in input[..b * od].iter_mut().zip(&next_obs[..b * od]) {
                *d = T::of_f32(s);
            }
            for (d, &s) in input[b * od..].iter_mut().zip(&obs[..b * od]) {
                *d = T::of_f32(s);
            }
            e.net.forward(&mut e.cache, 2 * b, par);
        }
        for (net, cache) in self
            .target_experts
            .iter()
            .zip(&mut self.target_expert_caches)
        {
            for (d, &s) in cache.input_mut(0..b).iter_mut().zip(&next_obs[..b * od]) {
                *d = T::of_f32(s);
            }
            net.forward(cache, b, par);
        }
        // Mixtures, each followed by the task encoding.
        let z = self.task_encoder.cache.output(0..nt);
        for (i, &t) in tasks.iter().enumerate() {
            let t = t as usize;
            let zt = &z[t * zd..(t + 1) * zd];
            let start = |front: &mut [T], row: usize| {
                let r = &mut front[row * p..(row + 1) * p];
                r[..f].fill(T::of(0.0));
                r[f..].copy_from_slice(zt);
            };
            start(&mut self.front_policy, i);
            start(&mut self.front_policy, b + i);
            start(&mut self.front_critic, i);
            start(&mut self.front_target, i);
        }
        let add = |front: &mut [T], row: usize, wk: T, e: &[T]| {
            for (hv, &ev) in front[row * p..row * p + f].iter_mut().zip(e) {
                *hv += wk * ev;
            }
        };
        for kk in 0..k {
            let e = &self.experts[kk].cache;
            let target = &self.target_expert_caches[kk];
            for (i, &t) in tasks.iter().enumerate() {
                let t = t as usize;
                let (wa, wc, wt) = (
                    self.w_actor[t * k + kk],
                    self.w_critic[t * k + kk],
                    self.w_target[t * k + kk],
                );
                let (next, now) = (e.output(i..i + 1), e.output(b + i..b + i + 1));
                add(&mut self.front_policy, i, wa, next);
                add(&mut self.front_policy, b + i, wa, now);
                add(&mut self.front_critic, i, wc, now);
                add(&mut self.front_target, i, wt, target.output(i..i + 1));
            }
        }
    }

    /// Gradients of the critics' loss into the experts, the critics' attention and the task
    /// encoder, from its gradient w.r.t. the critics' front `d_front` (`[b, front_dim]`, both
    /// critics summed). Gradients are written, not accumulated.
    pub(crate) fn backward_critic(&mut self, tasks: &[u32], d_front: &[T], par: faer::Par) {
        let (b, nt, k) = (tasks.len(), self.num_tasks, self.cfg.num_experts);
        let (f, zd, p) = (
            self.cfg.feature_dim,
            self.cfg.encoding_dim,
            self.cfg.front_dim(),
        );
        self.dw.fill(T::of(0.0));
        self.dz.fill(T::of(0.0));
        for (kk, e) in self.experts.iter_mut().enumerate() {
            // dE_k(s_i) = w_k(t_i)·dh_i; dw_k(t) += ⟨dh_i, E_k(s_i)⟩.
            let (out, dout) = e.cache.output_and_grad_mut(b..2 * b);
            for i in 0..b {
                let t = tasks[i] as usize;
                let dh = &d_front[i * p..i * p + f];
                let wk = self.w_critic[t * k + kk];
                let mut dot = T::of(0.0);
                for ((g, &d), &o) in dout[i * f..(i + 1) * f]
                    .iter_mut()
                    .zip(dh)
                    .zip(&out[i * f..(i + 1) * f])
                {
                    *g = wk * d;
                    dot += d * o;
                }
                self.dw[t * k + kk] += dot;
            }
            e.backward_params(b..2 * b, par);
        }
        for (i, &t) in tasks.iter().enumerate() {
            let t = t as usize;
            for (acc, &d) in self.dz[t * zd..(t + 1) * zd]
                .iter_mut()
                .zip(&d_front[i * p + f..(i + 1) * p])
            {
                *acc += d;
            }
        }
        self.critic_gate
            .backward_attention(&self.w_critic, &self.dw, k, self.cfg.temperature, par);
        let enc = &mut self.task_encoder;
        enc.cache.grad_output_mut(0..nt).copy_from_slice(&self.dz);
        enc.backward_params(0..nt, par);
    }

    /// Gradient of the actor's loss into the actor's attention, from its gradient w.r.t. the
    /// mixture part of the policy's input on `s` (`d_features`: `[b, feature_dim]`).
    pub(crate) fn backward_actor(&mut self, tasks: &[u32], d_features: &[T], par: faer::Par) {
        let (b, k, f) = (tasks.len(), self.cfg.num_experts, self.cfg.feature_dim);
        self.dw.fill(T::of(0.0));
        for (kk, e) in self.experts.iter().enumerate() {
            let out = e.cache.output(b..2 * b);
            for (i, &t) in tasks.iter().enumerate() {
                let t = t as usize;
                let dot = d_features[i * f..(i + 1) * f]
                    .iter()
                    .zip(&out[i * f..(i + 1) * f])
                    .fold(T::of(0.0), |acc, (&d, &o)| acc + d * o);
                self.dw[t * k + kk] += dot;
            }
        }
        self.actor_gate
            .backward_attention(&self.w_actor, &self.dw, k, self.cfg.temperature, par);
    }

    /// `Σ g²` (in f64) over the gradients the critics' optimisers step: experts, attention,
    /// task encoder.
    pub(crate) fn critic_grad_sq_norm(&self) -> f64 {
        self.experts.iter().map(|e| sq_norm(&e.grads)).sum::<f64>()
            + sq_norm(&self.critic_gate.grads)
            + sq_norm(&self.task_encoder.grads)
    }

    /// Multiplies the critics' encoder gradients by `scale` (global-norm clipping).
    pub(crate) fn scale_critic_grads(&mut self, scale: T) {
        for e in &mut self.experts {
            e.grads.iter_mut().for_each(|v| *v *= scale);
        }
        self.critic_gate.grads.iter_mut().for_each(|v| *v *= scale);
        self.task_encoder.grads.iter_mut().for_each(|v| *v *= scale);
    }

    /// The actor attention's gradient.
    pub(crate) fn actor_grads_mut(&mut self) -> &mut [T] {
        &mut self.actor_gate.grads[..]
    }

    /// Whether every gradient is finite; else the name of the first network that is not.
    pub(crate) fn non_finite_gradient(&self) -> Option<&'static str> {
        let finite = |g: &[T]| g.iter().all(|v| v.is_finite());
        if !self.experts.iter().all(|e| finite(&e.grads)) {
            return Some("care experts");
        }
        if !finite(&self.critic_gate.grads) {
            return Some("care critic attention");
        }
        if !finite(&self.actor_gate.grads) {
            return Some("care actor attention");
        }
        if !finite(&self.task_encoder.grads) {
            return Some("care task encoder");
        }
        None
    }

    /// Steps every optimiser and moves the targets (`encoder_tau`).
    pub(crate) fn step(&mut self) {
        let tau = T::of(self.cfg.encoder_tau);
        for e in &mut self.experts {
            e.step();
        }
        self.critic_gate.step();
        self.actor_gate.step();
        self.task_encoder.step();
        for (t, e) in self.target_experts.iter_mut().zip(&self.experts) {
            t.polyak_from(&e.net, tau);
        }
        self.target_gate.polyak_from(&self.critic_gate.net, tau);
    }

    /// FLOPs of the GEMMs of one update on `b` rows.
    pub(crate) fn update_flops(&self, b: usize) -> u64 {
        let nt = self.num_tasks;
        let e = &self.experts[0].net;
        let experts = e.forward_flops(2 * b) + e.forward_flops(b) + e.backward_flops(b, true, 0);
        let te = &self.task_encoder.net;
        let g = &self.critic_gate.net;
        let task_side = te.forward_flops(nt)
            + te.backward_flops(nt, true, 0)
            + 3 * g.forward_flops(nt)
            + 2 * g.backward_flops(nt, true, 0);
        self.experts.len() as u64 * experts + task_side
    }

    /// Every network, target and optimiser state, and the context table, as named tensors.
    pub(crate) fn checkpoint_tensors(&self, out: &mut Vec<Tensor>) {
        for (k, e) in self.experts.iter().enumerate() {
            e.export(&names::expert(k), out);
        }
        for (k, t) in self.target_experts.iter().enumerate() {
            t.export(&names::target_expert(k), out);
        }
        self.task_encoder.export(names::TASK_ENCODER, out);
        self.critic_gate.export(names::CRITIC_GATE, out);
        self.actor_gate.export(names::ACTOR_GATE, out);
        self.target_gate.export(names::TARGET_GATE, out);
        out.push(Tensor::from_values(
            names::CONTEXT,
            vec![self.num_tasks, self.cfg.context_dim(self.num_tasks)],
            &self.context,
        ));
    }

    /// Restores [`Self::checkpoint_tensors`]; on error nothing is changed.
    pub(crate) fn restore(&self, file: &TensorFile) -> Result<Self, SacError> {
        let mut next = self.clone();
        for k in 0..self.experts.len() {
            next.experts[k] = self.experts[k].import(&names::expert(k), file)?;
            next.target_experts[k].import(&names::target_expert(k), file)?;
        }
        next.task_encoder = self.task_encoder.import(names::TASK_ENCODER, file)?;
        next.critic_gate = self.critic_gate.import(names::CRITIC_GATE, file)?;
        next.actor_gate = self.actor_gate.import(names::ACTOR_GATE, file)?;
        next.target_gate.import(names::TARGET_GATE, file)?;
        next.context = file.values::<T>(
            names::CONTEXT,
            &[self.num_tasks, self.cfg.context_dim(self.num_tasks)],
        )?;
        if next.context.iter().any(|v| !v.is_finite()) {
            return Err(SacError::Shape(
                "care: the checkpoint's context table has a non-finite value".into(),
            ));
        }
        Ok(next)
    }

    /// What an actor's policy needs besides the head, as `f32` in the order of
    /// [`CarePolicy`]'s flat layout: experts, actor attention, task encoder, context table.
    pub(crate) fn policy_params_f32(&self, out: &mut Vec<f32>) {
        for e in &self.experts {
            out.extend(e.net.params.iter().map(|v| v.f32()));
        }
        out.extend(self.actor_gate.net.params.iter().map(|v| v.f32()));
        out.extend(self.task_encoder.net.params.iter().map(|v| v.f32()));
        out.extend(self.context.iter().map(|v| v.f32()));
    }

    /// The same as named `f32` tensors (for checkpoint readers that load a policy by name).
    pub(crate) fn policy_tensors(&self, out: &mut Vec<Tensor>) {
        for (k, e) in self.experts.iter().enumerate() {
            let v: Vec<f32> = e.net.params.iter().map(|v| v.f32()).collect();
            e.net.export_values(&names::expert(k), &v, out);
        }
        for (name, net) in [
            (names::ACTOR_GATE, &self.actor_gate.net),
            (names::TASK_ENCODER, &self.task_encoder.net),
        ] {
            let v: Vec<f32> = net.params.iter().map(|v| v.f32()).collect();
            net.export_values(name, &v, out);
        }
        let c: Vec<f32> = self.context.iter().map(|v| v.f32()).collect();
        out.push(Tensor::from_values(
            names::CONTEXT,
            vec![self.num_tasks, self.cfg.context_dim(self.num_tasks)],
            &c,
        ));
    }
}

/// CARE's encoder side of an inference policy: the experts, the actor's attention, the task
/// encoder and the context table, `f32`, with the per-task encoding and attention computed
/// once per weight update.
#[derive(Clone, Debug)]
pub(crate) struct CarePolicy {
    cfg: CareConfig,
    num_tasks: usize,
    experts: Vec<Mlp<f32>>,
    expert_caches: Vec<MlpCache<f32>>,
    gate: Mlp<f32>,
    gate_cache: MlpCache<f32>,
    task_encoder: Mlp<f32>,
    encoder_cache: MlpCache<f32>,
    /// `[num_tasks, context_dim]`.
    context: Vec<f32>,
    /// Per task: encoding `[num_tasks, encoding_dim]` and attention `[num_tasks, k]`.
    z: Vec<f32>,
    w: Vec<f32>,
    /// Per row of a call with explicit contexts.
    z_rows: Vec<f32>,
    w_rows: Vec<f32>,
}

impl CarePolicy {
    pub(crate) fn new(
        cfg: &CareConfig,
        obs_dim: usize,
        num_tasks: usize,
        max_batch: usize,
    ) -> Self {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
        let experts: Vec<Mlp<f32>> = (0..cfg.num_experts)
            .map(|_| Mlp::new(&cfg.expert_spec(obs_dim), &mut rng))
            .collect();
        let gate = Mlp::new(&cfg.gate_spec(), &mut rng);
        let task_encoder = Mlp::new(&cfg.task_encoder_spec(num_tasks), &mut rng);
        let rows = max_batch.max(num_tasks).max(1);
        let mut context = vec![0.0; num_tasks * cfg.context_dim(num_tasks)];
        if cfg.context == CareContext::OneHot {
            for t in 0..num_tasks {
                context[t * num_tasks + t] = 1.0;
            }
        }
        let mut p = Self {
            expert_caches: experts
                .iter()
                .map(|e| MlpCache::new(e, max_batch.max(1)))
                .collect(),
            gate_cache: MlpCache::new(&gate, rows),
            encoder_cache: MlpCache::new(&task_encoder, rows),
            z: vec![0.0; num_tasks * cfg.encoding_dim],
            w: vec![0.0; num_tasks * cfg.num_experts],
            z_rows: vec![0.0; max_batch * cfg.encoding_dim],
            w_rows: vec![0.0; max_batch * cfg.num_experts],
            experts,
            gate,
            task_encoder,
            context,
            num_tasks,
            cfg: cfg.clone(),
        };
        p.refresh();
        p
    }

    /// Loads the flat layout of [`CareEncoder::policy_params_f32`] (length already checked).
    pub(crate) fn set_params(&mut self, mut params: &[f32]) {
        let mut take = |dst: &mut [f32]| {
            let (head, rest) = params.split_at(dst.len());
            dst.copy_from_slice(head);
            params = rest;
        };
        for e in &mut self.experts {
            take(&mut e.params);
        }
        take(&mut self.gate.params);
        take(&mut self.task_encoder.params);
        take(&mut self.context);
        self.refresh();
    }

    /// Loads the named tensors of [`CareEncoder::policy_tensors`]; on error nothing changes.
    pub(crate) fn load(&mut self, file: &TensorFile) -> Result<(), SacError> {
        let mut next = self.clone();
        for (k, e) in next.experts.iter_mut().enumerate() {
            e.import(&names::expert(k), file)?;
        }
        next.gate.import(names::ACTOR_GATE, file)?;
        next.task_encoder.import(names::TASK_ENCODER, file)?;
        next.context = file.values::<f32>(
            names::CONTEXT,
            &[self.num_tasks, self.cfg.context_dim(self.num_tasks)],
        )?;
        if next.context.iter().any(|v| !v.is_finite()) {
            return Err(SacError::Shape(
                "care: the context table has a non-finite value".into(),
            ));
        }
        next.refresh();
        *self = next;
        Ok(())
    }

    /// Copies the weights and context of `other` (same shapes).
    pub(crate) fn copy_from(&mut self, other: &Self) {
        for (d, s) in self.experts.iter_mut().zip(&other.experts) {
            d.params.copy_from_slice(&s.params);
        }
        self.gate.params.copy_from_slice(&other.gate.params);
        self.task_encoder
            .params
            .copy_from_slice(&other.task_encoder.params);
        self.context.copy_from_slice(&other.context);
        self.refresh();
    }

    /// Task `t`'s row of the context table.
    pub(crate) fn context_row(&self, t: usize) -> Option<&[f32]> {
        let cd = self.cfg.context_dim(self.num_tasks);
        (t < self.num_tasks).then(|| &self.context[t * cd..(t + 1) * cd])
    }

    /// Recomputes the per-task encoding and attention.
    fn refresh(&mut self) {
        let nt = self.num_tasks;
        let (z, w) = (std::mem::take(&mut self.z), std::mem::take(&mut self.w));
        let context = std::mem::take(&mut self.context);
        let (z, w) = self.encode_rows(&context, nt, z, w);
        self.context = context;
        self.z = z;
        self.w = w;
    }

    fn encode_rows(
        &mut self,
        contexts: &[f32],
        rows: usize,
        mut z: Vec<f32>,
        mut w: Vec<f32>,
    ) -> (Vec<f32>, Vec<f32>) {
        let par = faer::Par::Seq;
        let (zd, k) = (self.cfg.encoding_dim, self.cfg.num_experts);
        for start in (0..rows).step_by(self.encoder_cache.capacity().max(1)) {
            let n = (rows - start).min(self.encoder_cache.capacity());
            let cd = self.cfg.context_dim(self.num_tasks);
            self.encoder_cache
                .input_mut(0..n)
                .copy_from_slice(&contexts[start * cd..(start + n) * cd]);
            self.task_encoder.forward(&mut self.encoder_cache, n, par);
            let zs = self.encoder_cache.output(0..n);
            z[start * zd..(start + n) * zd].copy_from_slice(zs);
            self.gate_cache.input_mut(0..n).copy_from_slice(zs);
            self.gate.forward(&mut self.gate_cache, n, par);
            softmax_rows(
                self.gate_cache.output(0..n),
                k,
                self.cfg.temperature,
                &mut w[start * k..(start + n) * k],
            );
        }
        (z, w)
    }

    /// Writes the heads' front `[h, z]` (`[rows, front_dim]`) for `obs` (`[rows, obs_dim]`),
    /// with the encoding and attention of each row's task (`Ok(task ids)`) or of explicit
    /// context rows (`Err(contexts)`, `[rows, context_dim]`).
    pub(crate) fn front(
        &mut self,
        obs: &[f32],
        rows: usize,
        tasks: Result<&[usize], &[f32]>,
        front: &mut [f32],
    ) {
        let par = faer::Par::Seq;
        let (f, zd, k) = (
            self.cfg.feature_dim,
            self.cfg.encoding_dim,
            self.cfg.num_experts,
        );
        let p = f + zd;
        if let Err(contexts) = tasks {
            let (z, w) = (
                std::mem::take(&mut self.z_rows),
                std::mem::take(&mut self.w_rows),
            );
            let (z, w) = self.encode_rows(contexts, rows, z, w);
            self.z_rows = z;
            self.w_rows = w;
        }
        for (e, c) in self.experts.iter().zip(&mut self.expert_caches) {
            c.input_mut(0..rows).copy_from_slice(obs);
            e.forward(c, rows, par);
        }
        for r in 0..rows {
            let (z, w) = match tasks {
                Ok(ids) => {
                    let t = ids[r];
                    (&self.z[t * zd..(t + 1) * zd], &self.w[t * k..(t + 1) * k])
                }
                Err(_) => (
                    &self.z_rows[r * zd..(r + 1) * zd],
                    &self.w_rows[r * k..(r + 1) * k],
                ),
            };
            let row = &mut front[r * p..(r + 1) * p];
            let (h, zpart) = row.split_at_mut(f);
            h.fill(0.0);
            for (c, &wk) in self.expert_caches.iter().zip(w) {
                for (hv, &ev) in h.iter_mut().zip(c.output(r..r + 1)) {
                    *hv += wk * ev;
                }
            }
            zpart.copy_from_slice(z);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_metaworld_task_has_a_published_embedding_and_they_differ() {
        let reach = task_embedding("reach-v3").unwrap();
        let push = task_embedding("push-v3").unwrap();
        assert_eq!(reach.len(), EMBEDDING_DIM);
        assert_ne!(reach, push);
        assert!(task_embedding("reach-v1").is_none());
        let all = embeddings();
        assert_eq!(all.len(), 50);
    }

    #[test]
    fn the_context_table_is_the_relu_of_the_embeddings_or_one_hot() {
        let tasks = vec!["reach-v3".to_string(), "push-v3".to_string()];
        let cfg = CareConfig::default();
        let t = context_table(&cfg, &tasks).unwrap();
        assert_eq!(t.len(), 2 * EMBEDDING_DIM);
        let e = task_embedding("push-v3").unwrap();
        for (a, b) in t[EMBEDDING_DIM..].iter().zip(e) {
            assert_eq!(*a, b.max(0.0));
        }
        let one_hot = CareConfig {
            context: CareContext::OneHot,
            ..CareConfig::default()
        };
        assert_eq!(
            context_table(&one_hot, &tasks).unwrap(),
            vec![1.0, 0.0, 0.0, 1.0]
        );
        let err = context_table(&cfg, &["no-such-task".to_string()]).unwrap_err();
        assert!(err.to_string().contains("no-such-task"), "{err}");
    }

    #[test]
    fn attention_sums_to_one_and_its_backward_matches_finite_differences() {
        let k = 5;
        let logits: Vec<f64> = (0..3 * k)
            .map(|i| ((i * 37) % 11) as f64 * 0.3 - 1.0)
            .collect();
        let dw: Vec<f64> = (0..3 * k)
            .map(|i| ((i * 13) % 7) as f64 * 0.2 - 0.5)
            .collect();
        for temperature in [1.0, 0.5, 3.0] {
            let mut w = vec![0.0; 3 * k];
            softmax_rows(&logits, k, temperature, &mut w);
            for row in w.chunks(k) {
                assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12);
                assert!(row.iter().all(|&v| v > 0.0));
            }
            let mut analytic = vec![0.0; 3 * k];
            softmax_backward(&w, &dw, k, temperature, &mut analytic);
            let loss = |l: &[f64]| {
                let mut w = vec![0.0; 3 * k];
                softmax_rows(l, k, temperature, &mut w);
                w.iter().zip(&dw).map(|(a, b)| a * b).sum::<f64>()
            };
            for j in 0..3 * k {
                let h = 1e-6;
                let (mut up, mut down) = (logits.clone(), logits.clone());
                up[j] += h;
                down[j] -= h;
                let fd = (loss(&up) - loss(&down)) / (2.0 * h);
                assert!(
                    (fd - analytic[j]).abs() < 1e-8,
                    "{j}: {fd} vs {}",
                    analytic[j]
                );
            }
        }
    }
}
