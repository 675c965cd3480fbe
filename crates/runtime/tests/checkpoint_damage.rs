//! `load_policy_checkpoint` on a damaged learner checkpoint (random cuts, flipped bytes, huge
//! header lengths, overwritten words): never a panic or an oversized allocation; a clear
//! checkpoint error, or, where the damage left the content intact, the checkpoint's own policy.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;

use proptest::prelude::*;
use terl_nn::TensorFile;
use terl_rl::{Sac, SacConfig};
use terl_runtime::eval::{load_policy_checkpoint, EvalError};

/// A real checkpoint as the learner saves it (small networks), as bytes.
fn checkpoint() -> &'static [u8] {
    static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
    BYTES.get_or_init(|| {
        let config = SacConfig {
            num_tasks: 2,
            policy_hidden: vec![16, 16],
            critic_hidden: vec![16, 16],
            batch_size: 8,
            ..SacConfig::default()
        };
        let sac = Sac::<f32>::new(config).unwrap();
        let dir = fresh_dir();
        let path = dir.join("source.safetensors");
        sac.save_checkpoint(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        bytes
    })
}

fn fresh_dir() -> PathBuf {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let dir = std::env::temp_dir().join(format!(
        "terl-ckpt-damage-{}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn load(bytes: &[u8]) -> Result<(), TestCaseError> {
    let dir = fresh_dir();
    let path = dir.join("policy.safetensors");
    std::fs::write(&path, bytes).unwrap();
    let got = load_policy_checkpoint(&path);
    std::fs::remove_dir_all(&dir).unwrap();
    match got {
        Ok(_) => {
            // Accepted only if what was read is what the learner wrote.
            let want = TensorFile::from_bytes(checkpoint()).unwrap();
            let read = TensorFile::from_bytes(bytes).unwrap();
            prop_assert!(read.tensors == want.tensors, "damaged tensors accepted");
        }
        Err(e) => {
            prop_assert!(
                matches!(e, EvalError::Checkpoint { .. } | EvalError::Policy(_)),
                "{e}"
            );
            prop_assert!(
                e.to_string().contains("policy.safetensors") || matches!(e, EvalError::Policy(_)),
                "{e}"
            );
        }
    }
    Ok(())
}

/// A fixed seed: the same cases on every run, so a failure is reproducible and CI is stable.
fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x7e71_0005),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

#[derive(Debug, Clone)]
enum Damage {
    Cut(usize),
    Flip(usize, u8),
    HeaderLength(u64),
    Word(usize, u64),
}

fn damage() -> impl Strategy<Value = Damage> {
    let huge = prop_oneof![
        proptest::sample::select(vec![u64::MAX, 4 << 60, 1 << 40, u32::MAX as u64 + 1]),
        any::<u64>(),
    ];
    prop_oneof![
        any::<usize>().prop_map(Damage::Cut),
        (any::<usize>(), 1u8..=255).prop_map(|(at, m)| Damage::Flip(at, m)),
        huge.clone().prop_map(Damage::HeaderLength),
        (any::<usize>(), huge).prop_map(|(at, v)| Damage::Word(at, v)),
    ]
}

proptest! {
    #![proptest_config(config(200))]

    #[test]
    fn a_damaged_checkpoint_is_a_clear_error(damage in damage()) {
        let mut bytes = checkpoint().to_vec();
        let n = bytes.len();
        match damage {
            Damage::Cut(at) => bytes.truncate(at % n),
            Damage::Flip(at, mask) => bytes[at % n] ^= mask,
            Damage::HeaderLength(len) => bytes[..8].copy_from_slice(&len.to_le_bytes()),
            Damage::Word(at, v) => {
                let at = at % (n - 8);
                bytes[at..at + 8].copy_from_slice(&v.to_le_bytes());
            }
        }
        load(&bytes)?;
    }
}

#[test]
fn the_intact_checkpoint_loads() {
    let dir = fresh_dir();
    let path = dir.join("policy.safetensors");
    std::fs::write(&path, checkpoint()).unwrap();
    let ckpt = load_policy_checkpoint(&path).unwrap();
    assert_eq!(ckpt.sac.policy_hidden, vec![16, 16]);
    std::fs::remove_dir_all(&dir).unwrap();
}
