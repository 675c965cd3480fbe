//! What the learner's process-free tests share: a stand-in actor feeding the in-memory
//! transport.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use terl_transport::{MemoryTransport, Transition, TransitionBatch, Transport, OBS_DIM};

/// A stand-in actor 0: full batches of finite transitions of both tasks until `stop`.
pub fn feed(transport: MemoryTransport, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<u64> {
    std::thread::spawn(move || {
        let mut sink = transport.sink::<TransitionBatch>().unwrap();
        let mut sent = 0u64;
        let mut k = 0u32;
        while !stop.load(Ordering::Relaxed) {
            let mut b = TransitionBatch::EMPTY;
            b.sequence = sent;
            while !b.is_full() {
                k += 1;
                let x = (k as f32 * 0.013).sin();
                let _ = b.push(Transition {
                    policy_version: 0,
                    obs: [x; OBS_DIM],
                    next_obs: [x * 0.9; OBS_DIM],
                    action: [x, -x, 0.5 * x, 0.0],
                    reward: x,
                    actor_id: 0,
                    env_index: (k % 2) as u16,
                    task: (k % 2) as u16,
                    flags: 0,
                    reserved: 0,
                    guidance_probability_q: 0,
                    action_gap_q: 0,
                });
            }
            if sink.send(&b).is_ok() {
                sent += 1;
            } else {
                std::thread::sleep(Duration::from_millis(5));
            }
            // About the pace of a small actor, so the learner's limiter paces the updates.
            std::thread::sleep(Duration::from_millis(2));
        }
        sent
    })
}
