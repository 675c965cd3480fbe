//! The scripted expert policies against the Rust tasks and the Python traces.
//!
//! * Every task of the Meta-World v3 benchmark sets has a policy.
//! * For every registered task, the noiseless scripted policy reaches success within 500 steps
//!   from three Rust-generated initial states (goal variations of seed 0): reward and success
//!   are wired up end to end. The first-success steps are printed (`--nocapture`).
//! * The policies compute Python's actions (benchmark and registered tasks): the fixture
//!   traces were recorded with Python's policy plus `default_rng(seed).normal(0, 0.1, 4)` per
//!   step, the same noise sequence for every task of a seed, so `recorded action - Rust
//!   policy(previous obs)` must give the same value across all tasks wherever the action was
//!   not clipped.

use std::collections::HashMap;
use std::path::PathBuf;

use terl_sim::metaworld::{goal_variations, policies, task_names, Env, MAX_PATH_LENGTH, OBS_DIM};
use terl_sim::trace::Trace;

/// The tasks of MT10, MT20, MT1-ind and the held-out test set.
const BENCHMARK_TASKS: [&str; 23] = [
    "reach-v3",
    "push-v3",
    "pick-place-v3",
    "door-open-v3",
    "drawer-open-v3",
    "drawer-close-v3",
    "button-press-topdown-v3",
    "peg-insert-side-v3",
    "window-open-v3",
    "window-close-v3",
    "door-close-v3",
    "door-lock-v3",
    "door-unlock-v3",
    "button-press-v3",
    "coffee-button-v3",
    "dial-turn-v3",
    "faucet-open-v3",
    "faucet-close-v3",
    "handle-press-v3",
    "plate-slide-v3",
    "sweep-into-v3",
    "shelf-place-v3",
    "lever-pull-v3",
];

/// Goal variations (of `goal_variations(task, 0)`) rolled out per task.
const VARIATIONS: [usize; 3] = [0, 17, 42];

#[test]
fn every_benchmark_and_registered_task_has_a_policy() {
    let registered = task_names();
    let missing: Vec<&str> = BENCHMARK_TASKS
        .iter()
        .chain(registered.iter())
        .copied()
        .filter(|t| policies::policy(t).is_err())
        .collect();
    assert!(
        missing.is_empty(),
        "tasks without a scripted policy: {missing:?}"
    );
}

/// A rollout's outcome: the first success step, none, or an error.
type Outcome = Result<Option<u32>, String>;

/// First step (1-based) at which the noiseless scripted policy succeeds, if any.
fn first_success(task: &str, rand_vec: &[f64]) -> Outcome {
    let policy = policies::policy(task).map_err(|e| e.to_string())?;
    let mut env = Env::new(task).map_err(|e| e.to_string())?;
    let mut obs = env.reset(rand_vec).map_err(|e| e.to_string())?;
    for t in 1..=MAX_PATH_LENGTH {
        let step = env.step(&policy(&obs)).map_err(|e| e.to_string())?;
        if step.unstable {
            return Err(format!("physics went unstable at step {t}"));
        }
        if step.success {
            return Ok(Some(t));
        }
        obs = step.obs;
    }
    Ok(None)
}

#[test]
fn scripted_policies_succeed_on_every_registered_task() {
    let tasks = task_names();
    let jobs: Vec<(&str, usize)> = tasks
        .iter()
        .flat_map(|t| VARIATIONS.iter().map(move |v| (*t, *v)))
        .collect();
    let workers = std::thread::available_parallelism().map_or(2, |n| n.get().min(4));
    let results: Vec<(&str, usize, Outcome)> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..workers)
            .map(|w| {
                let jobs = &jobs;
                s.spawn(move || {
                    jobs.iter()
                        .skip(w)
                        .step_by(workers)
                        .map(|&(task, v)| {
                            let result = goal_variations(task, 0)
                                .map_err(|e| e.to_string())
                                .and_then(|vars| first_success(task, &vars[v]));
                            (task, v, result)
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    });

    let mut failures = Vec::new();
    for task in &tasks {
        let mut runs: Vec<_> = results.iter().filter(|(t, _, _)| t == task).collect();
        runs.sort_by_key(|(_, v, _)| *v);
        let row: Vec<String> = runs
            .into_iter()
            .map(|(_, v, r)| match r {
                Ok(Some(step)) => format!("var {v:>2}: step {step:>3}"),
                Ok(None) => {
                    failures.push(format!("{task} variation {v}: no success in 500 steps"));
                    format!("var {v:>2}: FAILED")
                }
                Err(e) => {
                    failures.push(format!("{task} variation {v}: {e}"));
                    format!("var {v:>2}: ERROR")
                }
            })
            .collect();
        eprintln!("{task:<24} first success  {}", row.join("  "));
    }
    assert!(
        failures.is_empty(),
        "scripted rollouts failed:\n{}",
        failures.join("\n")
    );
}

fn fixture(task: &str, seed: u32) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!(
        "../../tests/fixtures/metaworld/{task}-s{seed}.jsonl.gz"
    ))
}

#[test]
fn policies_reproduce_python_actions_on_fixture_traces() {
    // The benchmark tasks and every other registered task (each has fixtures for parity).
    let mut tasks = BENCHMARK_TASKS.to_vec();
    for task in task_names() {
        if !tasks.contains(&task) {
            tasks.push(task);
        }
    }
    let mut failures = Vec::new();
    for seed in [1, 2] {
        // (step, component) -> [(task, recorded action - policy action)]
        let mut implied: HashMap<(usize, usize), Vec<(&str, f64)>> = HashMap::new();
        for &task in &tasks {
            let path = fixture(task, seed);
            let trace = Trace::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            let policy = policies::policy(task).unwrap();
            for (t, pair) in trace.steps.windows(2).enumerate() {
                let obs: [f64; OBS_DIM] = pair[0].obs.as_slice().try_into().unwrap();
                let recorded = pair[1]
                    .action
                    .as_ref()
                    .expect("step lines carry the action");
                let ours = policy(&obs);
                for i in 0..4 {
                    // Clipped components carry no information about the noise.
                    if recorded[i].abs() < 1.0 - 1e-6 {
                        let noise = f64::from(recorded[i]) - f64::from(ours[i]);
                        implied.entry((t, i)).or_default().push((task, noise));
                    }
                }
            }
        }
        let mut compared: HashMap<&str, usize> = HashMap::new();
        let mut mismatched: HashMap<&str, Vec<String>> = HashMap::new();
        for ((t, i), values) in &implied {
            if values.len() < 3 {
                continue;
            }
            let mut sorted: Vec<f64> = values.iter().map(|(_, v)| *v).collect();
            sorted.sort_by(f64::total_cmp);
            let median = sorted[sorted.len() / 2];
            for (task, v) in values {
                *compared.entry(task).or_default() += 1;
                if (v - median).abs() > 1e-5 {
                    mismatched.entry(task).or_default().push(format!(
                        "step {} component {i}: implied noise {v:.6}, consensus {median:.6}",
                        t + 1
                    ));
                }
            }
        }
        for &task in &tasks {
            let n = compared.get(task).copied().unwrap_or(0);
            let bad = mismatched.get(task).map_or(&[][..], Vec::as_slice);
            eprintln!(
                "s{seed} {task:<24} {n:>4} action components compared, {} mismatches",
                bad.len()
            );
            // Most steps of a 500-step episode give at least one unclipped component.
            if n < 200 || !bad.is_empty() {
                failures.push(format!(
                    "s{seed} {task}: {n} compared, {} mismatches, first: {:?}",
                    bad.len(),
                    bad.iter().take(3).collect::<Vec<_>>()
                ));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "policy/fixture disagreements:\n{}",
        failures.join("\n")
    );
}
