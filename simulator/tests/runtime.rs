//! The simulation as an async service under tokio's paused clock: link ends carry packets, and
//! simulated time advances in lockstep with the host tasks.

use std::time::Duration;

use protocol::packets::{Ping, StraightMovement};
use protocol::AnyPacket;
use simulator::runtime::{self, Pace};
use simulator::world::presets;
use simulator::{SimConfig, Simulation};

fn encode(p: impl Into<AnyPacket>) -> Vec<u8> {
    let mut buf = [0u8; protocol::MAX_PACKET];
    let n = p.into().encode(&mut buf).unwrap();
    buf[..n].to_vec()
}

#[tokio::test(start_paused = true)]
async fn a_move_over_an_async_link_end_moves_the_body() {
    let sim = Simulation::new(presets::preset("oval").unwrap(), SimConfig::default());
    let start = sim.robots()[0].pose();
    let (handle, mut ends, task) = runtime::spawn(sim, Pace::TokioClock);
    let mut end = ends.remove(0);
    end.connect();
    let hello = loop {
        if let Ok(AnyPacket::Hello(h)) = protocol::decode(&end.recv().await.unwrap()) {
            break h;
        }
    };
    assert_eq!({ hello.robot_id }, end.robot_id);
    end.send(encode(StraightMovement {
        distance_m: 0.1,
        speed_mps: 0.2,
        move_id: 1,
    }));
    let t0 = tokio::time::Instant::now();
    let finished = tokio::time::timeout(Duration::from_secs(5), async {
        let mut pings = tokio::time::interval(Duration::from_millis(100));
        loop {
            tokio::select! {
                _ = pings.tick() => { end.send(encode(Ping { seq: 0, host_time_us: 0 })); }
                p = end.recv() => {
                    if let Ok(AnyPacket::MoveFinished(m)) = protocol::decode(&p.unwrap()) {
                        if { m.move_id } == 1 { break; }
                    }
                }
            }
        }
    })
    .await;
    assert!(
        finished.is_ok(),
        "move not finished in 5 s of simulated time"
    );
    // Paused-clock time is simulated time: a 0.1 m move at 0.2 m/s with ramps takes 0.5–1.5 s.
    let took = t0.elapsed();
    assert!(
        took > Duration::from_millis(500) && took < Duration::from_millis(1500),
        "{took:?}"
    );
    tokio::time::sleep(Duration::from_millis(300)).await;
    let truth = handle.truth().await.unwrap();
    let p = truth.robots[0].1;
    let moved = (p.x - start.x).hypot(p.y - start.y);
    assert!((moved - 0.1).abs() < 0.005, "moved {moved} m");
    handle.stop();
    task.await.unwrap();
}

#[tokio::test(start_paused = true)]
async fn a_kick_lands_at_its_simulated_time_and_poses_report_it() {
    let sim = Simulation::new(presets::preset("oval").unwrap(), SimConfig::default());
    let start = sim.robots()[1].pose();
    let (handle, _ends, task) = runtime::spawn(sim, Pace::TokioClock);
    handle.kick_at(
        Duration::from_millis(500),
        1,
        [0.0, 0.04, 0.0],
        world::cli::KickHow::Teleport,
    );
    // Paused-clock time is simulated time.
    tokio::time::sleep(Duration::from_millis(400)).await;
    let before = handle.poses().await.unwrap();
    assert!(before.now < Duration::from_millis(500), "{:?}", before.now);
    assert!((before.robots[1].1.y - start.y).abs() < 1e-4, "{before:?}");
    tokio::time::sleep(Duration::from_millis(200)).await;
    let after = handle.poses().await.unwrap();
    assert!(
        (after.robots[1].1.y - start.y - 0.04).abs() < 1e-3,
        "{after:?}"
    );
    assert_eq!(after.robots[0].1, before.robots[0].1, "only robot 1 moved");
    let direct = handle.displace(1, 0.0, -0.04, 0.0).await.unwrap();
    assert!((direct.y - start.y).abs() < 1e-3, "{direct:?}");
    assert!(handle.displace(99, 0.0, 0.0, 0.0).await.is_err());
    handle.stop();
    let _ = task.await;
}

#[tokio::test(start_paused = true)]
async fn a_sink_takes_the_robots_packets_and_hears_the_stop() {
    let sim = Simulation::new(presets::preset("oval").unwrap(), SimConfig::default());
    let (handle, ends, task) = runtime::spawn(sim, Pace::TokioClock);
    let (sender, mut channel) = ends.into_iter().next().unwrap().split();
    let (tx, mut sunk) = tokio::sync::mpsc::unbounded_channel();
    let key = sender.set_sink(Box::new(move |p| tx.send(p).is_ok()));
    sender.connect();
    let hello = loop {
        let p = sunk
            .recv()
            .await
            .unwrap()
            .expect("a packet before the stop");
        if let Ok(AnyPacket::Hello(h)) = protocol::decode(&p) {
            break h;
        }
    };
    assert_eq!({ hello.robot_id }, sender.robot_id);
    // While the sink is set, nothing goes to the channel.
    assert!(channel.try_recv().is_err());
    // Cleared, the packets (the answer to a ping) come through the channel again.
    sender.clear_sink(key);
    sender.send(encode(Ping {
        seq: 7,
        host_time_us: 0,
    }));
    let pong = loop {
        if let Ok(AnyPacket::Pong(p)) = protocol::decode(&channel.recv().await.unwrap()) {
            break p;
        }
    };
    assert_eq!({ pong.seq }, 7);
    // A sink set again hears the simulation's stop; one set after it hears so at once.
    let (tx, mut sunk) = tokio::sync::mpsc::unbounded_channel();
    sender.set_sink(Box::new(move |p| tx.send(p).is_ok()));
    handle.stop();
    task.await.unwrap();
    let heard = tokio::time::timeout(Duration::from_secs(1), async {
        while let Some(p) = sunk.recv().await {
            if p.is_none() {
                return true;
            }
        }
        false
    })
    .await;
    assert_eq!(heard, Ok(true), "the sink heard the stop");
    assert!(sunk.recv().await.is_none(), "the stop drops the sink");
    let (tx, mut late) = tokio::sync::mpsc::unbounded_channel();
    sender.set_sink(Box::new(move |p| tx.send(p).is_ok()));
    assert_eq!(
        late.try_recv(),
        Ok(None),
        "a sink set after the stop hears it at once"
    );
}
