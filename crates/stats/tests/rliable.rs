//! The second path: rliable 1.2.0 itself (in `.deps/rliable-venv`, made by `deploy/setup.sh`)
//! on fixed score matrices. Point estimates must agree to 1e-9; the interval endpoints, which
//! both sides estimate by Monte Carlo with different random streams, within a tolerance a few
//! times their Monte-Carlo error, and tight enough that a bootstrap which ignores the task
//! strata lands outside it.

use std::io::Write as _;
use std::path::PathBuf;
use std::process::{Command, Stdio};

use terl_stats::{aggregate_iqm, aggregate_mean, probability_of_improvement, Bootstrap};
use terl_stats::{Interval, ScoreMatrix};

/// Success % of 5 runs × 4 tasks: tasks at very different levels (so stratification matters),
/// ties and zeros (so the Mann–Whitney half-counts matter), few repeated values (so the
/// bootstrap distributions are not lumpier than their Monte-Carlo error).
const X: [[f64; 4]; 5] = [
    [12.4, 81.0, 0.0, 55.3],
    [31.7, 90.2, 0.0, 60.9],
    [20.6, 62.5, 10.8, 41.1],
    [22.3, 100.0, 0.0, 70.4],
    [0.0, 73.9, 20.2, 66.7],
];
/// A second algorithm with 4 runs on the same tasks (ties with X at 81.0, 90.2 and 0).
const Y: [[f64; 4]; 4] = [
    [5.5, 81.0, 0.0, 20.8],
    [15.1, 40.3, 0.0, 31.6],
    [25.9, 90.2, 0.0, 35.4],
    [6.2, 60.7, 0.0, 25.3],
];
/// rliable's resamples (its default is 50 000; fewer keep the test's Python side near 10 s).
const REF_REPS: usize = 10_000;
const REF_POI_REPS: usize = 4_000;
/// Ours: many, so that nearly all the Monte-Carlo error is rliable's.
const OUR_REPS: usize = 50_000;
/// Tolerances of an interval endpoint: in % for mean and IQM (rliable's endpoints move by up to
/// 0.3 between its seeds 0, 1, 2 here: Y has only 4 runs), in probability for P(X > Y) (the
/// statistic moves in steps of 1/160 = 0.00625).
const TOL_PCT: f64 = 0.75;
const TOL_POI: f64 = 0.02;

fn matrix<const T: usize>(rows: &[[f64; T]]) -> ScoreMatrix {
    ScoreMatrix::from_rows(&rows.iter().map(|r| r.to_vec()).collect::<Vec<_>>()).unwrap()
}

fn venv_python() -> PathBuf {
    let python =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../.deps/rliable-venv/bin/python");
    assert!(
        python.exists(),
        "the rliable venv is missing ({}); run ./deploy/setup.sh (or \
         crates/stats/tests/python/setup-venv.sh) to create it",
        python.display()
    );
    python
}

fn rliable() -> serde_json::Value {
    let script =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/python/rliable_reference.py");
    let request = serde_json::json!({
        "x": X, "y": Y, "reps": REF_REPS, "poi_reps": REF_POI_REPS, "seed": 0,
    });
    let mut child = Command::new(venv_python())
        .arg(&script)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the venv's python starts");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(request.to_string().as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "rliable_reference.py failed ({}):\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON from rliable_reference.py")
}

fn pair(v: &serde_json::Value) -> (f64, f64) {
    (v[0].as_f64().unwrap(), v[1].as_f64().unwrap())
}

fn assert_close(what: &str, ours: Interval, point: f64, ci: (f64, f64), tol: f64) {
    assert!(
        (ours.point - point).abs() < 1e-9,
        "{what}: point {} here, {point} in rliable",
        ours.point
    );
    assert!(
        (ours.lower - ci.0).abs() <= tol && (ours.upper - ci.1).abs() <= tol,
        "{what}: interval [{}, {}] here, [{}, {}] in rliable (tolerance {tol})",
        ours.lower,
        ours.upper,
        ci.0,
        ci.1
    );
}

#[test]
fn iqm_mean_and_probability_of_improvement_match_rliable() {
    let reference = rliable();
    let (x, y) = (matrix(&X), matrix(&Y));
    let b = Bootstrap::with_reps(OUR_REPS);
    for (name, m) in [("x", &x), ("y", &y)] {
        let r = &reference[name];
        let iqm = b.iqm(m).unwrap();
        assert_close(
            &format!("IQM of {name}"),
            iqm,
            r["iqm"].as_f64().unwrap(),
            pair(&r["iqm_ci"]),
            TOL_PCT,
        );
        assert_eq!(iqm.point, aggregate_iqm(m));
        let mean = b.mean(m).unwrap();
        assert_close(
            &format!("mean of {name}"),
            mean,
            r["mean"].as_f64().unwrap(),
            pair(&r["mean_ci"]),
            TOL_PCT,
        );
        assert_eq!(mean.point, aggregate_mean(m));
    }
    let poi = b.probability_of_improvement(&x, &y).unwrap();
    assert_close(
        "P(X > Y)",
        poi,
        reference["poi"].as_f64().unwrap(),
        pair(&reference["poi_ci"]),
        TOL_POI,
    );
    assert_eq!(poi.point, probability_of_improvement(&x, &y).unwrap());

    // The comparison can tell: a bootstrap that pools all 20 scores as one stratum (the same
    // IQM, a wrong interval) is outside the tolerance of rliable's stratified interval.
    let pooled = ScoreMatrix::new(20, 1, X.concat()).unwrap();
    let wrong = b.iqm(&pooled).unwrap();
    assert_eq!(wrong.point, reference["x"]["iqm"].as_f64().unwrap());
    let (lo, hi) = pair(&reference["x"]["iqm_ci"]);
    assert!(
        (wrong.lower - lo).abs() > 3.0 * TOL_PCT || (wrong.upper - hi).abs() > 3.0 * TOL_PCT,
        "pooled [{}, {}] vs stratified [{lo}, {hi}]",
        wrong.lower,
        wrong.upper
    );
}
