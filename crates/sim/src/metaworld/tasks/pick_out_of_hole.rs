//! pick-out-of-hole-v3: pick a peg out of a hole in the table and lift it to a goal in the air.

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, norm2, sub, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "pick-out-of-hole-v3",
    xml: "sawyer_xyz/sawyer_pick_out_of_hole.xml",
    hand_low: [-0.5, 0.40, -0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[0.0, 0.75, 0.02, -0.1, 0.5, 0.15],
    rand_high: &[0.0, 0.75, 0.02, 0.1, 0.6, 0.3],
    goal_low: [-0.1, 0.5, 0.15],
    goal_high: [0.1, 0.6, 0.3],
    rand_vec_ok: obj_goal_apart::<15>,
};

/// Success: the peg within this distance of the goal.
const SUCCESS_RADIUS: f64 = 0.07;

#[derive(Debug)]
struct PickOutOfHole {
    obj: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(PickOutOfHole {
        obj: scene.sim.body("obj")?,
    }))
}

impl Task for PickOutOfHole {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.set_obj_xyz(scene.obj_init_pos);
        scene.target_pos = [rv[3], rv[4], rv[5]];
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        // MuJoCo's (w, x, y, z) quaternion, as Python reads `data.body("obj").xquat`.
        out[..3].copy_from_slice(&scene.body_com(self.obj));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.obj));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let gripper = scene.tcp_center();
        let obj_init = scene.obj_init_pos;
        let obj_to_target = dist(obj, scene.target_pos);
        let tcp_to_obj = dist(obj, gripper);
        // The gripper must stay above a log-shaped floor around the hole.
        const THRESHOLD: f64 = 0.03;
        let radius = norm2(sub(gripper, obj_init));
        let floor = if radius <= THRESHOLD {
            0.0
        } else {
            0.015 * (radius - THRESHOLD).ln() + 0.15
        };
        let above_floor = if gripper[2] >= floor {
            1.0
        } else {
            tolerance(
                (floor - gripper[2]).max(0.0),
                (0.0, 0.01),
                0.02,
                Sigmoid::LongTail,
            )
        };
        let object_grasped =
            scene.gripper_caging_reward(action, obj, 0.015, 0.02, 0.01, 0.03, 0.1, Density::High);
        let in_place = tolerance(
            obj_to_target,
            (0.0, 0.02),
            dist(obj_init, scene.target_pos),
            Sigmoid::LongTail,
        );
        let mut reward = hamacher_product(object_grasped, in_place);
        let near_object = tcp_to_obj < 0.04;
        let pinched_without_obj = obs[3] < 0.33;
        let lifted = obj[2] - 0.02 > obj_init[2];
        if near_object && lifted && !pinched_without_obj {
            reward += 1.0 + 5.0 * hamacher_product(in_place, above_floor);
        }
        if obj_to_target < TARGET_RADIUS {
            reward = 10.0;
        }
        Eval {
            reward,
            success: obj_to_target <= SUCCESS_RADIUS,
        }
    }
}
