//! coffee-button-v3: press the button on the front of a coffee machine.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

/// How far the button travels (`max_dist`).
const MAX_DIST: f64 = 0.03;

pub const SPEC: TaskSpec = TaskSpec {
    name: "coffee-button-v3",
    xml: "sawyer_xyz/sawyer_coffee.xml",
    hand_low: [-0.5, 0.4, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float64 here, unlike most tasks.
    hand_init_pos: [0.0, 0.4, 0.2],
    rand_low: &[-0.1, 0.8, -0.001],
    rand_high: &[0.1, 0.9, 0.001],
    // obj bounds + [-/+0.001, -0.22 + max_dist, 0.299 / 0.301], evaluated as Python does.
    goal_low: [-0.1 + -0.001, 0.8 + (-0.22 + MAX_DIST), -0.001 + 0.299],
    goal_high: [0.1 + 0.001, 0.9 + (-0.22 + MAX_DIST), 0.001 + 0.301],
    rand_vec_ok: always_ok,
};

/// Mug position relative to the machine.
const MUG_OFFSET: [f64; 3] = [0.0, -0.22, 0.0];
/// Button position relative to the machine.
const BUTTON_OFFSET: [f64; 3] = [0.0, -0.22, 0.3];
const NEAR_BUTTON: f64 = 0.05;
const SUCCESS_DISTANCE: f64 = 0.02;

#[derive(Debug)]
struct CoffeeButton {
    machine: usize,
    button_start: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(CoffeeButton {
        machine: scene.sim.body("coffee_machine")?,
        button_start: scene.sim.site("buttonStart")?,
    }))
}

impl Task for CoffeeButton {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        let machine = [rv[0], rv[1], rv[2]];
        scene.obj_init_pos = machine;
        scene.sim.set_body_pos(self.machine, machine);
        // This task's `_set_obj_xyz`: the mug's free joint is qpos[0..3]; it zeroes
        // qvel[9..15] (arm and finger velocities, not the mug's), then mj_forward.
        let mug: [f64; 3] = std::array::from_fn(|i| machine[i] + MUG_OFFSET[i]);
        scene.sim.qpos_mut()[0..3].copy_from_slice(&mug);
        scene.sim.qvel_mut()[9..15].fill(0.0);
        scene.forward();
        let button: [f64; 3] = std::array::from_fn(|i| machine[i] + BUTTON_OFFSET[i]);
        scene.target_pos = [button[0], button[1] + MAX_DIST, button[2]];
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.button_start));
        // A constant identity quaternion.
        out[3] = 1.0;
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
        let button_pressed = tolerance(obj_to_target, (0.0, 0.005), MAX_DIST, Sigmoid::LongTail);
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
