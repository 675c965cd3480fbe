//! pick-place-v3: pick up a puck and hold it at a goal in the air.

use super::pad_caging::PadCaging;
use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, scipy_quat_from_mat, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "pick-place-v3",
    xml: "sawyer_xyz/sawyer_pick_place_v3.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[-0.1, 0.6, 0.02, -0.1, 0.8, 0.05],
    rand_high: &[0.1, 0.7, 0.02, 0.1, 0.9, 0.3],
    goal_low: [-0.1, 0.8, 0.05],
    goal_high: [0.1, 0.9, 0.3],
    rand_vec_ok: obj_goal_apart::<15>,
};

/// Parameters of the task's own caging reward (its gripping term reads the action instead
/// of the pads, so `grip_extra` is unused).
const CAGING: PadCaging = PadCaging {
    obj_radius: 0.015,
    grip_extra: 0.0,
    xz_success_margin: 0.005,
};
/// Success: the puck within this distance of the goal.
const SUCCESS_RADIUS: f64 = 0.07;

#[derive(Debug)]
struct PickPlace {
    obj: usize,
    obj_geom: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(PickPlace {
        obj: scene.sim.body("obj")?,
        obj_geom: scene.sim.geom("objGeom")?,
    }))
}

impl PickPlace {
    /// The task's override of `_gripper_caging_reward` (high density). Its margins are measured
    /// from `init_left_pad`/`init_right_pad`, which in Python are live views of `data.xpos`
    /// (`get_body_com` returns no copy): they are the *current* pad positions, not the ones at
    /// reset.
    fn caging_reward(scene: &Scene, action: &[f32; ACTION_DIM], obj: [f64; 3]) -> f64 {
        let (caging, _) = CAGING.caging(scene, obj);
        let gripper_closed = f64::from(action[3].clamp(0.0, 1.0));
        let gripping = if caging > 0.97 { gripper_closed } else { 0.0 };
        (hamacher_product(caging, gripping) + caging) / 2.0
    }
}

impl Task for PickPlace {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.target_pos = [rv[3], rv[4], rv[5]];
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        // Python re-reads `init_tcp` and the pad views here: no change in value.
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
        let target = scene.target_pos;
        let obj_to_target = dist(obj, target);
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let in_place_margin = dist(scene.obj_init_pos, target);
        let in_place = tolerance(
            obj_to_target,
            (0.0, TARGET_RADIUS),
            in_place_margin,
            Sigmoid::LongTail,
        );
        let object_grasped = Self::caging_reward(scene, action, obj);
        let mut reward = hamacher_product(object_grasped, in_place);
        if tcp_to_obj < 0.02 && tcp_opened > 0.0 && obj[2] - 0.01 > scene.obj_init_pos[2] {
            reward += 1.0 + 5.0 * in_place;
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
