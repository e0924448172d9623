//! The coordinator drives robots served over TCP (SLIP) by the simulator's server, as it would
//! robots behind serial bridges: wall-clock time, no in-process shortcuts.

use std::process::{Command, Output};
use std::sync::mpsc;

use simulator::runtime::{Pace, Truth};
use simulator::serve::serve;
use simulator::{BodyFault, SimConfig, Simulation};
use world::presets;

/// Serves the `open` world's first two robots over TCP, one of them with `fault`, runs
/// `square_walk` on them through the coordinator binary, and returns its output and the truth.
fn square_walk_over_tcp(fault: Option<(usize, BodyFault)>) -> (Output, Truth) {
    let (tx, rx) = mpsc::channel();
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let server = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async move {
            let mut world = presets::preset("open").unwrap();
            world.robots.truncate(2);
            let mut sim = Simulation::new(world, SimConfig::default());
            if let Some((index, fault)) = fault {
                sim.set_body_fault(index, Some(fault));
            }
            let (addrs, handle, _task) = serve(sim, "127.0.0.1", 0, Pace::WallClock).await.unwrap();
            tx.send(addrs).unwrap();
            let _ = stop_rx.await;
            let truth = handle.truth().await.unwrap();
            handle.stop();
            truth
        })
    });
    let addrs = rx.recv().unwrap();
    let list: Vec<String> = addrs.iter().map(|(_, a)| format!("tcp://{a}")).collect();
    let out = Command::new(env!("CARGO_BIN_EXE_coordinator"))
        .args([
            "--behaviour",
            "square_walk",
            "--world",
            "open",
            "--transport",
            "tcp",
            "--duration",
            "30",
        ])
        .args(["--robots", &list.join(",")])
        .output()
        .unwrap();
    let _ = stop_tx.send(());
    (out, server.join().unwrap())
}

#[test]
fn square_walk_over_tcp_against_served_robots() {
    let (out, truth) = square_walk_over_tcp(None);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let world = presets::preset("open").unwrap();
    for (id, pose) in truth.robots {
        let start = world.robots.iter().find(|r| r.id == id).unwrap().position;
        let closure = (pose.x - start.x).hypot(pose.y - start.y);
        assert!(
            closure < 0.010,
            "robot {id} closed {:.1} mm from its start\n{text}",
            closure * 1e3
        );
    }
}

#[test]
fn a_served_robot_whose_encoders_never_tick_fails_square_walk() {
    // The robot's firmware answers and reports its moves, but counts no pulse: without encoder
    // evidence of the walk the verdict must be a failure naming it.
    let id = presets::preset("open").unwrap().robots[1].id;
    let (out, _) = square_walk_over_tcp(Some((1, BodyFault::DeadEncoders)));
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(1),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains(&format!("robot {id}")) && text.contains("encoder"),
        "the verdict names robot {id} and its encoders:\n{text}"
    );
}
