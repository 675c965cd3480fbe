//! `terl eval` end to end: real checkpoints (a hand-built controller with a known outcome and a
//! real `terl train` run), real MuJoCo, the JSON shape, the shape-mismatch error, the MT-Test
//! task encoding, and a second evaluation path (`terl_rl::train::evaluate` over a separate
//! environment adapter) that must agree with `terl eval` episode for episode.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;
use terl_rl::env::{StepBuffers, VecEnvironment};
use terl_rl::{Sac, SacConfig};
use terl_sim::metaworld::goal_variations;
use terl_sim::{Env, SimError, ACTION_DIM, OBS_DIM};

fn terl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(args)
        .output()
        .unwrap()
}

fn json(o: &Output) -> Value {
    assert!(
        o.status.success(),
        "terl failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).expect("one JSON object on stdout")
}

/// A run folder trained on `reach-v3,push-v3` whose policy is a hand-built proportional
/// controller: hidden units `relu(±(goal_j − hand_j))`, mean action `10·(goal − hand)`, so the
/// deterministic action `tanh(10·(goal − hand))` drives the hand to the goal. It solves reach
/// (success = hand within 5 cm of the goal) and, not aiming at the puck, almost never push.
fn hand_built_run(dir: &Path) -> PathBuf {
    let run = dir.join("hand-built");
    std::fs::create_dir_all(run.join("checkpoints")).unwrap();
    std::fs::write(
        run.join("config.toml"),
        "tasks = \"reach-v3,push-v3\"\nnum_envs = 2\n[sac]\npolicy_hidden = [6]\ncritic_hidden = [8]\n",
    )
    .unwrap();
    let cfg = SacConfig {
        obs_dim: OBS_DIM,
        act_dim: ACTION_DIM,
        num_tasks: 2,
        policy_hidden: vec![6],
        critic_hidden: vec![8],
        ..SacConfig::default()
    };
    let mut sac = Sac::<f32>::new(cfg).unwrap();
    let net = sac.policy_net_mut();
    let input = OBS_DIM + 2;
    let (w0, b0, w1, b1) = (
        net.weight_range(0),
        net.bias_range(0),
        net.weight_range(1),
        net.bias_range(1),
    );
    let p = &mut net.params;
    for r in [w0.clone(), b0, w1.clone(), b1] {
        p[r].fill(0.0);
    }
    for j in 0..3 {
        // hidden 2j: goal_j - hand_j; hidden 2j+1: hand_j - goal_j (obs[0..3] hand, obs[36..39] goal).
        p[w0.start + 2 * j * input + 36 + j] = 1.0;
        p[w0.start + 2 * j * input + j] = -1.0;
        p[w0.start + (2 * j + 1) * input + 36 + j] = -1.0;
        p[w0.start + (2 * j + 1) * input + j] = 1.0;
        // mean_j = 10 (h_2j - h_2j+1); outputs 4..8 (log std) stay 0.
        p[w1.start + j * 6 + 2 * j] = 10.0;
        p[w1.start + j * 6 + 2 * j + 1] = -10.0;
    }
    sac.save_checkpoint(&run.join("checkpoints/final.safetensors"))
        .unwrap();
    run
}

/// The second path's environments: one `terl_sim::Env` per (task, variation), reset to that
/// variation, auto-reset to it again (only the first episode is counted).
struct VariationEnvs {
    envs: Vec<Env>,
    rand_vecs: Vec<Vec<f64>>,
    task_ids: Vec<usize>,
    num_tasks: usize,
}

impl VariationEnvs {
    fn new(tasks: &[&str], episodes: usize, seed: u64) -> Self {
        let mut v = Self {
            envs: vec![],
            rand_vecs: vec![],
            task_ids: vec![],
            num_tasks: tasks.len(),
        };
        for (t, task) in tasks.iter().enumerate() {
            let vars = goal_variations(task, seed).unwrap();
            for k in 0..episodes {
                v.envs.push(Env::new(task).unwrap());
                v.rand_vecs.push(vars[k % vars.len()].clone());
                v.task_ids.push(t);
            }
        }
        v
    }
}

impl VecEnvironment for VariationEnvs {
    type Error = SimError;
    fn num_envs(&self) -> usize {
        self.envs.len()
    }
    fn obs_dim(&self) -> usize {
        OBS_DIM
    }
    fn act_dim(&self) -> usize {
        ACTION_DIM
    }
    fn num_tasks(&self) -> usize {
        self.num_tasks
    }
    fn task_ids(&self) -> &[usize] {
        &self.task_ids
    }
    fn reset_all(&mut self, _seed: u64, obs: &mut [f32]) -> Result<(), SimError> {
        for (i, env) in self.envs.iter_mut().enumerate() {
            let o = env.reset(&self.rand_vecs[i])?;
            for (d, s) in obs[i * OBS_DIM..(i + 1) * OBS_DIM].iter_mut().zip(o) {
                *d = s as f32;
            }
        }
        Ok(())
    }
    fn step(&mut self, actions: &[f32], out: &mut StepBuffers) -> Result<(), SimError> {
        for (i, env) in self.envs.iter_mut().enumerate() {
            let s = env.step(&actions[i * ACTION_DIM..(i + 1) * ACTION_DIM])?;
            out.reward[i] = s.reward as f32;
            out.success[i] = s.success;
            out.truncated[i] = s.truncated;
            out.terminated[i] = false;
            let row = i * OBS_DIM..(i + 1) * OBS_DIM;
            for (d, v) in out.final_obs[row.clone()].iter_mut().zip(s.obs) {
                *d = v as f32;
            }
            if s.truncated {
                let o = env.reset(&self.rand_vecs[i])?;
                for (d, v) in out.obs[row].iter_mut().zip(o) {
                    *d = v as f32;
                }
            } else {
                let (src, dst) = (out.final_obs[row.clone()].to_vec(), &mut out.obs[row]);
                dst.copy_from_slice(&src);
            }
        }
        Ok(())
    }
}

#[test]
fn eval_json_of_a_hand_built_reach_controller_is_known_and_matches_train_evaluate() {
    let dir = tempfile::tempdir().unwrap();
    let run = hand_built_run(dir.path());
    let o = terl(&["eval", "--checkpoint", run.to_str().unwrap(), "--json"]);
    let v = json(&o);
    // The JSON shape.
    assert!(v["checkpoint"]
        .as_str()
        .unwrap()
        .ends_with("final.safetensors"));
    assert_eq!(
        v["trained_tasks"],
        serde_json::json!(["reach-v3", "push-v3"])
    );
    assert_eq!(v["unseen_task_encoding"], "uniform");
    assert_eq!(v["episodes_per_task"], 50);
    assert_eq!(v["variation_seed"], 0);
    assert_eq!(v["eval_env_steps"], 2 * 50 * 500);
    assert!(v["wall_seconds"].as_f64().unwrap() > 0.0);
    let tasks = v["tasks"].as_array().unwrap();
    assert_eq!(tasks.len(), 2);
    for (t, name) in tasks.iter().zip(["reach-v3", "push-v3"]) {
        assert_eq!(t["task"], name);
        assert_eq!(t["episodes"], 50);
        assert_eq!(t["trained"], true);
        for key in [
            "success_rate",
            "successes",
            "mean_return",
            "mean_first_success_step",
            "unstable_episodes",
            "encoding",
        ] {
            assert!(t.get(key).is_some(), "no {key} in {t}");
        }
    }
    assert_eq!(tasks[0]["encoding"], "one-hot:0");
    assert_eq!(tasks[1]["encoding"], "one-hot:1");
    // The known outcome: the controller reaches the goals, quickly; push needs the puck moved
    // to the goal, which it does only by chance.
    let reach = tasks[0]["success_rate"].as_f64().unwrap();
    let first = tasks[0]["mean_first_success_step"].as_f64().unwrap();
    assert!(reach >= 0.9, "reach success {reach}");
    assert!((1.0..150.0).contains(&first), "first success step {first}");
    let push = tasks[1]["success_rate"].as_f64().unwrap();
    assert!(push <= 0.1, "push success {push}");
    let rates: Vec<f64> = tasks
        .iter()
        .map(|t| t["success_rate"].as_f64().unwrap())
        .collect();
    assert_eq!(
        v["mean_success_rate"].as_f64().unwrap(),
        (rates[0] + rates[1]) / 2.0
    );

    // The second path: the trainer's own evaluate over a separate adapter, same variations.
    let ckpt = terl_runtime::eval::load_policy_checkpoint(&run).unwrap();
    let mut policy = ckpt.policy.with_max_batch(100);
    let mut envs = VariationEnvs::new(&["reach-v3", "push-v3"], 50, 0);
    let other = terl_rl::train::evaluate(&mut policy, &mut envs, 1, 0).unwrap();
    assert_eq!(
        other.per_task_success, rates,
        "per-task success of both paths"
    );
    let returns: f64 = tasks
        .iter()
        .map(|t| t["mean_return"].as_f64().unwrap())
        .sum::<f64>()
        / 2.0;
    assert!(
        (other.mean_return - returns).abs() <= 1e-9 * returns.abs().max(1.0),
        "mean return {} vs {returns}",
        other.mean_return
    );

    // The table names the tasks and the protocol.
    let o = terl(&[
        "eval",
        "--checkpoint",
        run.join("checkpoints/final.safetensors").to_str().unwrap(),
        "--tasks",
        "reach-v3",
        "--episodes-per-task",
        "3",
    ]);
    assert!(o.status.success());
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("deterministic policy"), "{table}");
    assert!(
        table.contains("reach-v3") && !table.contains("push-v3"),
        "{table}"
    );
    assert!(table.contains("100.0%"), "{table}");
}

#[test]
fn eval_reads_a_terl_train_run_folder_and_rejects_shapes_that_do_not_fit() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let o = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["train", "--config"])
        .arg(root.join("deploy/configs/smoke.toml"))
        .arg("--out")
        .arg(&run)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // A run folder: its newest checkpoint, its task list and variation seed.
    let v = json(&terl(&[
        "eval",
        "--checkpoint",
        run.to_str().unwrap(),
        "--episodes-per-task",
        "4",
        "--json",
    ]));
    assert!(v["policy_version"].as_u64().unwrap() > 1000, "{v}");
    assert_eq!(v["tasks"].as_array().unwrap().len(), 2);
    assert_eq!(v["tasks"][1]["episodes"], 4);

    // Shape mismatch: the 2-task policy against a 10-task list.
    let ckpt = run.join("checkpoints/final.safetensors");
    let o = terl(&[
        "eval",
        "--checkpoint",
        ckpt.to_str().unwrap(),
        "--trained-tasks",
        "mt10",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("shape mismatch")
            && err.contains("policy for 2 task(s)")
            && err.contains("has 10"),
        "{err}"
    );
    // The same from the run's own config.toml claiming mt10.
    let cfg = std::fs::read_to_string(run.join("config.toml")).unwrap();
    std::fs::write(
        run.join("config.toml"),
        cfg.replace("tasks = \"reach-v3,push-v3\"", "tasks = \"mt10\""),
    )
    .unwrap();
    let o = terl(&["eval", "--checkpoint", run.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("shape mismatch") && err.contains("changed after training"),
        "{err}"
    );
    // A lone checkpoint carries its task order (terl train records it).
    let lone = dir.path().join("lone.safetensors");
    std::fs::copy(&ckpt, &lone).unwrap();
    let v = json(&terl(&[
        "eval",
        "--checkpoint",
        lone.to_str().unwrap(),
        "--episodes-per-task",
        "1",
        "--json",
    ]));
    assert_eq!(
        v["trained_tasks"],
        serde_json::json!(["reach-v3", "push-v3"])
    );
    // A checkpoint without a recorded order, alone: the order must be given.
    let mut file = terl_nn::tensors::TensorFile::load(&lone).unwrap();
    file.metadata.remove("terl.tasks");
    let tensors: Vec<_> = file.tensors.into_values().collect();
    terl_nn::tensors::save_file(&lone, &tensors, &file.metadata).unwrap();
    let o = terl(&["eval", "--checkpoint", lone.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("--trained-tasks"));
    // Not a checkpoint at all.
    let junk = dir.path().join("junk.safetensors");
    std::fs::write(&junk, b"not safetensors").unwrap();
    let o = terl(&[
        "eval",
        "--checkpoint",
        junk.to_str().unwrap(),
        "--trained-tasks",
        "reach-v3",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("junk.safetensors"),
        "{err}"
    );
}

#[test]
fn eval_of_mt_test_tasks_uses_the_chosen_unseen_task_encoding() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let o = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["train", "--config"])
        .arg(root.join("deploy/configs/smoke.toml"))
        .arg("--out")
        .arg(&run)
        .output()
        .unwrap();
    assert!(o.status.success());
    let eval = |tasks: &str, encoding: Option<&str>| {
        let mut args = vec![
            "eval",
            "--checkpoint",
            run.to_str().unwrap(),
            "--tasks",
            tasks,
            "--episodes-per-task",
            "2",
            "--json",
        ];
        if let Some(e) = encoding {
            args.extend(["--unseen-task-encoding", e]);
        }
        json(&terl(&args))
    };
    let uniform = eval("mt-test", None);
    assert_eq!(uniform["unseen_task_encoding"], "uniform");
    let names: Vec<&str> = uniform["tasks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            assert_eq!(t["trained"], false);
            assert_eq!(t["encoding"], "uniform");
            t["task"].as_str().unwrap()
        })
        .collect();
    assert_eq!(
        names,
        [
            "door-close-v3",
            "sweep-into-v3",
            "shelf-place-v3",
            "lever-pull-v3"
        ]
    );
    let zeros = eval("mt-test", Some("zeros"));
    assert!(zeros["tasks"]
        .as_array()
        .unwrap()
        .iter()
        .all(|t| t["encoding"] == "zeros"));
    // The encoding reaches the network: the trained policy acts differently under the two.
    let returns = |v: &Value| -> Vec<f64> {
        v["tasks"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| t["mean_return"].as_f64().unwrap())
            .collect()
    };
    assert_ne!(returns(&uniform), returns(&zeros));
    // Trained and unseen tasks mixed: a trained task keeps its one-hot.
    let mixed = eval("push-v3,door-close-v3", None);
    assert_eq!(mixed["tasks"][0]["encoding"], "one-hot:1");
    assert_eq!(mixed["tasks"][1]["encoding"], "uniform");
    let bad = terl(&[
        "eval",
        "--checkpoint",
        run.to_str().unwrap(),
        "--unseen-task-encoding",
        "nearest",
    ]);
    assert!(!bad.status.success());
}

/// `ffprobe`'s view of a video's first stream: (codec, frames decoded, width, height).
fn probe(video: &Path) -> (String, u64, u64, u64) {
    let o = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0", "-count_frames"])
        .args([
            "-show_entries",
            "stream=codec_name,nb_read_frames,width,height",
        ])
        .args(["-of", "json"])
        .arg(video)
        .output()
        .expect("ffprobe (Debian's ffmpeg package, installed by ./deploy/setup.sh)");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    let s = &v["streams"][0];
    (
        s["codec_name"].as_str().unwrap().to_string(),
        s["nb_read_frames"].as_str().unwrap().parse().unwrap(),
        s["width"].as_u64().unwrap(),
        s["height"].as_u64().unwrap(),
    )
}

#[test]
fn render_writes_playable_videos_of_the_episodes_eval_scores() {
    let dir = tempfile::tempdir().unwrap();
    let run = hand_built_run(dir.path());
    let out = dir.path().join("videos");
    let o = terl(&[
        "render",
        "--checkpoint",
        run.to_str().unwrap(),
        "--variations",
        "0,1",
        "--size",
        "96x64",
        "--every",
        "5",
        "--fps",
        "16",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rendered: Value =
        serde_json::from_slice(&std::fs::read(out.join("render.json")).unwrap()).unwrap();
    let episodes = rendered["episodes"].as_array().unwrap();
    assert_eq!(episodes.len(), 4, "{rendered}");
    assert_eq!(rendered["complete"], true, "{rendered}");
    // The same episodes as `terl eval`'s first two per task (episode k on variation k).
    let eval = json(&terl(&[
        "eval",
        "--checkpoint",
        run.to_str().unwrap(),
        "--episodes-per-task",
        "2",
        "--json",
    ]));
    for t in eval["tasks"].as_array().unwrap() {
        let name = t["task"].as_str().unwrap();
        let mine: Vec<&Value> = episodes.iter().filter(|e| e["task"] == name).collect();
        assert_eq!(mine.len(), 2);
        let successes = mine.iter().filter(|e| e["success"] == true).count() as u64;
        assert_eq!(successes, t["successes"].as_u64().unwrap(), "{name}");
        let mean_return: f64 = mine
            .iter()
            .map(|e| e["episode_return"].as_f64().unwrap())
            .sum::<f64>()
            / 2.0;
        assert!(
            (mean_return - t["mean_return"].as_f64().unwrap()).abs() < 1e-9,
            "{name}: {mean_return} vs {}",
            t["mean_return"]
        );
    }
    // The hand-built controller solves reach: its video shows a success.
    assert!(episodes
        .iter()
        .any(|e| e["task"] == "reach-v3" && e["first_success_step"].as_u64().is_some()));
    for e in episodes {
        let video = out.join(e["video"].as_str().unwrap());
        let (codec, frames, w, h) = probe(&video);
        assert_eq!(codec, "h264");
        assert_eq!((w, h), (96, 64));
        // 500 steps, one frame every 5.
        assert_eq!(frames, 100);
        assert_eq!(e["frames"].as_u64().unwrap(), 100);
        let strip = image::open(out.join(e["strip"].as_str().unwrap())).unwrap();
        assert_eq!((strip.width(), strip.height()), (3 * 96 + 2 * 4, 64));
    }
    assert!(!std::fs::read_dir(&out).unwrap().any(|f| f
        .unwrap()
        .path()
        .to_string_lossy()
        .ends_with(".part")));

    // Clear errors: an unknown camera (listing the scene's), an odd size, a bad variation;
    // none of them creates the output folder.
    let not_made = dir.path().join("not-made");
    for (args, expect) in [
        (vec!["--camera", "nope"], "behindGripper"),
        (vec!["--size", "95x64"], "WIDTHxHEIGHT"),
        (vec!["--variations", "50"], "0..50"),
    ] {
        let mut all = vec![
            "render",
            "--checkpoint",
            run.to_str().unwrap(),
            "--out",
            not_made.to_str().unwrap(),
        ];
        all.extend(args.iter().copied());
        let o = terl(&all);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(expect), "{err}");
        assert!(!not_made.exists(), "{args:?} made the output folder");
    }
    // A pipe under the lock file's name is refused, not opened (that would wait forever).
    let piped = dir.path().join("piped");
    std::fs::create_dir(&piped).unwrap();
    assert!(std::process::Command::new("mkfifo")
        .arg(piped.join(".render.lock"))
        .status()
        .unwrap()
        .success());
    let o = std::process::Command::new("timeout")
        .arg("60")
        .arg(env!("CARGO_BIN_EXE_terl"))
        .args(["render", "--checkpoint", run.to_str().unwrap(), "--out"])
        .arg(&piped)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("not a regular file"), "{err}");
}
