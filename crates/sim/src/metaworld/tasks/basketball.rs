//! basketball-v3: pick up a ball and put it through a hoop.

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, scaled_dist, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "basketball-v3",
    xml: "sawyer_xyz/sawyer_basketball.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.6, 0.0299, -0.1, 0.85, 0.0],
    rand_high: &[0.1, 0.7, 0.0301, 0.1, 0.9 + 1e-7, 0.0],
    // The basket's range shifted to the hoop, evaluated as Python does.
    goal_low: [-0.1 + 0.0, 0.85 + -0.083, 0.0 + 0.2499],
    goal_high: [0.1 + 0.0, (0.9 + 1e-7) + -0.083, 0.0 + 0.2501],
    rand_vec_ok: obj_goal_apart::<15>,
};

/// Height of the ball's start: the float32 z of Python's `init_config["obj_init_pos"]`.
const BALL_START_Z: f64 = 0.03f32 as f64;
/// The task's `TARGET_RADIUS` (wider than the shared one).
const TARGET_RADIUS: f64 = 0.08;
/// The reward aims at this height above the hoop's centre.
const AIM_Z: f64 = 0.3;

#[derive(Debug)]
struct Basketball {
    ball: usize,
    basket: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(Basketball {
        ball: scene.sim.body("bsktball")?,
        basket: scene.sim.body("basket_goal")?,
        goal_site: scene.sim.site("goal")?,
    }))
}

/// The z error counts twice in the ball-to-goal distance.
const Z_SCALING: [f64; 3] = [1.0, 1.0, 2.0];

impl Task for Basketball {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], BALL_START_Z];
        scene.sim.set_body_pos(self.basket, [rv[3], rv[4], rv[5]]);
        scene.set_obj_xyz(scene.obj_init_pos);
        // Python keeps a view of the goal site's world position (the hoop). It also writes
        // that position into the site's local offset, which MuJoCo ignores: the site sits at
        // its body's origin, so its world position is always the body's.
        scene.target_pos = scene.sim.site_xpos(self.goal_site);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.body_com(self.ball));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.ball));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let target = [scene.target_pos[0], scene.target_pos[1], AIM_Z];
        let target_to_obj = scaled_dist(obj, target, Z_SCALING);
        let target_to_obj_init = scaled_dist(scene.obj_init_pos, target, Z_SCALING);
        let in_place = tolerance(
            target_to_obj,
            (0.0, TARGET_RADIUS),
            target_to_obj_init,
            Sigmoid::LongTail,
        );
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let lifted = tcp_to_obj < 0.035 && obs[3] > 0.0 && obj[2] - 0.01 > scene.obj_init_pos[2];
        let object_grasped = if lifted {
            1.0
        } else {
            scene.gripper_caging_reward(action, obj, 0.025, 0.06, 0.01, 0.005, 1.0, Density::High)
        };
        let mut reward = hamacher_product(object_grasped, in_place);
        if lifted {
            reward += 1.0 + 5.0 * in_place;
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
