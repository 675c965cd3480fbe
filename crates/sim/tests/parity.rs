//! Replays the Python Meta-World traces in `tests/fixtures/metaworld` through the Rust tasks:
//! observations within 1e-4, rewards within 1e-3, identical success flags and truncation.

use std::path::PathBuf;

use terl_sim::trace::{Comparison, Tolerance, Trace};

fn fixtures(task: &str) -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/metaworld");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy();
            name.starts_with(&format!("{task}-s")) && name.ends_with(".jsonl.gz")
        })
        .collect();
    files.sort();
    files
}

fn check(task: &str) {
    let files = fixtures(task);
    assert!(
        files.len() >= 2,
        "{task}: expected at least 2 fixtures, found {}",
        files.len()
    );
    let mut failures = Vec::new();
    for f in &files {
        let python = Trace::read(f).unwrap();
        assert_eq!(
            python.steps.len(),
            501,
            "{}: a full 500-step trace",
            f.display()
        );
        let rust = python
            .replay()
            .unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        let c = Comparison::of(&python, &rust);
        eprintln!(
            "{}: obs max err {:.2e} at {:?}, reward max err {:.2e} at {}, success mismatches {}",
            f.file_name().unwrap().to_string_lossy(),
            c.obs_max_abs,
            c.obs_worst,
            c.reward_max_abs,
            c.reward_worst_step,
            c.success_mismatches
        );
        if !c.within(Tolerance::default()) {
            failures.push(format!("{}: {c:?}", f.display()));
        }
    }
    assert!(
        failures.is_empty(),
        "parity failures:\n{}",
        failures.join("\n")
    );
}

macro_rules! parity {
    ($($fn_name:ident => $task:literal),* $(,)?) => {
        $(#[test] fn $fn_name() { check($task); })*
    };
}

parity! {
    reach => "reach-v3",
    push => "push-v3",
    pick_place => "pick-place-v3",
    door_open => "door-open-v3",
    drawer_open => "drawer-open-v3",
    drawer_close => "drawer-close-v3",
    button_press_topdown => "button-press-topdown-v3",
    peg_insert_side => "peg-insert-side-v3",
    window_open => "window-open-v3",
    window_close => "window-close-v3",
    door_close => "door-close-v3",
    door_lock => "door-lock-v3",
    door_unlock => "door-unlock-v3",
    button_press => "button-press-v3",
    coffee_button => "coffee-button-v3",
    dial_turn => "dial-turn-v3",
    faucet_open => "faucet-open-v3",
    faucet_close => "faucet-close-v3",
    handle_press => "handle-press-v3",
    plate_slide => "plate-slide-v3",
    sweep_into => "sweep-into-v3",
    shelf_place => "shelf-place-v3",
    lever_pull => "lever-pull-v3",
    // MT50 tasks, part A.
    assembly => "assembly-v3",
    basketball => "basketball-v3",
    bin_picking => "bin-picking-v3",
    box_close => "box-close-v3",
    button_press_topdown_wall => "button-press-topdown-wall-v3",
    button_press_wall => "button-press-wall-v3",
    coffee_pull => "coffee-pull-v3",
    coffee_push => "coffee-push-v3",
    disassemble => "disassemble-v3",
    hammer => "hammer-v3",
    hand_insert => "hand-insert-v3",
    handle_press_side => "handle-press-side-v3",
    handle_pull => "handle-pull-v3",
    handle_pull_side => "handle-pull-side-v3",
    peg_unplug_side => "peg-unplug-side-v3",
    pick_out_of_hole => "pick-out-of-hole-v3",
    pick_place_wall => "pick-place-wall-v3",
    plate_slide_back => "plate-slide-back-v3",
    plate_slide_back_side => "plate-slide-back-side-v3",
    plate_slide_side => "plate-slide-side-v3",
    push_back => "push-back-v3",
    push_wall => "push-wall-v3",
    reach_wall => "reach-wall-v3",
    soccer => "soccer-v3",
    stick_pull => "stick-pull-v3",
    stick_push => "stick-push-v3",
    sweep => "sweep-v3",
}
