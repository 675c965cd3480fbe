//! Helpers shared by the SAC and CARE checks.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use terl_rl::{Batch, SacConfig};

/// `rows` random transitions of `cfg`'s shapes: observations and next observations uniform in
/// `[-1, 1)`, actions in `[-0.9, 0.9)` (inside tanh's range), rewards in `[-1, 1)`, every
/// `terminal_every`-th row terminal, tasks `i mod num_tasks`.
pub fn random_batch(rows: usize, cfg: &SacConfig, seed: u64, terminal_every: usize) -> Batch {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut b = Batch::with_capacity(rows, cfg.obs_dim, cfg.act_dim);
    for i in 0..rows {
        let obs: Vec<f32> = (0..cfg.obs_dim).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let next: Vec<f32> = (0..cfg.obs_dim).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let act: Vec<f32> = (0..cfg.act_dim).map(|_| rng.gen_range(-0.9..0.9)).collect();
        b.push(
            &obs,
            &act,
            rng.gen_range(-1.0..1.0),
            &next,
            i % terminal_every == 0,
            (i % cfg.num_tasks) as u32,
        );
    }
    b
}
