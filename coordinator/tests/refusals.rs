//! Bad requests and lying robots are refused before any robot moves: the binary exits with the
//! usage-error status 2 (a failed experiment exits with 1) and one clear message, never a panic.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::process::{Command, Output};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use protocol::packets::Hello;
use protocol::slip::{self, SlipDecoder};
use protocol::{Frame, PacketType, Settings, MAX_PACKET};
use simulator::runtime::Pace;
use simulator::serve::serve;
use simulator::{SimConfig, Simulation};
use world::presets;

fn coordinator(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_coordinator"))
        .args(args)
        .output()
        .expect("the coordinator runs")
}

/// Asserts a usage refusal: status 2, every `parts` in stderr, no panic and no report.
/// Runs `square_walk` through the binary on robots at `robots` (comma-separated TCP addresses).
fn square_walk_over_tcp(robots: &str, duration: &str) -> Output {
    coordinator(&[
        "--behaviour",
        "square_walk",
        "--transport",
        "tcp",
        "--robots",
        robots,
        "--duration",
        duration,
    ])
}

fn assert_refused(out: &Output, parts: &[&str]) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(2), "{stderr}\n{stdout}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(
        !stdout.contains("verdict"),
        "a report after a refusal: {stdout}"
    );
    for part in parts {
        assert!(stderr.contains(part), "{part:?} not in: {stderr}");
    }
    stderr
}

/// A scratch directory of one test's own, removed when it is dropped.
fn scratch() -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix("coordinator-refusals-")
        .tempdir()
        .expect("scratch directory")
}

#[test]
fn durations_out_of_range_are_usage_errors() {
    for bad in ["1e20", "NaN", "inf", "-0.5", "0", "1000001", "soon"] {
        let out = coordinator(&["--behaviour", "square_walk", "--duration", bad]);
        assert_refused(&out, &["--duration", bad]);
    }
    let out = coordinator(&["--help"]);
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(help.contains("at most 1000000"), "{help}");
}

#[test]
fn resume_refuses_what_it_cannot_take_over() {
    let dir = scratch();
    let missing = dir.path().join("none.mcap");
    let out = coordinator(&["--resume", missing.to_str().unwrap()]);
    assert_refused(&out, &["none.mcap"]);
    // Robots simulated inside a coordinator die with it: nothing is left to adopt.
    let simulated = dir.path().join("sim.mcap");
    let out = coordinator(&[
        "--behaviour",
        "square_walk",
        "--robots",
        "1",
        "--duration",
        "1",
        "--record",
        simulated.to_str().unwrap(),
    ]);
    assert_eq!(
        out.status.code(),
        Some(1),
        "a second is too short for a square"
    );
    let out = coordinator(&["--resume", simulated.to_str().unwrap()]);
    assert_refused(
        &out,
        &["simulated inside the coordinator", "nothing to take over"],
    );
    // A resumed run's behaviour, world and robots are the recording's.
    let out = coordinator(&["--resume", "x.mcap", "--behaviour", "square_walk"]);
    assert_refused(&out, &["--behaviour"]);
}

#[test]
fn an_unknown_parameter_is_named_with_the_behaviours_parameters() {
    let out = coordinator(&["--behaviour", "square_walk", "--param", "bogus=1"]);
    assert_refused(
        &out,
        &["unknown parameter \"bogus\" for square_walk; its parameters: side"],
    );
    let out = coordinator(&["--behaviour", "teleop", "--param", "speed=1"]);
    assert_refused(&out, &["teleop; it takes no parameters"]);
}

#[test]
fn unwritable_output_paths_are_refused_before_the_run() {
    let missing = "/nonexistent-directory/out";
    for flag in ["--json-report", "--plot", "--record"] {
        let started = Instant::now();
        let out = coordinator(&["--behaviour", "square_walk", flag, missing]);
        assert_refused(&out, &[flag, missing]);
        // Refused before the experiment, which takes several seconds even simulated.
        assert!(started.elapsed() < Duration::from_secs(20));
    }
    // A run refused for another reason leaves no empty output file behind.
    let dir = scratch();
    let report = dir.path().join("refused.json");
    let out = coordinator(&[
        "--behaviour",
        "square_walk",
        "--param",
        "bogus=1",
        "--json-report",
        report.to_str().expect("utf-8 path"),
    ]);
    assert_refused(&out, &["bogus"]);
    assert!(!report.exists(), "{} left behind", report.display());
}

#[test]
fn worlds_without_room_for_the_robots_are_refused() {
    let out = coordinator(&["--behaviour", "traffic_control", "--world", "grid:2x2:50"]);
    assert_refused(
        &out,
        &["grid:2x2:50", "50 robots do not fit on a 2x2 lattice"],
    );
    let out = coordinator(&["--behaviour", "line_follow", "--world", "serpentine:0"]);
    assert_refused(&out, &["serpentine:0", "expected serpentine:ROBOTS"]);
    let out = coordinator(&["--behaviour", "square_walk", "--robots", "5"]);
    assert_refused(&out, &["--robots 5", "room for 1 to 4 robots"]);
    let dir = scratch();
    let empty = dir.path().join("empty.toml");
    std::fs::write(
        &empty,
        "name = \"empty\"\n[arena]\nwidth_m = 1.0\nheight_m = 1.0\n",
    )
    .expect("world file written");
    let path = empty.to_str().expect("utf-8 path");
    let out = coordinator(&["--behaviour", "square_walk", "--world", path]);
    assert_refused(&out, &["places no robots"]);
}

#[test]
fn a_physics_rate_the_clock_cannot_divide_is_refused() {
    for rate in ["300", "2000", "fast"] {
        let out = coordinator(&["--behaviour", "square_walk", "--physics-hz", rate]);
        assert_refused(&out, &["--physics-hz", rate, "1000, 500, 250, 200"]);
    }
}

#[test]
fn a_truncated_world_file_names_its_line_and_what_is_wrong() {
    let text = presets::preset_text("open").expect("preset");
    let cut = text
        .find("heading_deg = ")
        .expect("a heading in the open world")
        + 14;
    let dir = scratch();
    let truncated = dir.path().join("truncated.toml");
    std::fs::write(&truncated, &text[..cut]).expect("world file written");
    let path = truncated.to_str().expect("utf-8 path");
    let out = coordinator(&["--behaviour", "square_walk", "--world", path]);
    let line = text[..cut].lines().count();
    let stderr = assert_refused(&out, &[&format!("{path}:{line}: ")]);
    let message = stderr
        .split_once(&format!("{path}:{line}: "))
        .map(|(_, m)| m.trim())
        .unwrap_or_default();
    assert!(!message.is_empty(), "{stderr}");
}

#[test]
fn a_refused_connection_says_so_within_the_time_limit() {
    // A port that was just free on loopback: nothing listens there.
    let port = TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let address = format!("tcp://127.0.0.1:{port}");
    let started = Instant::now();
    let out = square_walk_over_tcp(&address, "2");
    let stderr = assert_refused(&out, &["connection refused", &format!("127.0.0.1:{port}")]);
    assert!(!stderr.contains("did not say hello"), "{stderr}");
    // The hello deadline is the 2 s time limit, not the usual 10 s.
    assert!(
        started.elapsed() < Duration::from_secs(8),
        "{:?}",
        started.elapsed()
    );
}

#[test]
fn two_robots_saying_the_same_id_are_refused_naming_both() {
    let (tx, rx) = mpsc::channel();
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let server = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        rt.block_on(async move {
            // Two one-robot simulations, each robot saying id 1.
            let mut addrs = Vec::new();
            let mut handles = Vec::new();
            for _ in 0..2 {
                let mut world = presets::preset("open").expect("preset");
                world.robots.truncate(1);
                let sim = Simulation::new(world, SimConfig::default());
                let (a, handle, _task) = serve(sim, "127.0.0.1", 0, Pace::WallClock)
                    .await
                    .expect("served on loopback");
                addrs.extend(a);
                handles.push(handle);
            }
            tx.send(addrs).expect("test waits");
            let _ = stop_rx.await;
            let mut moved = Vec::new();
            for h in handles {
                moved.push(h.truth().await.expect("truth").distances_m);
                h.stop();
            }
            moved
        })
    });
    let addrs = rx.recv().expect("served");
    assert!(addrs.iter().all(|(id, _)| *id == 1), "{addrs:?}");
    let list: Vec<String> = addrs.iter().map(|(_, a)| format!("tcp://{a}")).collect();
    let out = coordinator(&[
        "--behaviour",
        "square_walk",
        "--transport",
        "tcp",
        "--robots",
        &list.join(","),
        "--duration",
        "30",
    ]);
    let _ = stop_tx.send(());
    let moved = server.join().expect("server thread");
    let first = addrs[0].1.to_string();
    let second = addrs[1].1.to_string();
    assert_refused(&out, &[&first, &second, "both say they are robot 1"]);
    for d in moved.iter().flatten() {
        assert!(*d < 1e-3, "a robot drove {d} m: {moved:?}");
    }
}

/// A robot on loopback that answers every hello request with `hello` and records the type of
/// every packet it receives until the host closes the connection.
fn fake_robot(hello: Hello) -> (String, std::thread::JoinHandle<Vec<u8>>) {
    let listener = TcpListener::bind("127.0.0.1:0").expect("loopback listener");
    let address = format!("tcp://{}", listener.local_addr().expect("bound"));
    let robot = std::thread::spawn(move || {
        let (mut stream, _) = listener.accept().expect("the host connects");
        stream
            .set_read_timeout(Some(Duration::from_secs(30)))
            .expect("timeout set");
        let mut decoder = SlipDecoder::<MAX_PACKET>::new();
        let mut received = Vec::new();
        let mut buf = [0u8; 1024];
        loop {
            let n = match stream.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => n,
            };
            for &b in &buf[..n] {
                let Ok(Some(frame)) = decoder.push(b) else {
                    continue;
                };
                let Ok(frame) = Frame::parse(frame) else {
                    continue;
                };
                received.push(frame.packet_type() as u8);
                if frame.packet_type() == PacketType::HelloRequest {
                    reply(&mut stream, &hello);
                }
            }
        }
        received
    });
    (address, robot)
}

fn reply(stream: &mut TcpStream, hello: &Hello) {
    let (frame, n) = protocol::frame::encode_to_array(hello);
    let mut out = [0u8; 2 * MAX_PACKET + 2];
    let len = slip::encode(&frame[..n], &mut out).expect("a hello fits a SLIP frame");
    let _ = stream.write_all(&out[..len]);
}

#[test]
fn a_robot_of_another_protocol_version_is_refused_before_any_command() {
    let mut hello = Hello::new(&Settings::default(), [9, 9, 9]);
    hello.protocol_version = protocol::PROTOCOL_VERSION + 98;
    hello.settings_hash ^= 1;
    let (address, robot) = fake_robot(hello);
    let out = square_walk_over_tcp(&address, "30");
    let received = robot.join().expect("fake robot");
    let version = protocol::PROTOCOL_VERSION;
    assert_refused(
        &out,
        &[
            &address,
            "robot 1 refused",
            &format!("protocol version {}, host speaks {version}", version + 98),
            &format!(
                "settings layout {:#018x}, host knows {:#018x}",
                protocol::SETTINGS_LAYOUT_HASH ^ 1,
                protocol::SETTINGS_LAYOUT_HASH
            ),
        ],
    );
    // Pings keep a robot's watchdog fed and may go out before the hello is in; nothing else may.
    let harmless = [PacketType::HelloRequest as u8, PacketType::Ping as u8];
    assert!(
        received.iter().all(|t| harmless.contains(t)),
        "a refused robot was sent {received:?}"
    );
    assert!(received.contains(&(PacketType::HelloRequest as u8)));
}
