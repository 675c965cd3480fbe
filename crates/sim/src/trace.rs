//! Meta-World traces (JSON Lines, optionally gzip): reading, replaying through the Rust tasks,
//! writing, and comparing. Format: `shared/formats/metaworld-trace.md`.
//!
//! Line 1 is a header with `task` and `rand_vec`; line 2 the reset observation (`t` = 0); then one
//! line per step with `action`, `obs`, `reward`, `success` and `truncated`.

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::Path;

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use crate::error::{Result, SimError};
use crate::metaworld::{Env, ACTION_DIM, OBS_DIM};

/// One step line (the reset line has no action, reward, success or truncated).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TraceStep {
    /// Step index: 0 for the reset line, then 1, 2, ... (steps taken so far).
    pub t: u32,
    /// The 4 action values applied at this step (absent on the reset line).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub action: Option<Vec<f32>>,
    /// The 39-value observation after the step (or the reset).
    pub obs: Vec<f64>,
    /// Reward of the step.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub reward: Option<f64>,
    /// Meta-World's `info["success"]` as written by Python (1.0 or 0.0; > 0.5 counts as success).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub success: Option<f64>,
    /// Whether the step hit the time limit.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub truncated: Option<bool>,
}

/// A whole trace.
#[derive(Debug, Clone, PartialEq)]
pub struct Trace {
    /// All header keys (unknown ones are kept and written back).
    pub header: Map<String, Value>,
    /// Meta-World v3 task name, from the header.
    pub task: String,
    /// The episode's `rand_vec`, from the header.
    pub rand_vec: Vec<f64>,
    /// The reset line then one line per step, in file order.
    pub steps: Vec<TraceStep>,
}

fn bad(line: usize, msg: impl std::fmt::Display) -> SimError {
    SimError::Trace(format!("line {line}: {msg}"))
}

impl Trace {
    /// Reads a `.jsonl` or `.jsonl.gz` file (gzip detected by its magic bytes).
    pub fn read(path: &Path) -> Result<Self> {
        let io = |source| SimError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut file = File::open(path).map_err(io)?;
        let mut magic = [0u8; 2];
        let n = file.read(&mut magic).map_err(io)?;
        let file = File::open(path).map_err(io)?;
        let reader: Box<dyn BufRead> = if n == 2 && magic == [0x1f, 0x8b] {
            Box::new(BufReader::new(flate2::read::GzDecoder::new(file)))
        } else {
            Box::new(BufReader::new(file))
        };
        Self::parse(reader).map_err(|e| match e {
            SimError::Trace(m) => SimError::Trace(format!("{}: {m}", path.display())),
            other => other,
        })
    }

    /// Parses JSON Lines from a reader.
    pub fn parse(reader: impl BufRead) -> Result<Self> {
        let mut lines = reader.lines().enumerate();
        let (_, first) = lines.next().ok_or_else(|| bad(1, "empty trace"))?;
        let first = first.map_err(|e| bad(1, e))?;
        let header: Map<String, Value> =
            serde_json::from_str(&first).map_err(|e| bad(1, format!("header: {e}")))?;
        let task = header
            .get("task")
            .and_then(Value::as_str)
            .ok_or_else(|| bad(1, "header has no string `task`"))?
            .to_string();
        let rand_vec: Vec<f64> = header
            .get("rand_vec")
            .and_then(Value::as_array)
            .ok_or_else(|| bad(1, "header has no array `rand_vec`"))?
            .iter()
            .map(|v| {
                v.as_f64()
                    .ok_or_else(|| bad(1, "rand_vec holds a non-number"))
            })
            .collect::<Result<_>>()?;
        let mut steps = Vec::new();
        for (i, line) in lines {
            let line = line.map_err(|e| bad(i + 1, e))?;
            if line.trim().is_empty() {
                continue;
            }
            let step: TraceStep = serde_json::from_str(&line).map_err(|e| bad(i + 1, e))?;
            if step.obs.len() != OBS_DIM {
                return Err(bad(
                    i + 1,
                    format!("obs has length {}, expected {OBS_DIM}", step.obs.len()),
                ));
            }
            match &step.action {
                Some(a) if a.len() != ACTION_DIM => {
                    return Err(bad(
                        i + 1,
                        format!("action has length {}, expected {ACTION_DIM}", a.len()),
                    ))
                }
                None if !steps.is_empty() => return Err(bad(i + 1, "step line without action")),
                _ => {}
            }
            steps.push(step);
        }
        if steps.is_empty() {
            return Err(bad(2, "trace has no reset line"));
        }
        Ok(Self {
            header,
            task,
            rand_vec,
            steps,
        })
    }

    /// Writes JSON Lines (gzip if the path ends in `.gz`).
    pub fn write(&self, path: &Path) -> Result<()> {
        let io = |source| SimError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = File::create(path).map_err(io)?;
        let mut out: Box<dyn Write> = if path.extension().is_some_and(|e| e == "gz") {
            Box::new(BufWriter::new(flate2::write::GzEncoder::new(
                file,
                flate2::Compression::default(),
            )))
        } else {
            Box::new(BufWriter::new(file))
        };
        let json = |e: serde_json::Error| SimError::Trace(e.to_string());
        serde_json::to_writer(&mut out, &self.header).map_err(json)?;
        out.write_all(b"\n").map_err(io)?;
        for s in &self.steps {
            serde_json::to_writer(&mut out, s).map_err(json)?;
            out.write_all(b"\n").map_err(io)?;
        }
        out.flush().map_err(io)
    }

    /// Replays this trace's actions through the Rust task and returns the Rust trace (same
    /// header and actions, Rust observations, rewards, success flags and truncation).
    pub fn replay(&self) -> Result<Trace> {
        let mut env = Env::new(&self.task)?;
        let obs = env.reset(&self.rand_vec)?;
        let mut steps = Vec::with_capacity(self.steps.len());
        steps.push(TraceStep {
            t: 0,
            action: None,
            obs: obs.to_vec(),
            reward: None,
            success: None,
            truncated: None,
        });
        for s in &self.steps[1..] {
            let action = s.action.as_ref().expect("checked on parse");
            let out = env.step(action)?;
            steps.push(TraceStep {
                t: s.t,
                action: Some(action.clone()),
                obs: out.obs.to_vec(),
                reward: Some(out.reward),
                success: Some(if out.success { 1.0 } else { 0.0 }),
                truncated: Some(out.truncated),
            });
        }
        Ok(Trace {
            header: self.header.clone(),
            task: self.task.clone(),
            rand_vec: self.rand_vec.clone(),
            steps,
        })
    }
}

/// Per-field maximum errors between two traces of the same episode.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Comparison {
    /// Task of trace `a`.
    pub task: String,
    /// Lines of trace `a` (reset line included).
    pub steps_a: usize,
    /// Lines of trace `b`.
    pub steps_b: usize,
    /// Largest absolute observation difference (infinite if one side is NaN).
    pub obs_max_abs: f64,
    /// (step, obs index) of the largest observation error.
    pub obs_worst: (u32, usize),
    /// Largest absolute reward difference (infinite if one side is NaN).
    pub reward_max_abs: f64,
    /// Step of the largest reward difference.
    pub reward_worst_step: u32,
    /// Steps whose success flags disagree.
    pub success_mismatches: usize,
    /// First step whose success flags disagree.
    pub first_success_mismatch: Option<u32>,
    /// Steps whose truncation flags disagree.
    pub truncated_mismatches: usize,
    /// Steps whose actions are not identical.
    pub action_mismatches: usize,
}

/// Tolerances of the parity checks.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Tolerance {
    /// Largest allowed absolute observation difference (default 1e-4).
    pub obs: f64,
    /// Largest allowed absolute reward difference (default 1e-3).
    pub reward: f64,
}

impl Default for Tolerance {
    fn default() -> Self {
        Self {
            obs: 1e-4,
            reward: 1e-3,
        }
    }
}

impl Comparison {
    /// Compares step by step.
    pub fn of(a: &Trace, b: &Trace) -> Self {
        let mut c = Comparison {
            task: a.task.clone(),
            steps_a: a.steps.len(),
            steps_b: b.steps.len(),
            ..Default::default()
        };
        for (sa, sb) in a.steps.iter().zip(&b.steps) {
            for (i, (x, y)) in sa.obs.iter().zip(&sb.obs).enumerate() {
                let e = (x - y).abs();
                if e > c.obs_max_abs || e.is_nan() {
                    c.obs_max_abs = if e.is_nan() { f64::INFINITY } else { e };
                    c.obs_worst = (sa.t, i);
                }
            }
            if let (Some(x), Some(y)) = (sa.reward, sb.reward) {
                let e = (x - y).abs();
                if e > c.reward_max_abs || e.is_nan() {
                    c.reward_max_abs = if e.is_nan() { f64::INFINITY } else { e };
                    c.reward_worst_step = sa.t;
                }
            }
            if sa.success.map(|s| s > 0.5) != sb.success.map(|s| s > 0.5) {
                c.success_mismatches += 1;
                c.first_success_mismatch.get_or_insert(sa.t);
            }
            if sa.truncated.unwrap_or(false) != sb.truncated.unwrap_or(false) {
                c.truncated_mismatches += 1;
            }
            if sa.action != sb.action {
                c.action_mismatches += 1;
            }
        }
        c
    }

    /// Whether everything agrees within the tolerance.
    pub fn within(&self, tol: Tolerance) -> bool {
        self.steps_a == self.steps_b
            && self.obs_max_abs <= tol.obs
            && self.reward_max_abs <= tol.reward
            && self.success_mismatches == 0
            && self.truncated_mismatches == 0
            && self.action_mismatches == 0
    }
}
