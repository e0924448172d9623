//! Robot actors on shard arbiters: every state reaches a batch subscriber, in order per robot, and
//! a robot's event arrives after the states it published before it and before those after it;
//! robots woken together hand their states over in a few batches, not one each.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use actix::prelude::*;
use protocol::packets;
use protocol::RobotState;
use robot_actor::link::scripted::{Feed, Scripted};
use robot_actor::link::LinkEvent;
use robot_actor::{RobotConfig, RobotEvent, RobotEventKind, Shards, StateBatch};
use tokio::sync::mpsc;

fn frame<P: protocol::Packet>(p: &P) -> Vec<u8> {
    let (buf, n) = protocol::frame::encode_to_array(p);
    buf[..n].to_vec()
}

/// What the subscriber heard, in order: a robot's state (by its encoder count), or its event.
#[derive(Debug)]
enum Heard {
    State(u16, i32),
    Event(u16),
}

struct Collector {
    to: mpsc::UnboundedSender<Heard>,
}

impl Actor for Collector {
    type Context = Context<Self>;
}

impl Handler<StateBatch> for Collector {
    type Result = ();
    fn handle(&mut self, batch: StateBatch, _: &mut Context<Self>) {
        for u in batch.0 {
            let _ = self
                .to
                .send(Heard::State(u.robot_id, u.state.encoders.left_ticks));
        }
    }
}

impl Handler<RobotEvent> for Collector {
    type Result = ();
    fn handle(&mut self, e: RobotEvent, _: &mut Context<Self>) {
        if e.kind == RobotEventKind::WatchdogStop {
            let _ = self.to.send(Heard::Event(e.robot_id));
        }
    }
}

#[actix_rt::test]
async fn sharded_robots_deliver_every_state_in_order_and_events_between_them() {
    const ROBOTS: u16 = 6;
    const STATES: i32 = 200;
    let shards = Shards::new(2);
    let feed: Feed = Arc::new(Mutex::new(Vec::new()));
    let (to, mut heard) = mpsc::unbounded_channel();
    let collector = Collector { to }.start();
    let mut robots = Vec::new();
    for id in 1..=ROBOTS {
        let robot = shards.start(
            Arc::new(Scripted {
                id,
                feed: Arc::clone(&feed),
            }),
            RobotConfig::default(),
        );
        robot.subscribe_batches(collector.clone().recipient());
        robot.subscribe_events(collector.clone().recipient());
        robots.push(robot);
    }
    for r in &robots {
        r.connected().await.expect("hello");
    }
    let sinks = feed.lock().unwrap().clone();
    // Interleaved over the robots, with each robot's event after its first half of states.
    for seq in 1..=STATES {
        for (_, sink) in &sinks {
            let mut s = RobotState::default();
            s.encoders.left_ticks = seq;
            let _ = sink.send(LinkEvent::Packet(frame(&s)));
            if seq == STATES / 2 {
                let _ = sink.send(LinkEvent::Packet(frame(&packets::WatchdogStop {
                    at_ms: 0,
                    seq: 1,
                    silent_ms: 0,
                })));
            }
        }
    }
    let mut last = vec![0i32; usize::from(ROBOTS) + 1];
    let mut events = 0;
    let expected = usize::from(ROBOTS) * (STATES as usize + 1);
    for _ in 0..expected {
        let h = tokio::time::timeout(Duration::from_secs(20), heard.recv())
            .await
            .expect("every state and event arrives")
            .expect("the collector lives");
        match h {
            Heard::State(id, seq) => {
                assert_eq!(
                    seq,
                    last[usize::from(id)] + 1,
                    "robot {id}'s states in order"
                );
                last[usize::from(id)] = seq;
            }
            Heard::Event(id) => {
                assert_eq!(
                    last[usize::from(id)],
                    STATES / 2,
                    "robot {id}'s event between its states"
                );
                events += 1;
            }
        }
    }
    assert_eq!(events, usize::from(ROBOTS));
    assert!(last[1..].iter().all(|&s| s == STATES));
    for r in &robots {
        r.close();
    }
}

/// Counts the batches and the states in them.
struct Counter {
    to: mpsc::UnboundedSender<usize>,
}

impl Actor for Counter {
    type Context = Context<Self>;
}

impl Handler<StateBatch> for Counter {
    type Result = ();
    fn handle(&mut self, batch: StateBatch, _: &mut Context<Self>) {
        let _ = self.to.send(batch.0.len());
    }
}

#[actix_rt::test]
async fn robots_woken_together_send_their_states_in_few_batches() {
    const ROBOTS: u16 = 100;
    let arbiter = Arbiter::new();
    let feed: Feed = Arc::new(Mutex::new(Vec::new()));
    let (to, mut sizes) = mpsc::unbounded_channel();
    let counter = Counter { to }.start();
    let mut robots = Vec::new();
    for id in 1..=ROBOTS {
        let robot = robot_actor::Robot::start_in(
            &arbiter.handle(),
            Arc::new(Scripted {
                id,
                feed: Arc::clone(&feed),
            }),
            RobotConfig {
                batch_states: true,
                ..RobotConfig::default()
            },
        );
        robot.subscribe_batches(counter.clone().recipient());
        robots.push(robot);
    }
    for r in &robots {
        r.connected().await.expect("hello");
    }
    // Hold the arbiter's thread while every robot gets a frame, as a burst from the links' I/O
    // would find it busy; then every robot is woken before any runs.
    let (release, held) = std::sync::mpsc::channel::<()>();
    arbiter.spawn_fn(move || {
        let _ = held.recv();
    });
    for (_, sink) in feed.lock().unwrap().iter() {
        let _ = sink.send(LinkEvent::Packet(frame(&RobotState::default())));
    }
    release.send(()).expect("the arbiter waits");
    let (mut states, mut batches) = (0, 0);
    while states < usize::from(ROBOTS) {
        states += tokio::time::timeout(Duration::from_secs(20), sizes.recv())
            .await
            .expect("every state arrives")
            .expect("the counter lives");
        batches += 1;
    }
    // One batch per pass of the arbiter's scheduler (61 tasks in tokio), not one per robot.
    assert!(
        batches <= 4,
        "{states} states came in {batches} batches, expected a few"
    );
    for r in &robots {
        r.close();
    }
    arbiter.stop();
}
