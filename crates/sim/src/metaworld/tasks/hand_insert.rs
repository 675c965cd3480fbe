//! hand-insert-v3: push a small block into a hole in the table.

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "hand-insert-v3",
    xml: "sawyer_xyz/sawyer_table_with_hole.xml",
    hand_low: [-0.5, 0.40, -0.15],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.6, 0.05, -0.04, 0.8, -0.0201],
    rand_high: &[0.1, 0.7, 0.05, 0.04, 0.88, -0.0199],
    goal_low: [-0.04, 0.8, -0.0201],
    goal_high: [0.04, 0.88, -0.0199],
    rand_vec_ok: obj_goal_apart::<15>,
};

/// Height of the block's start (Python keeps the z of its initial `obj_init_pos`).
const OBJ_START_Z: f64 = 0.05;

#[derive(Debug)]
struct HandInsert {
    obj: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(HandInsert {
        obj: scene.sim.body("obj")?,
        goal_site: scene.sim.site("goal")?,
    }))
}

impl Task for HandInsert {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], OBJ_START_Z];
        scene.target_pos = [rv[3], rv[4], rv[5]];
        scene.set_obj_xyz(scene.obj_init_pos);
        scene.sim.set_site_pos(self.goal_site, scene.target_pos);
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
        let obj = [obs[4], obs[5], obs[6]];
        let target_to_obj = dist(obj, scene.target_pos);
        let target_to_obj_init = dist(scene.obj_init_pos, scene.target_pos);
        let in_place = tolerance(
            target_to_obj,
            (0.0, TARGET_RADIUS),
            target_to_obj_init,
            Sigmoid::LongTail,
        );
        let object_grasped =
            scene.gripper_caging_reward(action, obj, 0.015, 0.05, 0.01, 0.005, 1.0, Density::High);
        let mut reward = hamacher_product(object_grasped, in_place);
        let tcp_to_obj = dist(obj, scene.tcp_center());
        if tcp_to_obj < 0.02 && obs[3] > 0.0 {
            reward += 1.0 + 7.0 * in_place;
        }
        if target_to_obj < TARGET_RADIUS {
            reward = 10.0;
        }
        Eval {
            reward,
            success: target_to_obj <= 0.05,
        }
    }
}
