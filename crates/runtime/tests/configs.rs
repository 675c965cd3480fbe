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

#[test]
fn every_shipped_config_loads_and_names_known_tasks() {
    let mut n = 0;
    for entry in std::fs::read_dir(configs_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let cfg =
                RunConfig::load(&path).unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
            terl_runtime::resolve_tasks(&cfg.tasks)
                .unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
            n += 1;
        }
    }
    assert!(n >= 6, "found only {n} configs");
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
