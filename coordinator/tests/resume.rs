//! A coordinator killed in the middle of a run (SIGKILL, nothing flushed or closed) is taken over
//! by `coordinator --resume` from its recording: real processes over TCP, judged by the served
//! simulation's ground truth.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use simulator::runtime::Pace;
use simulator::serve::serve;
use simulator::{SimConfig, Simulation};
use world::presets;

/// The firmware's watchdog (500 ms) and the coasting after it: the campaign's bound.
const UNATTENDED_BOUND_S: f64 = 0.75;

#[test]
fn a_killed_coordinator_is_resumed_from_its_recording_and_the_run_ends_in_success() {
    let dir = tempfile::tempdir().unwrap();
    let recording = dir.path().join("run.mcap");
    let report = dir.path().join("resumed.json");
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let world = presets::preset("oval").unwrap();
        let sim = Simulation::new(world, SimConfig::default());
        let (addrs, handle, _task) = serve(sim, "127.0.0.1", 0, Pace::WallClock).await.unwrap();
        let list: Vec<String> = addrs.iter().map(|(_, a)| format!("tcp://{a}")).collect();
        let mut first = Command::new(env!("CARGO_BIN_EXE_coordinator"))
            .args(["--behaviour", "line_follow", "--world", "oval"])
            .args(["--transport", "tcp", "--robots", &list.join(",")])
            .args(["--param", "laps=1", "--duration", "120", "--record"])
            .arg(&recording)
            .env("RUST_LOG", "coordinator=info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // The run has begun once both robots are connected.
        let stderr = first.stderr.take().unwrap();
        let connected = tokio::task::spawn_blocking(move || {
            let mut lines = BufReader::new(stderr).lines();
            let mut seen = 0;
            while seen < 2 {
                let line = lines
                    .next()
                    .expect("the coordinator connects its robots")
                    .unwrap();
                seen += usize::from(line.contains("connected robot="));
            }
            // Keeps reading, so the coordinator never blocks on a full pipe.
            lines.for_each(drop);
        });
        let start = handle.inspect(|s| s.now()).await.unwrap();
        // Six simulated seconds in, mid-lap: both robots are driving when it dies.
        let before = handle
            .at(start + Duration::from_secs(6), |_| ())
            .await
            .and(handle.truth().await)
            .unwrap();
        first.kill().unwrap();
        first.wait().unwrap();
        let _ = connected.await;
        for (i, d) in before.distances_m.iter().enumerate() {
            assert!(*d > 0.3, "robot {i} drove {d:.2} m before the kill");
        }
        // Every robot stops within its watchdog, by the ground truth.
        let stopped = handle
            .at(before.now + Duration::from_millis(1500), |_| ())
            .await
            .and(handle.truth().await)
            .unwrap();
        assert!(
            stopped.wheel_speeds_mps.iter().flatten().all(|v| *v == 0.0),
            "wheels still turning: {:?}",
            stopped.wheel_speeds_mps
        );
        let unattended = stopped.longest_unattended_s();
        assert!(
            unattended > 0.0 && unattended <= UNATTENDED_BOUND_S,
            "a robot drove on {unattended:.3} s with its host dead"
        );
        let resumed = tokio::task::spawn_blocking({
            let (recording, report) = (recording.clone(), report.clone());
            move || {
                Command::new(env!("CARGO_BIN_EXE_coordinator"))
                    .arg("--resume")
                    .arg(&recording)
                    .arg("--json-report")
                    .arg(&report)
                    .output()
                    .unwrap()
            }
        })
        .await
        .unwrap();
        let text = String::from_utf8_lossy(&resumed.stdout);
        assert!(
            resumed.status.success(),
            "{text}\n{}",
            String::from_utf8_lossy(&resumed.stderr)
        );
        let after = handle.truth().await.unwrap();
        handle.stop();
        assert_eq!(after.robot_collisions, 0, "{text}");
        assert_eq!(after.wall_contacts, 0, "{text}");
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
        let adopted = json["conditions"]["resumed"]["robots"].as_array().unwrap();
        assert_eq!(adopted.len(), 2, "{json}");
        for a in adopted {
            // The same robots, not restarted: their clocks ran on through the gap.
            assert_eq!(a["rebooted"], false, "{a}");
            assert!(a["gap_s"].as_f64().unwrap() > 0.0, "{a}");
        }
        for (i, (id, truth)) in after.robots.iter().enumerate() {
            // The resumed behaviour drove its own lap (the oval's is 1.94 m).
            let driven = after.distances_m[i] - stopped.distances_m[i];
            assert!(
                driven > 1.8,
                "robot {id} drove {driven:.2} m after the resume\n{text}"
            );
            // And the model, started from the recording and carried across the gap by the
            // encoders, still knows where the robot is.
            let r = json["robots"]
                .as_array()
                .unwrap()
                .iter()
                .find(|r| r["id"] == *id)
                .unwrap();
            let (x, y) = (
                r["estimate"][0].as_f64().unwrap(),
                r["estimate"][1].as_f64().unwrap(),
            );
            let error = (x - truth.x).hypot(y - truth.y);
            assert!(
                error < 0.02,
                "robot {id}: model {:.1},{:.1} mm, truth {:.1},{:.1} mm\n{text}",
                x * 1e3,
                y * 1e3,
                truth.x * 1e3,
                truth.y * 1e3
            );
        }
    });
}
