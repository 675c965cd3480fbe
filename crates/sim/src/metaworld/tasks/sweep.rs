//! sweep-v3: sweep a block sideways (towards +x) off the table edge.

use super::pad_caging::PadCaging;
use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "sweep-v3",
    xml: "sawyer_xyz/sawyer_sweep_v3.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    // Only the block is randomised; the goal takes its y.
    rand_low: &[-0.1, 0.6, 0.02],
    rand_high: &[0.1, 0.7, 0.02],
    goal_low: [0.49, 0.6, 0.0],
    goal_high: [0.51, 0.7, 0.02],
    rand_vec_ok: always_ok,
};

/// The goal beyond the table edge (`self.goal`); its y is the block's.
const GOAL: [f64; 3] = [0.5, 0.65, 0.01];
/// The block's height at reset (`init_config["obj_init_pos"][2]`), m.
const BLOCK_Z: f64 = 0.02;
const CAGING: PadCaging = PadCaging {
    obj_radius: 0.02,
    grip_extra: 0.01,
    xz_success_margin: 0.005,
};

#[derive(Debug)]
struct Sweep {
    obj: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(Sweep {
        obj: scene.sim.body("obj")?,
    }))
}

impl Task for Sweep {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], BLOCK_Z];
        scene.target_pos = [GOAL[0], rv[1], GOAL[2]];
        scene.set_obj_xyz(scene.obj_init_pos);
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        // MuJoCo's (w, x, y, z) quaternion, as Python reads `data.body("obj").xquat`.
        out[..3].copy_from_slice(&scene.sim.body_xpos(self.obj));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.obj));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let target = scene.target_pos;
        let obj_to_target = dist(obj, target);
        let in_place = tolerance(
            obj_to_target,
            (0.0, TARGET_RADIUS),
            dist(scene.obj_init_pos, target),
            Sigmoid::LongTail,
        );
        let object_grasped = CAGING.reward(scene, obj);
        let mut reward = 2.0 * object_grasped + 6.0 * hamacher_product(object_grasped, in_place);
        if obj_to_target < TARGET_RADIUS {
            reward = 10.0;
        }
        Eval {
            reward,
            success: obj_to_target <= 0.05,
        }
    }
}
