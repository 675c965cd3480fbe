//! `terl render --checkpoint PATH --out DIR`: videos of the episodes `terl eval` scores. For
//! every task and goal variation, one deterministic episode ([`observe_episode`]: the same code
//! and the same episode as evaluation episode `k` on variation `k`), drawn offscreen from one of
//! the scene's cameras by MuJoCo's renderer ([`terl_sim::render`]), with the task, the step,
//! the success so far and the return so far burned into the top-left corner:
//!
//! - `<task>-v<k>.mp4`: H.264 (yuv420p, plays in a browser), one frame every `--every` env
//!   steps (the states after steps `every, 2·every, …, 500`: 500 / every frames), at `--fps`;
//!   encoded by `ffmpeg` (Debian package `ffmpeg`), streamed, so memory stays one frame;
//! - `<task>-v<k>.png`: a strip of three frames: the start (after the reset), the first
//!   success (else the video frame with the highest reward, "nearest the goal"), the end;
//! - `render.json`: per episode the success flag, first-success step, return, frame count and
//!   the files; rewritten after every episode, with `complete: false` until the last one, so
//!   it always describes this render's files (a render killed mid-way leaves a true, partial
//!   list; its `*.<pid>.part` leftovers are removed by the next render into the folder).

use std::io::{IsTerminal, Write as _};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, ExitCode, Stdio};
use terl_runtime::flags;

use anyhow::{bail, Context, Result};
use clap::Args;
use plotters::prelude::*;
use serde::Serialize;
use terl_rl::Policy;
use terl_runtime::eval::{observe_episode, Episode, EvalError, EvalTask, UnseenTaskEncoding};
use terl_sim::metaworld::{goal_variations, MAX_PATH_LENGTH, NUM_VARIATIONS};
use terl_sim::render::{Frame, Renderer, MAX_SIDE};
use terl_sim::Env;

use crate::eval::PolicyAndTasks;

#[derive(Debug, Args)]
pub struct RenderArgs {
    /// A checkpoint (`.safetensors`), or a run folder (its newest checkpoint).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Tasks: a task set (mt10, mt-test, ...; see `terl env list`) or comma-separated names
    /// (default: the tasks the checkpoint was trained on).
    #[arg(long)]
    pub tasks: Option<String>,
    /// Goal variations to render, comma-separated indices in 0..50 (evaluation episode `k`
    /// runs variation `k`).
    #[arg(long, default_value = "0")]
    pub variations: String,
    /// Camera of the Meta-World scene: corner, corner2, corner3, corner4, topview,
    /// behindGripper, gripperPOV.
    #[arg(long, default_value = "corner")]
    pub camera: String,
    /// Frame size WIDTHxHEIGHT in pixels, both even (H.264's 4:2:0 sampling), at most 4096.
    #[arg(long, default_value = "480x480")]
    pub size: String,
    /// One video frame every N env steps (the frame skip): 500 / N frames per episode.
    #[arg(long, value_parser = flags::count::<u32>(u64::from(MAX_PATH_LENGTH)), default_value_t = 2)]
    pub every: u32,
    /// Frames per second of the video (Meta-World's control rate is 80 steps/s: `--every 2
    /// --fps 40` plays in real time).
    #[arg(long, value_parser = flags::count::<u32>(240), default_value_t = 40)]
    pub fps: u32,
    /// Seed of the goal variations (default: the run's variation_seed, else 0).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Task vector of a task the policy was not trained on (as `terl eval`).
    #[arg(long)]
    pub unseen_task_encoding: Option<UnseenTaskEncoding>,
    /// The task list the checkpoint was trained on, in order (default: the run's config.toml).
    #[arg(long)]
    pub trained_tasks: Option<String>,
    /// Output folder (created).
    #[arg(long)]
    pub out: PathBuf,
}

/// One rendered episode, as `render.json` lists it.
#[derive(Debug, Serialize)]
struct RenderedEpisode {
    task: String,
    variation: usize,
    success: bool,
    first_success_step: Option<u32>,
    episode_return: f64,
    steps: u32,
    unstable: bool,
    frames: u64,
    video: String,
    strip: String,
}

#[derive(Debug, Serialize)]
struct RenderOutput {
    checkpoint: String,
    policy_version: u64,
    camera: String,
    width: u32,
    height: u32,
    every: u32,
    fps: u32,
    variation_seed: u64,
    /// False while the render runs (the episodes listed are the ones finished so far, their
    /// files in place); true once every requested episode is written.
    complete: bool,
    episodes: Vec<RenderedEpisode>,
}

impl RenderOutput {
    /// Replaces `<out>/render.json` (through a temporary file and a rename).
    fn write(&self, out: &Path) -> Result<()> {
        let json_path = out.join("render.json");
        let json = serde_json::to_vec_pretty(self)?;
        write_atomically(&json_path, |part| {
            std::fs::write(part, &json).with_context(|| format!("writing {}", json_path.display()))
        })
    }
}

/// `WIDTHxHEIGHT`, both even and in 2..=MAX_SIDE.
fn parse_size(s: &str) -> Result<(u32, u32)> {
    let bad = || {
        anyhow::anyhow!(
            "--size {s:?}: expected WIDTHxHEIGHT, two even numbers of pixels in 2..={MAX_SIDE} \
             (e.g. 480x480)"
        )
    };
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let w: u32 = w.trim().parse().map_err(|_| bad())?;
    let h: u32 = h.trim().parse().map_err(|_| bad())?;
    if !(2..=MAX_SIDE).contains(&w) || !(2..=MAX_SIDE).contains(&h) || w % 2 == 1 || h % 2 == 1 {
        return Err(bad());
    }
    Ok((w, h))
}

fn parse_variations(s: &str) -> Result<Vec<usize>> {
    let mut out = Vec::new();
    for part in s.split(',') {
        let k: usize = part.trim().parse().map_err(|_| {
            anyhow::anyhow!("--variations {s:?}: {part:?} is not an index in 0..{NUM_VARIATIONS}")
        })?;
        if k >= NUM_VARIATIONS {
            bail!("--variations {s:?}: {k} is not an index in 0..{NUM_VARIATIONS}");
        }
        if !out.contains(&k) {
            out.push(k);
        }
    }
    Ok(out)
}

/// An `ffmpeg` process encoding raw RGB frames from its stdin into an MP4 (H.264, yuv420p) at
/// `part`, renamed to the final name by [`Encoder::finish`].
pub(crate) struct Encoder {
    child: Child,
    stdin: Option<ChildStdin>,
    part: PathBuf,
    path: PathBuf,
    frames: u64,
    /// The video was written and renamed.
    done: bool,
}

impl Encoder {
    fn start(path: &Path, width: u32, height: u32, fps: u32) -> Result<Self> {
        let part = part_path(path);
        let mut child = Command::new("ffmpeg")
            .args(["-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo"])
            .args(["-pixel_format", "rgb24", "-video_size"])
            .arg(format!("{width}x{height}"))
            .arg("-framerate")
            .arg(fps.to_string())
            .args(["-i", "-", "-c:v", "libx264", "-pix_fmt", "yuv420p"])
            .args(["-movflags", "+faststart", "-f", "mp4"])
            .arg(&part)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| {
                if e.kind() == std::io::ErrorKind::NotFound {
                    anyhow::anyhow!(
                        "ffmpeg is not on PATH: install Debian's ffmpeg package (./deploy/setup.sh \
                         does) to write MP4 videos"
                    )
                } else {
                    anyhow::anyhow!("cannot start ffmpeg: {e}")
                }
            })?;
        let stdin = child.stdin.take();
        Ok(Self {
            child,
            stdin,
            part,
            path: path.to_owned(),
            frames: 0,
            done: false,
        })
    }

    fn push(&mut self, frame: &Frame) -> std::result::Result<(), String> {
        let Some(stdin) = self.stdin.as_mut() else {
            return Err("ffmpeg's input is closed".into());
        };
        if let Err(e) = stdin.write_all(&frame.rgb) {
            let (status, stderr) = self.wait();
            return Err(format!(
                "ffmpeg stopped reading frames ({e}; {}): {stderr}",
                status.map_or_else(|| "its status is unknown".into(), |s| s.to_string())
            ));
        }
        self.frames += 1;
        Ok(())
    }

    /// Closes ffmpeg's input and waits for it: its exit status (if waiting worked) and its
    /// error output.
    fn wait(&mut self) -> (Option<std::process::ExitStatus>, String) {
        drop(self.stdin.take());
        let mut stderr = String::new();
        if let Some(mut e) = self.child.stderr.take() {
            let _ = std::io::Read::read_to_string(&mut e, &mut stderr);
        }
        (self.child.wait().ok(), stderr.trim().to_string())
    }

    fn finish(mut self) -> Result<u64> {
        let (status, stderr) = self.wait();
        if !status.is_some_and(|s| s.success()) {
            let _ = std::fs::remove_file(&self.part);
            bail!(
                "ffmpeg failed ({}): {stderr}",
                status.map_or_else(|| "status unknown".into(), |s| s.to_string())
            );
        }
        std::fs::rename(&self.part, &self.path).with_context(|| {
            format!(
                "renaming {} to {}",
                self.part.display(),
                self.path.display()
            )
        })?;
        self.done = true;
        Ok(self.frames)
    }
}

impl Drop for Encoder {
    fn drop(&mut self) {
        // Dropped without a successful `finish` (an error): stop ffmpeg, remove its partial file.
        if !self.done {
            let _ = self.child.kill();
            let _ = self.child.wait();
            let _ = std::fs::remove_file(&self.part);
        }
    }
}

/// Burns up to two lines of text into the top-left corner of `frame` (white on a dark box).
fn caption(frame: &mut Frame, lines: &[String]) -> Result<()> {
    let (w, h) = (frame.width, frame.height);
    let size = (h / 22).clamp(8, 40);
    let root = BitMapBackend::with_buffer(&mut frame.rgb, (w, h)).into_drawing_area();
    let style = ("sans-serif", size).into_font().color(&WHITE);
    let width = lines
        .iter()
        .map(|l| root.estimate_text_size(l, &style).map_or(0, |(x, _)| x))
        .max()
        .unwrap_or(0);
    let line_h = size as i32 + size as i32 / 3;
    let pad = (size / 3) as i32;
    root.draw(&Rectangle::new(
        [
            (0, 0),
            (width as i32 + 2 * pad, line_h * lines.len() as i32 + pad),
        ],
        BLACK.mix(0.6).filled(),
    ))
    .map_err(|e| anyhow::anyhow!("drawing the caption: {e}"))?;
    for (i, l) in lines.iter().enumerate() {
        root.draw(&Text::new(
            l.as_str(),
            (pad, pad + line_h * i as i32),
            style.clone(),
        ))
        .map_err(|e| anyhow::anyhow!("drawing the caption: {e}"))?;
    }
    root.present()
        .map_err(|e| anyhow::anyhow!("drawing the caption: {e}"))?;
    Ok(())
}

/// Where a file is written before it is renamed to `path`: `<name>.<pid>.part` beside it, so a
/// killed writer leaves no file under the final name and two writers never share one.
pub(crate) fn part_path(path: &Path) -> PathBuf {
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    path.with_file_name(format!("{name}.{}.part", std::process::id()))
}

/// Removes the `<name>.<pid>.part` files of videos, strips and `render.json` in `dir` whose
/// writer no longer runs (a render killed mid-file); parts of a live process and files of any
/// other name are left alone. Returns how many went.
pub(crate) fn remove_stale_parts(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for entry in entries.filter_map(std::result::Result::ok) {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some((file, pid)) = name
            .strip_suffix(".part")
            .and_then(|stem| stem.rsplit_once('.'))
            .and_then(|(file, pid)| Some((file, pid.parse::<u32>().ok()?)))
        else {
            continue;
        };
        let ours = file.ends_with(".mp4") || file.ends_with(".png") || file == "render.json";
        if !ours {
            continue;
        }
        let alive = pid == std::process::id() || Path::new(&format!("/proc/{pid}")).exists();
        if !alive && std::fs::remove_file(entry.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// Writes `path` through [`part_path`] and a rename (`write` gets the temporary path).
fn write_atomically(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let part = part_path(path);
    if let Err(e) = write(&part) {
        let _ = std::fs::remove_file(&part);
        return Err(e);
    }
    std::fs::rename(&part, path).with_context(|| {
        let _ = std::fs::remove_file(&part);
        format!("renaming {} to {}", part.display(), path.display())
    })
}

/// Rows of frames side by side, separated by 4 white pixels, as a PNG (every frame the size of
/// the first).
pub(crate) fn write_grid(path: &Path, rows: &[Vec<Frame>]) -> Result<()> {
    let first = rows.iter().flatten().next().context("no frames to write")?;
    let (w, h) = (first.width, first.height);
    let gap = 4u32;
    let cols = rows.iter().map(Vec::len).max().unwrap_or(1) as u32;
    let n = rows.len() as u32;
    let mut img = image::RgbImage::from_pixel(
        w * cols + gap * (cols - 1),
        h * n + gap * (n - 1),
        image::Rgb([255, 255, 255]),
    );
    for (r, row) in rows.iter().enumerate() {
        for (c, f) in row.iter().enumerate() {
            let tile = image::RgbImage::from_raw(f.width, f.height, f.rgb.clone())
                .context("a frame's size does not match its pixels")?;
            let (x, y) = (c as u32 * (w + gap), r as u32 * (h + gap));
            image::imageops::replace(&mut img, &tile, i64::from(x), i64::from(y));
        }
    }
    write_atomically(path, |part| {
        img.save_with_format(part, image::ImageFormat::Png)
            .with_context(|| format!("writing {}", path.display()))
    })
}

/// What a rendered episode keeps for its strip.
#[derive(Default)]
struct StripFrames {
    start: Option<Frame>,
    /// The first success's frame.
    success: Option<Frame>,
    /// Else the best-reward video frame `(reward, frame)`.
    nearest: Option<(f64, Frame)>,
    end: Option<Frame>,
}

/// One episode's three strip frames (after the reset; the first success, else the video frame
/// with the highest reward; the last step) and its outcome.
pub(crate) struct EpisodeFrames {
    pub(crate) tiles: Vec<Frame>,
    pub(crate) outcome: Episode,
}

/// Where and how [`record_episode`] draws.
pub(crate) struct Shot<'a> {
    pub(crate) camera: &'a str,
    /// A video frame every this many env steps (also the candidates for "nearest the goal").
    pub(crate) every: u32,
    /// The caption's first words (`reach-v3`, `MTSAC seed 1`).
    pub(crate) label: &'a str,
}

/// Runs evaluation episode `k` of `task` ([`observe_episode`]) in `env`, drawing it with
/// `renderer`: every `shot.every`-th state goes to `encoder` (if any), captioned; the strip's
/// frames are kept.
#[allow(clippy::too_many_arguments)]
pub(crate) fn record_episode(
    policy: &Policy,
    task: &EvalTask,
    env: &mut Env,
    renderer: &mut Renderer,
    variations: &[Vec<f64>],
    k: usize,
    shot: &Shot<'_>,
    mut encoder: Option<&mut Encoder>,
    progress: &dyn Fn(u64),
) -> Result<EpisodeFrames> {
    let mut strip = StripFrames::default();
    let mut ret = 0.0f64;
    let mut steps = 0u32;
    let mut first_success: Option<u32> = None;
    let mut failure: Option<anyhow::Error> = None;
    let label = shot.label;
    let outcome = {
        let mut observe = |env: &Env, step: Option<&terl_sim::Step>| -> Result<(), EvalError> {
            let fail = |e: anyhow::Error, slot: &mut Option<anyhow::Error>| {
                let text = format!("{e:#}");
                *slot = Some(e);
                EvalError::Observer(text)
            };
            let sim = &env.scene().sim;
            let Some(step) = step else {
                let mut f = renderer
                    .render_upright(sim, shot.camera)
                    .map_err(EvalError::Sim)?;
                caption(&mut f, &[format!("{label} · variation {k} · start")])
                    .map_err(|e| fail(e, &mut failure))?;
                strip.start = Some(f);
                return Ok(());
            };
            steps += 1;
            ret += f64::from(step.reward as f32);
            let new_success = step.success && first_success.is_none();
            if new_success {
                first_success = Some(steps);
            }
            let video_frame = steps.is_multiple_of(shot.every);
            let last = steps >= MAX_PATH_LENGTH || step.truncated;
            progress(1);
            if !(video_frame || new_success || last) {
                return Ok(());
            }
            let mut f = renderer
                .render_upright(sim, shot.camera)
                .map_err(EvalError::Sim)?;
            let status = match first_success {
                Some(s) => format!("success at step {s}"),
                None => "no success yet".to_string(),
            };
            caption(
                &mut f,
                &[
                    format!("{label} · variation {k} · step {steps}"),
                    format!("{status} · return {ret:.1}"),
                ],
            )
            .map_err(|e| fail(e, &mut failure))?;
            if video_frame {
                if let Some(enc) = encoder.as_deref_mut() {
                    enc.push(&f)
                        .map_err(|e| fail(anyhow::anyhow!(e), &mut failure))?;
                }
                let better = strip.nearest.as_ref().is_none_or(|(r, _)| step.reward > *r);
                if first_success.is_none() && better {
                    strip.nearest = Some((step.reward, f.clone()));
                }
            }
            if new_success {
                strip.success = Some(f.clone());
            }
            if last {
                strip.end = Some(f);
            }
            Ok(())
        };
        observe_episode(policy, env, task, variations, k, &mut observe)
    };
    let outcome = match (outcome, failure) {
        (Ok(o), _) => o,
        (Err(_), Some(e)) => return Err(e),
        (Err(e), None) => return Err(e.into()),
    };
    let middle = strip.success.or(strip.nearest.map(|(_, f)| f));
    let tiles: Vec<Frame> = [strip.start, middle, strip.end]
        .into_iter()
        .flatten()
        .collect();
    Ok(EpisodeFrames { tiles, outcome })
}

#[allow(clippy::too_many_lines)] // one episode's frames, overlay and files in order
pub fn run(args: RenderArgs) -> Result<ExitCode> {
    let size = parse_size(&args.size)?;
    let variation_list = parse_variations(&args.variations)?;
    if args.every == 0 || args.every > MAX_PATH_LENGTH {
        bail!("--every must be in 1..={MAX_PATH_LENGTH} env steps");
    }
    if !(1..=240).contains(&args.fps) {
        bail!("--fps must be in 1..=240");
    }
    crate::font::register_font()?;
    let loaded = PolicyAndTasks::load(
        &args.checkpoint,
        args.trained_tasks.as_deref(),
        args.tasks.as_deref(),
        args.unseen_task_encoding,
    )?;
    let seed = loaded.variation_seed(args.seed);
    let mut out = RenderOutput {
        checkpoint: loaded.ckpt.path.display().to_string(),
        policy_version: loaded.ckpt.policy.version,
        camera: args.camera.clone(),
        width: size.0,
        height: size.1,
        every: args.every,
        fps: args.fps,
        variation_seed: seed,
        complete: false,
        episodes: Vec::new(),
    };
    let total = (loaded.tasks.len() * variation_list.len()) as u64 * u64::from(MAX_PATH_LENGTH);
    let bar = std::io::stderr().is_terminal().then(|| {
        let bar = indicatif::ProgressBar::new(total);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} env steps  {elapsed_precise} (eta {eta})",
        ) {
            bar.set_style(style);
        }
        bar
    });
    let progress = |n: u64| {
        if let Some(b) = &bar {
            b.inc(n);
        }
    };
    // Held from the folder's creation to the end: one render writes into a folder at a time.
    let mut lock: Option<std::fs::File> = None;
    for task in &loaded.tasks {
        let mut env = Env::for_rendering(task.name)?;
        let mut renderer = Renderer::new(&env.scene().sim, size.0, size.1)?;
        if !renderer.cameras().iter().any(|c| c == &args.camera) {
            bail!(
                "{}: no camera {:?}; the scene has {}",
                task.name,
                args.camera,
                renderer.cameras().join(", ")
            );
        }
        if out.episodes.is_empty() {
            // The folder is made once the first scene has the camera; from then on render.json
            // names only this render's finished episodes.
            std::fs::create_dir_all(&args.out)
                .with_context(|| format!("creating {}", args.out.display()))?;
            lock = Some(crate::folder_lock::lock_folder(
                &args.out,
                ".render.lock",
                "terl render",
            )?);
            let stale = remove_stale_parts(&args.out);
            if stale > 0 {
                eprintln!(
                    "removed {stale} partial file(s) an interrupted render left in {}",
                    args.out.display()
                );
            }
            out.write(&args.out)?;
        }
        let variations = goal_variations(task.name, seed)?;
        for &k in &variation_list {
            let stem = format!("{}-v{k}", task.name);
            let video = args.out.join(format!("{stem}.mp4"));
            let strip = args.out.join(format!("{stem}.png"));
            let mut encoder = Encoder::start(&video, size.0, size.1, args.fps)?;
            let shot = Shot {
                camera: &args.camera,
                every: args.every,
                label: task.name,
            };
            let got = record_episode(
                &loaded.ckpt.policy,
                task,
                &mut env,
                &mut renderer,
                &variations,
                k,
                &shot,
                Some(&mut encoder),
                &progress,
            )
            .with_context(|| format!("rendering {stem}"))?;
            let frames = encoder.finish()?;
            write_grid(&strip, std::slice::from_ref(&got.tiles))?;
            let o = got.outcome;
            out.episodes.push(RenderedEpisode {
                task: task.name.to_string(),
                variation: k,
                success: o.first_success.is_some(),
                first_success_step: o.first_success,
                episode_return: o.ret,
                steps: o.steps,
                unstable: o.unstable,
                frames,
                video: format!("{stem}.mp4"),
                strip: format!("{stem}.png"),
            });
            out.write(&args.out)?;
        }
    }
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    out.complete = true;
    out.write(&args.out)?;
    drop(lock);
    for e in &out.episodes {
        println!(
            "{}  variation {:>2}  {}  return {:>8.1}  {} frames  {}  {}",
            e.task,
            e.variation,
            match e.first_success_step {
                Some(s) => format!("success at step {s:>3}"),
                None => "no success         ".to_string(),
            },
            e.episode_return,
            e.frames,
            args.out.join(&e.video).display(),
            e.strip
        );
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_variations_parse_or_say_why_not() {
        assert_eq!(parse_size("480x320").unwrap(), (480, 320));
        assert_eq!(parse_size("64X64").unwrap(), (64, 64));
        for bad in ["481x480", "480", "0x0", "8192x480", "axb", "480x-2"] {
            let e = parse_size(bad).unwrap_err().to_string();
            assert!(e.contains("WIDTHxHEIGHT"), "{bad}: {e}");
        }
        assert_eq!(parse_variations("3, 0,3").unwrap(), vec![3, 0]);
        for bad in ["50", "-1", "a", ""] {
            assert!(parse_variations(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn only_the_parts_of_writers_that_are_gone_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        // A child that has exited (and been reaped) is a pid no process holds any more.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let gone = child.id();
        child.wait().unwrap();
        let names = [
            format!("reach-v3-v0.mp4.{gone}.part"),
            format!("reach-v3-v0.png.{}.part", std::process::id()),
            "notes.part".to_string(),
            format!("notes.txt.{gone}.part"),
            "reach-v3-v0.mp4".to_string(),
        ];
        for n in &names {
            std::fs::write(dir.path().join(n), b"x").unwrap();
        }
        assert_eq!(remove_stale_parts(dir.path()), 1);
        assert!(!dir.path().join(&names[0]).exists());
        for n in &names[1..] {
            assert!(dir.path().join(n).exists(), "{n}");
        }
    }
}
