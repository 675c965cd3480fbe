//! Damaged MCAP logs: a record length, a flipped byte or a cut anywhere never crashes the
//! readers; they keep the messages before the damage and say what stopped them.

use std::{fs, path::PathBuf};

use terl_telemetry::{read_log, read_tep_dataset, MetricsWriter};
use terl_wire::Metric;

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("terl-damage-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    dir
}

/// (offset, opcode, length) of every top-level record after the leading magic.
fn records(bytes: &[u8]) -> Vec<(usize, u8, u64)> {
    let mut out = Vec::new();
    let mut at = 8;
    while at + 9 <= bytes.len() {
        let opcode = bytes[at];
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap());
        out.push((at, opcode, len));
        match (at + 9).checked_add(len as usize) {
            Some(next) if next <= bytes.len() => at = next,
            _ => break,
        }
    }
    out
}

fn metric(i: usize) -> Metric {
    Metric {
        name: format!("loss/task-{}", i % 3),
        value: i as f64,
        step: i as u64,
        unix_time_nanos: 1_000 + i as u64,
    }
}

#[test]
fn damaged_record_length_keeps_the_messages_before_it() {
    let dir = temp("length");
    let path = dir.join("metrics.mcap");
    let mut w = MetricsWriter::create(&path).unwrap();
    for i in 0..300 {
        w.write(&metric(i), 1_000 + i as u64).unwrap();
        if i == 99 || i == 199 {
            w.flush().unwrap();
        }
    }
    w.finish().unwrap();
    let mut bytes = fs::read(&path).unwrap();
    const CHUNK: u8 = 0x06;
    let chunks: Vec<_> = records(&bytes).into_iter().filter(|r| r.1 == CHUNK).collect();
    // Chunk 1 holds schema and channel, then one chunk per 100 metrics.
    assert!(chunks.len() >= 3, "{chunks:?}");
    let (at, _, _) = chunks[2];
    bytes[at + 1..at + 9].copy_from_slice(&0xfff0_0000_0000_0000u64.to_le_bytes());
    fs::write(&path, &bytes).unwrap();
    let got = read_log::<Metric>(&path).unwrap();
    assert!(got.truncated);
    assert_eq!(got.records, (0..100).map(metric).collect::<Vec<_>>());
    let reason = got.truncation.unwrap();
    assert!(reason.contains("claims"), "{reason}");
    let _ = read_tep_dataset(&path);
    fs::remove_dir_all(&dir).unwrap();
}
