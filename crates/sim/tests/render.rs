//! terl's offscreen renderer (`terl_sim::render`, MuJoCo's `mjr_*` in an EGL surfaceless
//! context) against a second path: Python MuJoCo 3.3.7's own `mujoco.Renderer` on its own EGL
//! backend (`.deps/render-venv`, made by `deploy/setup.sh`), given the same model file, the same
//! state (qpos, qvel, mocap poses and the task's own `body_pos`/`site_pos`) and the same camera.

use std::path::PathBuf;
use std::process::Command;

use rand::{Rng, SeedableRng};
use terl_sim::metaworld::assets_dir;
use terl_sim::render::Renderer;
use terl_sim::{Env, SimError};

fn python() -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../.deps/render-venv/bin/python");
    assert!(
        p.exists(),
        "{} is missing: run ./deploy/setup.sh (or crates/sim/tests/python/setup-venv.sh)",
        p.display()
    );
    p
}

/// An environment of `task` after a reset to variation `variation` and `steps` random actions.
fn env_after(task: &str, variation: usize, steps: usize, seed: u64) -> Env {
    let mut env = Env::for_rendering(task).unwrap();
    env.reset_variation(0, variation).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    for _ in 0..steps {
        let a: [f32; 4] = std::array::from_fn(|_| rng.gen_range(-1.0f32..1.0));
        env.step(&a).unwrap();
    }
    env
}

/// Python MuJoCo's rendering of `env`'s current state.
fn python_frame(env: &Env, camera: &str, width: u32, height: u32) -> Vec<u8> {
    let sim = &env.scene().sim;
    let body_pos: Vec<f64> = (0..sim.nbody()).flat_map(|b| sim.body_pos(b)).collect();
    let site_pos: Vec<f64> = (0..sim.nsite()).flat_map(|s| sim.site_pos(s)).collect();
    let state = serde_json::json!({
        "xml": assets_dir().join(env.spec().xml),
        "width": width,
        "height": height,
        "camera": camera,
        "qpos": sim.qpos(),
        "qvel": sim.qvel(),
        "mocap_pos": sim.mocap_pos(),
        "mocap_quat": sim.mocap_quat(),
        "body_pos": body_pos,
        "site_pos": site_pos,
        "time": sim.time(),
    });
    let dir = tempfile::tempdir().unwrap();
    let state_path = dir.path().join("state.json");
    let out = dir.path().join("frame.rgb");
    std::fs::write(&state_path, serde_json::to_vec(&state).unwrap()).unwrap();
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/python/render_reference.py");
    let o = Command::new(python())
        .arg(&script)
        .arg(&state_path)
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "python renderer failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    std::fs::read(&out).unwrap()
}

/// (mean absolute difference per channel, share of pixels with a channel off by more than 16).
fn difference(a: &[u8], b: &[u8]) -> (f64, f64) {
    assert_eq!(a.len(), b.len());
    let sum: u64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| u64::from(x.abs_diff(*y)))
        .sum();
    let off = a
        .chunks_exact(3)
        .zip(b.chunks_exact(3))
        .filter(|(p, q)| p.iter().zip(q.iter()).any(|(x, y)| x.abs_diff(*y) > 16))
        .count();
    (
        sum as f64 / a.len() as f64,
        off as f64 / (a.len() / 3) as f64,
    )
}

#[test]
fn frames_match_python_mujocos_own_renderer() {
    let cases = [
        ("pick-place-v3", "corner", 3, 40),
        ("window-open-v3", "topview", 7, 15),
        ("button-press-v3", "behindGripper", 11, 25),
        ("door-open-v3", "corner2", 0, 0),
    ];
    for (task, camera, variation, steps) in cases {
        let env = env_after(task, variation, steps, 7);
        let (w, h) = (160, 120);
        let mut renderer = Renderer::new(&env.scene().sim, w, h).unwrap();
        let ours = renderer.render(&env.scene().sim, camera).unwrap();
        assert_eq!((ours.width, ours.height), (w, h));
        assert_eq!(ours.rgb.len(), (3 * w * h) as usize);
        let theirs = python_frame(&env, camera, w, h);
        let (mean, off) = difference(&ours.rgb, &theirs);
        let identical = ours.rgb == theirs;
        eprintln!("{task} from {camera}: mean |difference| {mean:.4}, off {off:.4}, identical {identical}");
        assert!(
            mean < 0.5 && off < 0.005,
            "{task} from {camera}: mean |difference| {mean:.3} per channel, {:.2} % of pixels \
             off by more than 16",
            100.0 * off
        );
        // Not a blank image: the scene has content (many distinct colours), and another
        // camera sees something else.
        let distinct: std::collections::HashSet<&[u8]> = ours.rgb.chunks_exact(3).collect();
        assert!(
            distinct.len() > 200,
            "{task}: only {} colours",
            distinct.len()
        );
        let other = renderer.render(&env.scene().sim, "gripperPOV").unwrap();
        assert!(
            difference(&ours.rgb, &other.rgb).0 > 5.0,
            "{task}: two cameras, one image"
        );
    }
}

/// `render_upright` turns the cameras that look upside down (their up axis below the horizon:
/// Meta-World's `corner`, `corner2`) by 180° and leaves the others as MuJoCo draws them.
#[test]
fn upside_down_cameras_are_turned_upright() {
    let env = env_after("reach-v3", 0, 0, 1);
    let sim = &env.scene().sim;
    let mut r = Renderer::new(sim, 48, 32).unwrap();
    for (camera, upside_down) in [("corner", true), ("corner2", true), ("topview", false)] {
        let raw = r.render(sim, camera).unwrap();
        let upright = r.render_upright(sim, camera).unwrap();
        let mut turned = raw.clone();
        turned.rotate_half_turn();
        assert_eq!(upright == turned, upside_down, "{camera}");
        assert_eq!(upright == raw, !upside_down, "{camera}");
        // A half turn is its own inverse, pixel for pixel: top-left ends bottom-right.
        assert_eq!(&turned.rgb[turned.rgb.len() - 3..], &raw.rgb[..3]);
    }
}

#[test]
fn a_rendered_episode_steps_exactly_like_an_unrendered_one() {
    let mut plain = Env::for_rendering("push-v3").unwrap();
    let mut drawn = Env::for_rendering("push-v3").unwrap();
    let mut renderer = Renderer::new(&drawn.scene().sim, 64, 48).unwrap();
    let o1 = plain.reset_variation(0, 5).unwrap();
    let o2 = drawn.reset_variation(0, 5).unwrap();
    assert_eq!(o1, o2);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let mut frames = Vec::new();
    for _ in 0..60 {
        let a: [f32; 4] = std::array::from_fn(|_| rng.gen_range(-1.0f32..1.0));
        frames.push(renderer.render(&drawn.scene().sim, "corner").unwrap());
        let s1 = plain.step(&a).unwrap();
        let s2 = drawn.step(&a).unwrap();
        assert_eq!(s1.obs, s2.obs);
        assert_eq!(s1.reward.to_bits(), s2.reward.to_bits());
    }
    // The hand moved: the first and last frames differ.
    assert!(difference(&frames[0].rgb, &frames[59].rgb).0 > 0.1);
}

#[test]
fn misuse_is_a_clear_error() {
    let env = Env::for_rendering("reach-v3").unwrap();
    let sim = &env.scene().sim;
    for (w, h) in [(0, 10), (10, 0), (5000, 10)] {
        let err = Renderer::new(sim, w, h).unwrap_err();
        assert!(matches!(err, SimError::Render { .. }), "{err}");
        assert!(err.to_string().contains("outside"), "{err}");
    }
    let mut renderer = Renderer::new(sim, 32, 32).unwrap();
    let err = renderer.render(sim, "no-such-camera").unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("no-such-camera") && text.contains("corner"),
        "{text}"
    );
    assert!(renderer.cameras().iter().any(|c| c == "topview"));
    // Another task's model: refused, not drawn with the wrong meshes.
    let other = Env::for_rendering("push-v3").unwrap();
    let err = renderer.render(&other.scene().sim, "corner").unwrap_err();
    assert!(err.to_string().contains("another model"), "{err}");
    // A training environment's shared model gave its rendering arrays back.
    let shared = Env::new("reach-v3").unwrap();
    let err = Renderer::new(&shared.scene().sim, 32, 32).unwrap_err();
    assert!(err.to_string().contains("for_rendering"), "{err}");
}
