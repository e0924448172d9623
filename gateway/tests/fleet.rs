//! The fleet as separate processes, as a lab runs it: `pocketbot-sim` serving simulated robots
//! over TCP, one `pocketfleet-gateway` per robot bridging it onto zenoh, and `coordinator
//! --transport zenoh` running a behaviour over them. Every endpoint is on 127.0.0.1 and every
//! process reads the same zenoh configuration, which turns multicast scouting off. Verdicts are
//! judged from the ground truth `pocketbot-sim --truth` writes, not from what the coordinator
//! believes.
//!
//! The binaries are the workspace's own: `cargo test --workspace` builds them all, and this
//! crate's development dependency on `coordinator` turns on its `zenoh` feature in that build.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use serde_json::Value;

/// One of the workspace's binaries, beside this crate's own.
fn bin(name: &str) -> PathBuf {
    let path = PathBuf::from(env!("CARGO_BIN_EXE_pocketfleet-gateway")).with_file_name(name);
    assert!(
        path.exists(),
        "{} is not built: run `cargo test --workspace`, which builds every binary, or build it \
         with `cargo build --bin {name} --features coordinator/zenoh`",
        path.display()
    );
    path
}

/// A child process killed when the test lets go of it, so a failing test leaves none behind.
struct Proc {
    name: String,
    pid: i32,
    child: Option<Child>,
}

impl Proc {
    /// Starts `cmd` with its standard error in `DIR/NAME.log`.
    fn spawn(name: &str, cmd: &mut Command, dir: &Path) -> Proc {
        let log = std::fs::File::create(dir.join(format!("{name}.log"))).expect("a log file");
        let child = cmd
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("{name} does not start: {e}"));
        Proc {
            name: name.into(),
            pid: child.id() as i32,
            child: Some(child),
        }
    }

    fn signal(&self, signal: i32) {
        // SAFETY: kill(2) on our own child's pid; it has not been reaped (we hold the Child).
        unsafe { libc::kill(self.pid, signal) };
    }

    /// Waits for the process to end by itself, at most `limit`; kills it and fails if it does not.
    fn wait(mut self, limit: Duration) -> ExitStatus {
        let mut child = self.child.take().expect("running");
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(child.wait());
        });
        match rx.recv_timeout(limit) {
            Ok(status) => status.expect("an exit status"),
            Err(_) => {
                // SAFETY: as in `signal`; the waiting thread reaps it.
                unsafe { libc::kill(self.pid, libc::SIGKILL) };
                panic!("{} did not end within {limit:?}", self.name)
            }
        }
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// Each test runs a simulator, two or three gateways and a coordinator against the wall clock:
/// run side by side on two cores they starve each other's timing, so they take turns.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn take_turn() -> std::sync::MutexGuard<'static, ()> {
    // A test that failed while holding the turn has said so; the next may still run.
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

/// A scratch directory for one test's logs, reports and configuration.
fn scratch(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("pf-fleet-{test}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("a scratch directory");
    dir
}

/// A loopback port nobody listens on now.
fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").expect("a loopback port");
    l.local_addr().expect("bound").port()
}

/// The zenoh configuration every process of a test reads: multicast scouting off, so peers
/// meet only through the loopback endpoints on their command lines.
fn zenoh_config(dir: &Path) -> PathBuf {
    let text =
        "{\n  // Peers meet only through the endpoints given: nothing leaves 127.0.0.0/8.\n  \
                scouting: { multicast: { enabled: false } },\n}\n";
    let path = dir.join("zenoh.json5");
    std::fs::write(&path, text).expect("the zenoh configuration");
    path
}

/// `pocketbot-sim` serving a world's robots on ephemeral loopback ports, writing its ground truth.
struct Sim {
    proc: Proc,
    /// Each robot's id and `tcp://` address.
    robots: Vec<(u16, String)>,
    truth: PathBuf,
}

impl Sim {
    /// Serves `world`; `rate` simulated seconds pass per wall-clock second.
    fn start(world: &str, rate: f64, dir: &Path) -> Sim {
        let truth = dir.join("truth.json");
        let mut proc = Proc::spawn(
            "pocketbot-sim",
            Command::new(bin("pocketbot-sim"))
                .args(["--world", world, "--bind", "127.0.0.1", "--port-base", "0"])
                .args(["--rate", &rate.to_string()])
                .arg("--truth")
                .arg(&truth)
                .stdout(Stdio::piped()),
            dir,
        );
        let out = proc
            .child
            .as_mut()
            .and_then(|c| c.stdout.take())
            .expect("stdout");
        let mut robots = Vec::new();
        for line in BufReader::new(out).lines() {
            let line = line.expect("pocketbot-sim's output");
            if line.starts_with("serving ") {
                break;
            }
            let mut words = line.split_whitespace().skip(1);
            let id: u16 = words.next().and_then(|w| w.parse().ok()).expect(&line);
            robots.push((id, words.next().expect(&line).to_string()));
        }
        assert!(!robots.is_empty(), "pocketbot-sim served no robot");
        Sim {
            proc,
            robots,
            truth,
        }
    }

    fn address(&self, id: u16) -> &str {
        &self
            .robots
            .iter()
            .find(|(r, _)| *r == id)
            .expect("served")
            .1
    }

    /// The ground truth as last written (every second).
    fn truth_now(&self) -> Option<Value> {
        let text = std::fs::read_to_string(&self.truth).ok()?;
        serde_json::from_str(&text).ok()
    }

    /// Stops the simulation and reads the ground truth it wrote at exit.
    fn finish(self) -> Value {
        self.proc.signal(libc::SIGTERM);
        let status = self.proc.wait(Duration::from_secs(10));
        assert!(status.success(), "pocketbot-sim ended {status}");
        let text = std::fs::read_to_string(&self.truth).expect("the ground truth");
        serde_json::from_str(&text).expect("JSON")
    }
}

/// Waits, reading the ground truth as it is rewritten, until `done` holds; fails after `limit`.
fn until(sim: &Sim, what: &str, limit: Duration, done: impl Fn(&Value) -> bool) -> Value {
    let start = Instant::now();
    loop {
        if let Some(t) = sim.truth_now().filter(|t| done(t)) {
            return t;
        }
        assert!(start.elapsed() < limit, "{what}: not within {limit:?}");
        // The condition is checked, not assumed: the file is rewritten once a second and
        // nothing else signals it, so it is read again a tenth of that later.
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn robot(truth: &Value, id: u16) -> &Value {
    truth["robots"]
        .as_array()
        .and_then(|rs| rs.iter().find(|r| r["id"] == id))
        .unwrap_or_else(|| panic!("robot {id} in the ground truth"))
}

fn gateway(
    name: &str,
    fleet: &str,
    robot: &str,
    coordinator: &str,
    config: &Path,
    dir: &Path,
) -> Proc {
    Proc::spawn(
        &format!("gateway-{name}"),
        Command::new(bin("pocketfleet-gateway"))
            .args(["--fleet", fleet, "--name", name, "--robots", robot])
            .args(["--zenoh-connect", coordinator])
            .arg("--zenoh-config")
            .arg(config)
            .stdout(Stdio::null()),
        dir,
    )
}

fn coordinator(fleet: &str, listen: &str, config: &Path, dir: &Path, run: &[&str]) -> Proc {
    let coordinator = bin("coordinator");
    let help = Command::new(&coordinator)
        .arg("--help")
        .output()
        .expect("coordinator --help");
    assert!(
        String::from_utf8_lossy(&help.stdout).contains("over zenoh"),
        "{} was built without its zenoh feature",
        coordinator.display()
    );
    Proc::spawn(
        "coordinator",
        Command::new(coordinator)
            .args(["--transport", "zenoh", "--fleet", fleet, "--robots", "2"])
            .args(["--zenoh-listen", listen])
            .arg("--zenoh-config")
            .arg(config)
            .arg("--json-report")
            .arg(dir.join("report.json"))
            .args(run)
            .stdout(Stdio::null()),
        dir,
    )
}

fn report(dir: &Path) -> Value {
    let text = std::fs::read_to_string(dir.join("report.json")).expect("the coordinator's report");
    serde_json::from_str(&text).expect("JSON")
}

/// Every contact the ground truth logged: robot against robot, robot against wall.
fn contacts(truth: &Value) -> usize {
    let n = |k: &str| truth[k].as_array().map_or(usize::MAX, Vec::len);
    n("robot_contacts") + n("wall_contacts")
}

#[test]
fn cooperative_push_runs_through_two_gateways_and_the_box_moves() {
    let _turn = take_turn();
    let dir = scratch("push");
    let config = zenoh_config(&dir);
    // The robots live at half the wall clock's pace, which leaves the host's answers room on a
    // loaded 2-core machine: each pusher covers only 12 mm of the box's corner. The box is
    // placed from the state stream, whatever the link's latency; full pace is not measured here.
    let sim = Sim::start("push", 0.5, &dir);
    let fleet = format!("push{}", std::process::id());
    let listen = format!("tcp/127.0.0.1:{}", free_port());
    let coordinator = coordinator(
        &fleet,
        &listen,
        &config,
        &dir,
        &["--behaviour", "cooperative_push"],
    );
    // Robot 1 behind gateway A, robot 2 behind gateway B.
    let _a = gateway("a", &fleet, sim.address(1), &listen, &config, &dir);
    let _b = gateway("b", &fleet, sim.address(2), &listen, &config, &dir);

    let status = coordinator.wait(Duration::from_secs(300));
    let report = report(&dir);
    let truth = sim.finish();
    assert_eq!(
        status.code(),
        Some(0),
        "the coordinator failed: {}",
        report["summary"]
    );
    assert_eq!(report["success"], true, "{report}");
    assert_eq!(contacts(&truth), 0, "contacts in the ground truth: {truth}");
    let moved = truth["boxes"][0]["displacement_m"]
        .as_f64()
        .expect("the box");
    assert!(moved > 0.04, "the box moved {moved:.3} m: nobody pushed it");
    for id in [1, 2] {
        let driven = robot(&truth, id)["distance_m"].as_f64().expect("distance");
        assert!(driven > 0.3, "robot {id} drove only {driven:.2} m");
    }
}

/// `line_follow` on the oval over zenoh: one simulator, robot 1 behind gateway `a`, robot 2
/// behind gateway `b`, and the coordinator, each its own process.
struct OvalFleet {
    dir: PathBuf,
    config: PathBuf,
    sim: Sim,
    fleet: String,
    listen: String,
    coordinator: Proc,
    a: Proc,
    b: Proc,
}

impl OvalFleet {
    /// Starts it for test `name`, with `--param` and any flags after it in `param`.
    fn start(name: &str, param: &[&str]) -> OvalFleet {
        let dir = scratch(name);
        let config = zenoh_config(&dir);
        let sim = Sim::start("oval", 1.0, &dir);
        let fleet = format!("{name}{}", std::process::id());
        let listen = format!("tcp/127.0.0.1:{}", free_port());
        let mut run = vec!["--behaviour", "line_follow", "--world", "oval", "--param"];
        run.extend_from_slice(param);
        let coordinator = coordinator(&fleet, &listen, &config, &dir, &run);
        let a = gateway("a", &fleet, sim.address(1), &listen, &config, &dir);
        let b = gateway("b", &fleet, sim.address(2), &listen, &config, &dir);
        OvalFleet {
            dir,
            config,
            sim,
            fleet,
            listen,
            coordinator,
            a,
            b,
        }
    }
}

fn unix_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .expect("after 1970")
        .as_millis() as u64
}

#[test]
fn a_killed_gateway_loses_its_robot_which_stops_and_is_adopted_again() {
    let _turn = take_turn();
    // The host's own setting, which the robot must get again when it is adopted again: a
    // watchdog of 400 ms instead of the firmware's 500 (wheels braked from 0.15 m/s take about
    // 0.12 s to stand, and the stop must come within 0.6 s of the last packet).
    let f = OvalFleet::start("kill", &["laps=2", "--setting", "watchdog.timeout_ms=400"]);
    let (dir, config, sim, fleet, listen, coordinator, b) = (
        f.dir,
        f.config,
        f.sim,
        f.fleet,
        f.listen,
        f.coordinator,
        f.b,
    );
    let _a = f.a;

    // Mid-run: robot 2 is following the tape.
    until(&sim, "robot 2 driving", Duration::from_secs(60), |t| {
        robot(t, 2)["distance_m"].as_f64().unwrap_or(0.0) > 0.3
    });
    let killed_ms = unix_ms();
    drop(b); // SIGKILL, then reaped.
             // Its robot stops by its own watchdog; only then does the gateway come back.
    until(&sim, "robot 2 stopped", Duration::from_secs(10), |t| {
        robot(t, 2)["host_silences"]
            .as_array()
            .and_then(|s| s.last())
            .is_some_and(|s| !s["wheels_stopped_s"].is_null())
    });
    let _b = gateway("b2", &fleet, sim.address(2), &listen, &config, &dir);

    let status = coordinator.wait(Duration::from_secs(180));
    let report = report(&dir);
    let truth = sim.finish();
    assert!(
        matches!(status.code(), Some(0 | 1)),
        "the coordinator ended without a verdict: {status}"
    );
    // line_follow carries on with a robot adopted again: the laps are done by both.
    assert_eq!(report["success"], true, "{}", report["summary"]);
    let links: Vec<&Value> = report["link_events"]
        .as_array()
        .expect("the report's link log")
        .iter()
        .filter(|l| l["robot"] == 2)
        .collect();
    let lost = links
        .iter()
        .find(|l| l["what"] == "lost")
        .unwrap_or_else(|| panic!("robot 2 never declared lost: {links:?}"));
    let noticed_ms = lost["unix_ms"].as_u64().expect("a time") as i64 - killed_ms as i64;
    assert!(
        (0..=1500).contains(&noticed_ms),
        "robot 2 declared lost {noticed_ms} ms after its gateway was killed"
    );
    let lost_at = lost["at_s"].as_f64().expect("a time");
    assert!(
        links
            .iter()
            .any(|l| l["what"] == "connected" && l["at_s"].as_f64() > Some(lost_at)),
        "robot 2 was not adopted again: {links:?}"
    );
    let held = report["held_intents"].as_array().expect("held intents");
    assert!(
        held.iter().any(|h| h
            .as_str()
            .is_some_and(|h| h.contains("robot 2's link is lost"))),
        "no intent for robot 2 was held while its link was lost: {held:?}"
    );
    let robot2 = &report["robots"]
        .as_array()
        .and_then(|rs| rs.iter().find(|r| r["id"] == 2))
        .expect("robot 2 in the report");
    assert!(robot2["reconnects"].as_u64() >= Some(1), "{robot2}");

    // The ground truth: robot 2 heard nothing from the host for a while, its wheels stopped
    // within 0.6 s of the last packet, and the host spoke to it again.
    let silences = robot(&truth, 2)["host_silences"]
        .as_array()
        .expect("silences")
        .clone();
    let gap = silences
        .iter()
        .find(|s| !s["resumed_s"].is_null())
        .unwrap_or_else(|| panic!("robot 2's host never spoke again: {silences:?}"));
    let last = gap["last_packet_s"].as_f64().expect("a time");
    let stopped = gap["wheels_stopped_s"]
        .as_f64()
        .expect("its wheels stopped");
    assert!(
        stopped - last <= 0.6,
        "robot 2's wheels stopped {:.3} s after its last packet",
        stopped - last
    );
    assert_eq!(contacts(&truth), 0, "contacts in the ground truth: {truth}");
    // The host's setting reached both robots, and robot 2 again once adopted again.
    for (id, writes) in [(1, 1), (2, 2)] {
        let r = robot(&truth, id);
        assert_eq!(r["watchdog_timeout_ms"], 400, "robot {id}: {r}");
        let got = r["settings_updates_received"].as_u64().expect("a count");
        assert_eq!(got, writes, "robot {id}: settings writes received");
    }
    eprintln!(
        "lost after {noticed_ms} ms; wheels stopped {:.3} s after the last packet; verdict: {}",
        stopped - last,
        report["summary"]
    );
}

/// A robot id belongs to one gateway at a time. With robot 2 of one simulator bridged, a second
/// gateway offering robot 2 of another simulator refuses it and says why, the run succeeds with
/// the first, and the foreign robot never moves (it once received the host's commands for the
/// whole run and moved 29 mm, while the real robot 2's model was corrupted).
#[test]
fn a_second_gateway_offering_a_taken_robot_id_refuses_it_and_that_robot_never_moves() {
    let _turn = take_turn();
    let f = OvalFleet::start("dup", &["laps=1"]);
    let (dir, config, sim, fleet, listen, coordinator) =
        (f.dir, f.config, f.sim, f.fleet, f.listen, f.coordinator);
    let (_a, _b) = (f.a, f.b);
    let other_dir = scratch("dup-other");
    let other = Sim::start("oval", 1.0, &other_dir);
    until(&sim, "robot 2 driving", Duration::from_secs(60), |t| {
        robot(t, 2)["distance_m"].as_f64().unwrap_or(0.0) > 0.1
    });
    let _c = gateway("c", &fleet, other.address(2), &listen, &config, &other_dir);

    let status = coordinator.wait(Duration::from_secs(180));
    let report = report(&dir);
    let truth = sim.finish();
    let foreign = other.finish();
    assert_eq!(status.code(), Some(0), "{}", report["summary"]);
    assert_eq!(report["success"], true, "{}", report["summary"]);
    assert_eq!(contacts(&truth), 0, "contacts in the ground truth: {truth}");
    let moved = robot(&foreign, 2)["distance_m"].as_f64().expect("distance");
    assert!(
        moved < 0.002,
        "the other simulator's robot 2 drove {moved:.3} m"
    );
    let log = std::fs::read_to_string(other_dir.join("gateway-c.log")).expect("gateway c's log");
    assert!(
        log.contains("robot 2 is already bridged by another gateway"),
        "gateway c did not refuse robot 2: {log}"
    );
}
