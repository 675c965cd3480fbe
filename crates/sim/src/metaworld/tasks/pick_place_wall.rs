//! pick-place-wall-v3: pick up a puck and carry it over a wall to a goal in the air.

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{
    dist, hamacher_product, scaled_dist, scipy_quat_from_mat, tolerance, Sigmoid,
};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "pick-place-wall-v3",
    xml: "sawyer_xyz/sawyer_pick_place_wall_v3.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[-0.05, 0.6, 0.015, -0.05, 0.85, 0.05],
    rand_high: &[0.05, 0.65, 0.015, 0.05, 0.9, 0.3],
    goal_low: [-0.05, 0.85, 0.05],
    goal_high: [0.05, 0.9, 0.3],
    rand_vec_ok: obj_goal_apart::<15>,
};

/// Success: the puck within this distance of the goal.
const SUCCESS_RADIUS: f64 = 0.07;

#[derive(Debug)]
struct PickPlaceWall {
    obj_geom: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(PickPlaceWall {
        obj_geom: scene.sim.geom("objGeom")?,
    }))
}

impl Task for PickPlaceWall {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.target_pos = [rv[3], rv[4], rv[5]];
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.set_obj_xyz(scene.obj_init_pos);
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.geom_xpos(self.obj_geom));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(self.obj_geom)));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let tcp_opened = obs[3];
        let target = scene.target_pos;
        let midpoint = [target[0], 0.77, 0.25];
        let scaling = [1.0, 1.0, 3.0];
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let obj_to_target = dist(obj, target);
        let in_place_part1 = tolerance(
            scaled_dist(obj, midpoint, scaling),
            (0.0, TARGET_RADIUS),
            scaled_dist(scene.obj_init_pos, midpoint, scaling),
            Sigmoid::LongTail,
        );
        let in_place_part2 = tolerance(
            obj_to_target,
            (0.0, TARGET_RADIUS),
            dist(scene.obj_init_pos, target),
            Sigmoid::LongTail,
        );
        let object_grasped = scene.gripper_caging_reward(
            action,
            obj,
            0.015,
            0.05,
            0.01,
            0.005,
            1.0,
            Density::Normal,
        );
        let grasped_in_place = hamacher_product(object_grasped, in_place_part1);
        let mut reward = grasped_in_place;
        if tcp_to_obj < 0.02 && tcp_opened > 0.0 && obj[2] - 0.015 > scene.obj_init_pos[2] {
            reward = grasped_in_place + 1.0 + 4.0 * in_place_part1;
            if obj[1] > 0.75 {
                reward = grasped_in_place + 1.0 + 4.0 + 3.0 * in_place_part2;
            }
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
