//! Hello robot (thesis Appendix A.1) in Rust: find robots, connect to the first, print its pose on
//! every state update, walk a square, wait until the queue is done, close.
//!
//! The robot is simulated: the unmodified firmware in the physics world, reached through the same
//! packets a Bluetooth link would carry. Simulated time runs as fast as the host keeps up.

use std::sync::Arc;
use std::time::Duration;

use actix::prelude::*;
use protocol::packets::ReflectorMode;
use robot_actor::actor::ReflectorSetup;
use robot_actor::link::sim::SimDiscoverer;
use robot_actor::link::Discoverer;
use robot_actor::{Pose, Robot, RobotConfig, StateUpdated};
use simulator::runtime::{self, Pace};
use simulator::{SimConfig, Simulation};
use world::presets;

/// Prints the odometry pose on each new state (the thesis's `onNewState`).
struct PosePrinter;

impl Actor for PosePrinter {
    type Context = Context<Self>;
}

impl Handler<StateUpdated> for PosePrinter {
    type Result = ();
    fn handle(&mut self, u: StateUpdated, _: &mut Context<Self>) {
        let p = u.pose;
        println!(
            "robot {}: x {:7.1} mm  y {:7.1} mm  heading {:6.1}°",
            u.robot_id,
            p.x * 1e3,
            p.y * 1e3,
            p.theta.to_degrees()
        );
    }
}

fn main() -> anyhow::Result<()> {
    let system = actix::System::with_tokio_rt(|| {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .start_paused(true)
            .build()
            .expect("tokio runtime")
    });
    system.block_on(hello())
}

async fn hello() -> anyhow::Result<()> {
    let world = presets::preset("oval").expect("built-in world");
    let start = world.robots[0];
    let sim = Simulation::new(world, SimConfig::default());
    let (sim_handle, ends, _stepping) = runtime::spawn(sim, Pace::TokioClock);
    let discoverer = SimDiscoverer::new(ends);

    // Find all connectable robots.
    let robots = discoverer.discover().await?;
    let Some(first) = robots.first() else {
        println!("No robots found, exiting");
        std::process::exit(1);
    };
    println!("Some robots found, taking the first one");

    // Connects and starts state reflection.
    let origin = Pose {
        x: start.position.x,
        y: start.position.y,
        theta: start.heading_rad,
    };
    let config = RobotConfig {
        origin,
        reflector: ReflectorSetup {
            mode: ReflectorMode::Full,
            period_ms: 250,
        },
        ..RobotConfig::default()
    };
    let robot = Robot::start(Arc::clone(&first.connector), config);
    let hello = robot.connected().await?;
    println!("Robot {} ({}) connected", first.name, { hello.robot_id });
    robot.subscribe(PosePrinter.start().recipient());

    // Square walk: every move is queued at once and runs on the robot.
    let (speed, length, angle) = (0.2, 0.1, 90.0);
    let mut moves = Vec::new();
    for _ in 0..4 {
        moves.push(robot.straight(length, speed));
        moves.push(robot.rotate(angle, speed));
    }
    for m in moves {
        m.await?;
    }
    // Wait until all movements are finished, and let the wheels come to rest.
    robot.wait_idle().await?;
    tokio::time::sleep(Duration::from_millis(300)).await;

    let odometry = robot.pose().await?;
    let truth = sim_handle.truth().await.expect("simulation running").robots[0].1;
    println!(
        "square closed {:.1} mm from its start (odometry says {:.1} mm); heading {:.1}° after 360° of turns",
        (truth.x - origin.x).hypot(truth.y - origin.y) * 1e3,
        (odometry.x - origin.x).hypot(odometry.y - origin.y) * 1e3,
        (truth.theta - origin.theta).to_degrees(),
    );

    // Close the connection and exit.
    robot.close();
    sim_handle.stop();
    Ok(())
}
