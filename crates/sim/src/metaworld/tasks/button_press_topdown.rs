//! button-press-topdown-v3: press a button down from above.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "button-press-topdown-v3",
    xml: "sawyer_xyz/sawyer_button_press_topdown.xml",
    hand_low: HAND_LOW,
    hand_high: HAND_HIGH,
    mocap_low: None,
    mocap_high: None,
    // Python stores it as float32.
    hand_init_pos: [0.0, 0.4f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.8, 0.115],
    rand_high: &[0.1, 0.9, 0.115],
    goal_low: HAND_LOW,
    goal_high: HAND_HIGH,
    rand_vec_ok: always_ok,
};

const HAND_LOW: [f64; 3] = [-0.5, 0.40, 0.05];
const HAND_HIGH: [f64; 3] = [0.5, 1.0, 0.5];
/// Button top relative to the button body.
const BUTTON_TOP_OFFSET: f64 = 0.193;
/// Success: the button top within this height of the goal.
const SUCCESS_DIST: f64 = 0.024;

#[derive(Debug)]
struct ButtonPressTopdown {
    box_body: usize,
    button: usize,
    hole: usize,
    button_start: usize,
    /// Initial height difference between button and goal (`_obj_to_target_init`).
    obj_to_target_init: f64,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(ButtonPressTopdown {
        box_body: scene.sim.body("box")?,
        button: scene.sim.body("button")?,
        hole: scene.sim.site("hole")?,
        button_start: scene.sim.site("buttonStart")?,
        obj_to_target_init: 0.0,
    }))
}

impl Task for ButtonPressTopdown {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.sim.set_body_pos(self.box_body, scene.obj_init_pos);
        scene.forward();
        scene.target_pos = scene.sim.site_xpos(self.hole);
        self.obj_to_target_init =
            (scene.target_pos[2] - scene.sim.site_xpos(self.button_start)[2]).abs();
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        let mut pos = scene.body_com(self.button);
        pos[2] += BUTTON_TOP_OFFSET;
        out[..3].copy_from_slice(&pos);
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.button));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let tcp_to_obj_init = dist(obj, scene.init_tcp);
        let obj_to_target = (scene.target_pos[2] - obj[2]).abs();
        let tcp_closed = 1.0 - obs[3];
        let near_button = tolerance(tcp_to_obj, (0.0, 0.01), tcp_to_obj_init, Sigmoid::LongTail);
        let button_pressed = tolerance(
            obj_to_target,
            (0.0, 0.005),
            self.obj_to_target_init,
            Sigmoid::LongTail,
        );
        let mut reward = 5.0 * hamacher_product(tcp_closed, near_button);
        if tcp_to_obj <= 0.03 {
            reward += 5.0 * button_pressed;
        }
        Eval {
            reward,
            success: obj_to_target <= SUCCESS_DIST,
        }
    }
}
