//! assembly-v3 (`metaworld/envs/sawyer_assembly_peg_v3.py`): pick up a ring nut by its handle
//! and put it over a peg.
//!
//! The body of both nut tasks: disassemble builds it with its own [`Variant`].

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{self, norm, norm2, sub, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "assembly-v3",
    xml: "sawyer_xyz/sawyer_assembly_peg.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[0.0, 0.6, 0.02, -0.1, 0.75, 0.1],
    rand_high: &[0.0, 0.6, 0.02, 0.1, 0.85, 0.1],
    goal_low: [-0.1, 0.75, 0.1],
    goal_high: [0.1, 0.85, 0.1],
    rand_vec_ok: obj_goal_apart::<10>,
};

/// The peg's base is this far below the goal (its top).
const PEG_BELOW_GOAL: f64 = 0.05;
/// Length of the nut's handle (`WRENCH_HANDLE_LENGTH`).
const HANDLE_LENGTH: f64 = 0.02;
/// Quaternion (w, x, y, z) of the nut lying flat, as the reward wants it.
const IDEAL_QUAT: [f64; 4] = [0.707, 0.0, 0.0, 0.707];

const VARIANT: Variant = Variant {
    reset: reset_assembly,
    evaluate: evaluate_assembly,
};

/// What differs between assembly and disassemble: the reset and the reward.
#[derive(Debug)]
pub(super) struct Variant {
    /// Places the nut, the peg and the goal (after the hand reset).
    pub reset: fn(&NutParts, &mut Scene, &[f64]) -> Result<()>,
    /// The task's reward and success.
    pub evaluate: fn(&NutParts, &Scene, &[f64; OBS_DIM], &[f32; ACTION_DIM]) -> Eval,
}

/// The nut, its handle and centre sites, the peg and its top site.
#[derive(Debug)]
pub(super) struct NutParts {
    pub nut: usize,
    pub nut_handle: usize,
    pub nut_center: usize,
    pub peg: usize,
    pub peg_top: usize,
}

#[derive(Debug)]
struct Nut {
    spec: &'static TaskSpec,
    variant: &'static Variant,
    parts: NutParts,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    build_with(scene, &SPEC, &VARIANT)
}

/// A nut task with another layout and variant.
pub(super) fn build_with(
    scene: &Scene,
    spec: &'static TaskSpec,
    variant: &'static Variant,
) -> Result<Box<dyn Task>> {
    Ok(Box::new(Nut {
        spec,
        variant,
        parts: NutParts {
            nut: scene.sim.body("RoundNut")?,
            nut_handle: scene.sim.site("RoundNut-8")?,
            nut_center: scene.sim.site("RoundNut")?,
            peg: scene.sim.body("peg")?,
            peg_top: scene.sim.site("pegTop")?,
        },
    }))
}

/// `_reward_quat`: 1 for a nut lying flat, falling to 0 at a quaternion error of 0.4
/// (shared with disassemble).
fn quat_reward(obs: &[f64; OBS_DIM]) -> f64 {
    reward::quat_reward(obs, IDEAL_QUAT, 0.4)
}

/// The nut's position for the caging reward: that reward treats its object as a sphere, so
/// along the handle the hand's x counts as on the nut (shared with disassemble).
fn threshed(hand: [f64; 3], nut: [f64; 3]) -> [f64; 3] {
    let mut threshed = nut;
    if (nut[0] - hand[0]).abs() < HANDLE_LENGTH / 2.0 {
        threshed[0] = hand[0];
    }
    threshed
}

/// The caging reward of the nut (shared with disassemble), with the nut [`threshed`] along
/// its handle.
pub(super) fn nut_grab(
    scene: &Scene,
    obs: &[f64; OBS_DIM],
    action: &[f32; ACTION_DIM],
    density: Density,
) -> f64 {
    let hand = [obs[0], obs[1], obs[2]];
    let nut = [obs[4], obs[5], obs[6]];
    scene.gripper_caging_reward(
        action,
        threshed(hand, nut),
        0.015,
        0.02,
        0.01,
        0.01,
        1.0,
        density,
    )
}

/// Reward and success of both nut tasks (shared with disassemble): 10 on success, else
/// `(2 grab + 6 in place) × quat reward`.
pub(super) fn nut_eval(obs: &[f64; OBS_DIM], grab: f64, in_place: f64, success: bool) -> Eval {
    let reward = if success {
        10.0
    } else {
        (2.0 * grab + 6.0 * in_place) * quat_reward(obs)
    };
    Eval { reward, success }
}

/// `_reward_pos`: (in place, success) of the nut's centre relative to the peg's top.
fn reward_pos(nut_center: [f64; 3], target: [f64; 3]) -> (f64, bool) {
    let mut error = sub(target, nut_center);
    let radius = norm2(error);
    let aligned = radius < 0.02;
    let hooked = error[2] > 0.0;
    let success = aligned && hooked;
    // The target height is a funnel centred on the peg, wider once the nut is on it.
    let threshold = if success { 0.02 } else { 0.01 };
    let target_height = if radius > threshold {
        0.02 * (radius - threshold).ln() + 0.2
    } else {
        0.0
    };
    error[2] = target_height - nut_center[2];
    let lifted = nut_center[2] > 0.02 || radius < threshold;
    let scaled = norm([error[0], error[1], 3.0 * error[2]]);
    let in_place = 0.1 * f64::from(u8::from(lifted))
        + 0.9 * tolerance(scaled, (0.0, 0.02), 0.4, Sigmoid::LongTail);
    (in_place, success)
}

fn reset_assembly(parts: &NutParts, scene: &mut Scene, rv: &[f64]) -> Result<()> {
    scene.obj_init_pos = [rv[0], rv[1], rv[2]];
    scene.target_pos = [rv[3], rv[4], rv[5]];
    let t = scene.target_pos;
    scene.set_obj_xyz(scene.obj_init_pos);
    scene
        .sim
        .set_body_pos(parts.peg, [t[0], t[1], t[2] - PEG_BELOW_GOAL]);
    // As in Python, the peg-top site's offset is overwritten with the goal's world
    // position (it appears in no observation or reward).
    scene.sim.set_site_pos(parts.peg_top, t);
    Ok(())
}

fn evaluate_assembly(
    parts: &NutParts,
    scene: &Scene,
    obs: &[f64; OBS_DIM],
    action: &[f32; ACTION_DIM],
) -> Eval {
    let grab = nut_grab(scene, obs, action, Density::Medium);
    let (in_place, success) = reward_pos(scene.sim.site_xpos(parts.nut_center), scene.target_pos);
    nut_eval(obs, grab, in_place, success)
}

impl Task for Nut {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        (self.variant.reset)(&self.parts, scene, rv)
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.parts.nut_handle));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.parts.nut));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        (self.variant.evaluate)(&self.parts, scene, obs, action)
    }
}
