//! CPU time and resident memory of a process (Linux `/proc/<pid>/stat` through the `procfs`
//! crate), for `terl status` and the learner's metrics log. Whether a run is learner- or
//! actor-bound is judged from the share of the learner's time spent in updates
//! (`charts/update_share`), not from these counters.

use std::time::{Duration, Instant};

/// One reading of a process's counters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Usage {
    /// User plus system CPU time since the process started, in seconds (all threads).
    pub cpu_seconds: f64,
    /// Resident set size, in bytes.
    pub rss_bytes: u64,
    /// Threads of the process.
    pub threads: u64,
    /// When it was read.
    pub at: Instant,
    /// The process has exited and waits to be reaped (a zombie, state `Z`) or is dead (`X`).
    pub exited: bool,
}

/// Why a process could not be read.
#[derive(Debug, thiserror::Error)]
#[error("cannot read /proc/{pid}: {source}")]
pub struct UsageError {
    /// The process id asked for (0: this process).
    pub pid: u32,
    /// What `procfs` reported (the process is gone, or another user's).
    #[source]
    pub source: procfs::ProcError,
}

/// Reads the counters of process `pid`, or of this process with `None`.
///
/// # Errors
/// The process does not exist (any more) or its `/proc` files cannot be read.
pub fn usage(pid: Option<u32>) -> Result<Usage, UsageError> {
    let err = |source| UsageError {
        pid: pid.unwrap_or(0),
        source,
    };
    let process = match pid {
        None => procfs::process::Process::myself(),
        Some(p) => procfs::process::Process::new(i32::try_from(p).unwrap_or(i32::MAX)),
    }
    .map_err(err)?;
    let stat = process.stat().map_err(err)?;
    let ticks = procfs::ticks_per_second() as f64;
    Ok(Usage {
        cpu_seconds: (stat.utime + stat.stime) as f64 / ticks,
        rss_bytes: stat.rss * procfs::page_size(),
        threads: u64::try_from(stat.num_threads).unwrap_or(0),
        at: Instant::now(),
        exited: matches!(stat.state, 'Z' | 'X' | 'x'),
    })
}

/// CPU use between two readings of one process, in cores (1.0 = one core fully busy); 0 when
/// no time passed.
pub fn cores_between(earlier: &Usage, later: &Usage) -> f64 {
    let wall = later.at.saturating_duration_since(earlier.at).as_secs_f64();
    if wall <= 0.0 {
        return 0.0;
    }
    ((later.cpu_seconds - earlier.cpu_seconds) / wall).max(0.0)
}

/// CPU use of each of `pids` over `window` (two readings, `window` apart), in cores, with its
/// resident set size at the end; `None` for a process that could not be read.
pub fn sample(pids: &[u32], window: Duration) -> Vec<Option<(f64, u64)>> {
    let first: Vec<_> = pids.iter().map(|&p| usage(Some(p)).ok()).collect();
    std::thread::sleep(window);
    pids.iter()
        .zip(first)
        .map(|(&p, a)| {
            let b = usage(Some(p)).ok()?;
            Some((cores_between(&a?, &b), b.rss_bytes))
        })
        .collect()
}

/// The cores this machine offers the process (`available_parallelism`: affinity and cgroup
/// quotas).
pub fn available_cores() -> usize {
    std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
}

/// The machine's online CPUs (`/proc/cpuinfo`), whatever this process's own affinity: what a
/// cluster's processes share. Falls back to [`available_cores`].
pub fn machine_cores() -> usize {
    <procfs::CpuInfo as procfs::Current>::current()
        .map(|c| c.num_cores())
        .ok()
        .filter(|&n| n > 0)
        .unwrap_or_else(available_cores)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The thread's own CPU clock in seconds (`/proc/thread-self/schedstat`, nanoseconds on
    /// CPU): the second path the process's CPU time is checked against.
    fn thread_cpu_seconds() -> f64 {
        let text = std::fs::read_to_string("/proc/thread-self/schedstat").unwrap();
        text.split_whitespace()
            .next()
            .unwrap()
            .parse::<f64>()
            .unwrap()
            / 1e9
    }

    /// A thread that spins for 0.3 s of its own CPU time adds that much to the process's CPU
    /// time (whatever the machine's load: both count CPU time, not wall time); RSS grows by what
    /// the test touches, checked against `/proc/self/statm`.
    #[test]
    fn a_busy_thread_is_one_core_and_touched_memory_is_resident() {
        let before = usage(None).unwrap();
        let spent = std::thread::spawn(|| {
            let start = thread_cpu_seconds();
            let mut x = 0u64;
            while thread_cpu_seconds() - start < 0.3 {
                for _ in 0..10_000 {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            }
            thread_cpu_seconds() - start
        })
        .join()
        .unwrap();
        let after = usage(None).unwrap();
        let cpu = after.cpu_seconds - before.cpu_seconds;
        // Clock ticks are 10 ms; the waiting main thread adds next to nothing.
        assert!(
            cpu >= spent - 0.03 && cpu <= spent + 0.15,
            "process CPU {cpu} s for a thread that spent {spent} s"
        );
        let cores = cores_between(&before, &after);
        assert!(cores > 0.0 && cores.is_finite(), "{cores}");
        // 64 MB touched page by page must show as resident.
        let big = vec![1u8; 64 << 20];
        let with = usage(None).unwrap();
        std::hint::black_box(&big);
        let statm = std::fs::read_to_string("/proc/self/statm").unwrap();
        let resident_pages: u64 = statm.split_whitespace().nth(1).unwrap().parse().unwrap();
        let statm_bytes = resident_pages * procfs::page_size();
        assert!(
            with.rss_bytes >= after.rss_bytes + (60 << 20),
            "{with:?} after {after:?}"
        );
        let diff = statm_bytes.abs_diff(with.rss_bytes);
        assert!(
            diff < (8 << 20),
            "procfs {} vs statm {statm_bytes}",
            with.rss_bytes
        );
        assert!(with.threads >= 1);
        assert!(usage(Some(u32::MAX)).is_err(), "no such process");
    }
}
