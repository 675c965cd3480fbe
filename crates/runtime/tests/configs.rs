//! Every shipped run file loads, and the MTSAC/TERL pairs differ only in the algorithm (and,
//! for the smoke pair, in the TERL sections), so their runs are comparable at equal budget.

use std::path::{Path, PathBuf};

use terl_runtime::{Algorithm, RunConfig};

fn configs_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../deploy/configs")
}

fn load(name: &str) -> RunConfig {
    RunConfig::load(&configs_dir().join(name)).unwrap_or_else(|e| panic!("{name}: {e:#}"))
}

/// Every `.toml` under `deploy/configs`, its `experiments/` folder included.
fn shipped_configs() -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut dirs = vec![configs_dir()];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "toml") {
                out.push(path);
            }
        }
    }
    out.sort();
    out
}

#[test]
fn every_shipped_config_loads_and_names_known_tasks() {
    let configs = shipped_configs();
    for path in &configs {
        let cfg = RunConfig::load(path).unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
        let tasks = terl_runtime::resolve_tasks(&cfg.tasks)
            .unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
        // Weights messages of the run's size fit the configured gRPC limit.
        cfg.check_weight_messages(tasks.len())
            .unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
    }
    let names: Vec<String> = configs
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    for expected in [
        "mt10.toml",
        "mt10-workstation.toml",
        "mt50.toml",
        "mt50-workstation.toml",
        "mt20-paper.toml",
        "cluster-smoke.toml",
    ] {
        assert!(names.iter().any(|n| n == expected), "{expected} not found");
    }
}

#[test]
fn mt10_terl_is_mt10_with_the_algorithm_switched() {
    let (a, b) = (load("mt10.toml"), load("mt10-terl.toml"));
    assert_eq!(
        (a.algorithm, b.algorithm),
        (Algorithm::Mtsac, Algorithm::Terl)
    );
    let strip = |c: &RunConfig| {
        let mut c = c.clone();
        c.algorithm = Algorithm::Mtsac;
        toml::to_string(&c).unwrap()
    };
    assert_eq!(strip(&a), strip(&b));
    // The paper's TERL settings are the defaults.
    assert_eq!(b.ptr.success_threshold, 0.85);
    assert_eq!((b.tep.batch_size, b.tep.buffer_capacity), (1024, 6_000_000));
    assert_eq!(b.guidance.sigma, 0.98);
}

#[test]
fn mt10_uses_the_reference_mtsac_settings() {
    for name in ["mt10.toml", "mt10-terl.toml"] {
        let c = load(name);
        let tasks = terl_runtime::resolve_tasks(&c.tasks).unwrap();
        // The reference replay: 1M transitions in total, split evenly over the ten tasks.
        assert_eq!(
            c.train.replay_capacity_per_task * tasks.len(),
            1_000_000,
            "{name}"
        );
        let s = &c.sac;
        assert_eq!(s.policy_hidden, vec![400, 400, 400], "{name}");
        assert_eq!(s.critic_hidden, vec![400, 400, 400], "{name}");
        assert_eq!((s.adam_eps, s.max_grad_norm), (1e-5, 1.0), "{name}");
        assert_eq!(s.init, terl_rl::NetInit::HeUniform, "{name}");
        assert_eq!(
            (s.policy_head_init, s.critic_head_init),
            (1e-3, 3e-3),
            "{name}"
        );
    }
}

#[test]
fn a_task_named_twice_is_refused() {
    assert_eq!(terl_runtime::resolve_tasks("mt10").unwrap().len(), 10);
    for spec in ["reach-v3,reach-v3", "mt10,reach-v3", "mt1-ind,mt-test"] {
        let e = format!("{:#}", terl_runtime::resolve_tasks(spec).unwrap_err());
        assert!(e.contains("twice"), "{spec}: {e}");
    }
}

/// Updates per transition of a run file (the cluster's default update-to-data ratio).
fn updates_per_transition(c: &RunConfig) -> f64 {
    c.train.updates_per_vec_step / c.num_envs as f64
}

#[test]
fn mt50_runs_every_task_with_the_reference_mtsac_settings() {
    let paper = load("mt50.toml");
    let tasks = terl_runtime::resolve_tasks(&paper.tasks).unwrap();
    assert_eq!(tasks.len(), 50);
    // One environment per task, the MT10 run's update-to-data ratio.
    assert_eq!(paper.num_envs, 50);
    assert_eq!(
        updates_per_transition(&paper),
        updates_per_transition(&load("mt10.toml"))
    );
    // The reference MT50 MTSAC: 1M transitions in all, batch 128 per task, 100M env steps.
    assert_eq!(
        paper.train.replay_capacity_per_task * tasks.len(),
        1_000_000
    );
    assert_eq!(paper.sac.batch_size, 128 * tasks.len());
    assert_eq!(paper.train.total_env_steps, 100_000_000);
    let reference = load("mt10.toml").sac;
    let s = &paper.sac;
    assert_eq!(s.policy_hidden, reference.policy_hidden);
    assert_eq!(s.critic_hidden, reference.critic_hidden);
    assert_eq!((s.adam_eps, s.max_grad_norm), (1e-5, 1.0));
    assert_eq!(s.init, terl_rl::NetInit::HeUniform);

    // The workstation run: the same tasks and ratio, the MT10 workstation's networks.
    let ws = load("mt50-workstation.toml");
    assert_eq!(terl_runtime::resolve_tasks(&ws.tasks).unwrap(), tasks);
    assert_eq!(ws.num_envs, 50);
    assert_eq!(updates_per_transition(&ws), updates_per_transition(&paper));
    assert_eq!(
        ws.train.replay_capacity_per_task,
        paper.train.replay_capacity_per_task
    );
    let small = load("mt10-workstation.toml");
    assert_eq!(ws.sac.policy_hidden, small.sac.policy_hidden);
    assert_eq!(ws.sac.critic_hidden, small.sac.critic_hidden);
    assert_eq!(ws.sac.batch_size, small.sac.batch_size);
    // The same env steps per task as the MT10 workstation run.
    assert_eq!(
        ws.train.total_env_steps / 50,
        small.train.total_env_steps / 10
    );
}

/// The run file inside the Kubernetes ConfigMap (deploy/k8s/run.yaml, key `run.toml`, a YAML
/// block scalar indented by four spaces) loads, runs over Zenoh as a client of the
/// `terl-zenoh` router over TLS with the files the manifests mount, and is MT10's run file in
/// every other key.
#[test]
fn the_kubernetes_run_file_is_mt10_over_zenoh_through_the_router() {
    let yaml = std::fs::read_to_string(configs_dir().join("../k8s/run.yaml")).unwrap();
    let body: Vec<&str> = yaml
        .lines()
        .skip_while(|l| l.trim() != "run.toml: |")
        .skip(1)
        .take_while(|l| l.is_empty() || l.starts_with("    "))
        .map(|l| l.strip_prefix("    ").unwrap_or(l))
        .collect();
    assert!(body.len() > 10, "no run.toml block in deploy/k8s/run.yaml");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.toml");
    std::fs::write(&path, body.join("\n")).unwrap();
    let k8s = RunConfig::load(&path).unwrap_or_else(|e| panic!("run.toml of run.yaml: {e:#}"));
    assert_eq!(k8s.cluster.transport, terl_transport::TransportKind::Zenoh);
    assert_eq!(k8s.cluster.zenoh.mode, terl_transport::ZenohMode::Client);
    assert_eq!(k8s.cluster.zenoh.connect, ["quic/terl-zenoh:7447"]);
    // As a pod opens it (with the terl-token secret), the Zenoh session passes the lock: TLS
    // to the router, its certificate checked against the terl-tls secret's CA.
    let session = k8s
        .cluster
        .service_transport_config("mt10-k8s", 16, Some("k8s-test-token-0123456789".into()))
        .unwrap();
    session.zenoh.check_locked().unwrap();
    // The TLS files are where the manifests mount the terl-tls secret, and the router serves
    // the endpoint the run connects to with the same certificate.
    let tls_dir = "/etc/terl-tls";
    for (file, key) in [
        (&k8s.cluster.tls_ca, "ca.pem"),
        (&k8s.cluster.tls_cert, "cert.pem"),
        (&k8s.cluster.tls_key, "key.pem"),
    ] {
        assert_eq!(
            file.as_deref(),
            Some(Path::new(tls_dir).join(key).as_path())
        );
    }
    let manifest =
        |name: &str| std::fs::read_to_string(configs_dir().join("../k8s").join(name)).unwrap();
    for name in ["learner.yaml", "actors.yaml", "zenoh-router.yaml"] {
        let m = manifest(name);
        assert!(
            m.contains(&format!("mountPath: {tls_dir}")) && m.contains("secretName: terl-tls"),
            "{name} does not mount the terl-tls secret at {tls_dir}"
        );
    }
    let router = manifest("zenoh-router.yaml");
    for flag in [
        "--listen=quic/0.0.0.0:7447".to_string(),
        format!("--tls-cert={tls_dir}/cert.pem"),
        format!("--tls-key={tls_dir}/key.pem"),
        "--run-id=$(TERL_RUN_ID)".to_string(),
    ] {
        assert!(
            router.contains(&flag),
            "the router is not started with {flag}"
        );
    }
    let mut as_shm = k8s.clone();
    as_shm.cluster.transport = Default::default();
    as_shm.cluster.zenoh = Default::default();
    as_shm.cluster.tls_ca = None;
    as_shm.cluster.tls_cert = None;
    as_shm.cluster.tls_key = None;
    assert_eq!(format!("{as_shm:?}"), format!("{:?}", load("mt10.toml")));
}

/// Every numeric key of a run file, each section's.
const NUMERIC_KEYS: &[(&str, &str)] = &[
    ("", "num_envs"),
    ("", "eval_envs_per_task"),
    ("", "variation_seed"),
    ("train", "total_env_steps"),
    ("train", "warmup_env_steps"),
    ("train", "updates_per_vec_step"),
    ("train", "replay_capacity_per_task"),
    ("train", "eval_every_env_steps"),
    ("train", "eval_episodes_per_env"),
    ("train", "success_window"),
    ("train", "stop_at_eval_success"),
    ("train", "max_consecutive_failed_updates"),
    ("train", "seed"),
    ("sac", "batch_size"),
    ("sac", "threads"),
    ("sac", "gamma"),
    ("sac", "tau"),
    ("cluster", "envs_per_actor"),
    ("cluster", "samples_per_insert"),
    ("cluster", "rate_error_buffer"),
    ("cluster", "publish_every_updates"),
    ("cluster", "critic_publish_every_updates"),
    ("cluster", "checkpoint_every_secs"),
    ("cluster", "learner_calibrate_secs"),
    ("cluster", "keep_checkpoints"),
    ("cluster", "block_timeout_secs"),
    ("cluster", "buffer_batches"),
    ("cluster", "eval_episodes_per_task"),
    ("cluster", "eval_threads"),
    ("cluster", "eval_envs_per_task"),
    ("cluster", "max_message_mib"),
    ("cluster", "policy_lag_rounds"),
    ("ptr", "batch_size"),
    ("ptr", "success_window"),
    ("ptr", "pool_trajectories"),
    ("ptr", "top_fraction"),
    ("ptr", "gamma"),
    ("tep", "buffer_capacity"),
    ("tep", "threads"),
    ("tep", "updates_per_sac_update"),
    ("tep", "f_output_scale"),
    ("guidance", "sigma"),
];

/// Values that pass a type check and break arithmetic: zeros of both signs, subnormals, huge,
/// infinite and not-a-number floats, the integer extremes, negatives.
const EXTREMES: &[&str] = &[
    "0",
    "-0",
    "0.0",
    "-0.0",
    "5e-324",
    "1e-310",
    "0.5",
    "1",
    "3",
    "1e300",
    "-1e300",
    "inf",
    "-inf",
    "nan",
    "-1",
    "4294967296",
    "9223372036854775807",
    "18446744073709551615",
];

/// What a service derives from an accepted run file before it allocates anything, each of
/// which must not panic; and what it then allocates must be within the documented ranges.
fn use_accepted(cfg: &RunConfig) {
    let _ = cfg.samples_per_insert();
    let _ = cfg.envs_per_actor();
    let _ = cfg.rate_error_buffer(cfg.sac.batch_size);
    let _ = cfg.cluster.max_message_bytes();
    let _ = cfg.cluster.transport_config("props", 1);
    let _ = cfg.check_weight_messages(2);
    for secs in [
        cfg.cluster.checkpoint_every_secs,
        cfg.cluster.block_timeout_secs,
        cfg.cluster.learner_calibrate_secs,
    ] {
        let _ = std::time::Duration::from_secs_f64(secs);
    }
    assert!((1..=terl_runtime::MAX_NUM_ENVS).contains(&cfg.num_envs));
    assert!(cfg.envs_per_actor() <= terl_runtime::MAX_NUM_ENVS);
    assert!((1..=terl_runtime::MAX_REPLAY_CAPACITY_PER_TASK)
        .contains(&cfg.train.replay_capacity_per_task));
    assert!((1..=terl_runtime::MAX_BATCH_SIZE).contains(&cfg.sac.batch_size));
    assert!(cfg.cluster.buffer_batches <= terl_runtime::MAX_BUFFER_BATCHES);
    assert!(cfg.cluster.eval_episodes_per_task <= terl_runtime::MAX_EPISODE_COUNT);
    assert!(cfg.train.success_window <= terl_runtime::MAX_EPISODE_COUNT);
    assert!(cfg.ptr.success_window <= 100_000 && cfg.ptr.pool_trajectories <= 100_000);
    assert!(cfg.tep.threads <= 256 && cfg.tep.buffer_capacity <= 50_000_000);
    let ratio = cfg.samples_per_insert();
    assert!(ratio.is_finite() && ratio > 0.0);
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(256))]

    /// Any numeric key of a run file set to any extreme value, up to three at once: the run file
    /// is accepted or refused with an error, never a panic, and what is accepted stays in the
    /// documented ranges (issue: "every input bounded before anything is spent").
    #[test]
    fn extreme_values_in_a_run_file_are_refused_or_bounded_never_a_panic(
        picks in proptest::collection::vec(
            (0..NUMERIC_KEYS.len(), 0..EXTREMES.len()),
            1..=3,
        )
    ) {
        let dir = tempfile::tempdir().unwrap();
        let mut top = String::from("tasks = \"reach-v3,push-v3\"\nalgorithm = \"terl\"\n");
        let mut sections: std::collections::BTreeMap<&str, String> = Default::default();
        let mut seen = std::collections::BTreeSet::new();
        for (k, v) in &picks {
            let (section, key) = NUMERIC_KEYS[*k];
            if !seen.insert((section, key)) {
                continue;
            }
            let line = format!("{key} = {}\n", EXTREMES[*v]);
            if section.is_empty() {
                top.push_str(&line);
            } else {
                sections.entry(section).or_default().push_str(&line);
            }
        }
        if !top.contains("num_envs") {
            top.push_str("num_envs = 2\n");
        }
        for (section, lines) in &sections {
            top.push_str(&format!("[{section}]\n{lines}"));
        }
        let path = dir.path().join("run.toml");
        std::fs::write(&path, &top).unwrap();
        match RunConfig::load(&path) {
            Ok(cfg) => use_accepted(&cfg),
            Err(e) => proptest::prop_assert!(!format!("{e:#}").is_empty(), "{top}"),
        }
    }
}
