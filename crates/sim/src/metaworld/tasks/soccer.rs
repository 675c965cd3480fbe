//! soccer-v3: push a ball into a goal box on the table.

use super::pad_caging::PadCaging;
use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, scaled_dist, scipy_quat_from_mat, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "soccer-v3",
    xml: "sawyer_xyz/sawyer_soccer.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[-0.1, 0.6, 0.03, -0.1, 0.8, 0.0],
    rand_high: &[0.1, 0.7, 0.03, 0.1, 0.9, 0.0],
    goal_low: [-0.1, 0.8, 0.0],
    goal_high: [0.1, 0.9, 0.0],
    rand_vec_ok: obj_goal_apart::<15>,
};

/// The ball's height at reset (`init_config["obj_init_pos"][2]`), m.
const BALL_Z: f64 = 0.03;
const CAGING: PadCaging = PadCaging {
    obj_radius: 0.013,
    grip_extra: 0.01,
    xz_success_margin: 0.005,
};
/// The task's `TARGET_RADIUS` (the class overrides the default 0.05), m; also the success
/// radius.
const TARGET_RADIUS: f64 = 0.07;
/// The in-place distance weighs x three times.
const X_SCALING: [f64; 3] = [3.0, 1.0, 1.0];

#[derive(Debug)]
struct Soccer {
    ball: usize,
    goal_whole: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(Soccer {
        ball: scene.sim.body("soccer_ball")?,
        goal_whole: scene.sim.body("goal_whole")?,
    }))
}

/// Norm of `(a - b)` with x weighed three times.
fn x_scaled_dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    scaled_dist(a, b, X_SCALING)
}

impl Task for Soccer {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.target_pos = [rv[3], rv[4], rv[5]];
        scene.obj_init_pos = [rv[0], rv[1], BALL_Z];
        scene.sim.set_body_pos(self.goal_whole, scene.target_pos);
        scene.set_obj_xyz(scene.obj_init_pos);
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.body_com(self.ball));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.body_xmat(self.ball)));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let target = scene.target_pos;
        let target_to_obj = x_scaled_dist(obj, target);
        // Python measures the margin from the ball's current position, not its start.
        let target_to_obj_init = x_scaled_dist(obj, scene.obj_init_pos);
        let mut in_place = tolerance(
            target_to_obj,
            (0.0, TARGET_RADIUS),
            target_to_obj_init,
            Sigmoid::LongTail,
        );
        let goal_line = target[1] - 0.1;
        if obj[1] > goal_line && (obj[0] - target[0]).abs() > 0.10 {
            in_place =
                (in_place - 2.0 * ((obj[1] - goal_line) / (1.0 - goal_line))).clamp(0.0, 1.0);
        }
        let object_grasped = CAGING.reward(scene, obj);
        let mut reward = 3.0 * object_grasped + 6.5 * in_place;
        if target_to_obj < TARGET_RADIUS {
            reward = 10.0;
        }
        Eval {
            reward,
            success: dist(obj, target) <= TARGET_RADIUS,
        }
    }
}
