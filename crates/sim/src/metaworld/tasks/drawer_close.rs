//! drawer-close-v3 (`metaworld/envs/sawyer_drawer_close_v3.py`): push an open drawer shut.
//!
//! Its layout is drawer-open-v3's ([`super::drawer_open`]).

use super::{drawer_open, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, radius_tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "drawer-close-v3",
    ..drawer_open::SPEC
};

/// How far the drawer is pulled out at reset (`maxDist`).
const MAX_DIST: f64 = 0.15;
/// Handle position relative to the drawer link.
const HANDLE_OFFSET: [f64; 3] = [0.0, -0.16, 0.05];
/// The drawer slide joint's qpos index.
const SLIDE_QPOS: usize = 9;
const HANDLE_REACH_RADIUS: f64 = 0.005;
/// Success: the handle within this distance of the goal.
const SUCCESS_DIST: f64 = TARGET_RADIUS + 0.015;

#[derive(Debug)]
struct DrawerClose {
    drawer: usize,
    drawer_link: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(DrawerClose {
        drawer: scene.sim.body("drawer")?,
        drawer_link: scene.sim.body("drawer_link")?,
    }))
}

impl DrawerClose {
    fn handle_pos(&self, scene: &Scene) -> [f64; 3] {
        let link = scene.body_com(self.drawer_link);
        std::array::from_fn(|i| link[i] + HANDLE_OFFSET[i])
    }
}

impl Task for DrawerClose {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        let drawer_pos = [rv[0], rv[1], rv[2]];
        scene.sim.set_body_pos(self.drawer, drawer_pos);
        let goal_offset = [0.0, -0.16, 0.09];
        scene.target_pos = std::array::from_fn(|i| drawer_pos[i] + goal_offset[i]);
        // `_set_obj_xyz(-maxDist)`: pull the drawer all the way out (velocity kept).
        scene.sim.qpos_mut()[SLIDE_QPOS] = -MAX_DIST;
        scene.forward();
        scene.obj_init_pos = self.handle_pos(scene);
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&self.handle_pos(scene));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let target = scene.target_pos;
        let target_to_obj = dist(obj, target);
        let target_to_obj_init = dist(scene.obj_init_pos, target);
        let in_place = radius_tolerance(
            target_to_obj,
            TARGET_RADIUS,
            target_to_obj_init,
            Sigmoid::LongTail,
        );
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let tcp_to_obj_init = dist(scene.obj_init_pos, scene.init_tcp);
        let reach = radius_tolerance(
            tcp_to_obj,
            HANDLE_REACH_RADIUS,
            tcp_to_obj_init,
            Sigmoid::Gaussian,
        );
        let gripper_closed = f64::from(action[3].clamp(0.0, 1.0));
        let reach = hamacher_product(reach, gripper_closed);
        let success = target_to_obj <= SUCCESS_DIST;
        let reward = if success {
            1.0
        } else {
            hamacher_product(reach, in_place)
        };
        Eval {
            reward: 10.0 * reward,
            success,
        }
    }
}
