//! Recording and replay: a recorded `cooperative_push` run replays to the same world snapshots, the
//! file is readable MCAP with Foxglove scene messages, and a recorder killed mid-run leaves a file
//! that reads up to its last flushed chunk.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use behaviours::Registry;
use coordinator::{Instruments, Plan, Transport};

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("pocketfleet-record-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn plan(behaviour: &str, transport: Transport) -> Plan {
    Plan {
        behaviour: behaviour.into(),
        world: None,
        robots: None,
        transport,
        seed: 1,
        realtime: false,
        duration: Duration::from_secs(150),
        params: Default::default(),
        faults: Vec::new(),
        body_faults: Vec::new(),
    }
}

/// Runs on its own thread so each run has its own actix system.
fn run(plan: Plan, instruments: Instruments) -> coordinator::Run {
    std::thread::spawn(move || {
        let registry = Registry::builtin();
        coordinator::actor_system(true)
            .block_on(coordinator::run_with(plan, &registry, instruments))
            .expect("the run completes")
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
    let path = temp("push.mcap");
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
        serde_json::json!(recorded.report.verdict.success)
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

#[test]
fn a_killed_recorder_leaves_a_file_readable_to_its_last_chunk() {
    let path = temp("killed.mcap");
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

    let bytes = std::fs::read(&path).unwrap();
    assert!(
        mcap::MessageStream::new(&bytes)
            .map(|s| s.collect::<Result<Vec<_>, _>>().is_err())
            .unwrap_or(true),
        "a killed recording has no footer, so a strict reader must notice"
    );
    let lenient =
        mcap::MessageStream::new_with_options(&bytes, mcap::read::Options::IgnoreEndMagic.into())
            .unwrap();
    let read = lenient.take_while(|m| m.is_ok()).count();
    assert!(read > 1000, "only {read} messages readable");

    let recording = coordinator::replay::load(&path).expect("load reads up to the cut");
    assert!(recording.counts["/packets"] > 500, "{:?}", recording.counts);
    assert!(recording.counts["/world"] > 5, "{:?}", recording.counts);
    assert_eq!(recording.info.behaviour, "teleop");
}

#[test]
fn garbage_and_cut_headers_are_clear_errors() {
    let junk = temp("junk.mcap");
    std::fs::write(&junk, b"definitely not MCAP").unwrap();
    let e = coordinator::replay::load(&junk).unwrap_err();
    assert!(format!("{e:#}").contains("not a readable PocketFleet recording"));
    let missing = coordinator::replay::load(&temp("nothing-here.mcap")).unwrap_err();
    assert!(format!("{missing:#}").contains("reading"));
    // A valid MCAP magic and header with nothing after it.
    let cut = temp("cut.mcap");
    std::fs::write(&cut, b"\x89MCAP0\r\n\x01").unwrap();
    assert!(coordinator::replay::load(&cut).is_err());
}
