//! dial-turn-v3: rotate a dial on the table by pushing the edge of its knob.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, radius_tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "dial-turn-v3",
    xml: "sawyer_xyz/sawyer_dial.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.7, 0.0],
    rand_high: &[0.1, 0.8, 0.0],
    goal_low: [-0.1, 0.73, 0.0299],
    goal_high: [0.1, 0.83, 0.0301],
    rand_vec_ok: always_ok,
};

/// This task's `TARGET_RADIUS` (wider than the usual 0.05).
const TARGET_RADIUS: f64 = 0.07;
/// Goal relative to the dial.
const GOAL_OFFSET: [f64; 3] = [0.0, 0.03, 0.03];
const DIAL_RADIUS: f64 = 0.05;
/// Where the hand should be, relative to the knob's edge, to push it round.
const PUSH_OFFSET: [f64; 3] = [0.05, 0.02, 0.09];
const DIAL_REACH_RADIUS: f64 = 0.005;

#[derive(Debug)]
struct DialTurn {
    dial: usize,
    knob_qpos: usize,
    push_position_init: [f64; 3],
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    let knob = scene.sim.joint("knob_Joint_1")?;
    Ok(Box::new(DialTurn {
        dial: scene.sim.body("dial")?,
        knob_qpos: scene.sim.jnt_qposadr(knob),
        push_position_init: [0.0; 3],
    }))
}

impl DialTurn {
    /// The point on the knob's edge: dial centre (kinematics) + radius at the joint angle
    /// (current qpos).
    fn knob_edge(&self, scene: &Scene) -> [f64; 3] {
        let center = scene.body_com(self.dial);
        let angle = scene.sim.qpos()[self.knob_qpos];
        [
            center[0] + angle.sin() * DIAL_RADIUS,
            center[1] + -angle.cos() * DIAL_RADIUS,
            center[2] + 0.0 * DIAL_RADIUS,
        ]
    }

    fn push_position(&self, scene: &Scene) -> [f64; 3] {
        let edge = self.knob_edge(scene);
        std::array::from_fn(|i| edge[i] + PUSH_OFFSET[i])
    }
}

/// `10 * hamacher(hamacher(reach, min(max(0, effort), 1)), in_place)` with Python's types:
/// a positive effort up to 1 stays a NumPy float32, which turns the rest of the arithmetic
/// into float32 (NEP 50); above 1 the clamp yields the int 1 (float64 arithmetic), at or
/// below 0 the int 0 (zero reward).
fn gripped_reward(reach: f64, in_place: f64, effort: f32) -> f64 {
    if effort > 1.0 {
        10.0 * hamacher_product(hamacher_product(reach, 1.0), in_place)
    } else if effort > 0.0 {
        let reach = hamacher_f32(reach as f32, effort);
        f64::from(10.0 * hamacher_f32(reach, in_place as f32))
    } else {
        0.0
    }
}

/// The Hamacher product evaluated in float32.
fn hamacher_f32(a: f32, b: f32) -> f32 {
    let denominator = a + b - a * b;
    if denominator > 0.0 {
        a * b / denominator
    } else {
        0.0
    }
}

impl Task for DialTurn {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.target_pos = std::array::from_fn(|i| rv[i] + GOAL_OFFSET[i]);
        scene.sim.set_body_pos(self.dial, scene.obj_init_pos);
        // No forward pass: the kinematics of the hand reset's last substep.
        self.push_position_init = self.push_position(scene);
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&self.knob_edge(scene));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.dial));
    }

    fn evaluate(&mut self, scene: &Scene, _obs: &[f64; OBS_DIM], a: &[f32; ACTION_DIM]) -> Eval {
        let obj = self.knob_edge(scene);
        let push_position = self.push_position(scene);
        let tcp = scene.tcp_center();
        let target = scene.target_pos;

        let target_to_obj = dist(obj, target);
        let target_to_obj_init = dist(self.push_position_init, target);
        let in_place = radius_tolerance(
            target_to_obj,
            TARGET_RADIUS,
            target_to_obj_init,
            Sigmoid::LongTail,
        );

        let tcp_to_obj = dist(push_position, tcp);
        let tcp_to_obj_init = dist(self.push_position_init, scene.init_tcp);
        let reach = radius_tolerance(
            tcp_to_obj,
            DIAL_REACH_RADIUS,
            tcp_to_obj_init,
            Sigmoid::Gaussian,
        );
        Eval {
            reward: gripped_reward(reach, in_place, a[3]),
            success: target_to_obj <= TARGET_RADIUS,
        }
    }
}
