//! Robot actors against simulated robots, on actix over tokio's paused clock (simulated time):
//! reflection, settings, reflector rates, moves and odometry, layout refusal, reconnect.

use std::future::Future;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use actix::prelude::*;
use futures::future::BoxFuture;
use futures::FutureExt;
use protocol::packets::{self, ReflectorMode};
use protocol::{PacketType, Settings};
use robot_actor::actor::{Command, ReflectorSetup, RobotSnapshot};
use robot_actor::link::sim::SimConnector;
use robot_actor::link::{Connector, Link, LinkCounters, LinkError, LinkEvent};
use robot_actor::odometry::Pose;
use robot_actor::{setting, CallError, Robot, RobotConfig, RobotError, StateUpdated};
use simulator::runtime::{self, Pace, SimHandle};
use simulator::{SimConfig, Simulation};
use tokio::sync::{mpsc, Notify};
use world::{file, presets};

/// Runs `f` in an actix system on a current-thread tokio runtime whose clock is paused: time
/// advances only when every task waits, so simulated and host time are one.
fn paused<F: Future>(f: impl FnOnce() -> F) -> F::Output {
    let sys = actix::System::with_tokio_rt(|| {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .start_paused(true)
            .build()
            .expect("runtime")
    });
    sys.block_on(f())
}

const OPEN: &str = r#"
name = "open"
[arena]
width_m = 1.2
height_m = 1.2
[track]
nodes = [{ id = "a", x = 0.1, y = 0.1 }, { id = "b", x = 0.2, y = 0.1 }]
edges = [{ from = "a", to = "b" }]
[[robots]]
id = 3
x = 0.6
y = 0.6
heading_deg = 0
"#;

/// Records every packet the host sends through a wrapped connector.
struct Tap {
    inner: Arc<dyn Connector>,
    sent: Arc<Mutex<Vec<Vec<u8>>>>,
}

impl Connector for Tap {
    fn peer(&self) -> String {
        self.inner.peer()
    }
    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let inner = self.inner.connect();
        let sent = Arc::clone(&self.sent);
        async move {
            let link = inner.await?;
            let (tx, mut rx) = mpsc::channel::<Vec<u8>>(64);
            let downstream = link.tx;
            tokio::spawn(async move {
                while let Some(p) = rx.recv().await {
                    sent.lock().unwrap().push(p.clone());
                    if downstream.send(p).await.is_err() {
                        break;
                    }
                }
            });
            Ok(Link {
                peer: link.peer,
                tx,
                rx: link.rx,
                counters: link.counters,
            })
        }
        .boxed()
    }
}

struct Setup {
    robot: Robot,
    handle: SimHandle,
    sent: Arc<Mutex<Vec<Vec<u8>>>>,
}

fn start(world: simulator::World, config: RobotConfig) -> Setup {
    let origin = world.robots[0];
    let sim = Simulation::new(world, SimConfig::default());
    let (handle, mut ends, _task) = runtime::spawn(sim, Pace::TokioClock);
    let sent = Arc::new(Mutex::new(Vec::new()));
    let tap = Tap {
        inner: Arc::new(SimConnector::new(ends.remove(0))),
        sent: Arc::clone(&sent),
    };
    let config = RobotConfig {
        origin: Pose {
            x: origin.position.x,
            y: origin.position.y,
            theta: origin.heading_rad,
        },
        ..config
    };
    Setup {
        robot: Robot::start(Arc::new(tap), config),
        handle,
        sent,
    }
}

async fn snapshot(r: &Robot) -> RobotSnapshot {
    r.snapshot().await.expect("actor alive")
}

#[test]
fn reflected_encoders_equal_the_simulators_and_odometry_matches_ground_truth() {
    paused(|| async {
        let s = start(
            file::parse(OPEN, "open.toml").unwrap(),
            RobotConfig::default(),
        );
        s.robot.connected().await.unwrap();
        // The square walk of thesis A.1.
        let mut moves = Vec::new();
        for _ in 0..4 {
            moves.push(s.robot.straight(0.1, 0.2));
            moves.push(s.robot.rotate(90.0, 0.2));
        }
        for m in moves {
            assert_eq!(m.await.unwrap(), packets::MoveOutcome::Completed);
        }
        s.robot.wait_idle().await.unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
        let snap = snapshot(&s.robot).await;
        let (counts, truth) = s
            .handle
            .inspect(|sim| {
                let r = &sim.robots()[0];
                let e = r.firmware().state().encoders;
                ((e.left_ticks, e.right_ticks), r.pose())
            })
            .await
            .unwrap();
        let reflected = (
            snap.state.encoders.left_ticks,
            snap.state.encoders.right_ticks,
        );
        assert_eq!(reflected, counts, "reflected encoder totals");
        let p = snap.pose;
        let err_mm = (p.x - truth.x).hypot(p.y - truth.y) * 1e3;
        let err_deg = (p.theta - truth.theta).to_degrees().abs();
        eprintln!("odometry {p:?} truth {truth:?}: {err_mm:.1} mm, {err_deg:.2} deg");
        assert!(err_mm < 10.0, "odometry {err_mm:.1} mm off");
        assert!(err_deg < 3.0, "odometry {err_deg:.2} deg off");
        // θ = θ₀ + 2πr/(l·T)·(N₂ − N₁), computed here from the counts alone.
        let g = snap.settings.geometry;
        let r = f64::from(g.wheel_diameter_m) / 2.0;
        let k =
            std::f64::consts::TAU * r / (f64::from(g.wheel_gauge_m) * f64::from(g.ticks_per_rev));
        let (n1, n2) = snap.odometry_totals;
        assert_eq!(p.theta, k * (n2 - n1) as f64);
    });
}

#[test]
fn setting_one_field_sends_one_packet_and_the_robot_holds_it() {
    paused(|| async {
        let s = start(presets::preset("oval").unwrap(), RobotConfig::default());
        s.robot.connected().await.unwrap();
        // Let the connect-time settings read-back finish, then look only at what the write sends.
        tokio::time::sleep(Duration::from_millis(200)).await;
        s.sent.lock().unwrap().clear();
        s.robot.set(setting!(line_pid.kp), 55.5).await.unwrap();
        let updates: Vec<Vec<u8>> = s
            .sent
            .lock()
            .unwrap()
            .iter()
            .filter(|p| p[1] == PacketType::SettingsUpdate as u8)
            .cloned()
            .collect();
        assert_eq!(updates.len(), 1, "one update packet");
        let (offset, len) = Settings::field("line_pid.kp").unwrap();
        assert_eq!(
            updates[0].len(),
            3 + 2 + 1 + 4,
            "header + offset + length + f32"
        );
        assert_eq!(&updates[0][3..5], &(offset as u16).to_le_bytes());
        assert_eq!(updates[0][5] as usize, len);
        assert_eq!(&updates[0][6..], &55.5f32.to_le_bytes());
        let kp = s
            .handle
            .inspect(|sim| sim.robots()[0].firmware().settings().line_pid.kp)
            .await
            .unwrap();
        assert_eq!(kp, 55.5);
    });
}

#[test]
fn a_refused_setting_names_its_field_and_changes_nothing() {
    paused(|| async {
        let s = start(presets::preset("oval").unwrap(), RobotConfig::default());
        s.robot.connected().await.unwrap();
        let err = s
            .robot
            .set(setting!(geometry.ticks_per_rev), 0)
            .await
            .unwrap_err();
        match &err {
            CallError::Robot(RobotError::SettingRefused { field, reason, .. }) => {
                assert_eq!(field.as_deref(), Some("geometry.ticks_per_rev"));
                assert_eq!(*reason, Some(packets::NackReason::BadSettingValue));
            }
            other => panic!("expected a refusal, got {other:?}"),
        }
        assert!(err.to_string().contains("geometry.ticks_per_rev"), "{err}");
        let ticks = s
            .handle
            .inspect(|sim| sim.robots()[0].firmware().settings().geometry.ticks_per_rev)
            .await
            .unwrap();
        assert_eq!(ticks, { Settings::default().geometry.ticks_per_rev });
        // The refusal resolved its own write only: the next one still succeeds.
        s.robot.set(setting!(line_pid.kp), 7.0).await.unwrap();
    });
}

/// Counts state updates by kind.
struct Counter(Arc<Mutex<(usize, usize)>>);
impl Actor for Counter {
    type Context = Context<Self>;
}
impl Handler<StateUpdated> for Counter {
    type Result = ();
    fn handle(&mut self, u: StateUpdated, _: &mut Context<Self>) {
        let mut c = self.0.lock().unwrap();
        if u.reduced {
            c.1 += 1;
        } else {
            c.0 += 1;
        }
    }
}

#[test]
fn reflector_rates_in_simulated_time() {
    paused(|| async {
        let s = start(presets::preset("oval").unwrap(), RobotConfig::default());
        s.robot.connected().await.unwrap();
        let counts = Arc::new(Mutex::new((0, 0)));
        s.robot
            .subscribe(Counter(Arc::clone(&counts)).start().recipient());
        let setup = |mode, period_ms| Command::Reflector(ReflectorSetup { mode, period_ms });
        s.robot
            .command(setup(ReflectorMode::Reduced, 5))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        *counts.lock().unwrap() = (0, 0);
        tokio::time::sleep(Duration::from_secs(1)).await;
        let reduced = counts.lock().unwrap().1;
        s.robot
            .command(setup(ReflectorMode::Full, 20))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        *counts.lock().unwrap() = (0, 0);
        tokio::time::sleep(Duration::from_secs(1)).await;
        let full = counts.lock().unwrap().0;
        eprintln!("reduced at 5 ms: {reduced}/s, full at 20 ms: {full}/s");
        assert!(reduced >= 190, "{reduced} reduced states in one second");
        assert!(
            (49..=51).contains(&full),
            "{full} full states in one second"
        );
    });
}

/// A scripted robot whose hello is this build's, altered by `alter`.
struct Stranger {
    alter: fn(&mut packets::Hello),
    /// The type of every packet the host sent.
    received: Arc<Mutex<Vec<u8>>>,
    connects: Arc<AtomicUsize>,
    /// Signalled when the host closes a link.
    closed: Arc<Notify>,
}

impl Stranger {
    fn new(alter: fn(&mut packets::Hello)) -> Self {
        Self {
            alter,
            received: Arc::default(),
            connects: Arc::default(),
            closed: Arc::default(),
        }
    }
}

impl Connector for Stranger {
    fn peer(&self) -> String {
        "fake://stranger".into()
    }
    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        self.connects.fetch_add(1, Ordering::SeqCst);
        let received = Arc::clone(&self.received);
        let closed = Arc::clone(&self.closed);
        let alter = self.alter;
        async move {
            let (tx, mut from_host) = mpsc::channel::<Vec<u8>>(64);
            let (events, rx) = mpsc::unbounded_channel();
            tokio::spawn(async move {
                while let Some(p) = from_host.recv().await {
                    received.lock().unwrap().push(p[1]);
                    if p[1] == PacketType::HelloRequest as u8 {
                        let mut hello = packets::Hello::new(&Settings::default(), [9, 9, 9]);
                        alter(&mut hello);
                        let (buf, n) = protocol::frame::encode_to_array(&hello);
                        let _ = events.send(LinkEvent::Packet(buf[..n].to_vec()));
                    }
                }
                closed.notify_one();
            });
            Ok(Link {
                peer: "fake://stranger".into(),
                tx,
                rx,
                counters: Arc::new(LinkCounters::default()),
            })
        }
        .boxed()
    }
}

/// A change to this build's hello.
type Alter = fn(&mut packets::Hello);

#[test]
fn a_robot_of_another_protocol_or_layout_is_refused_and_its_link_closed() {
    use robot_actor::Incompatibility as I;
    let state = <protocol::RobotState as protocol::Layout>::LAYOUT.hash;
    let settings = protocol::SETTINGS_LAYOUT_HASH;
    let version = protocol::PROTOCOL_VERSION;
    let cases: [(Alter, Vec<I>); 4] = [
        (
            |h| h.protocol_version += 1,
            vec![I::ProtocolVersion {
                robot: version + 1,
                host: version,
            }],
        ),
        (
            |h| h.state_hash ^= 1,
            vec![I::StateLayout {
                robot: state ^ 1,
                host: state,
            }],
        ),
        (
            |h| h.settings_hash ^= 0xdead_beef,
            vec![I::SettingsLayout {
                robot: settings ^ 0xdead_beef,
                host: settings,
            }],
        ),
        (
            |h| {
                h.protocol_version = 0;
                h.state_hash = 0;
                h.settings_hash = 0;
            },
            vec![
                I::ProtocolVersion {
                    robot: 0,
                    host: version,
                },
                I::StateLayout {
                    robot: 0,
                    host: state,
                },
                I::SettingsLayout {
                    robot: 0,
                    host: settings,
                },
            ],
        ),
    ];
    for (alter, expected) in cases {
        paused(|| async move {
            let stranger = Stranger::new(alter);
            let (received, connects, closed) = (
                Arc::clone(&stranger.received),
                Arc::clone(&stranger.connects),
                Arc::clone(&stranger.closed),
            );
            let robot = Robot::start(Arc::new(stranger), RobotConfig::default());
            let refusal = RobotError::Incompatible {
                robot: 1,
                differences: expected.clone(),
            };
            match robot.connected().await {
                Err(robot_actor::CallError::Robot(e)) => assert_eq!(e, refusal),
                other => panic!("{expected:?}: {other:?}"),
            }
            tokio::time::timeout(Duration::from_secs(5), closed.notified())
                .await
                .expect("the refused robot's link is closed");
            let text = refusal.to_string();
            assert!(text.starts_with("robot 1 refused: "), "{text}");
            for d in &expected {
                assert!(text.contains(&d.to_string()), "{text}");
            }
            match robot.straight(0.1, 0.1).await {
                Err(robot_actor::CallError::Robot(e)) => assert_eq!(e, refusal),
                other => panic!("a move to a refused robot: {other:?}"),
            }
            let err = robot.set(setting!(line_pid.kp), 1.0).await.unwrap_err();
            assert!(err.to_string().contains("refused"), "{err}");
            // Long past every reconnect backoff: a refused robot is not dialled again.
            tokio::time::sleep(Duration::from_secs(5)).await;
            assert_eq!(connects.load(Ordering::SeqCst), 1);
            assert_eq!(snapshot(&robot).await.refused, Some(refusal));
            let types = received.lock().unwrap().clone();
            assert_eq!(
                types,
                [PacketType::HelloRequest as u8],
                "nothing but the hello request reaches a refused robot"
            );
        });
    }
}

#[test]
fn a_compatible_hello_is_accepted() {
    paused(|| async {
        let stranger = Stranger::new(|_| {});
        let received = Arc::clone(&stranger.received);
        let robot = Robot::start(Arc::new(stranger), RobotConfig::default());
        let hello = robot.connected().await.expect("compatible");
        assert!(robot_actor::actor::incompatibilities(&hello).is_empty());
        let types = received.lock().unwrap().clone();
        assert!(
            types.contains(&(PacketType::ReflectorConfig as u8)),
            "{types:?}"
        );
    });
}

#[test]
fn a_lost_link_is_reported_retried_and_resumed_with_host_settings() {
    paused(|| async {
        let s = start(presets::preset("oval").unwrap(), RobotConfig::default());
        s.robot.connected().await.unwrap();
        s.robot
            .set(setting!(line_follow.speed_mps), 0.12)
            .await
            .unwrap();
        s.handle
            .inspect(|sim| sim.set_link_up(0, false))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_secs(2)).await;
        let lost = snapshot(&s.robot).await;
        assert!(!lost.connected, "link loss not noticed");
        assert!(lost.link.losses >= 1);
        // The robot reboots while away: the unsaved host setting is gone from it.
        let after_reboot = s
            .handle
            .inspect(|sim| {
                sim.reboot(0);
                sim.robots()[0].firmware().settings().line_follow.speed_mps
            })
            .await
            .unwrap();
        assert_eq!(after_reboot, { Settings::default().line_follow.speed_mps });
        s.handle
            .inspect(|sim| sim.set_link_up(0, true))
            .await
            .unwrap();
        s.robot.connected().await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        let back = snapshot(&s.robot).await;
        assert!(back.connected);
        assert!(back.link.reconnects >= 1);
        let before = back.full_state_at.unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
        assert!(
            snapshot(&s.robot).await.full_state_at.unwrap() > before,
            "reflector resumed"
        );
        let speed = s
            .handle
            .inspect(|sim| sim.robots()[0].firmware().settings().line_follow.speed_mps)
            .await
            .unwrap();
        assert_eq!(speed, 0.12, "host setting re-applied after the reconnect");
    });
}
