//! `SawyerPegInsertionSideV3Policy`: grasp the peg, line it up with the hole, push it in.

use super::{add, grab_near, object_to_goal, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    object_to_goal(obs, 25.0, desired_pos, grab_effort)
}

fn desired_pos(hand: V3, peg: V3, goal: V3) -> V3 {
    // The hole's x is at most -0.35 (overshooting is harmless), its z constant at 0.16.
    let hole = [-0.35, goal[1], 0.16];
    let (dy, dz) = (peg[1] - hole[1], peg[2] - hole[2]);
    if xy_dist(hand, peg) > 0.04 {
        add(peg, [0.0, 0.0, 0.3])
    } else if (hand[2] - peg[2]).abs() > 0.025 {
        peg
    } else if (dy * dy + dz * dz).sqrt() > 0.03 {
        add(hole, [0.4, 0.0, 0.0])
    } else {
        hole
    }
}

fn grab_effort(hand: V3, peg: V3) -> f64 {
    grab_near(hand, peg, 0.04, 0.15, -1.0, 0.6)
}
