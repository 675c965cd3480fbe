//! The Sawyer scene every Meta-World task shares: mocap-driven hand, two-finger gripper, and the
//! state `SawyerXYZEnv` keeps between calls (initial TCP, object start, goal).

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use super::reward::{self, dist, hamacher_product, tolerance, Sigmoid};
use crate::error::Result;
use crate::mujoco::Simulation;

/// Entries the hand-reset cache may hold, process-wide (each about 2 KiB).
const HAND_RESET_CACHE_ENTRIES: usize = 65_536;

/// Outcome of one hand reset: the integration state before its last `mj_step` and after it.
struct HandReset {
    before_last_step: Vec<f64>,
    after: Vec<f64>,
}

/// Results of `_reset_hand`, keyed by everything they depend on (model, exact dynamical state,
/// hand target). The hand reset is 250 physics steps in every episode reset. A hit replays
/// only the last one's effect: set the state before the last step, `mj_forward` (which
/// computes exactly what that step computed before integrating), then set the state after it.
/// The data then matches a real run bit for bit, including the kinematics one substep behind
/// the state that Meta-World's reset observation shows.
#[derive(Default)]
struct HandResetCache {
    entries: HashMap<Vec<u64>, Arc<HandReset>>,
}

fn hand_reset_cache() -> &'static Mutex<HandResetCache> {
    static CACHE: OnceLock<Mutex<HandResetCache>> = OnceLock::new();
    CACHE.get_or_init(Default::default)
}

/// Meta-World's frame skip: physics steps per env step.
pub const FRAME_SKIP: usize = 5;
/// Mocap orientation Meta-World writes every step (MuJoCo normalises it).
const MOCAP_QUAT: [f64; 4] = [1.0, 0.0, 1.0, 0.0];
/// Meta-World's `TARGET_RADIUS`.
pub const TARGET_RADIUS: f64 = 0.05;

/// Shared per-environment state, the Rust counterpart of `SawyerXYZEnv`'s attributes.
#[derive(Debug)]
pub struct Scene {
    /// The MuJoCo simulation of this env (its own `mjData` over the shared model).
    pub sim: Simulation,
    hand: usize,
    right_claw: usize,
    left_claw: usize,
    left_pad: usize,
    right_pad: usize,
    right_end_effector: usize,
    left_end_effector: usize,
    mocap: usize,
    /// Hand position the reset drives the mocap to.
    pub hand_init_pos: [f64; 3],
    /// TCP position right after the hand reset (`init_tcp`).
    pub init_tcp: [f64; 3],
    /// Object start position of the current episode (`obj_init_pos`).
    pub obj_init_pos: [f64; 3],
    /// Goal of the current episode (`_target_pos`, obs[36..39]).
    pub target_pos: [f64; 3],
    /// Lower corner of the box the mocap (hand target) is clipped to, metres.
    pub mocap_low: [f64; 3],
    /// Upper corner of the mocap box, metres.
    pub mocap_high: [f64; 3],
    /// Identifies the model in cache keys.
    pub(crate) model_id: u64,
    /// Whether hand resets use the process-wide cache (on by default; off runs every step).
    pub(crate) hand_reset_cache: bool,
    /// False during the first of Python's two `reset_model` passes: that pass only matters
    /// through the model fields it writes, so its physics is skipped.
    pub(crate) physics: bool,
}

impl Scene {
    pub(crate) fn new(
        mut sim: Simulation,
        mocap_low: [f64; 3],
        mocap_high: [f64; 3],
    ) -> Result<Self> {
        sim.forward();
        // SawyerMocapBase.reset_mocap_welds
        let weld = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 5.0];
        if sim.nmocap() > 0 {
            let types = sim.eq_type().to_vec();
            let data = sim.eq_data_mut();
            for (i, t) in types.iter().enumerate() {
                if *t == crate::mujoco::EQ_WELD {
                    let n = crate::mujoco::EQ_DATA_LEN;
                    data[i * n..(i + 1) * n].copy_from_slice(&weld[..n]);
                }
            }
        }
        let mocap_body = sim.body("mocap")?;
        let mocap = sim
            .body_mocapid(mocap_body)
            .ok_or_else(|| crate::SimError::UnknownName {
                kind: "mocap body",
                name: "mocap".into(),
            })?;
        let mut scene = Self {
            hand: sim.body("hand")?,
            right_claw: sim.body("rightclaw")?,
            left_claw: sim.body("leftclaw")?,
            left_pad: sim.body("leftpad")?,
            right_pad: sim.body("rightpad")?,
            right_end_effector: sim.site("rightEndEffector")?,
            left_end_effector: sim.site("leftEndEffector")?,
            mocap,
            hand_init_pos: [0.0; 3],
            init_tcp: [0.0; 3],
            obj_init_pos: [0.0; 3],
            target_pos: [0.0; 3],
            mocap_low,
            mocap_high,
            physics: true,
            model_id: 0,
            hand_reset_cache: true,
            sim,
        };
        scene.sim.forward();
        Ok(scene)
    }

    // ------------------------------------------------------------------ positions

    /// `get_body_com(name)`: a body's frame position.
    pub fn body_com(&self, body: usize) -> [f64; 3] {
        self.sim.body_xpos(body)
    }
    /// End-effector (hand body) position, obs[0..3].
    pub fn hand_pos(&self) -> [f64; 3] {
        self.sim.body_xpos(self.hand)
    }
    /// Midpoint of the two finger sites.
    pub fn tcp_center(&self) -> [f64; 3] {
        let r = self.sim.site_xpos(self.right_end_effector);
        let l = self.sim.site_xpos(self.left_end_effector);
        [
            (r[0] + l[0]) / 2.0,
            (r[1] + l[1]) / 2.0,
            (r[2] + l[2]) / 2.0,
        ]
    }
    /// Finger separation normalised to [0, 1], `obs[3]`.
    pub fn gripper_distance_apart(&self) -> f64 {
        let d = dist(
            self.sim.body_xpos(self.right_claw),
            self.sim.body_xpos(self.left_claw),
        );
        (d / 0.1).clamp(0.0, 1.0)
    }
    /// World position of the left finger pad body (`leftpad`).
    pub fn left_pad_pos(&self) -> [f64; 3] {
        self.sim.body_xpos(self.left_pad)
    }
    /// World position of the right finger pad body (`rightpad`).
    pub fn right_pad_pos(&self) -> [f64; 3] {
        self.sim.body_xpos(self.right_pad)
    }

    // ------------------------------------------------------------------ state changes

    /// Gymnasium's `do_simulation`: set the gripper controls and step `n` times.
    /// (`mj_rnePostConstraint` is skipped: it only fills acceleration/force outputs nobody reads.)
    pub fn do_simulation(&mut self, ctrl: [f64; 2], n: usize) {
        if !self.physics {
            return;
        }
        self.sim.ctrl_mut()[..2].copy_from_slice(&ctrl);
        self.sim.step_n(n);
    }

    /// `mj_step` without touching the controls (used by a few resets).
    pub fn raw_steps(&mut self, n: usize) {
        if self.physics {
            self.sim.step_n(n);
        }
    }

    /// `mj_forward`.
    pub fn forward(&mut self) {
        if self.physics {
            self.sim.forward();
        }
    }

    /// `_reset_hand`: drive the mocap to `hand_init_pos` with the gripper open for 50 env steps.
    pub fn reset_hand(&mut self) {
        self.reset_hand_steps(50);
    }

    /// [`Self::reset_hand`] with `steps` env steps of [`FRAME_SKIP`] physics steps each, served
    /// from the process-wide hand-reset cache when the same model, state and target were reset
    /// before.
    pub fn reset_hand_steps(&mut self, steps: usize) {
        if self.physics {
            let key = self.hand_reset_cache.then(|| {
                let mut key = Vec::new();
                self.sim.dynamics_key(&mut key);
                key.push(self.model_id);
                key.push(steps as u64);
                key.extend(self.hand_init_pos.map(f64::to_bits));
                key
            });
            let cached = key.as_ref().and_then(|key| {
                hand_reset_cache()
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .entries
                    .get(key)
                    .cloned()
            });
            let restored = cached.is_some_and(|hit| {
                self.sim.set_integration_state(&hit.before_last_step) && {
                    self.sim.forward();
                    self.sim.set_integration_state(&hit.after)
                }
            });
            if !restored && steps > 0 {
                let m = self.mocap;
                let mut before_last_step = Vec::new();
                for i in 0..steps {
                    self.sim.mocap_pos_mut()[3 * m..3 * m + 3].copy_from_slice(&self.hand_init_pos);
                    self.sim.mocap_quat_mut()[4 * m..4 * m + 4].copy_from_slice(&MOCAP_QUAT);
                    self.sim.ctrl_mut()[..2].copy_from_slice(&[-1.0, 1.0]);
                    if i + 1 < steps {
                        self.sim.step_n(FRAME_SKIP);
                    } else {
                        self.sim.step_n(FRAME_SKIP - 1);
                        self.sim.integration_state(&mut before_last_step);
                        self.sim.step();
                    }
                }
                if let Some(key) = key {
                    let mut after = Vec::new();
                    self.sim.integration_state(&mut after);
                    let mut cache = hand_reset_cache().lock().unwrap_or_else(|e| e.into_inner());
                    if cache.entries.len() >= HAND_RESET_CACHE_ENTRIES {
                        cache.entries.clear();
                    }
                    cache.entries.insert(
                        key,
                        Arc::new(HandReset {
                            before_last_step,
                            after,
                        }),
                    );
                }
            }
        }
        self.init_tcp = self.tcp_center();
    }

    /// `set_xyz_action`: move the mocap by `clip(a, -1, 1) * 0.01` (computed in `f32`, as NumPy 2
    /// does) and clip it to the mocap box.
    pub(crate) fn apply_xyz_action(&mut self, a: [f32; 3]) {
        let m = self.mocap;
        let (low, high) = (self.mocap_low, self.mocap_high);
        let pos = &mut self.sim.mocap_pos_mut()[3 * m..3 * m + 3];
        for i in 0..3 {
            let delta = (a[i].clamp(-1.0, 1.0) * 0.01f32) as f64;
            pos[i] = (pos[i] + delta).clamp(low[i], high[i]);
        }
        self.sim.mocap_quat_mut()[4 * m..4 * m + 4].copy_from_slice(&MOCAP_QUAT);
    }

    /// Gymnasium's `set_state`: write qpos and qvel, then `mj_forward`.
    pub fn set_state(&mut self, qpos: &[f64], qvel: &[f64]) {
        self.sim.qpos_mut().copy_from_slice(qpos);
        self.sim.qvel_mut().copy_from_slice(qvel);
        self.forward();
    }

    /// `_set_obj_xyz`: the free object's position is `qpos[9..12]`; its velocity is zeroed.
    pub fn set_obj_xyz(&mut self, pos: [f64; 3]) {
        self.sim.qpos_mut()[9..12].copy_from_slice(&pos);
        self.sim.qvel_mut()[9..15].fill(0.0);
        self.forward();
    }

    /// The `_set_obj_xyz` of tasks whose object is one hinge/slide joint: `qpos[qpos_adr] =
    /// value`, `qvel[dof_adr] = 0`, then `mj_forward` (as `set_state` does).
    pub fn set_scalar_joint(&mut self, qpos_adr: usize, dof_adr: usize, value: f64) {
        self.sim.qpos_mut()[qpos_adr] = value;
        self.sim.qvel_mut()[dof_adr] = 0.0;
        self.forward();
    }

    /// Sets the goal site of the model (`model.site("goal").pos = ...`).
    pub fn set_site_pos(&mut self, name: &str, pos: [f64; 3]) -> Result<()> {
        let s = self.sim.site(name)?;
        self.sim.set_site_pos(s, pos);
        Ok(())
    }

    // ------------------------------------------------------------------ reward helpers

    /// `_gripper_caging_reward`: reward for surrounding and closing on an object.
    #[allow(clippy::too_many_arguments)]
    pub fn gripper_caging_reward(
        &self,
        action: &[f32; 4],
        obj_pos: [f64; 3],
        obj_radius: f64,
        pad_success_thresh: f64,
        object_reach_radius: f64,
        xz_thresh: f64,
        desired_gripper_effort: f64,
        density: Density,
    ) -> f64 {
        let left = self.left_pad_pos();
        let right = self.right_pad_pos();
        let pad_y = [left[1], right[1]];
        let caging_lr: Vec<f64> = (0..2)
            .map(|i| {
                let pad_to_obj = (pad_y[i] - obj_pos[1]).abs();
                let pad_to_objinit = (pad_y[i] - self.obj_init_pos[1]).abs();
                let margin = (pad_to_objinit - pad_success_thresh).abs();
                tolerance(
                    pad_to_obj,
                    (obj_radius, pad_success_thresh),
                    margin,
                    Sigmoid::LongTail,
                )
            })
            .collect();
        let caging_y = hamacher_product(caging_lr[0], caging_lr[1]);

        let tcp = self.tcp_center();
        let xz = |p: [f64; 3]| [p[0], p[2]];
        let norm_xz =
            |a: [f64; 2], b: [f64; 2]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
        let caging_xz_margin = norm_xz(xz(self.obj_init_pos), xz(self.init_tcp)) - xz_thresh;
        let caging_xz = tolerance(
            norm_xz(xz(tcp), xz(obj_pos)),
            (0.0, xz_thresh),
            caging_xz_margin,
            Sigmoid::LongTail,
        );

        let effort = f64::from(action[3]);
        let gripper_closed = effort.max(0.0).min(desired_gripper_effort) / desired_gripper_effort;
        let caging = hamacher_product(caging_y, caging_xz);
        let gripping = if caging > 0.97 { gripper_closed } else { 0.0 };
        let mut caging_and_gripping = hamacher_product(caging, gripping);
        match density {
            Density::Normal => {}
            Density::High => caging_and_gripping = (caging_and_gripping + caging) / 2.0,
            Density::Medium => {
                let tcp_to_obj = dist(obj_pos, tcp);
                let tcp_to_obj_init = dist(self.obj_init_pos, self.init_tcp);
                let reach_margin = (tcp_to_obj_init - object_reach_radius).abs();
                let reach = reward::tolerance(
                    tcp_to_obj,
                    (0.0, object_reach_radius),
                    reach_margin,
                    Sigmoid::LongTail,
                );
                caging_and_gripping = (caging_and_gripping + reach) / 2.0;
            }
        }
        caging_and_gripping
    }
}

/// Density option of the caging reward (`high_density` / `medium_density` flags).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Density {
    /// Neither flag: caging times gripping only.
    Normal,
    /// `high_density`: the mean of that product and the caging reward.
    High,
    /// `medium_density`: also mixes in a reach reward toward the object.
    Medium,
}
