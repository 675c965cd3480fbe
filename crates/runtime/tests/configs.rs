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
/// `terl-zenoh` router, and is MT10's run file in every other key.
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
    assert_eq!(k8s.cluster.zenoh.connect, ["tcp/terl-zenoh:7447"]);
    let mut as_shm = k8s.clone();
    as_shm.cluster.transport = Default::default();
    as_shm.cluster.zenoh = Default::default();
    assert_eq!(format!("{as_shm:?}"), format!("{:?}", load("mt10.toml")));
}
