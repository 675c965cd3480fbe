//! The registry and the benchmark task sets are Meta-World 3.1.1's: compared with
//! `tests/fixtures/metaworld/benchmarks.json`, which `tests/parity/benchmark_sets.py` writes
//! from the wheel's `metaworld/env_dict.py`.

use std::collections::BTreeSet;
use std::path::PathBuf;

use terl_sim::metaworld::{task_names, task_set, task_set_names};
use terl_sim::SimError;

/// The fixture's sets, by name.
fn metaworld_sets() -> serde_json::Map<String, serde_json::Value> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/fixtures/metaworld/benchmarks.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(
        v["metaworld"], "3.1.1",
        "fixture written from another version"
    );
    v["sets"].as_object().unwrap().clone()
}

fn names(v: &serde_json::Value) -> Vec<String> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_str().unwrap().to_string())
        .collect()
}

#[test]
fn registry_is_all_fifty_metaworld_tasks_in_metaworld_order() {
    let sets = metaworld_sets();
    let all = names(&sets["all"]);
    assert_eq!(all.len(), 50);
    assert_eq!(task_names(), all);
    for t in &all {
        assert_eq!(task_set(t).unwrap(), [t.as_str()], "{t} by name");
    }
}

#[test]
fn benchmark_sets_are_metaworld_3_1_1_sets() {
    let sets = metaworld_sets();
    for set in [
        "mt10",
        "mt50",
        "ml10-train",
        "ml10-test",
        "ml45-train",
        "ml45-test",
    ] {
        assert!(task_set_names().contains(&set), "{set} is not listed");
        let expected = names(&sets[set]);
        assert_eq!(task_set(set).unwrap(), expected, "{set}");
    }
    // Case and `_` for `-` do not matter.
    assert_eq!(
        task_set("ML45_Test").unwrap(),
        task_set("ml45-test").unwrap()
    );
}

#[test]
fn meta_learning_splits_are_disjoint_and_ml45_covers_all_tasks() {
    for (train, test) in [("ml10-train", "ml10-test"), ("ml45-train", "ml45-test")] {
        let a: BTreeSet<_> = task_set(train).unwrap().into_iter().collect();
        let b: BTreeSet<_> = task_set(test).unwrap().into_iter().collect();
        assert!(a.is_disjoint(&b), "{train} and {test} overlap");
    }
    let ml45: BTreeSet<_> = task_set("ml45-train")
        .unwrap()
        .into_iter()
        .chain(task_set("ml45-test").unwrap())
        .collect();
    assert_eq!(ml45, task_names().into_iter().collect());
}

#[test]
fn paper_sets_are_as_the_paper_defines_them() {
    let mt10 = task_set("mt10").unwrap();
    let mt20 = task_set("mt20").unwrap();
    assert_eq!(mt20.len(), 20);
    assert_eq!(mt20[..10], mt10[..], "MT20 starts with MT10");
    assert_eq!(mt20.iter().collect::<BTreeSet<_>>().len(), 20);
    assert_eq!(task_set("mt1-ind").unwrap().len(), 5);
    assert_eq!(task_set("mt-test").unwrap().len(), 4);
}

#[test]
fn every_listed_set_resolves_to_registered_tasks() {
    let registered = task_names();
    for set in task_set_names() {
        let tasks = task_set(set).unwrap_or_else(|e| panic!("{set}: {e}"));
        assert!(!tasks.is_empty(), "{set}");
        for t in tasks {
            assert!(registered.contains(&t), "{set}: {t} is not registered");
        }
    }
}

#[test]
fn unknown_set_error_lists_every_set() {
    let err = task_set("ml10").unwrap_err();
    assert!(matches!(err, SimError::UnknownTaskSet { .. }), "{err}");
    let msg = err.to_string();
    for set in task_set_names() {
        assert!(msg.contains(set), "{set} missing from: {msg}");
    }
    // A task name is a one-task set.
    assert_eq!(task_set("sweep").unwrap(), ["sweep-v3"]);
}

/// Each parity trace was recorded with the task's MT50 index in its header: the registry's
/// position of every task agrees with all 100 of them.
#[test]
fn trace_headers_agree_with_the_registry_order() {
    use std::io::BufRead;
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/metaworld");
    let registered = task_names();
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if !path.to_string_lossy().ends_with(".jsonl.gz") {
            continue;
        }
        let file = std::fs::File::open(&path).unwrap();
        let mut header = String::new();
        std::io::BufReader::new(flate2::read::GzDecoder::new(file))
            .read_line(&mut header)
            .unwrap();
        let v: serde_json::Value = serde_json::from_str(&header).unwrap();
        let task = v["task"].as_str().unwrap();
        let index = v["mt50_index"].as_u64().unwrap() as usize;
        assert_eq!(
            registered.iter().position(|t| *t == task),
            Some(index),
            "{path:?}"
        );
        seen += 1;
    }
    assert_eq!(seen, 100, "2 traces for each of the 50 tasks");
}
