//! Recording and replay: a recorded `cooperative_push` run replays to the same world snapshots, the
//! file is readable MCAP with Foxglove scene messages, a recorder killed mid-run leaves a complete
//! file up to its last flushed chunk (checked with Python's reference reader too when it is
//! installed), and `coordinator recover` gives such a file its summary.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use behaviours::Registry;
use coordinator::{Instruments, Plan, Transport};

/// One test's scratch directory, removed with its recordings when the test is done.
fn scratch() -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix("pocketfleet-record-")
        .tempdir()
        .unwrap()
}

fn plan(behaviour: &str, transport: Transport) -> Plan {
    Plan::sim(behaviour)
        .transport(transport)
        .duration(Duration::from_secs(150))
}

/// Runs on its own thread so each run has its own actix system.
fn run(plan: Plan, instruments: Instruments) -> coordinator::Run {
    std::thread::spawn(move || {
        let registry = Registry::builtin();
        coordinator::run_blocking_with(plan, &registry, instruments).expect("the run completes")
    })
    .join()
    .expect("run thread")
}

fn messages(path: &Path) -> Vec<(String, serde_json::Value)> {
    let bytes = std::fs::read(path).unwrap();
    mcap::MessageStream::new(&bytes)
        .expect("a complete MCAP file")
        .map(|m| {
            let m = m.expect("every message reads");
            (
                m.channel.topic.clone(),
                serde_json::from_slice(&m.data).expect("JSON message"),
            )
        })
        .collect()
}

#[test]
fn recorded_cooperative_push_replays_to_identical_world_snapshots() {
    let scratch = scratch();
    let path = scratch.path().join("push.mcap");
    let recorded = run(
        plan("cooperative_push", Transport::Sim),
        Instruments {
            record: Some(path.clone()),
            ..Instruments::default()
        },
    );
    let (_, stats) = recorded.recording.clone().expect("a recording");
    let secs = recorded.report.experiment_time.as_secs_f64();
    println!(
        "recorded {:.1} s of cooperative_push: {} messages ({} packets), {} bytes, {:.0} bytes/s",
        secs,
        stats.messages,
        stats.packets,
        stats.bytes,
        stats.bytes as f64 / secs
    );
    assert!(stats.packets > 1000, "{stats:?}");

    // Readable by the mcap crate, every topic present, Foxglove's scene names each robot.
    let all = messages(&path);
    for topic in ["/packets", "/world", "/events", "/scene", "/poses"] {
        assert!(all.iter().any(|(t, _)| t == topic), "no {topic} message");
    }
    let ids: std::collections::BTreeSet<&str> = all
        .iter()
        .filter(|(t, _)| t == "/scene")
        .flat_map(|(_, s)| s["entities"].as_array().unwrap())
        .filter_map(|e| e["id"].as_str())
        .collect();
    for id in ["track", "box-0", "robot-1", "robot-2", "trail-1", "trail-2"] {
        assert!(ids.contains(id), "no scene entity {id}: {ids:?}");
    }
    assert!(all
        .iter()
        .any(|(t, v)| t == "/packets" && v["dir"] == "tx" && v["type"] == "StraightMovement"));
    let verdict = &all.iter().rev().find(|(t, _)| t == "/events").unwrap().1;
    assert_eq!(verdict["kind"], "verdict");
    assert_eq!(
        verdict["success"],
        serde_json::json!(recorded.report.success())
    );

    // A finished recording recovers to the same messages, chunk for chunk.
    let again = scratch.path().join("push-recovered.mcap");
    let kept = coordinator::instruments::recover::recover_file(&path, &again).unwrap();
    assert_eq!(
        kept.ending,
        coordinator::instruments::recover::Ending::Complete
    );
    assert_eq!(kept.messages, stats.messages);
    let (before, after) = (
        std::fs::read(&path).unwrap(),
        std::fs::read(&again).unwrap(),
    );
    let summaries = [&before, &after].map(|b| mcap::Summary::read(b).unwrap().unwrap());
    assert_eq!(summaries[0].stats, summaries[1].stats);
    assert_eq!(
        summaries[0].chunk_indexes.len(),
        summaries[1].chunk_indexes.len()
    );
    assert_eq!(
        messages(&again)
            .into_iter()
            .map(|(t, _)| t)
            .collect::<Vec<_>>(),
        all.iter().map(|(t, _)| t.clone()).collect::<Vec<_>>()
    );

    // Replayed through fresh robot actors, the supervisor and the behaviour.
    let replayed = run(
        plan("cooperative_push", Transport::Replay(path.clone())),
        Instruments::default(),
    );
    let check = replayed.replay.expect("a replay check");
    println!("{check}");
    assert!(check.snapshots > 100, "{check}");
    assert!(check.views >= 2 * (check.snapshots - 10), "{check}");
    assert!(check.exact(), "{check}");
}

/// What Python's reference MCAP reader (PyPI `mcap`) makes of a file: the messages
/// `make_reader(f).iter_messages()` yields, and the summary's message count (`None` without a
/// summary). `None` when the package is missing, unless `POCKETFLEET_REQUIRE_PYMCAP=1`.
fn python_reads(path: &Path) -> Option<(u64, Option<u64>)> {
    const SCRIPT: &str = "
import sys
from mcap.reader import make_reader
with open(sys.argv[1], 'rb') as f:
    n = sum(1 for _ in make_reader(f).iter_messages())
with open(sys.argv[1], 'rb') as f:
    s = make_reader(f).get_summary()
print(n, -1 if s is None or s.statistics is None else s.statistics.message_count)
";
    let have = Command::new("python3")
        .args(["-c", "import mcap.reader"])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !have {
        assert!(
            std::env::var("POCKETFLEET_REQUIRE_PYMCAP").as_deref() != Ok("1"),
            "POCKETFLEET_REQUIRE_PYMCAP=1 but python3 cannot import mcap (pip install mcap)"
        );
        println!("skipped the Python reader's check: python3 cannot import mcap");
        return None;
    }
    let out = Command::new("python3")
        .args(["-c", SCRIPT])
        .arg(path)
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "Python's mcap reader failed on {}: {}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let mut words = text.split_whitespace().map(|w| w.parse::<i64>().unwrap());
    let (n, summary) = (words.next().unwrap(), words.next().unwrap());
    Some((n as u64, u64::try_from(summary).ok()))
}

fn coordinator(args: &[&std::ffi::OsStr]) -> std::process::Output {
    let out = Command::new(env!("CARGO_BIN_EXE_coordinator"))
        .args(args)
        .output()
        .expect("coordinator runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    out
}

#[test]
fn a_killed_recorder_leaves_a_complete_file_that_recover_indexes() {
    let scratch = scratch();
    let path = scratch.path().join("killed.mcap");
    let mut child = Command::new(env!("CARGO_BIN_EXE_coordinator"))
        .args(["--behaviour", "teleop", "--duration", "3000", "--record"])
        .arg(&path)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("coordinator starts");
    // Wait for a few closed chunks (the writer closes one every 256 KiB, and at least every
    // 0.5 s).
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let len = std::fs::metadata(&path).map_or(0, |m| m.len());
        if len > 1_000_000 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the recording did not grow: {len} bytes"
        );
        assert!(
            child.try_wait().unwrap().is_none(),
            "coordinator ended early"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    child.kill().unwrap(); // SIGKILL: no chance to finish the file.
    child.wait().unwrap();

    // The file on disk only ever grows by whole chunks followed by a provisional end, so even a
    // strict reader reads all of it; only the summary is missing.
    let bytes = std::fs::read(&path).unwrap();
    let all = mcap::MessageStream::new(&bytes)
        .expect("a killed recording is a complete MCAP file")
        .collect::<Result<Vec<_>, _>>()
        .expect("every message of a killed recording reads")
        .len() as u64;
    assert!(all > 1000, "only {all} messages");
    assert!(mcap::Summary::read(&bytes).unwrap().is_none());

    // (a) Our replay reads it.
    let recording =
        coordinator::instruments::replay::load(&path).expect("load reads a killed recording");
    assert!(recording.counts["/packets"] > 500, "{:?}", recording.counts);
    assert!(recording.counts["/world"] > 5, "{:?}", recording.counts);
    assert_eq!(recording.counts.values().sum::<u64>(), all);
    assert_eq!(recording.truncated, None);
    assert_eq!(recording.info.behaviour, "teleop");

    // (b) So does the reference reader.
    if let Some((read, summary)) = python_reads(&path) {
        assert_eq!((read, summary), (all, None));
    }

    // (c) `recover` adds the summary and indexes, keeping every message.
    let fixed = scratch.path().join("killed-fixed.mcap");
    let out = coordinator(&[
        "recover".as_ref(),
        path.as_ref(),
        "-o".as_ref(),
        fixed.as_ref(),
    ]);
    let said = String::from_utf8_lossy(&out.stdout);
    println!("{said}");
    assert!(out.status.success(), "{said}");
    assert!(said.contains(&format!("kept {all} messages")), "{said}");
    assert!(said.contains("no tail was cut"), "{said}");
    let recovered = std::fs::read(&fixed).unwrap();
    let summary = mcap::Summary::read(&recovered)
        .unwrap()
        .expect("a recovered file has a summary");
    assert_eq!(summary.stats.map(|s| s.message_count), Some(all));
    assert!(!summary.chunk_indexes.is_empty());
    if let Some((read, summary)) = python_reads(&fixed) {
        assert_eq!((read, summary), (all, Some(all)));
    }
    // Replayed like any finished recording.
    let out = coordinator(&["replay".as_ref(), fixed.as_ref()]);
    let said = String::from_utf8_lossy(&out.stdout);
    println!("{said}");
    assert!(
        out.status.success(),
        "{said}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(said.contains(" 0 differ"), "{said}");

    // A copy torn inside its last chunk, as a kill during a write could leave it: recovered up
    // to the chunk before, next to the input by default.
    let mut last_chunk = 0;
    let mut at = mcap::MAGIC.len();
    while at + 9 <= bytes.len() {
        if bytes[at] == mcap::records::op::CHUNK {
            last_chunk = at;
        }
        at += 9 + u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
    }
    assert!(last_chunk > 0);
    let cut = scratch.path().join("cut-short.mcap");
    std::fs::write(&cut, &bytes[..last_chunk + 100]).unwrap();
    let out = coordinator(&["recover".as_ref(), cut.as_ref()]);
    let said = String::from_utf8_lossy(&out.stdout);
    println!("{said}");
    assert!(out.status.success(), "{said}");
    assert!(said.contains("the tail was cut"), "{said}");
    let default_out = scratch.path().join("cut-short.recovered.mcap");
    let kept = mcap::MessageStream::new(&std::fs::read(&default_out).unwrap())
        .unwrap()
        .collect::<Result<Vec<_>, _>>()
        .unwrap()
        .len() as u64;
    assert!(kept > 0 && kept < all, "kept {kept} of {all}");
    if let Some((read, summary)) = python_reads(&default_out) {
        assert_eq!((read, summary), (kept, Some(kept)));
    }
}

#[test]
fn recover_refuses_empty_and_foreign_files_clearly() {
    let scratch = scratch();
    let empty = scratch.path().join("empty.mcap");
    std::fs::write(&empty, b"").unwrap();
    let out = coordinator(&["recover".as_ref(), empty.as_ref()]);
    assert_eq!(out.status.code(), Some(2));
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(said.contains("empty"), "{said}");
    let text = scratch.path().join("notes.mcap");
    std::fs::write(&text, b"just some notes\n").unwrap();
    let out = coordinator(&["recover".as_ref(), text.as_ref()]);
    assert_eq!(out.status.code(), Some(2));
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(said.contains("not an MCAP file"), "{said}");
    assert!(!scratch.path().join("notes.recovered.mcap").exists());
    assert!(!scratch.path().join("notes.recovered.mcap.partial").exists());
}

#[test]
fn garbage_and_cut_headers_are_clear_errors() {
    let scratch = scratch();
    let junk = scratch.path().join("junk.mcap");
    std::fs::write(&junk, b"definitely not MCAP").unwrap();
    let e = coordinator::instruments::replay::load(&junk).unwrap_err();
    assert!(format!("{e:#}").contains("not a readable PocketFleet recording"));
    let missing = coordinator::instruments::replay::load(&scratch.path().join("nothing-here.mcap"))
        .unwrap_err();
    assert!(format!("{missing:#}").contains("reading"));
    // A valid MCAP magic and header with nothing after it.
    let cut = scratch.path().join("cut.mcap");
    std::fs::write(&cut, b"\x89MCAP0\r\n\x01").unwrap();
    assert!(coordinator::instruments::replay::load(&cut).is_err());
}

/// A flipped bit inside a recorded chunk's data is caught by the chunk's CRC: replay refuses the
/// file naming the chunk's byte offset (19 such flips once replayed with "0 differ"), and
/// recover keeps every other chunk.
#[test]
fn a_flipped_bit_in_a_recording_is_refused_by_replay_and_left_out_by_recover() {
    let scratch = scratch();
    let path = scratch.path().join("walk.mcap");
    run(
        plan("square_walk", Transport::Sim),
        Instruments {
            record: Some(path.clone()),
            ..Instruments::default()
        },
    );
    let mut bytes = std::fs::read(&path).unwrap();
    // The top-level chunks, walked by their lengths: opcode 0x06, then a u64 length.
    let mut chunks = Vec::new();
    let mut pos = 8;
    while pos + 9 <= bytes.len() && bytes[pos] != 0x0f {
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        if bytes[pos] == 0x06 {
            chunks.push((pos, len));
        }
        pos += 9 + len;
    }
    assert!(chunks.len() >= 3, "{} chunks", chunks.len());
    let (at, len) = chunks[chunks.len() - 1];
    bytes[at + 9 + len - 40] ^= 0x01;
    let damaged = scratch.path().join("damaged.mcap");
    std::fs::write(&damaged, &bytes).unwrap();
    let out = coordinator(&["replay".as_ref(), damaged.as_ref()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains(&format!("the chunk at byte {at}")) && stderr.contains("CRC"),
        "{stderr}"
    );
    let fixed = scratch.path().join("fixed.mcap");
    let out = coordinator(&[
        "recover".as_ref(),
        damaged.as_ref(),
        "-o".as_ref(),
        fixed.as_ref(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    assert!(
        stdout.contains(&format!("from {} chunks", chunks.len() - 1))
            && stdout.contains(&format!("damaged data at byte {at}")),
        "{stdout}"
    );
}
