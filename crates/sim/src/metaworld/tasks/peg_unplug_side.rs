//! peg-unplug-side-v3: pull a peg sideways (towards +x) out of a box.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM};

/// Where the plug sits relative to the box.
const PLUG_OFFSET: [f64; 3] = [0.044, 0.0, 0.131];
/// The goal relative to the plug's start: 15 cm along x.
const GOAL_OFFSET: [f64; 3] = [0.15, 0.0, 0.0];

pub const SPEC: TaskSpec = TaskSpec {
    name: "peg-unplug-side-v3",
    xml: "sawyer_xyz/sawyer_peg_unplug_side.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    // The box position only.
    rand_low: &[-0.25, 0.6, -0.001],
    rand_high: &[-0.15, 0.8, 0.001],
    // Python: obj_low/high + [0.194, 0, 0.131].
    goal_low: [-0.25 + 0.194, 0.6 + 0.0, -0.001 + 0.131],
    goal_high: [-0.15 + 0.194, 0.8 + 0.0, 0.001 + 0.131],
    rand_vec_ok: always_ok,
};

/// Success: the peg end within this distance of the goal.
const SUCCESS_RADIUS: f64 = 0.07;

#[derive(Debug)]
struct PegUnplugSide {
    box_body: usize,
    plug: usize,
    peg_end: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(PegUnplugSide {
        box_body: scene.sim.body("box")?,
        plug: scene.sim.body("plug1")?,
        peg_end: scene.sim.site("pegEnd")?,
    }))
}

impl Task for PegUnplugSide {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        let pos_box = [rv[0], rv[1], rv[2]];
        scene.sim.set_body_pos(self.box_body, pos_box);
        let pos_plug: [f64; 3] = std::array::from_fn(|i| pos_box[i] + PLUG_OFFSET[i]);
        // The task's `_set_obj_xyz`: plug position, identity orientation, zero linear
        // velocity (the angular velocity is left as it is), then mj_forward.
        let mut qpos = scene.sim.qpos().to_vec();
        let mut qvel = scene.sim.qvel().to_vec();
        qpos[9..12].copy_from_slice(&pos_plug);
        qpos[12..16].copy_from_slice(&[1.0, 0.0, 0.0, 0.0]);
        qvel[9..12].fill(0.0);
        scene.set_state(&qpos, &qvel);
        scene.obj_init_pos = scene.sim.site_xpos(self.peg_end);
        scene.target_pos = std::array::from_fn(|i| pos_plug[i] + GOAL_OFFSET[i]);
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        // MuJoCo's (w, x, y, z) quaternion, as Python reads `data.body("plug1").xquat`.
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.peg_end));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.plug));
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
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let obj_to_target = dist(obj, target);
        let object_grasped =
            scene.gripper_caging_reward(action, obj, 0.025, 0.05, 0.01, 0.005, 0.8, Density::High);
        let in_place = tolerance(
            obj_to_target,
            (0.0, 0.05),
            dist(scene.obj_init_pos, target),
            Sigmoid::LongTail,
        );
        let grasp_success = tcp_opened > 0.5 && obj[0] - scene.obj_init_pos[0] > 0.015;
        let mut reward = 2.0 * object_grasped;
        if grasp_success && tcp_to_obj < 0.035 {
            reward = 1.0 + 2.0 * object_grasped + 5.0 * in_place;
        }
        if obj_to_target <= 0.05 {
            reward = 10.0;
        }
        Eval {
            reward,
            success: obj_to_target <= SUCCESS_RADIUS,
        }
    }
}
