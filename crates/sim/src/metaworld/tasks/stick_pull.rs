//! stick-pull-v3 (`metaworld/envs/sawyer_stick_pull_v3.py`): grasp a stick, hook it into a
//! container's handle and pull the container to a goal.

use super::stick_push::{self, StickScene, STICK_Z};
use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::reward::{add, dist, hamacher_product, scaled_dist, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "stick-pull-v3",
    hand_low: [-0.5, 0.35, 0.05],
    rand_low: &[-0.1, 0.55, 0.0, 0.35, 0.45, 0.0199],
    rand_high: &[0.0, 0.65, 0.001, 0.45, 0.55, 0.0201],
    goal_low: [0.35, 0.45, 0.0199],
    goal_high: [0.45, 0.55, 0.0201],
    ..stick_push::SPEC
};

/// The container's slide joints at reset.
const CONTAINER_QPOS: [f64; 2] = [0.0, 0.09];
/// The container's centre relative to its handle (obs[11..14]).
const CONTAINER_FROM_HANDLE: [f64; 3] = [0.05, 0.0, 0.0];
/// The stick-to-container distance weighs z twice.
const YZ_SCALING: [f64; 3] = [1.0, 1.0, 2.0];

#[derive(Debug)]
struct StickPull {
    parts: StickScene,
    stick_end: usize,
    /// The stick's start (`stick_init_pos`); `scene.obj_init_pos` is the container's.
    stick_init_pos: [f64; 3],
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(StickPull {
        parts: StickScene::new(scene)?,
        stick_end: scene.sim.site("stick_end")?,
        stick_init_pos: [0.0; 3],
    }))
}

/// `_stick_is_inserted`: the stick's end is past the handle in x and close to it in y and z.
fn stick_is_inserted(handle: [f64; 3], end_of_stick: [f64; 3]) -> bool {
    end_of_stick[0] >= handle[0]
        && (end_of_stick[1] - handle[1]).abs() <= 0.040
        && (end_of_stick[2] - handle[2]).abs() <= 0.060
}

impl Task for StickPull {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        self.stick_init_pos = [rv[0], rv[1], STICK_Z];
        scene.target_pos = [rv[3], rv[4], STICK_Z];
        scene.obj_init_pos = self.parts.place(scene, self.stick_init_pos, CONTAINER_QPOS);
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        self.parts.objects(scene, [0.0; 3], out);
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let stick = [obs[4], obs[5], obs[6]];
        let end_of_stick = scene.sim.site_xpos(self.stick_end);
        let handle = [obs[11], obs[12], obs[13]];
        let container = add(handle, CONTAINER_FROM_HANDLE);
        let container_init_pos = add(scene.obj_init_pos, CONTAINER_FROM_HANDLE);
        let tcp_opened = obs[3];
        let target = scene.target_pos;
        let tcp_to_stick = dist(stick, scene.tcp_center());
        let handle_to_target = dist(handle, target);

        let stick_in_place = tolerance(
            scaled_dist(stick, container, YZ_SCALING),
            (0.0, TARGET_RADIUS),
            scaled_dist(self.stick_init_pos, container_init_pos, YZ_SCALING),
            Sigmoid::LongTail,
        );
        let stick_in_place_2 = tolerance(
            dist(stick, target),
            (0.0, TARGET_RADIUS),
            dist(self.stick_init_pos, target),
            Sigmoid::LongTail,
        );
        let container_in_place = tolerance(
            dist(container, target),
            (0.0, TARGET_RADIUS),
            dist(scene.obj_init_pos, target),
            Sigmoid::LongTail,
        );
        let mut object_grasped =
            scene.gripper_caging_reward(action, stick, 0.014, 0.05, 0.01, 0.01, 1.0, Density::High);
        let grasp_success =
            tcp_to_stick < 0.02 && tcp_opened > 0.0 && stick[2] - 0.01 > self.stick_init_pos[2];
        if grasp_success {
            object_grasped = 1.0;
        }
        let in_place_and_grasped = hamacher_product(object_grasped, stick_in_place);
        let inserted = stick_is_inserted(handle, end_of_stick);
        let mut reward = in_place_and_grasped;
        if grasp_success {
            reward = 1.0 + in_place_and_grasped + 5.0 * stick_in_place;
            if inserted {
                reward = 1.0
                    + in_place_and_grasped
                    + 5.0
                    + 2.0 * stick_in_place_2
                    + 1.0 * container_in_place;
                if handle_to_target <= 0.12 {
                    reward = 10.0;
                }
            }
        }
        Eval {
            reward,
            success: handle_to_target <= 0.12 && inserted,
        }
    }
}
