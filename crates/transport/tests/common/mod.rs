//! The conformance suite every transport implementation must pass, generic over
//! [`Transport`]. `make(config, role)` opens a transport as one process would.

#![allow(dead_code)]

use std::time::{Duration, Instant};

use terl_transport::*;

pub type Make<'a, T> = &'a (dyn Fn(&TransportConfig, &str) -> T + Sync);

pub fn unique_run(name: &str) -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos();
    format!("t{}-{nanos}-{name}", std::process::id())
}

/// A batch whose contents are a function of `(actor, sequence)`, with varying length.
pub fn batch(actor: u16, sequence: u64) -> Box<TransitionBatch> {
    let mut b = Box::new(TransitionBatch::EMPTY);
    b.actor_id = actor;
    b.sequence = sequence;
    let len = (sequence % TRANSITIONS_PER_BATCH as u64) + 1;
    for i in 0..len {
        let mut t = Transition::ZERO;
        let base = actor as f32 * 1e6 + sequence as f32 * 100.0 + i as f32;
        for (k, v) in t.obs.iter_mut().enumerate() {
            *v = base + k as f32 * 0.5;
        }
        t.next_obs = t.obs.map(|v| v + 0.25);
        t.action = [0.1, -0.2, 0.3, base];
        t.reward = base;
        t.policy_version = sequence / 7;
        t.actor_id = actor;
        t.env_index = (i % 5) as u16;
        t.task = (sequence % 10) as u16;
        t.flags = if i == len - 1 {
            flags::TRUNCATED | flags::SUCCESS
        } else {
            0
        };
        assert!(b.push(t));
    }
    b
}

/// The next message of `source`, waiting up to 10 s for it (network transports deliver
/// asynchronously; shared memory and the in-memory twin have it at once).
pub fn receive_next<M: Message>(source: &mut dyn MessageSource<M>) -> Option<Box<M>> {
    let start = Instant::now();
    loop {
        if let Some(m) = source.try_receive().unwrap() {
            return Some(m);
        }
        if start.elapsed() >= Duration::from_secs(10) {
            return None;
        }
        std::thread::yield_now();
    }
}

/// Waits up to 10 s for `cond` (peer counts of network transports settle asynchronously).
pub fn eventually(what: &str, mut cond: impl FnMut() -> bool) {
    let start = Instant::now();
    while !cond() {
        assert!(start.elapsed() < Duration::from_secs(10), "never: {what}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn receive_until<M: Message>(
    source: &mut dyn MessageSource<M>,
    want: usize,
    timeout: Duration,
    mut each: impl FnMut(&M),
) -> usize {
    let start = Instant::now();
    let mut out = M::empty();
    let mut got = 0;
    while got < want && start.elapsed() < timeout {
        if source.try_receive_into(&mut out).unwrap() {
            each(&out);
            got += 1;
        } else {
            std::thread::yield_now();
        }
    }
    got
}

/// One publisher → one subscriber: every batch arrives intact and in order.
pub fn one_to_one_in_order<T: Transport>(make: Make<T>, run: &str) {
    const N: u64 = 2000;
    let cfg = TransportConfig::new(run, 1);
    let learner = make(&cfg, "learner");
    let mut source = learner.source::<TransitionBatch>().unwrap();
    std::thread::scope(|s| {
        s.spawn(|| {
            let actor = make(&cfg, "actor-0");
            let mut sink = actor.sink::<TransitionBatch>().unwrap();
            sink.wait_for_receivers(1, Duration::from_secs(5)).unwrap();
            for seq in 0..N {
                assert_eq!(sink.send(&batch(0, seq)).unwrap(), SendOutcome::Delivered);
            }
            let stats = sink.stats();
            assert_eq!((stats.sent, stats.dropped, stats.no_receiver), (N, 0, 0));
        });
        let mut expected = 0;
        let got = receive_until(source.as_mut(), N as usize, Duration::from_secs(30), |b| {
            assert_eq!(
                b,
                &*batch(0, expected),
                "batch {expected} corrupted or out of order"
            );
            expected += 1;
        });
        assert_eq!(got as u64, N);
    });
    assert_eq!(source.stats().received, N);
}

/// N publishers, each its own node, into one subscriber under `Block`: zero loss and
/// per-publisher order.
pub fn many_publishers_block_zero_loss<T: Transport>(make: Make<T>, run: &str) {
    const ACTORS: u16 = 3;
    const PER_ACTOR: u64 = 1500;
    let cfg = TransportConfig {
        buffer_batches: 8,
        ..TransportConfig::new(run, ACTORS as usize)
    };
    let learner = make(&cfg, "learner");
    let mut source = learner.source::<TransitionBatch>().unwrap();
    let mut next = vec![0u64; ACTORS as usize];
    std::thread::scope(|s| {
        for actor in 0..ACTORS {
            let cfg = &cfg;
            s.spawn(move || {
                let t = make(cfg, &format!("actor-{actor}"));
                let mut sink = t.sink::<TransitionBatch>().unwrap();
                sink.wait_for_receivers(1, Duration::from_secs(5)).unwrap();
                for seq in 0..PER_ACTOR {
                    assert_eq!(
                        sink.send(&batch(actor, seq)).unwrap(),
                        SendOutcome::Delivered
                    );
                }
                assert_eq!(sink.stats().dropped, 0);
            });
        }
        let total = (ACTORS as u64 * PER_ACTOR) as usize;
        let got = receive_until(source.as_mut(), total, Duration::from_secs(60), |b| {
            let a = b.actor_id as usize;
            assert_eq!(b.sequence, next[a], "actor {a} out of order");
            assert_eq!(b, &*batch(b.actor_id, b.sequence));
            next[a] += 1;
        });
        assert_eq!(got, total);
    });
    assert!(next.iter().all(|&n| n == PER_ACTOR));
}

/// `DropNewest` on a stalled receiver: the buffer keeps the oldest messages, each further
/// send returns `Full` and is counted.
pub fn drop_newest_counts_drops<T: Transport>(make: Make<T>, run: &str) {
    let cfg = TransportConfig {
        buffer_batches: 4,
        overflow: OverflowPolicy::DropNewest,
        ..TransportConfig::new(run, 1)
    };
    let learner = make(&cfg, "learner");
    let mut source = learner.source::<TransitionBatch>().unwrap();
    let actor = make(&cfg, "actor-0");
    let mut sink = actor.sink::<TransitionBatch>().unwrap();
    let outcomes: Vec<_> = (0..10)
        .map(|seq| sink.send(&batch(0, seq)).unwrap())
        .collect();
    assert_eq!(outcomes[..4], [SendOutcome::Delivered; 4]);
    assert_eq!(outcomes[4..], [SendOutcome::Full; 6]);
    let stats = sink.stats();
    assert_eq!((stats.sent, stats.dropped, stats.full_events), (4, 6, 6));
    let mut seqs = vec![];
    receive_until(source.as_mut(), 10, Duration::from_millis(300), |b| {
        seqs.push(b.sequence)
    });
    assert_eq!(seqs, [0, 1, 2, 3]);
    // Room again: delivered.
    assert_eq!(sink.send(&batch(0, 10)).unwrap(), SendOutcome::Delivered);
}

/// `Block` on a stalled receiver gives up after the block timeout with an error — the
/// sender learns about it, nothing is lost silently.
pub fn block_times_out_on_stalled_receiver<T: Transport>(make: Make<T>, run: &str) {
    let cfg = TransportConfig {
        buffer_batches: 2,
        block_timeout: Duration::from_millis(200),
        ..TransportConfig::new(run, 1)
    };
    let learner = make(&cfg, "learner");
    let _source = learner.source::<TransitionBatch>().unwrap();
    let actor = make(&cfg, "actor-0");
    let mut sink = actor.sink::<TransitionBatch>().unwrap();
    for seq in 0..2 {
        assert_eq!(sink.send(&batch(0, seq)).unwrap(), SendOutcome::Delivered);
    }
    let start = Instant::now();
    let err = sink.send(&batch(0, 2)).unwrap_err();
    assert!(matches!(err, TransportError::BlockTimeout { .. }), "{err}");
    assert!(start.elapsed() >= Duration::from_millis(190));
    assert_eq!(sink.stats().full_events, 1);
}

/// A `Block` send that times out on a receiver that never drains (a stopped learner) drops
/// the batch, counts it and its transitions, and stamps the counts on the next batch that
/// gets through, so the receiver's [`LossTracker`] ends with the same numbers.
pub fn block_timeouts_are_counted_and_reported<T: Transport>(make: Make<T>, run: &str) {
    let cfg = TransportConfig {
        buffer_batches: 2,
        block_timeout: Duration::from_millis(50),
        ..TransportConfig::new(run, 1)
    };
    let learner = make(&cfg, "learner");
    let mut source = learner.source::<TransitionBatch>().unwrap();
    let actor = make(&cfg, "actor-0");
    let mut sink = actor.sink::<TransitionBatch>().unwrap();
    let mut tracker = LossTracker::new();
    let mut receive = |source: &mut Box<dyn MessageSource<TransitionBatch>>| {
        let b = receive_next(source.as_mut()).expect("a batch is queued");
        tracker.observe(b.actor_id, b.sequence, b.losses());
        b
    };

    let (mut seq, mut lost_batches, mut lost_transitions) = (0u64, 0u64, 0u64);
    for round in 0..3u64 {
        // Fill the receiver's buffer.
        for _ in 0..2 {
            assert_eq!(sink.send(&batch(0, seq)).unwrap(), SendOutcome::Delivered);
            seq += 1;
        }
        // The receiver does not drain: every further send times out and is dropped.
        for _ in 0..round + 1 {
            let b = batch(0, seq);
            let err = sink.send(&b).unwrap_err();
            assert!(matches!(err, TransportError::BlockTimeout { .. }), "{err}");
            lost_batches += 1;
            lost_transitions += b.len as u64;
            seq += 1;
            let s = sink.stats();
            assert_eq!(
                (s.dropped, s.dropped_items),
                (lost_batches, lost_transitions)
            );
        }
        // The receiver comes back and drains what it got.
        for _ in 0..2 {
            receive(&mut source);
        }
    }
    // The next batch that gets through carries the sender's whole count.
    assert_eq!(sink.send(&batch(0, seq)).unwrap(), SendOutcome::Delivered);
    let last = receive(&mut source);
    assert_eq!(last.sequence, seq);
    let want = Losses {
        messages: lost_batches,
        items: lost_transitions,
    };
    assert_eq!(last.losses(), want);
    assert_eq!(lost_batches, 6);
    let seen = tracker.sender(0);
    assert_eq!(seen.reported, want);
    // The only receiver missed exactly the dropped batches.
    assert_eq!(seen.missed, lost_batches);
    assert_eq!(sink.stats().sent, 7);
}

/// Episodes have two receivers: one that stops draining (a stalled selector) loses the
/// episodes that time out, the other still gets them. The actor's stamp counts episodes not
/// delivered to every receiver; each receiver's gap count is what it missed itself.
pub fn episode_timeouts_are_counted_per_receiver<T: Transport>(make: Make<T>, run: &str) {
    let cfg = TransportConfig {
        buffer_episodes: 1,
        block_timeout: Duration::from_millis(50),
        ..TransportConfig::new(run, 1)
    };
    let actor = make(&cfg, "actor-0");
    let mut sink = actor.sink::<EpisodeSummary>().unwrap();
    let selector = make(&cfg, "selector");
    let mut stalled = selector.source::<EpisodeSummary>().unwrap();
    let learner = make(&cfg, "learner");
    let mut draining = learner.source::<EpisodeSummary>().unwrap();
    sink.wait_for_receivers(2, Duration::from_secs(5)).unwrap();
    let (mut at_selector, mut at_learner) = (LossTracker::new(), LossTracker::new());
    let episode = |index: u64| {
        let mut e = EpisodeSummary::empty();
        e.episode_index = index;
        e.actor_id = 2;
        e
    };
    let observe = |tracker: &mut LossTracker, source: &mut Box<dyn MessageSource<_>>| {
        let e: Box<EpisodeSummary> = receive_next(source.as_mut()).expect("an episode");
        tracker.observe(e.actor_id, e.episode_index, e.losses());
        e
    };
    assert_eq!(sink.send(&episode(0)).unwrap(), SendOutcome::Delivered);
    observe(&mut at_learner, &mut draining);
    for index in 1..=3 {
        let err = sink.send(&episode(index)).unwrap_err();
        assert!(matches!(err, TransportError::BlockTimeout { .. }), "{err}");
        // The draining receiver got it all the same.
        assert_eq!(observe(&mut at_learner, &mut draining).episode_index, index);
    }
    assert_eq!((sink.stats().dropped, sink.stats().dropped_items), (3, 3));
    assert_eq!(observe(&mut at_selector, &mut stalled).episode_index, 0);
    assert_eq!(sink.send(&episode(4)).unwrap(), SendOutcome::Delivered);
    let e = observe(&mut at_selector, &mut stalled);
    assert_eq!(e.episode_index, 4);
    observe(&mut at_learner, &mut draining);
    let three = Losses {
        messages: 3,
        items: 3,
    };
    assert_eq!(e.losses(), three);
    let (s, l) = (at_selector.sender(2), at_learner.sender(2));
    assert_eq!((s.reported, s.missed), (three, 3));
    assert_eq!((l.reported, l.missed), (three, 0));
}

/// Shutdown unblocks a sender stuck on a full receiver.
pub fn cancel_unblocks_blocked_send<T: Transport + Sync>(make: Make<T>, run: &str) {
    let cfg = TransportConfig {
        buffer_batches: 1,
        ..TransportConfig::new(run, 1)
    };
    let learner = make(&cfg, "learner");
    let _source = learner.source::<TransitionBatch>().unwrap();
    let actor = make(&cfg, "actor-0");
    let mut sink = actor.sink::<TransitionBatch>().unwrap();
    assert_eq!(sink.send(&batch(0, 0)).unwrap(), SendOutcome::Delivered);
    let start = Instant::now();
    std::thread::scope(|s| {
        s.spawn(|| {
            std::thread::sleep(Duration::from_millis(100));
            actor.cancel_blocked_sends();
        });
        let err = sink.send(&batch(0, 1)).unwrap_err();
        assert!(matches!(err, TransportError::Cancelled(_)), "{err}");
    });
    assert!(start.elapsed() < Duration::from_secs(5));
}

/// `Block` with a slow receiver: the sender is slowed down, everything arrives.
pub fn block_applies_back_pressure<T: Transport>(make: Make<T>, run: &str) {
    const N: u64 = 60;
    let cfg = TransportConfig {
        buffer_batches: 2,
        ..TransportConfig::new(run, 1)
    };
    let learner = make(&cfg, "learner");
    let mut source = learner.source::<TransitionBatch>().unwrap();
    std::thread::scope(|s| {
        let sender = s.spawn(|| {
            let actor = make(&cfg, "actor-0");
            let mut sink = actor.sink::<TransitionBatch>().unwrap();
            sink.wait_for_receivers(1, Duration::from_secs(5)).unwrap();
            for seq in 0..N {
                assert_eq!(sink.send(&batch(0, seq)).unwrap(), SendOutcome::Delivered);
            }
            sink.stats()
        });
        let mut expected = 0;
        receive_until(source.as_mut(), N as usize, Duration::from_secs(30), |b| {
            assert_eq!(b.sequence, expected);
            expected += 1;
            std::thread::sleep(Duration::from_millis(2));
        });
        assert_eq!(expected, N);
        let stats = sender.join().unwrap();
        assert_eq!((stats.sent, stats.dropped), (N, 0));
        assert!(
            stats.full_events > 0,
            "a slow receiver should have been seen full"
        );
    });
}

/// A receiver that goes away: what the sender sends to nobody after it had a receiver is a
/// counted loss, stamped on the first message the next receiver gets.
pub fn a_receiver_gone_is_a_counted_loss<T: Transport>(make: Make<T>, run: &str) {
    let cfg = TransportConfig::new(run, 1);
    let actor = make(&cfg, "actor-0");
    let mut sink = actor.sink::<TransitionBatch>().unwrap();
    // Before the first receiver: nobody, but no loss (start-up).
    assert_eq!(sink.send(&batch(0, 0)).unwrap(), SendOutcome::NoReceiver);
    assert_eq!(sink.stats().dropped, 0);
    {
        let learner = make(&cfg, "learner");
        let mut source = learner.source::<TransitionBatch>().unwrap();
        sink.wait_for_receivers(1, Duration::from_secs(10)).unwrap();
        assert_eq!(sink.send(&batch(0, 1)).unwrap(), SendOutcome::Delivered);
        let got = receive_next(source.as_mut()).expect("the delivered batch");
        assert_eq!((got.sequence, got.losses()), (1, Losses::default()));
    }
    eventually("the receiver is gone", || sink.receivers() == 0);
    let lost = [batch(0, 2), batch(0, 3)];
    for b in &lost {
        assert_eq!(sink.send(b).unwrap(), SendOutcome::NoReceiver);
    }
    let items: u64 = lost.iter().map(|b| b.items()).sum();
    let stats = sink.stats();
    assert_eq!(
        (stats.dropped, stats.dropped_items, stats.no_receiver),
        (2, items, 3)
    );
    let learner = make(&cfg, "learner");
    let mut source = learner.source::<TransitionBatch>().unwrap();
    sink.wait_for_receivers(1, Duration::from_secs(10)).unwrap();
    assert_eq!(sink.send(&batch(0, 4)).unwrap(), SendOutcome::Delivered);
    let got = receive_next(source.as_mut()).expect("the batch after the loss");
    assert_eq!(got.sequence, 4);
    assert_eq!(got.losses(), Losses { messages: 2, items });
}

/// Without a subscriber a send reaches nobody and says so.
pub fn no_receiver_is_reported<T: Transport>(make: Make<T>, run: &str) {
    let cfg = TransportConfig::new(run, 1);
    let actor = make(&cfg, "actor-0");
    let mut sink = actor.sink::<TransitionBatch>().unwrap();
    assert_eq!(sink.receivers(), 0);
    assert_eq!(sink.send(&batch(0, 0)).unwrap(), SendOutcome::NoReceiver);
    assert_eq!(sink.stats().no_receiver, 1);
    let err = sink
        .wait_for_receivers(1, Duration::from_millis(20))
        .unwrap_err();
    assert!(matches!(err, TransportError::Timeout { .. }));
}

/// Two runs on one host never see each other's messages.
pub fn run_ids_do_not_mix<T: Transport>(make: Make<T>, run_a: &str, run_b: &str) {
    let cfg_a = TransportConfig::new(run_a, 1);
    let cfg_b = TransportConfig::new(run_b, 1);
    let (la, lb) = (make(&cfg_a, "learner"), make(&cfg_b, "learner"));
    let mut source_a = la.source::<TransitionBatch>().unwrap();
    let mut source_b = lb.source::<TransitionBatch>().unwrap();
    let (aa, ab) = (make(&cfg_a, "actor-0"), make(&cfg_b, "actor-0"));
    let mut sink_a = aa.sink::<TransitionBatch>().unwrap();
    let mut sink_b = ab.sink::<TransitionBatch>().unwrap();
    for seq in 0..5 {
        assert_eq!(sink_a.send(&batch(1, seq)).unwrap(), SendOutcome::Delivered);
    }
    assert_eq!(sink_b.send(&batch(2, 100)).unwrap(), SendOutcome::Delivered);
    let mut got_a = vec![];
    receive_until(source_a.as_mut(), 10, Duration::from_millis(200), |b| {
        got_a.push((b.actor_id, b.sequence))
    });
    let mut got_b = vec![];
    receive_until(source_b.as_mut(), 10, Duration::from_millis(200), |b| {
        got_b.push((b.actor_id, b.sequence))
    });
    assert_eq!(got_a, (0..5).map(|s| (1, s)).collect::<Vec<_>>());
    assert_eq!(got_b, [(2, 100)]);
}

/// Episodes go to both the selector and the learner, trajectory intact; selected batches
/// go selector → learner.
pub fn episodes_broadcast_and_selected_flow<T: Transport>(make: Make<T>, run: &str) {
    let cfg = TransportConfig::new(run, 1);
    let (learner, selector, actor) = (
        make(&cfg, "learner"),
        make(&cfg, "selector"),
        make(&cfg, "actor-0"),
    );
    let mut ep_learner = learner.source::<EpisodeSummary>().unwrap();
    let mut ep_selector = selector.source::<EpisodeSummary>().unwrap();
    let mut ep_sink = actor.sink::<EpisodeSummary>().unwrap();
    let mut episode = Box::new(EpisodeSummary::EMPTY);
    episode.actor_id = 0;
    episode.task = 7;
    episode.length = MAX_EPISODE_STEPS as u32;
    episode.success = 1;
    episode.policy_version = 42;
    for i in 0..MAX_EPISODE_STEPS {
        let mut step = TrajectoryStep::ZERO;
        step.obs[0] = i as f32;
        step.obs[OBS_DIM - 1] = -(i as f32);
        step.action = [i as f32; ACTION_DIM];
        step.reward = i as f32 * 0.01;
        episode.episode_return += step.reward;
        assert!(episode.push_step(step));
    }
    assert!(!episode.push_step(TrajectoryStep::ZERO));
    ep_sink
        .wait_for_receivers(2, Duration::from_secs(10))
        .unwrap();
    assert_eq!(ep_sink.receivers(), 2);
    assert_eq!(ep_sink.send(&episode).unwrap(), SendOutcome::Delivered);
    for source in [&mut ep_learner, &mut ep_selector] {
        let got = receive_next(source.as_mut()).expect("episode");
        assert_eq!(*got, *episode);
        assert_eq!(got.steps().len(), MAX_EPISODE_STEPS);
    }

    let mut selected_source = learner.source::<SelectedBatch>().unwrap();
    let mut selected_sink = selector.sink::<SelectedBatch>().unwrap();
    let mut sel = Box::new(SelectedBatch::EMPTY);
    sel.sequence = 9;
    for i in 0..SELECTED_PER_BATCH {
        let mut s = SelectedSample::ZERO;
        s.trajectory_id = 1 << 48 | i as u64;
        s.step_index = i as u16;
        s.priority = i as f32 / 512.0;
        assert!(sel.push(s));
    }
    selected_sink
        .wait_for_receivers(1, Duration::from_secs(10))
        .unwrap();
    assert_eq!(selected_sink.send(&sel).unwrap(), SendOutcome::Delivered);
    let got = receive_next(selected_source.as_mut()).expect("selected batch");
    assert_eq!(*got, *sel);
    eventually("one sender of selected batches", || {
        selected_source.senders() == 1
    });
}

/// Limits follow the config: one transition subscriber (the learner), `num_actors` + spare
/// publishers.
pub fn limits_are_enforced<T: Transport>(make: Make<T>, run: &str) {
    let cfg = TransportConfig::new(run, 1);
    let learner = make(&cfg, "learner");
    let _source = learner.source::<TransitionBatch>().unwrap();
    let other = make(&cfg, "tap");
    assert!(
        other.source::<TransitionBatch>().is_err(),
        "a second transition subscriber must be refused"
    );
    let max = cfg.limits(Topic::Transitions).max_publishers;
    let actor = make(&cfg, "actors");
    let sinks: Vec<_> = (0..max)
        .map(|_| actor.sink::<TransitionBatch>().unwrap())
        .collect();
    assert!(actor.sink::<TransitionBatch>().is_err());
    drop(sinks);
    assert!(actor.sink::<TransitionBatch>().is_ok());
}
