//! Real shared memory: the conformance suite over iceoryx2, plus crash recovery.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use common::*;
use terl_transport::{ShmTransport, TransitionBatch, TransportConfig};

fn shm(cfg: &TransportConfig, role: &str) -> ShmTransport {
    ShmTransport::open(cfg.clone(), role).unwrap()
}

#[test]
fn one_to_one() {
    one_to_one_in_order(&shm, &unique_run("one"));
}

#[test]
fn many_publishers() {
    many_publishers_block_zero_loss(&shm, &unique_run("many"));
}

#[test]
fn drop_newest() {
    drop_newest_counts_drops(&shm, &unique_run("drop"));
}

#[test]
fn block_timeout() {
    block_times_out_on_stalled_receiver(&shm, &unique_run("block"));
}

#[test]
fn block_timeouts_are_counted() {
    block_timeouts_are_counted_and_reported(&shm, &unique_run("lost"));
}

#[test]
fn episode_timeouts_are_counted() {
    episode_timeouts_are_counted_per_receiver(&shm, &unique_run("lost-eps"));
}

#[test]
fn a_second_actor_with_the_same_id_is_refused() {
    let cfg = TransportConfig::new(unique_run("claim"), 4);
    let first = shm(&cfg, "actor-3");
    let claim = first.claim_actor_id(3).unwrap();
    let second = shm(&cfg, "actor-3");
    let err = second.claim_actor_id(3).unwrap_err();
    assert!(
        matches!(err, terl_transport::TransportError::IdInUse { .. }),
        "{err}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains("actor id 3 is already streaming to run") && msg.contains(&cfg.run_id),
        "{msg}"
    );
    // Other ids are free; a released id can be claimed again.
    let _other = second.claim_actor_id(1).unwrap();
    drop(claim);
    let _again = second.claim_actor_id(3).unwrap();
    assert!(first.claim_actor_id(3).is_err());
}

#[test]
fn cancel() {
    cancel_unblocks_blocked_send(&shm, &unique_run("cancel"));
}

#[test]
fn back_pressure() {
    block_applies_back_pressure(&shm, &unique_run("bp"));
}

#[test]
fn a_receiver_gone_is_a_counted_loss() {
    common::a_receiver_gone_is_a_counted_loss(&shm, &unique_run("gone"));
}

#[test]
fn no_receiver() {
    no_receiver_is_reported(&shm, &unique_run("none"));
}

#[test]
fn run_ids() {
    run_ids_do_not_mix(&shm, &unique_run("a"), &unique_run("b"));
}

#[test]
fn episodes_and_selected() {
    episodes_broadcast_and_selected_flow(&shm, &unique_run("eps"));
}

#[test]
fn limits() {
    limits_are_enforced(&shm, &unique_run("lim"));
}

const CHILD_RUN_ENV: &str = "TERL_TRANSPORT_TEST_CHILD_RUN";

/// Not a test on its own: when started by `stale_resources_of_killed_process_are_cleaned`
/// it plays a learner that takes the only transition-subscriber slot (and an actor that holds
/// actor id 0), then waits to be killed.
#[test]
fn stale_child_entry() {
    let Ok(run) = std::env::var(CHILD_RUN_ENV) else {
        return;
    };
    let t = shm(&TransportConfig::new(run, 1), "doomed-learner");
    let _source = t.shm_source::<TransitionBatch>().unwrap();
    let _sink = t.shm_sink::<TransitionBatch>().unwrap();
    let _claim = t.claim_actor_id(0).unwrap();
    println!("READY");
    std::thread::sleep(Duration::from_secs(120));
}

#[test]
fn stale_resources_of_killed_process_are_cleaned() {
    let run = unique_run("stale");
    let cfg = TransportConfig::new(&run, 1);
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([
            "stale_child_entry",
            "--exact",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_RUN_ENV, &run)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let ready = BufReader::new(stdout)
        .lines()
        .map_while(Result::ok)
        .any(|line| line.contains("READY"));
    assert!(ready, "child did not come up");

    // While the child lives, its subscriber holds the only slot, and it holds actor id 0.
    let probe = shm(&cfg, "probe");
    assert!(probe.shm_source::<TransitionBatch>().is_err());
    assert!(probe.claim_actor_id(0).is_err());
    drop(probe);

    // kill -9: no destructor runs, the child's shared memory stays behind.
    child.kill().unwrap();
    child.wait().unwrap();

    // The next start cleans the dead node's resources and can take the slot.
    let restarted = shm(&cfg, "learner");
    let mut source = restarted
        .shm_source::<TransitionBatch>()
        .expect("stale subscriber of the killed process was not cleaned up");
    eprintln!("cleanup at start: {:?}", restarted.stale_cleanup());
    let _claim = restarted
        .claim_actor_id(0)
        .expect("the killed process's actor id was not released");
    let mut sink = restarted.shm_sink::<TransitionBatch>().unwrap();
    assert_eq!(
        sink_send(&mut sink, 3),
        terl_transport::SendOutcome::Delivered
    );
    let got = terl_transport::MessageSource::try_receive(&mut source)
        .unwrap()
        .unwrap();
    assert_eq!(got.sequence, 3);
}

fn sink_send(
    sink: &mut terl_transport::ShmSink<TransitionBatch>,
    seq: u64,
) -> terl_transport::SendOutcome {
    terl_transport::MessageSink::send(sink, &batch(0, seq)).unwrap()
}
