//! disassemble-v3 (`metaworld/envs/sawyer_disassemble_peg_v3.py`): lift a ring nut by its
//! handle off a peg.
//!
//! assembly-v3's task ([`super::assembly`]) with its own reset and reward.

use super::assembly::{self, nut_eval, nut_grab, NutParts, Variant};
use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "disassemble-v3",
    xml: "sawyer_xyz/sawyer_assembly_peg.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [0.0, 0.4f32 as f64, 0.2f32 as f64],
    // The goal part of `rand_vec` only enters the rejection rule; the goal is above the nut.
    rand_low: &[0.0, 0.6, 0.025, -0.1, 0.6, 0.1699],
    rand_high: &[0.1, 0.75, 0.02501, 0.1, 0.75, 0.1701],
    goal_low: [-0.1, 0.6, 0.1699 + 0.005],
    goal_high: [0.1, 0.75, 0.1701 + 0.005],
    rand_vec_ok: obj_goal_apart::<10>,
};

/// The goal is this far above the nut's start.
const GOAL_ABOVE_NUT: f64 = 0.15;
/// The peg's base and top relative to the nut's start.
const PEG_OFFSET: f64 = 0.03;
const PEG_TOP_OFFSET: f64 = 0.08;

const VARIANT: Variant = Variant { reset, evaluate };

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    assembly::build_with(scene, &SPEC, &VARIANT)
}

/// `_reward_pos`: a little for lifting the nut, most for its centre 10 cm above the goal.
fn in_place_reward(nut_center: [f64; 3], target: [f64; 3]) -> f64 {
    let aim = [target[0], target[1], target[2] + 0.1];
    let lifted = if nut_center[2] > 0.02 { 1.0 } else { 0.0 };
    0.1 * lifted + 0.9 * tolerance(dist(aim, nut_center), (0.0, 0.02), 0.2, Sigmoid::LongTail)
}

fn reset(parts: &NutParts, scene: &mut Scene, rv: &[f64]) -> Result<()> {
    let nut = [rv[0], rv[1], rv[2]];
    scene.obj_init_pos = nut;
    scene.target_pos = [nut[0], nut[1], nut[2] + GOAL_ABOVE_NUT];
    scene
        .sim
        .set_body_pos(parts.peg, [nut[0], nut[1], nut[2] + PEG_OFFSET]);
    scene
        .sim
        .set_site_pos(parts.peg_top, [nut[0], nut[1], nut[2] + PEG_TOP_OFFSET]);
    scene.forward();
    scene.set_obj_xyz(nut);
    Ok(())
}

fn evaluate(
    parts: &NutParts,
    scene: &Scene,
    obs: &[f64; OBS_DIM],
    action: &[f32; ACTION_DIM],
) -> Eval {
    let grab = nut_grab(scene, obs, action, Density::High);
    let in_place = in_place_reward(scene.sim.site_xpos(parts.nut_center), scene.target_pos);
    let success = obs[6] > scene.target_pos[2];
    nut_eval(obs, grab, in_place, success)
}
