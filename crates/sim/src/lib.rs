//! MuJoCo 3.3.7 through a thin, safe wrapper, and the Meta-World v3 task suite built on it.
//!
//! `mujoco` and `render` (its offscreen renderer) are the only modules with `unsafe`; everything
//! above them (tasks, vectorised envs, trace replay) is safe Rust.

#![warn(missing_docs)]

mod error;
mod ffi;
pub mod mujoco;

pub use error::{Result, SimError};
pub use mujoco::{Model, Simulation};
pub mod metaworld;
pub mod render;
pub mod trace;
pub mod vec_env;

pub use metaworld::{Env, Step, ACTION_DIM, OBS_DIM};
pub use vec_env::{EpisodeEnd, VecEnv};
