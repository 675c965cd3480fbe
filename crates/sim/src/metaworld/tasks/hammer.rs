//! hammer-v3: pick up a hammer and drive a nail into a box.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{self, dist, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "hammer-v3",
    xml: "sawyer_xyz/sawyer_hammer.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.4, 0.2],
    rand_low: &[-0.1, 0.4, 0.0],
    rand_high: &[0.1, 0.5, 0.0],
    goal_low: [0.2399, 0.7399, 0.109],
    goal_high: [0.2401, 0.7401, 0.111],
    rand_vec_ok: always_ok,
};

/// Where the reset puts the box with the nail (fixed).
const BOX_POS: [f64; 3] = [0.24, 0.85, 0.0];
/// Length of the hammer's handle.
const HANDLE_LENGTH: f64 = 0.14;
/// From the hammer body to its head.
const HEAD_OFFSET: [f64; 3] = [0.16, 0.06, 0.0];
/// Quaternion (w, x, y, z) of the hammer lying flat, as the reward wants it.
const IDEAL_QUAT: [f64; 4] = [1.0, 0.0, 0.0, 0.0];
/// Success: the nail driven in this far (the slide joint's coordinate, m).
const NAIL_DRIVEN: f64 = 0.09;

#[derive(Debug)]
struct Hammer {
    hammer: usize,
    nail: usize,
    box_body: usize,
    goal_site: usize,
    nail_qpos: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    let nail_joint = scene.sim.joint("NailSlideJoint")?;
    Ok(Box::new(Hammer {
        hammer: scene.sim.body("hammer")?,
        nail: scene.sim.body("nail_link")?,
        box_body: scene.sim.body("box")?,
        goal_site: scene.sim.site("goal")?,
        nail_qpos: scene.sim.jnt_qposadr(nail_joint),
    }))
}

/// `_reward_quat`: 1 for a hammer lying flat, falling to 0 at a quaternion error of 0.4.
fn quat_reward(obs: &[f64; OBS_DIM]) -> f64 {
    reward::quat_reward(obs, IDEAL_QUAT, 0.4)
}

/// `_reward_pos`: a little for lifting the head, most for the head at the nail.
fn in_place_reward(head: [f64; 3], target: [f64; 3]) -> f64 {
    let lifted = if head[2] > 0.02 { 1.0 } else { 0.0 };
    0.1 * lifted + 0.9 * tolerance(dist(target, head), (0.0, 0.02), 0.2, Sigmoid::LongTail)
}

impl Task for Hammer {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.sim.set_body_pos(self.box_body, BOX_POS);
        // Read before the hammer is placed, from the hand reset's kinematics.
        scene.target_pos = scene.sim.site_xpos(self.goal_site);
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.set_obj_xyz(scene.obj_init_pos);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.body_com(self.hammer));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.hammer));
        out[7..10].copy_from_slice(&scene.body_com(self.nail));
        out[10..14].copy_from_slice(&scene.sim.body_xquat(self.nail));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let hand = [obs[0], obs[1], obs[2]];
        let hammer = [obs[4], obs[5], obs[6]];
        let head: [f64; 3] = std::array::from_fn(|i| hammer[i] + HEAD_OFFSET[i]);
        // The caging reward treats its object as a sphere; along the handle, the hand's x
        // counts as on the hammer.
        let mut threshed = hammer;
        if (hammer[0] - hand[0]).abs() < HANDLE_LENGTH / 2.0 {
            threshed[0] = hand[0];
        }
        let grab = scene.gripper_caging_reward(
            action,
            threshed,
            0.015,
            0.02,
            0.01,
            0.01,
            1.0,
            Density::High,
        );
        let in_place = in_place_reward(head, scene.target_pos);
        let mut reward = (2.0 * grab + 6.0 * in_place) * quat_reward(obs);
        let success = scene.sim.qpos()[self.nail_qpos] > NAIL_DRIVEN;
        // The reward threshold guards against an easily hacked success signal.
        if success && reward > 5.0 {
            reward = 10.0;
        }
        Eval { reward, success }
    }
}
