//! box-close-v3: pick up a box lid by its handle and put it on the box.

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{
    self, dist, hamacher_product, norm, norm2, sub, tolerance, Sigmoid,
};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, FRAME_SKIP, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "box-close-v3",
    xml: "sawyer_xyz/sawyer_box.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.05, 0.5, 0.02, -0.1, 0.7, 0.133],
    rand_high: &[0.05, 0.55, 0.02, 0.1, 0.8, 0.133],
    goal_low: [-0.1, 0.7, 0.133],
    goal_high: [0.1, 0.8, 0.133],
    rand_vec_ok: obj_goal_apart::<25>,
};

/// Height of the lid's start: the float32 z of Python's `init_config["obj_init_pos"]`.
const LID_START_Z: f64 = 0.02f32 as f64;
/// Quaternion (w, x, y, z) of the upright lid the reward asks for.
const IDEAL_QUAT: [f64; 4] = [0.707, 0.0, 0.0, 0.707];
/// Success: the lid within this distance of the goal.
const SUCCESS_DISTANCE: f64 = 0.08;

#[derive(Debug)]
struct BoxClose {
    lid: usize,
    box_body: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(BoxClose {
        lid: scene.sim.body("top_link")?,
        box_body: scene.sim.body("boxbody")?,
        goal_site: scene.sim.site("goal")?,
    }))
}

/// `_reward_grab_effort`: the gripper effort mapped to [0, 1], in `f32` as NumPy computes it.
fn grab_effort(action: &[f32; ACTION_DIM]) -> f64 {
    f64::from(((action[3].clamp(-1.0, 1.0) + 1.0) / 2.0).clamp(0.0, 1.0))
}

/// `_reward_quat`: 1 for an upright lid, falling to 0 at a quaternion error of 0.2.
fn quat_reward(obs: &[f64; OBS_DIM]) -> f64 {
    reward::quat_reward(obs, IDEAL_QUAT, 0.2)
}

/// `_reward_pos`: (ready to lift, lifted and placed).
fn reward_pos(obs: &[f64; OBS_DIM], target: [f64; 3]) -> (f64, f64) {
    let hand = [obs[0], obs[1], obs[2]];
    let lid = [obs[4], obs[5], obs[6] + 0.02];
    let threshold = 0.02;
    // A funnel around the handle keeps the hand from running into it prematurely.
    let radius = norm2(sub(hand, lid));
    let floor = if radius <= threshold {
        0.0
    } else {
        0.04 * (radius - threshold).ln() + 0.4
    };
    let above_floor = if hand[2] >= floor {
        1.0
    } else {
        tolerance(floor - hand[2], (0.0, 0.01), floor / 2.0, Sigmoid::LongTail)
    };
    let in_place = tolerance(dist(hand, lid), (0.0, 0.02), 0.5, Sigmoid::LongTail);
    let ready_to_lift = hamacher_product(above_floor, in_place);

    let error = sub(target, lid);
    let scaled = norm([error[0], error[1], 3.0 * error[2]]);
    let tried = if lid[2] > 0.04 { 1.0 } else { 0.0 };
    let lifted = 0.2 * tried + 0.8 * tolerance(scaled, (0.0, 0.05), 0.25, Sigmoid::LongTail);
    (ready_to_lift, lifted)
}

impl Task for BoxClose {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        let box_height = scene.body_com(self.box_body)[2];
        scene.obj_init_pos = [rv[0], rv[1], LID_START_Z];
        scene.target_pos = [rv[3], rv[4], rv[5]];
        scene
            .sim
            .set_body_pos(self.box_body, [rv[3], rv[4], box_height]);
        // Raw `mj_step`s (the hand reset's controls still apply) before placing the lid.
        scene.raw_steps(FRAME_SKIP);
        scene.set_obj_xyz(scene.obj_init_pos);
        scene.sim.set_site_pos(self.goal_site, scene.target_pos);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.body_com(self.lid));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.lid));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let target = scene.target_pos;
        let (ready, lifted) = reward_pos(obs, target);
        let mut reward = 2.0 * hamacher_product(grab_effort(action), ready) + 8.0 * lifted;
        let success = dist([obs[4], obs[5], obs[6]], target) < SUCCESS_DISTANCE;
        if success {
            reward = 10.0;
        }
        Eval {
            reward: reward * quat_reward(obs),
            success,
        }
    }
}
