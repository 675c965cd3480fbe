//! One compiled model per scene is shared by every environment of a process, and sharing
//! changes nothing: an env over the shared model (its own copies of the arrays tasks write at
//! reset, the right-sized arena, render-only pages released) steps bit for bit like an env over
//! a model compiled for it alone.

use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use terl_sim::metaworld::{goal_variations, Env, DEFAULT_ARENA_BYTES};

#[test]
fn envs_of_one_task_share_one_model() {
    let a = Env::new("door-open-v3").unwrap();
    let b = Env::new("door-open-v3").unwrap();
    assert!(Arc::ptr_eq(a.model(), b.model()));
    // The process cache holds one more reference besides the two envs.
    assert!(Arc::strong_count(a.model()) >= 3);
    let other = Env::new("reach-v3").unwrap();
    assert!(!Arc::ptr_eq(a.model(), other.model()));
    assert!(a.model().released_bytes() > 0, "render-only pages released");
    assert_eq!(a.arena_use().1, DEFAULT_ARENA_BYTES);
    let own = Env::new_unshared("door-open-v3").unwrap();
    assert!(!Arc::ptr_eq(a.model(), own.model()));
    assert_eq!(Arc::strong_count(own.model()), 1);
}

/// Steps two envs side by side over several resets (tasks that move bodies and sites of the
/// model at reset: door, basketball, shelf, assembly, button, plus plain reach) and compares
/// every observation, reward and flag as bits. A third env of the task shares the model and is
/// reset to other goals in between, so a write leaking into the shared model would show.
#[test]
fn shared_model_steps_like_an_own_model() {
    let tasks = [
        "door-open-v3",
        "basketball-v3",
        "shelf-place-v3",
        "assembly-v3",
        "button-press-wall-v3",
        "reach-v3",
    ];
    for task in tasks {
        let mut shared = Env::new(task).unwrap();
        let mut noise = Env::new(task).unwrap();
        let mut own = Env::new_unshared(task).unwrap();
        // The reference runs every hand-reset step itself instead of replaying the cache.
        own.set_hand_reset_cache(false);
        let variations = goal_variations(task, 0).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for ep in 0..3 {
            let rv = &variations[ep * 7];
            noise.reset(&variations[ep * 7 + 3]).unwrap();
            let o1 = shared.reset(rv).unwrap();
            noise.reset(&variations[ep * 7 + 5]).unwrap();
            let o2 = own.reset(rv).unwrap();
            assert_eq!(
                o1.map(f64::to_bits),
                o2.map(f64::to_bits),
                "{task} reset {ep}"
            );
            for step in 0..150 {
                let a: [f32; 4] = std::array::from_fn(|_| rng.gen_range(-1.0f32..1.0));
                let s1 = shared.step(&a).unwrap();
                let s2 = own.step(&a).unwrap();
                assert_eq!(
                    s1.obs.map(f64::to_bits),
                    s2.obs.map(f64::to_bits),
                    "{task} episode {ep} step {step}"
                );
                assert_eq!(s1.reward.to_bits(), s2.reward.to_bits(), "{task} {step}");
                assert_eq!(
                    (s1.success, s1.truncated),
                    (s2.success, s2.truncated),
                    "{task} {step}"
                );
            }
        }
    }
}
