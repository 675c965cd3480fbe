//! `SawyerBinPickingV3Policy`: above the cube, down, grip, up, over the target bin, down.

use super::{act, add, grab_near, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

/// Centre of the target bin.
const BIN: V3 = [0.12, 0.7, 0.02];

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    let mut cube = add(object(obs), [0.0, 0.0, 0.03]);
    // Aim as if the cube were nearer the bin's middle in y: the closing fingers drag it
    // there, which keeps them from catching on the bin's edge.
    cube[1] = cube[1].clamp(0.675, 0.725);
    act(hand, desired_pos(hand, cube), 25.0, grab_effort(hand, cube))
}

fn desired_pos(hand: V3, cube: V3) -> V3 {
    if xy_dist(hand, cube) > 0.02 {
        add(cube, [0.0, 0.0, 0.15])
    } else if (hand[2] - cube[2]).abs() > 0.01 {
        cube
    } else if xy_dist(hand, BIN) > 0.02 {
        if hand[2] < 0.15 {
            add(hand, [0.0, 0.0, 0.1])
        } else {
            [BIN[0], BIN[1], 0.18]
        }
    } else {
        BIN
    }
}

fn grab_effort(hand: V3, cube: V3) -> f64 {
    grab_near(hand, cube, 0.02, 0.02, -1.0, 0.6)
}
