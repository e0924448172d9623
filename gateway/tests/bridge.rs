//! Robots behind a gateway, reached over zenoh on loopback only (`tcp/127.0.0.1`, multicast
//! scouting off): simulated PocketBot2s served over TCP, a gateway bridging them, and a host
//! whose robot actors drive them through zenoh, judged from the simulator's ground truth.

use std::time::Duration;

use actix::prelude::*;
use gateway::{Gateway, GatewayConfig};
use protocol::packets::MoveOutcome;
use robot_actor::link::zenoh::{on_zenoh, open_session, Keys, ZenohDiscoverer, ZenohOptions};
use robot_actor::link::Discoverer;
use robot_actor::{Robot, RobotConfig, RobotEvent, RobotEventKind};
use simulator::runtime::Pace;
use simulator::{SimConfig, Simulation};

/// A port nobody listens on now, on loopback.
fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").expect("a loopback port");
    l.local_addr().expect("bound").port()
}

/// Fails the test instead of hanging when `what` does not happen within `secs` seconds.
async fn within<T>(what: &str, secs: u64, f: impl std::future::Future<Output = T>) -> T {
    tokio::time::timeout(Duration::from_secs(secs), f)
        .await
        .unwrap_or_else(|_| panic!("{what}: not within {secs} s"))
}

/// Tells once the robot's link is lost.
struct LossWatch(Option<tokio::sync::oneshot::Sender<()>>);

impl Actor for LossWatch {
    type Context = Context<Self>;
}

impl Handler<RobotEvent> for LossWatch {
    type Result = ();
    fn handle(&mut self, e: RobotEvent, _: &mut Context<Self>) {
        if e.kind == RobotEventKind::LinkLost {
            if let Some(tx) = self.0.take() {
                let _ = tx.send(());
            }
        }
    }
}

#[actix_rt::test]
async fn a_robot_behind_a_gateway_is_driven_over_zenoh_and_lost_when_the_gateway_goes() {
    let world = world::presets::preset("open").expect("a preset");
    let sim = Simulation::new(world, SimConfig::default());
    let (served, sim, _task) = simulator::serve::serve(sim, "127.0.0.1", 0, Pace::WallClock)
        .await
        .expect("robots served on loopback");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let gateway = Gateway::start(GatewayConfig {
        fleet: "bridge-test".into(),
        name: "a".into(),
        robots: served.iter().map(|(_, a)| format!("tcp://{a}")).collect(),
        zenoh: ZenohOptions {
            listen: vec![endpoint.clone()],
            ..Default::default()
        },
    })
    .await
    .expect("the gateway starts");

    let host = open_session(&ZenohOptions {
        connect: vec![endpoint],
        ..Default::default()
    })
    .await
    .expect("the host joins");
    let keys = Keys::new("bridge-test").expect("a fleet name");
    let discoverer = ZenohDiscoverer::new(
        host.clone(),
        keys.clone(),
        served.len(),
        Duration::from_secs(10),
    );
    let found = within("discovery", 15, discoverer.discover())
        .await
        .expect("discovered");
    assert_eq!(found.len(), served.len(), "{found:?}");

    let (id, _) = served[0];
    let discovered = found
        .iter()
        .find(|d| d.name == format!("robot {id}"))
        .expect("the first robot is found by its id");
    let robot = Robot::start(discovered.connector.clone(), RobotConfig::default());
    let hello = within("hello", 10, robot.connected()).await.expect("hello");
    assert_eq!({ hello.robot_id }, id);

    let before = sim.poses().await.expect("running").robots[0].1;
    let outcome = within("a 5 cm move", 20, robot.straight(0.05, 0.1))
        .await
        .expect("the move ends");
    assert_eq!(outcome, MoveOutcome::Completed);
    let after = sim.poses().await.expect("running").robots[0].1;
    let moved = (after.x - before.x).hypot(after.y - before.y);
    assert!(
        (0.04..0.06).contains(&moved),
        "the body moved {moved:.4} m for a 5 cm move"
    );

    let stats = gateway.stats();
    assert_eq!(stats[0].robot, Some(id));
    assert!(stats[0].connected && stats[0].packets_up > 10 && stats[0].packets_down > 3);
    let (session, key) = (host.clone(), keys.gateway_stats("a"));
    let answer = on_zenoh(async move {
        let replies = session
            .session()
            .get(key)
            .await
            .expect("the statistics query");
        let reply = replies.recv_async().await.expect("a reply");
        reply
            .result()
            .expect("statistics")
            .payload()
            .to_bytes()
            .to_vec()
    });
    let json: serde_json::Value =
        serde_json::from_slice(&within("statistics", 5, answer).await).expect("JSON");
    assert_eq!(json[0]["robot"], serde_json::json!(id));

    // The gateway goes: its tokens go with it, and the host's link to the robot is lost.
    let (tx, lost) = tokio::sync::oneshot::channel();
    robot.subscribe_events(LossWatch(Some(tx)).start().recipient());
    drop(gateway);
    within("the link lost", 5, lost).await.expect("told");
}
