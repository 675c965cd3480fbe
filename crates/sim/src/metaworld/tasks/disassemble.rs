//! disassemble-v3: lift a ring nut by its handle off a peg.

use super::assembly::{nut_eval, nut_grab};
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

#[derive(Debug)]
struct Disassemble {
    nut: usize,
    nut_handle: usize,
    nut_center: usize,
    peg: usize,
    peg_top: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(Disassemble {
        nut: scene.sim.body("RoundNut")?,
        nut_handle: scene.sim.site("RoundNut-8")?,
        nut_center: scene.sim.site("RoundNut")?,
        peg: scene.sim.body("peg")?,
        peg_top: scene.sim.site("pegTop")?,
    }))
}

/// `_reward_pos`: a little for lifting the nut, most for its centre 10 cm above the goal.
fn in_place_reward(nut_center: [f64; 3], target: [f64; 3]) -> f64 {
    let aim = [target[0], target[1], target[2] + 0.1];
    let lifted = if nut_center[2] > 0.02 { 1.0 } else { 0.0 };
    0.1 * lifted + 0.9 * tolerance(dist(aim, nut_center), (0.0, 0.02), 0.2, Sigmoid::LongTail)
}

impl Task for Disassemble {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        let nut = [rv[0], rv[1], rv[2]];
        scene.obj_init_pos = nut;
        scene.target_pos = [nut[0], nut[1], nut[2] + GOAL_ABOVE_NUT];
        scene
            .sim
            .set_body_pos(self.peg, [nut[0], nut[1], nut[2] + PEG_OFFSET]);
        scene
            .sim
            .set_site_pos(self.peg_top, [nut[0], nut[1], nut[2] + PEG_TOP_OFFSET]);
        scene.forward();
        scene.set_obj_xyz(nut);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.nut_handle));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.nut));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let grab = nut_grab(scene, obs, action, Density::High);
        let in_place = in_place_reward(scene.sim.site_xpos(self.nut_center), scene.target_pos);
        let success = obs[6] > scene.target_pos[2];
        nut_eval(obs, grab, in_place, success)
    }
}
