//! The in-memory twin passes the same conformance suite as shared memory.

mod common;

use common::*;
use terl_transport::memory::MemoryBus;
use terl_transport::{MemoryTransport, TransportConfig};

fn on(bus: &MemoryBus) -> impl Fn(&TransportConfig, &str) -> MemoryTransport + Sync + '_ {
    move |cfg, _role| MemoryTransport::on_bus(bus.clone(), cfg.clone()).unwrap()
}

#[test]
fn one_to_one() {
    one_to_one_in_order(&on(&MemoryBus::default()), "one");
}

#[test]
fn many_publishers() {
    many_publishers_block_zero_loss(&on(&MemoryBus::default()), "many");
}

#[test]
fn drop_newest() {
    drop_newest_counts_drops(&on(&MemoryBus::default()), "drop");
}

#[test]
fn block_timeout() {
    block_times_out_on_stalled_receiver(&on(&MemoryBus::default()), "block");
}

#[test]
fn block_timeouts_are_counted() {
    block_timeouts_are_counted_and_reported(&on(&MemoryBus::default()), "lost");
}

#[test]
fn episode_timeouts_are_counted() {
    episode_timeouts_are_counted_per_receiver(&on(&MemoryBus::default()), "lost-eps");
}

#[test]
fn cancel() {
    cancel_unblocks_blocked_send(&on(&MemoryBus::default()), "cancel");
}

#[test]
fn back_pressure() {
    block_applies_back_pressure(&on(&MemoryBus::default()), "bp");
}

#[test]
fn a_receiver_gone_is_a_counted_loss() {
    common::a_receiver_gone_is_a_counted_loss(&on(&MemoryBus::default()), "gone");
}

#[test]
fn no_receiver() {
    no_receiver_is_reported(&on(&MemoryBus::default()), "none");
}

#[test]
fn run_ids() {
    run_ids_do_not_mix(&on(&MemoryBus::default()), "a", "b");
}

#[test]
fn episodes_and_selected() {
    episodes_broadcast_and_selected_flow(&on(&MemoryBus::default()), "eps");
}

#[test]
fn limits() {
    limits_are_enforced(&on(&MemoryBus::default()), "lim");
}
