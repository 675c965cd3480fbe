//! Real Zenoh sessions (peer mode on 127.0.0.1, TCP): the same conformance suite as shared
//! memory and the in-memory twin, plus what only a network transport has to survive.

mod common;

use std::net::TcpListener;
use std::sync::Mutex;
use std::time::Duration;

use common::*;
use terl_transport::*;

/// Opens sessions like the processes of one cluster: each listens on its own loopback port
/// and connects to every session opened before it.
#[derive(Default)]
struct Mesh {
    endpoints: Mutex<Vec<String>>,
    /// The run's secret every session of the mesh authenticates with (none: open).
    secret: Option<ZenohSecret>,
    /// Sessions listen and connect over QUIC, TLS 1.3 (`quic/` endpoints, [`run_certificates`]).
    tls: bool,
}

/// The TLS files of this test process's runs, as `terl certs` makes them (a CA and one
/// certificate for localhost and 127.0.0.1), made once.
fn run_certificates() -> ZenohTls {
    static FILES: std::sync::OnceLock<(tempfile::TempDir, ZenohTls)> = std::sync::OnceLock::new();
    let (_, tls) = FILES.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let files = terl_wire::certs::write_run_certificates(
            dir.path(),
            "zenoh test",
            &["localhost".into(), "127.0.0.1".into()],
        )
        .unwrap();
        let tls = ZenohTls {
            ca: Some(files.ca),
            cert: Some(files.cert),
            key: Some(files.key),
        };
        (dir, tls)
    });
    tls.clone()
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

impl Mesh {
    fn make(&self) -> impl Fn(&TransportConfig, &str) -> ZenohTransport + Sync + '_ {
        move |cfg, role| {
            let scheme = if self.tls { "quic" } else { "tcp" };
            let listen = format!("{scheme}/127.0.0.1:{}", free_port());
            let connect = self.endpoints.lock().unwrap().clone();
            let cfg = TransportConfig {
                zenoh: ZenohConfig {
                    mode: ZenohMode::Peer,
                    listen: vec![listen.clone()],
                    connect,
                    multicast_scouting: false,
                    secret: self.secret.clone(),
                    tls: if self.tls {
                        run_certificates()
                    } else {
                        ZenohTls::default()
                    },
                },
                ..cfg.clone()
            };
            let t = ZenohTransport::open(cfg, role).unwrap();
            self.endpoints.lock().unwrap().push(listen);
            t
        }
    }
}

/// Opens sessions like the processes of a cluster behind a Zenoh router (the Kubernetes
/// layout): the first call starts the router, every session is a client connected to it.
#[derive(Default)]
struct Star {
    router: Mutex<Option<(String, ZenohRouter)>>,
}

impl Star {
    fn make(&self) -> impl Fn(&TransportConfig, &str) -> ZenohTransport + Sync + '_ {
        move |cfg, role| {
            let endpoint = {
                let mut router = self.router.lock().unwrap();
                let (endpoint, _) = router.get_or_insert_with(|| {
                    let listen = format!("tcp/127.0.0.1:{}", free_port());
                    let r = ZenohRouter::open(
                        &ZenohConfig {
                            listen: vec![listen.clone()],
                            ..ZenohConfig::default()
                        },
                        None,
                    )
                    .unwrap();
                    (listen, r)
                });
                endpoint.clone()
            };
            let cfg = TransportConfig {
                zenoh: ZenohConfig {
                    mode: ZenohMode::Client,
                    listen: vec![],
                    connect: vec![endpoint],
                    ..ZenohConfig::default()
                },
                ..cfg.clone()
            };
            ZenohTransport::open(cfg, role).unwrap()
        }
    }
}

#[test]
fn through_a_router_one_to_one() {
    one_to_one_in_order(&Star::default().make(), &unique_run("r-one"));
}

#[test]
fn through_a_router_many_publishers() {
    many_publishers_block_zero_loss(&Star::default().make(), &unique_run("r-many"));
}

#[test]
fn through_a_router_block_timeouts_are_counted() {
    block_timeouts_are_counted_and_reported(&Star::default().make(), &unique_run("r-lost"));
}

#[test]
fn through_a_router_episodes_and_selected() {
    episodes_broadcast_and_selected_flow(&Star::default().make(), &unique_run("r-eps"));
}

#[test]
fn through_a_router_limits_and_claims() {
    let star = Star::default();
    limits_are_enforced(&star.make(), &unique_run("r-lim"));
    let make = star.make();
    let cfg = TransportConfig::new(unique_run("r-claim"), 4);
    let first = make(&cfg, "actor-2");
    let _claim = first.claim_actor_id(2).unwrap();
    let second = make(&cfg, "actor-2");
    let err = second.claim_actor_id(2).unwrap_err();
    assert!(matches!(err, TransportError::IdInUse { .. }), "{err}");
}

#[test]
fn one_to_one() {
    one_to_one_in_order(&Mesh::default().make(), &unique_run("one"));
}

#[test]
fn many_publishers() {
    many_publishers_block_zero_loss(&Mesh::default().make(), &unique_run("many"));
}

#[test]
fn drop_newest() {
    drop_newest_counts_drops(&Mesh::default().make(), &unique_run("drop"));
}

#[test]
fn block_timeout() {
    block_times_out_on_stalled_receiver(&Mesh::default().make(), &unique_run("block"));
}

#[test]
fn block_timeouts_are_counted() {
    block_timeouts_are_counted_and_reported(&Mesh::default().make(), &unique_run("lost"));
}

#[test]
fn episode_timeouts_are_counted() {
    episode_timeouts_are_counted_per_receiver(&Mesh::default().make(), &unique_run("lost-eps"));
}

#[test]
fn cancel() {
    cancel_unblocks_blocked_send(&Mesh::default().make(), &unique_run("cancel"));
}

#[test]
fn back_pressure() {
    block_applies_back_pressure(&Mesh::default().make(), &unique_run("bp"));
}

#[test]
fn a_receiver_gone_is_a_counted_loss() {
    common::a_receiver_gone_is_a_counted_loss(&Mesh::default().make(), &unique_run("gone"));
}

#[test]
fn no_receiver() {
    no_receiver_is_reported(&Mesh::default().make(), &unique_run("none"));
}

#[test]
fn run_ids() {
    run_ids_do_not_mix(&Mesh::default().make(), &unique_run("a"), &unique_run("b"));
}

#[test]
fn episodes_and_selected() {
    episodes_broadcast_and_selected_flow(&Mesh::default().make(), &unique_run("eps"));
}

#[test]
fn limits() {
    limits_are_enforced(&Mesh::default().make(), &unique_run("lim"));
}

/// A frame of the wrong length (another version's sender, or garbage) is rejected and
/// counted; the stream goes on.
#[test]
fn malformed_frames_are_rejected_and_counted() {
    let mesh = Mesh::default();
    let make = mesh.make();
    let cfg = TransportConfig::new(unique_run("bad"), 1);
    let learner = make(&cfg, "learner");
    let mut source = learner.zenoh_source::<TransitionBatch>().unwrap();
    let actor = make(&cfg, "actor-0");
    let mut sink = actor.zenoh_sink::<TransitionBatch>().unwrap();
    sink.wait_for_receivers(1, Duration::from_secs(5)).unwrap();
    let key = format!("{}/to/*", cfg.service_name(Topic::Transitions));
    let rogue = make(&cfg, "rogue");
    // The source's token follows its data subscriber's declaration on the same link: once
    // the rogue sees the token, its puts reach the subscriber.
    let probe = rogue.zenoh_sink::<TransitionBatch>().unwrap();
    probe
        .wait_for_receivers(1, Duration::from_secs(10))
        .unwrap();
    use zenoh::Wait;
    for bytes in [
        vec![],
        vec![1u8; 7],
        vec![0u8; 16 + 5],
        vec![0u8; 16 + 22_561],
    ] {
        rogue.session().put(&key, bytes).wait().unwrap();
    }
    assert_eq!(sink.send(&batch(0, 0)).unwrap(), SendOutcome::Delivered);
    let start = std::time::Instant::now();
    let got = loop {
        if let Some(b) = source.try_receive().unwrap() {
            break b;
        }
        assert!(start.elapsed() < Duration::from_secs(10), "nothing arrived");
        std::thread::yield_now();
    };
    assert_eq!(*got, *batch(0, 0));
    eventually("4 rejected frames", || source.rejected() == 4);
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(source.rejected(), 4);
    assert!(source.try_receive().unwrap().is_none());
    assert_eq!(source.stats().received, 1);
}

/// A run whose sessions speak QUIC (TLS 1.3) and authenticate with its secret (Zenoh's user/password)
/// works as an open one does, and a session without the secret, with another one, or with the
/// secret but trusting another CA never joins it: its frames reach no receiver (not even as
/// rejected frames), it sees no receiver, and it cannot claim an actor id.
#[test]
fn only_sessions_with_the_run_secret_and_ca_join() {
    let secret = ZenohSecret::new("zenoh-test-secret-0123456789").unwrap();
    let mesh = Mesh {
        secret: Some(secret.clone()),
        tls: true,
        ..Mesh::default()
    };
    let make = mesh.make();
    let cfg = TransportConfig::new(unique_run("auth"), 2);
    let learner = make(&cfg, "learner");
    let mut source = learner.zenoh_source::<TransitionBatch>().unwrap();
    let actor = make(&cfg, "actor-0");
    let _claim = actor.claim_actor_id(0).unwrap();
    let mut sink = actor.zenoh_sink::<TransitionBatch>().unwrap();
    sink.wait_for_receivers(1, Duration::from_secs(10)).unwrap();
    assert_eq!(sink.send(&batch(0, 1)).unwrap(), SendOutcome::Delivered);
    assert_eq!(*receive_next(&mut source).unwrap(), *batch(0, 1));

    let key = format!("{}/to/*", cfg.service_name(Topic::Transitions));
    let endpoints = mesh.endpoints.lock().unwrap().clone();
    let other = ZenohSecret::new("another-secret-0123456789").unwrap();
    let other_ca = tempfile::tempdir().unwrap();
    let other_ca = terl_wire::certs::write_run_certificates(
        other_ca.path(),
        "another run",
        &["127.0.0.1".into()],
    )
    .unwrap()
    .ca;
    for (name, rogue_secret, ca) in [
        ("no secret", None, run_certificates().ca),
        ("another secret", Some(other), run_certificates().ca),
        ("another CA", Some(secret.clone()), Some(other_ca)),
    ] {
        let rogue = ZenohTransport::open(
            TransportConfig {
                zenoh: ZenohConfig {
                    connect: endpoints.clone(),
                    secret: rogue_secret,
                    tls: ZenohTls {
                        ca,
                        ..ZenohTls::default()
                    },
                    ..ZenohConfig::default()
                },
                ..cfg.clone()
            },
            "rogue",
        )
        .unwrap();
        let rogue_sink = rogue.zenoh_sink::<TransitionBatch>().unwrap();
        assert!(
            rogue_sink
                .wait_for_receivers(1, Duration::from_secs(3))
                .is_err(),
            "{name}: the rogue sees the learner"
        );
        use zenoh::Wait;
        for bytes in [vec![1u8; 7], vec![0u8; 16 + 22_561]] {
            rogue.session().put(&key, bytes).wait().unwrap();
        }
        let err = rogue.claim_actor_id(1).unwrap_err();
        assert!(
            matches!(err, TransportError::Timeout { .. }),
            "{name}: {err}"
        );
        assert_eq!(
            rogue.session().info().peers_zid().wait().count(),
            0,
            "{name}"
        );
    }
    std::thread::sleep(Duration::from_millis(200));
    assert!(source.try_receive().unwrap().is_none());
    assert_eq!(source.rejected(), 0, "a rogue frame reached the learner");
    // The run goes on: its own sessions still deliver and claim.
    assert_eq!(sink.send(&batch(0, 2)).unwrap(), SendOutcome::Delivered);
    assert_eq!(*receive_next(&mut source).unwrap(), *batch(0, 2));
    let late = make(&cfg, "actor-1");
    let _second = late.claim_actor_id(1).unwrap();
}

/// A client-mode session without an endpoint is refused with a clear message.
#[test]
fn client_without_connect_is_a_config_error() {
    let cfg = TransportConfig {
        zenoh: ZenohConfig {
            mode: ZenohMode::Client,
            ..ZenohConfig::default()
        },
        ..TransportConfig::new(unique_run("cfg"), 1)
    };
    let err = ZenohTransport::open(cfg, "actor").unwrap_err();
    assert!(err.to_string().contains("connect"), "{err}");
    let cfg = TransportConfig {
        zenoh: ZenohConfig {
            connect: vec!["udp/1.2.3.4:5".into()],
            ..ZenohConfig::default()
        },
        ..TransportConfig::new(unique_run("cfg"), 1)
    };
    let err = ZenohTransport::open(cfg, "actor").unwrap_err();
    assert!(err.to_string().contains("tcp/<host>:<port>"), "{err}");
}

/// One actor id, one process: a second claim is refused while the first lives, and the id
/// is free again once the holder drops it.
#[test]
fn a_second_actor_with_the_same_id_is_refused() {
    let mesh = Mesh::default();
    let make = mesh.make();
    let cfg = TransportConfig::new(unique_run("claim"), 4);
    let first = make(&cfg, "actor-3");
    let claim = first.claim_actor_id(3).unwrap();
    let second = make(&cfg, "actor-3");
    let err = second.claim_actor_id(3).unwrap_err();
    assert!(matches!(err, TransportError::IdInUse { .. }), "{err}");
    assert!(err.to_string().contains(&cfg.run_id), "{err}");
    let _other = second.claim_actor_id(1).unwrap();
    drop(claim);
    eventually("actor id 3 released", || second.claim_actor_id(3).is_ok());
}

/// Actors started at the same instant with `--actor-id auto` each take the lowest id they
/// can claim: every one ends with an id of its own, never two with the same.
#[test]
fn simultaneous_claims_end_with_distinct_ids() {
    let mesh = Mesh::default();
    let make = mesh.make();
    let cfg = TransportConfig::new(unique_run("race"), 4);
    let sessions: Vec<_> = (0..3).map(|_| make(&cfg, "actor-auto")).collect();
    let start = std::sync::Barrier::new(sessions.len());
    let claims: Vec<Option<(u16, ZenohClaim)>> = std::thread::scope(|s| {
        let handles: Vec<_> = sessions
            .iter()
            .map(|t| {
                let start = &start;
                s.spawn(move || {
                    start.wait();
                    for id in 0..4u16 {
                        match t.claim_actor_id(id) {
                            Ok(claim) => return Some((id, claim)),
                            Err(TransportError::IdInUse { .. }) => continue,
                            Err(e) => panic!("claim of {id}: {e}"),
                        }
                    }
                    None
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let mut ids: Vec<u16> = claims.iter().flatten().map(|(id, _)| *id).collect();
    assert_eq!(ids.len(), sessions.len(), "some got no id: {ids:?}");
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(
        ids.len(),
        sessions.len(),
        "an id was given twice: {claims:?}"
    );
}

/// A peer that has just opened never takes an id a live actor holds, however soon after
/// opening it claims (a claim that asked before the new peer had met the others took it).
#[test]
fn a_new_peer_never_takes_an_id_a_live_actor_holds() {
    let mesh = Mesh::default();
    let make = mesh.make();
    let cfg = TransportConfig::new(unique_run("held"), 2);
    let _learner = make(&cfg, "learner");
    let holder = make(&cfg, "actor-0");
    let _claim = holder.claim_actor_id(0).unwrap();
    for _ in 0..3 {
        let newcomer = make(&cfg, "actor-auto");
        let err = newcomer.claim_actor_id(0).unwrap_err();
        assert!(matches!(err, TransportError::IdInUse { .. }), "{err}");
    }
}

/// A raw Zenoh peer session connected to the mesh's first session (the learner) and
/// listening nowhere, so no other session can open a connection to it: what an actor on
/// another host, listening on its own loopback, is to the run.
fn peer_listening_nowhere(mesh: &Mesh) -> zenoh::Session {
    use zenoh::Wait as _;
    let learner = mesh.endpoints.lock().unwrap()[0].clone();
    let mut config = zenoh::Config::default();
    for (key, value) in [
        ("mode", "\"peer\"".to_string()),
        ("scouting/multicast/enabled", "false".to_string()),
        ("listen/endpoints", "[]".to_string()),
        ("connect/endpoints", format!("[\"{learner}\"]")),
    ] {
        config.insert_json5(key, &value).unwrap();
    }
    zenoh::open(config).wait().unwrap()
}

/// A holder the newcomer cannot reach itself is still seen: the learner's session answers
/// with the claims it sees. Across hosts such a holder is an actor listening on its own
/// loopback; here it is a peer session listening nowhere that declares a claim token
/// `terl/<run_id>/claims/actor-<id>/<session id>` (no claim time: the earliest claim in the
/// order `claim_actor_id` documents).
/// Whether Zenoh relays a token between two peers through a third depends on its routing
/// state (in CI a second actor took a held id); the learner's answer does not.
#[test]
fn a_holder_reachable_only_through_the_learner_keeps_its_id() {
    use zenoh::Wait as _;
    let mesh = Mesh::default();
    let make = mesh.make();
    let base = TransportConfig::new(unique_run("hub"), 2);
    let _learner = make(&base, "learner");
    let holder = peer_listening_nowhere(&mesh);
    let claim = format!("terl/{}/claims/actor-0/{}", base.run_id, holder.zid());
    let _token = holder.liveliness().declare_token(&claim).wait().unwrap();
    std::thread::sleep(Duration::from_millis(500));
    let newcomer = make(&base, "actor-auto");
    // The learner answers the claim view with the holder's claim (whether Zenoh itself
    // would relay the token between the two peers depends on its routing state).
    let view = format!("terl/{}/claim-view/actor-0", base.run_id);
    let replies = newcomer
        .session()
        .get(&view)
        .consolidation(zenoh::query::ConsolidationMode::None)
        .timeout(Duration::from_secs(2))
        .wait()
        .unwrap();
    let answers: Vec<String> = std::iter::from_fn(|| replies.recv().ok())
        .filter_map(|r| r.result().ok().map(|s| s.payload().to_bytes().into_owned()))
        .flat_map(|b| {
            String::from_utf8(b)
                .unwrap()
                .lines()
                .map(str::to_owned)
                .collect::<Vec<_>>()
        })
        .collect();
    assert!(answers.contains(&claim), "{answers:?}");
    let err = newcomer.claim_actor_id(0).unwrap_err();
    assert!(matches!(err, TransportError::IdInUse { .. }), "{err}");
    // Another id is free.
    let _other = newcomer.claim_actor_id(1).unwrap();
}

/// Two holders of one id meet only once a partition heals (a learner restarted before the
/// earlier holder reconnected, a host back after its lease expired). The holder whose claim
/// is the later one is told within a few seconds; a claim later than its own does not
/// disturb it. The other holder is a peer session listening nowhere, declaring a claim
/// token with a chosen time (`<claimed at ms>-<session id>`, as `claim_actor_id` documents).
#[test]
fn the_later_of_two_holders_that_meet_again_is_told() {
    use zenoh::Wait as _;
    let mesh = Mesh::default();
    let make = mesh.make();
    let base = TransportConfig::new(unique_run("heal"), 2);
    let _learner = make(&base, "learner");
    let holder = make(&base, "actor-0");
    let claim = holder.claim_actor_id(0).unwrap();
    let other = peer_listening_nowhere(&mesh);
    let now_ms = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_millis();
    let prefix = format!("terl/{}/claims/actor-0", base.run_id);
    let later = format!("{prefix}/{}-{}", now_ms + 60_000, other.zid());
    let later_token = other.liveliness().declare_token(&later).wait().unwrap();
    std::thread::sleep(Duration::from_secs(5));
    assert_eq!(claim.superseded(), None, "a later claim took the id away");
    drop(later_token);
    let earlier = format!("{prefix}/1-{}", other.zid());
    let _earlier_token = other.liveliness().declare_token(&earlier).wait().unwrap();
    let start = std::time::Instant::now();
    let why = loop {
        if let Some(why) = claim.superseded() {
            break why;
        }
        assert!(
            start.elapsed() < Duration::from_secs(15),
            "the earlier claim {earlier} went unseen"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(why.contains(&earlier), "{why}");
}

/// A peer that reaches none of its `connect` endpoints refuses to claim an id it cannot
/// check, naming the endpoint, instead of taking it blindly.
#[test]
fn a_peer_that_reaches_nobody_refuses_to_claim() {
    let cfg = TransportConfig {
        zenoh: ZenohConfig {
            mode: ZenohMode::Peer,
            listen: vec![format!("tcp/127.0.0.1:{}", free_port())],
            connect: vec![format!("tcp/127.0.0.1:{}", free_port())],
            ..ZenohConfig::default()
        },
        ..TransportConfig::new(unique_run("alone"), 2)
    };
    let lonely = ZenohTransport::open(cfg.clone(), "actor-auto").unwrap();
    let err = lonely.claim_actor_id(0).unwrap_err();
    assert!(matches!(err, TransportError::Timeout { .. }), "{err}");
    assert!(err.to_string().contains(&cfg.zenoh.connect[0]), "{err}");
}

/// The run file's choice opens the matching engine.
#[test]
fn run_transport_opens_the_configured_engine() {
    let mesh = Mesh::default();
    let make = mesh.make();
    let base = TransportConfig::new(unique_run("kind"), 1);
    let zenoh_learner = make(&base, "learner");
    let cfg = TransportConfig {
        transport: TransportKind::Zenoh,
        ..zenoh_learner.config().clone()
    };
    let learner = RunTransport::Zenoh(zenoh_learner);
    let actor_cfg = TransportConfig {
        zenoh: ZenohConfig {
            listen: vec![],
            connect: cfg.zenoh.listen.clone(),
            ..cfg.zenoh.clone()
        },
        ..cfg.clone()
    };
    let actor = RunTransport::open(actor_cfg, "actor-0").unwrap();
    assert_eq!(actor.kind(), TransportKind::Zenoh);
    let mut source = learner.source::<TransitionBatch>().unwrap();
    let mut sink = actor.sink::<TransitionBatch>().unwrap();
    sink.wait_for_receivers(1, Duration::from_secs(10)).unwrap();
    assert_eq!(sink.send(&batch(0, 5)).unwrap(), SendOutcome::Delivered);
    assert_eq!(*receive_next(source.as_mut()).unwrap(), *batch(0, 5));
    let shm = RunTransport::open(TransportConfig::new(unique_run("kind-shm"), 1), "learner");
    assert_eq!(shm.unwrap().kind(), TransportKind::Shm);
}
