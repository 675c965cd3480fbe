//! A log written onto a filesystem that fills up (a 256 KiB tmpfs of its own): the first
//! failed write is an error naming the file and "No space left on device", and every later
//! write, flush or finish of that file names the same first failure rather than the `mcap`
//! crate's bare "attempted another write after a write method failed". Needs root to mount (the
//! suite runs as root, CI too); fails where it cannot.

use std::path::{Path, PathBuf};
use std::process::Command;

use terl_telemetry::{MetricsWriter, TelemetryError};
use terl_wire::Metric;

struct Tmpfs(PathBuf);

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

fn mount_small(at: &Path) -> Tmpfs {
    std::fs::create_dir_all(at).unwrap();
    let out = Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=256k", "tmpfs"])
        .arg(at)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "cannot mount a tmpfs at {} (needs root, as ./deploy/test.sh and CI run): {}",
        at.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    Tmpfs(at.to_path_buf())
}

fn metric(i: u64) -> Metric {
    Metric {
        name: format!("loss/task-{}", i % 3),
        value: i as f64,
        step: i,
        unix_time_nanos: i,
    }
}

/// The error and its causes, as anyhow's `{:#}` prints them.
fn chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        text = format!("{text}: {c}");
        cause = c.source();
    }
    text
}

#[test]
fn after_a_failed_write_every_call_names_the_first_failure() {
    let dir = tempfile::tempdir().unwrap();
    let mount = dir.path().join("small");
    let _guard = mount_small(&mount);
    let path = mount.join("metrics.mcap");
    let mut w = MetricsWriter::create(&path).unwrap();
    // Write and flush until the filesystem refuses: a flush hands the chunk to the file.
    let mut first = None;
    for i in 0..1_000_000u64 {
        let result =
            w.write(&metric(i), i)
                .and_then(|()| if i % 500 == 499 { w.flush() } else { Ok(()) });
        if let Err(e) = result {
            first = Some((i, e));
            break;
        }
    }
    let (at, first) = first.expect("a 256 KiB filesystem filled up");
    assert!(at > 0, "the first writes fit");
    let first_text = chain(&first);
    assert!(
        matches!(
            first,
            TelemetryError::Mcap { .. } | TelemetryError::Io { .. }
        ),
        "{first:?}"
    );
    assert!(first.to_string().contains("metrics.mcap"), "{first}");
    // The cause is in the error's chain (anyhow prints it with `{:#}`).
    assert!(
        first_text.contains("No space left on device"),
        "{first_text}"
    );

    for later in [w.write(&metric(0), 0).unwrap_err(), w.flush().unwrap_err()] {
        let text = later.to_string();
        assert!(
            matches!(later, TelemetryError::AfterFailedWrite { .. }),
            "{later:?}"
        );
        assert!(text.contains("metrics.mcap"), "{text}");
        assert!(
            text.contains("No space left on device"),
            "{text} (first: {first_text})"
        );
    }
    let end = w.finish().unwrap_err().to_string();
    assert!(end.contains("No space left on device"), "{end}");
}
