//! push-v3: push a puck across the table to a goal on the table surface.

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, scipy_quat_from_mat, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "push-v3",
    xml: "sawyer_xyz/sawyer_push_v3.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[-0.1, 0.6, 0.02, -0.1, 0.8, 0.01],
    rand_high: &[0.1, 0.7, 0.02, 0.1, 0.9, 0.02],
    goal_low: [-0.1, 0.8, 0.01],
    goal_high: [0.1, 0.9, 0.02],
    rand_vec_ok: obj_goal_apart::<15>,
};

/// Caging reward parameters of the puck.
const OBJ_RADIUS: f64 = 0.015;
const PAD_SUCCESS_THRESH: f64 = 0.05;
const OBJECT_REACH_RADIUS: f64 = 0.01;
const XZ_THRESH: f64 = 0.005;

#[derive(Debug)]
struct Push {
    obj: usize,
    obj_geom: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(Push {
        obj: scene.sim.body("obj")?,
        obj_geom: scene.sim.geom("objGeom")?,
    }))
}

impl Task for Push {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        // The puck's resting height after the hand reset is both the object and the goal height.
        let height = scene.body_com(self.obj)[2];
        scene.target_pos = [rv[3], rv[4], height];
        scene.obj_init_pos = [rv[0], rv[1], height];
        scene.set_obj_xyz(scene.obj_init_pos);
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.body_com(self.obj));
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
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let target_to_obj = dist(obj, scene.target_pos);
        let target_to_obj_init = dist(scene.obj_init_pos, scene.target_pos);
        let in_place = tolerance(
            target_to_obj,
            (0.0, TARGET_RADIUS),
            target_to_obj_init,
            Sigmoid::LongTail,
        );
        let object_grasped = scene.gripper_caging_reward(
            action,
            obj,
            OBJ_RADIUS,
            PAD_SUCCESS_THRESH,
            OBJECT_REACH_RADIUS,
            XZ_THRESH,
            1.0,
            Density::High,
        );
        let mut reward = 2.0 * object_grasped;
        if tcp_to_obj < 0.02 && tcp_opened > 0.0 {
            reward += 1.0 + reward + 5.0 * in_place;
        }
        if target_to_obj < TARGET_RADIUS {
            reward = 10.0;
        }
        Eval {
            reward,
            success: target_to_obj <= TARGET_RADIUS,
        }
    }
}
