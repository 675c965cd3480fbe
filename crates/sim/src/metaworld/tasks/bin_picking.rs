//! bin-picking-v3: pick a cube out of one bin and put it into the other.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, norm2, sub, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "bin-picking-v3",
    xml: "sawyer_xyz/sawyer_bin_picking.xml",
    hand_low: [-0.5, 0.40, 0.07],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    // The goal part of `rand_vec` is drawn but unused: the goal is the target bin's centre.
    rand_low: &[-0.21, 0.65, 0.02, 0.1199, 0.699, -0.001],
    rand_high: &[-0.03, 0.75, 0.02, 0.1201, 0.701, 0.001],
    goal_low: [0.1199, 0.699, -0.001],
    goal_high: [0.1201, 0.701, 0.001],
    rand_vec_ok: always_ok,
};

/// Success: the cube within this distance of the target bin's centre.
const SUCCESS_DISTANCE: f64 = 0.05;

#[derive(Debug)]
struct BinPicking {
    obj: usize,
    bin_goal: usize,
    /// The cube's distance from the goal at the first step of the episode
    /// (`_target_to_obj_init`, set by the first reward computation).
    target_to_obj_init: Option<f64>,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(BinPicking {
        obj: scene.sim.body("obj")?,
        bin_goal: scene.sim.body("bin_goal")?,
        target_to_obj_init: None,
    }))
}

impl Task for BinPicking {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        // The cube keeps the height it settled at during the hand reset.
        let height = scene.body_com(self.obj)[2];
        scene.obj_init_pos = [rv[0], rv[1], height];
        scene.set_obj_xyz(scene.obj_init_pos);
        scene.target_pos = scene.body_com(self.bin_goal);
        self.target_to_obj_init = None;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.body_com(self.obj));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.obj));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let hand = [obs[0], obs[1], obs[2]];
        let obj = [obs[4], obs[5], obs[6]];
        let target = scene.target_pos;
        let target_to_obj = dist(obj, target);
        let margin = *self.target_to_obj_init.get_or_insert(target_to_obj);
        let in_place = tolerance(
            target_to_obj,
            (0.0, TARGET_RADIUS),
            margin,
            Sigmoid::LongTail,
        );

        // The floor is a pair of funnels centred on the cube's start and on the goal; it
        // keeps the hand clear of the bins' edges.
        let threshold = 0.03;
        let funnel = |radius: f64| {
            if radius > threshold {
                0.02 * (radius - threshold).ln() + 0.2
            } else {
                0.0
            }
        };
        let floor =
            funnel(norm2(sub(hand, scene.obj_init_pos))).min(funnel(norm2(sub(hand, target))));
        let above_floor = if hand[2] >= floor {
            1.0
        } else {
            tolerance(
                (floor - hand[2]).max(0.0),
                (0.0, 0.01),
                0.05,
                Sigmoid::LongTail,
            )
        };
        let object_grasped =
            scene.gripper_caging_reward(action, obj, 0.015, 0.05, 0.01, 0.01, 0.7, Density::High);
        let mut reward = hamacher_product(object_grasped, in_place);
        let near_object = dist(obj, hand) < 0.04;
        let pinched_without_obj = obs[3] < 0.43;
        let lifted = obj[2] - 0.02 > scene.obj_init_pos[2];
        if near_object && lifted && !pinched_without_obj {
            reward += 1.0 + 5.0 * hamacher_product(above_floor, in_place);
        }
        if target_to_obj < TARGET_RADIUS {
            reward = 10.0;
        }
        Eval {
            reward,
            success: target_to_obj <= SUCCESS_DISTANCE,
        }
    }
}
