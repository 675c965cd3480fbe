//! coffee-pull-v3 (`metaworld/envs/sawyer_coffee_pull_v3.py`): pull a mug out from under a
//! coffee machine to a goal in front of it.

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{
    dist, hamacher_product, scaled_dist, scipy_quat_from_mat, tolerance, Sigmoid,
};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "coffee-pull-v3",
    xml: "sawyer_xyz/sawyer_coffee.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.4, 0.2],
    rand_low: &[-0.05, 0.7, -0.001, -0.1, 0.55, -0.001],
    rand_high: &[0.05, 0.75, 0.001, 0.1, 0.65, 0.001],
    goal_low: [-0.1, 0.55, -0.001],
    goal_high: [0.1, 0.65, 0.001],
    rand_vec_ok: obj_goal_apart::<15>,
};

/// The machine stands this far behind the mug's start.
const MACHINE_OFFSET: [f64; 3] = [0.0, 0.22, 0.0];
/// Gripper effort the caging reward asks for.
const DESIRED_EFFORT: f64 = 0.7;
/// x and y weighted twice in the mug-to-goal distance of the reward.
const XY_SCALING: [f64; 3] = [2.0, 2.0, 1.0];
/// Success: the mug within this distance of the goal.
const SUCCESS_DISTANCE: f64 = 0.07;

#[derive(Debug)]
pub(super) struct Coffee {
    pub(super) spec: &'static TaskSpec,
    obj: usize,
    mug_geom: usize,
    machine: usize,
    goal_site: usize,
    /// Whether the machine stands behind the goal (push) rather than the mug's start (pull).
    machine_at_goal: bool,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(Coffee::new(scene, &SPEC, false)?))
}

impl Coffee {
    pub(super) fn new(
        scene: &Scene,
        spec: &'static TaskSpec,
        machine_at_goal: bool,
    ) -> Result<Self> {
        Ok(Self {
            spec,
            obj: scene.sim.body("obj")?,
            mug_geom: scene.sim.geom("mug")?,
            machine: scene.sim.body("coffee_machine")?,
            goal_site: scene.sim.site("mug_goal")?,
            machine_at_goal,
        })
    }
}

impl Task for Coffee {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        let mug = [rv[0], rv[1], rv[2]];
        let goal = [rv[3], rv[4], rv[5]];
        // The task's `_set_obj_xyz`: the mug's free joint is qpos[0..3]; it zeroes qvel[9..15]
        // (arm and finger velocities, not the mug's), then mj_forward.
        scene.sim.qpos_mut()[0..3].copy_from_slice(&mug);
        scene.sim.qvel_mut()[9..15].fill(0.0);
        scene.forward();
        scene.obj_init_pos = mug;
        let base = if self.machine_at_goal { goal } else { mug };
        let machine: [f64; 3] = std::array::from_fn(|i| base[i] + MACHINE_OFFSET[i]);
        scene.sim.set_body_pos(self.machine, machine);
        scene.target_pos = goal;
        scene.sim.set_site_pos(self.goal_site, goal);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.body_com(self.obj));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(self.mug_geom)));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let target = scene.target_pos;
        let target_to_obj = scaled_dist(obj, target, XY_SCALING);
        let target_to_obj_init = scaled_dist(scene.obj_init_pos, target, XY_SCALING);
        let in_place = tolerance(
            target_to_obj,
            (0.0, 0.05),
            target_to_obj_init,
            Sigmoid::LongTail,
        );
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let object_grasped = scene.gripper_caging_reward(
            action,
            obj,
            0.02,
            0.05,
            0.04,
            0.05,
            DESIRED_EFFORT,
            Density::Medium,
        );
        let mut reward = hamacher_product(object_grasped, in_place);
        if tcp_to_obj < 0.04 && obs[3] > 0.0 {
            reward += 1.0 + 5.0 * in_place;
        }
        if target_to_obj < 0.05 {
            reward = 10.0;
        }
        Eval {
            reward,
            success: dist(obj, target) <= SUCCESS_DISTANCE,
        }
    }
}
