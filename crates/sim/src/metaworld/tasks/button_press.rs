//! button-press-v3: press a button on a wall-mounted box horizontally (along +y).

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "button-press-v3",
    xml: "sawyer_xyz/sawyer_button_press.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [0.0, 0.4f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.85, 0.115],
    rand_high: &[0.1, 0.9, 0.115],
    goal_low: [-0.5, 0.40, 0.05],
    goal_high: [0.5, 1.0, 0.5],
    rand_vec_ok: always_ok,
};

/// The button's slide joint (`qpos[9]`, `qvel[9]` in Python).
const BUTTON_JOINT_ADR: usize = 9;
/// From the button body to its pressing surface.
const BUTTON_FACE_OFFSET: f64 = -0.193;
/// The hand counts as at the button within this distance.
const NEAR_BUTTON: f64 = 0.05;
const SUCCESS_DISTANCE: f64 = 0.02;

#[derive(Debug)]
struct ButtonPress {
    box_body: usize,
    button: usize,
    hole: usize,
    button_start: usize,
    obj_to_target_init: f64,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(ButtonPress {
        box_body: scene.sim.body("box")?,
        button: scene.sim.body("button")?,
        hole: scene.sim.site("hole")?,
        button_start: scene.sim.site("buttonStart")?,
        obj_to_target_init: 0.0,
    }))
}

impl Task for ButtonPress {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.sim.set_body_pos(self.box_body, scene.obj_init_pos);
        scene.set_scalar_joint(BUTTON_JOINT_ADR, BUTTON_JOINT_ADR, 0.0);
        scene.target_pos = scene.sim.site_xpos(self.hole);
        self.obj_to_target_init =
            (scene.target_pos[1] - scene.sim.site_xpos(self.button_start)[1]).abs();
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        let [x, y, z] = scene.body_com(self.button);
        out[..3].copy_from_slice(&[x, y + BUTTON_FACE_OFFSET, z]);
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.button));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let tcp_to_obj_init = dist(obj, scene.init_tcp);
        let obj_to_target = (scene.target_pos[1] - obj[1]).abs();
        let tcp_closed = obs[3].max(0.0);

        let near_button = tolerance(
            tcp_to_obj,
            (0.0, NEAR_BUTTON),
            tcp_to_obj_init,
            Sigmoid::LongTail,
        );
        let button_pressed = tolerance(
            obj_to_target,
            (0.0, 0.005),
            self.obj_to_target_init,
            Sigmoid::LongTail,
        );
        let mut reward = 2.0 * hamacher_product(tcp_closed, near_button);
        if tcp_to_obj <= NEAR_BUTTON {
            reward += 8.0 * button_pressed;
        }
        Eval {
            reward,
            success: obj_to_target <= SUCCESS_DISTANCE,
        }
    }
}
