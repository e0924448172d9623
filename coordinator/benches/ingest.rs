//! State packets reflected into the world model per second, for 10, 100, 1,000 and 10,000 robot
//! links fed by a synthetic packet source (no physics): frame bytes → robot actor (checksum,
//! decode, odometry) → `StateUpdated` → world model. Also the p99 latency from a frame entering
//! the link to the world model holding it.
//!
//! Everything runs on one actix arbiter; the source stamps each state packet with its send time so
//! the latency is measured end to end.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use actix::prelude::*;
use coordinator::world_model::WorldModel;
use futures::future::BoxFuture;
use futures::FutureExt;
use protocol::RobotState;
use robot_actor::link::{Connector, Link, LinkCounters, LinkError, LinkEvent};
use robot_actor::{Robot, RobotConfig, StateUpdated};
use tokio::sync::mpsc;

/// A robot that says hello and then sends whatever the bench pushes into its queue.
struct Synthetic {
    id: u16,
    feed: Arc<Mutex<Vec<mpsc::UnboundedSender<LinkEvent>>>>,
}

impl Connector for Synthetic {
    fn peer(&self) -> String {
        format!("synthetic://{}", self.id)
    }
    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let (tx, mut from_host) = mpsc::channel::<Vec<u8>>(1024);
        let (events, rx) = mpsc::unbounded_channel();
        let mut settings = protocol::Settings::default();
        settings.identity.robot_id = self.id;
        let hello = protocol::packets::Hello::new(&settings, [0, 1, 0]);
        let (buf, n) = protocol::frame::encode_to_array(&hello);
        let _ = events.send(LinkEvent::Packet(buf[..n].to_vec()));
        self.feed.lock().unwrap().push(events);
        // Host packets (pings, settings reads) are drained and ignored.
        tokio::spawn(async move { while from_host.recv().await.is_some() {} });
        async move {
            Ok(Link {
                peer: "synthetic".into(),
                tx,
                rx,
                counters: Arc::new(LinkCounters::default()),
            })
        }
        .boxed()
    }
}

/// Applies updates to the world model and records latencies.
struct Ingest {
    model: WorldModel,
    epoch: Instant,
    latencies: Arc<Mutex<Vec<u64>>>,
}

impl Actor for Ingest {
    type Context = Context<Self>;
}

impl Handler<StateUpdated> for Ingest {
    type Result = ();
    fn handle(&mut self, u: StateUpdated, _: &mut Context<Self>) {
        self.model.apply(&u);
        let sent = (u64::from(u.state.link.tx_packets) << 32) | u64::from(u.state.link.rx_packets);
        let now = self.epoch.elapsed().as_nanos() as u64;
        self.latencies
            .lock()
            .unwrap()
            .push(now.saturating_sub(sent));
    }
}

fn state_frame(epoch: Instant, id: u16, seq: i32) -> Vec<u8> {
    let mut s = RobotState::default();
    s.encoders.left_ticks = seq;
    s.encoders.right_ticks = seq;
    s.uptime_ms = id.into();
    let t = epoch.elapsed().as_nanos() as u64;
    s.link.rx_packets = t as u32;
    s.link.tx_packets = (t >> 32) as u32;
    let (buf, n) = protocol::frame::encode_to_array(&s);
    buf[..n].to_vec()
}

async fn measure(links: usize, wall: Duration) -> (f64, Duration) {
    let feed = Arc::new(Mutex::new(Vec::new()));
    let epoch = Instant::now();
    let latencies = Arc::new(Mutex::new(Vec::with_capacity(1 << 20)));
    let model = WorldModel::new(Arc::new(simulator::world::Track::default()));
    for id in 1..=links as u16 {
        model.add(id);
    }
    let ingest = Ingest {
        model: model.clone(),
        epoch,
        latencies: Arc::clone(&latencies),
    }
    .start();
    let mut robots = Vec::new();
    for id in 1..=links as u16 {
        let robot = Robot::start(
            Arc::new(Synthetic {
                id,
                feed: Arc::clone(&feed),
            }),
            RobotConfig {
                ping_period: Duration::from_secs(3600),
                link_timeout: Duration::from_secs(3600),
                ..RobotConfig::default()
            },
        );
        robot.subscribe(ingest.clone().recipient());
        robots.push(robot);
    }
    for r in &robots {
        r.connected().await.expect("hello");
    }
    let senders = feed.lock().unwrap().clone();
    // Keep a bounded number of frames in flight so latency measures the pipeline, not a backlog.
    let batch = 2_000.max(links);
    let start = Instant::now();
    let mut seq = 0i32;
    latencies.lock().unwrap().clear();
    while start.elapsed() < wall {
        seq = seq.wrapping_add(1);
        for k in 0..batch {
            let i = (seq as usize * batch + k) % links;
            let _ = senders[i].send(LinkEvent::Packet(state_frame(epoch, i as u16 + 1, seq)));
        }
        // Let the actors drain this batch before the next one.
        while latencies.lock().unwrap().len() < (seq as usize) * batch {
            tokio::task::yield_now().await;
        }
    }
    let elapsed = start.elapsed();
    let mut l = std::mem::take(&mut *latencies.lock().unwrap());
    let rate = l.len() as f64 / elapsed.as_secs_f64();
    l.sort_unstable();
    let p99 = l.get(l.len() * 99 / 100).copied().unwrap_or(0);
    for r in robots {
        r.close();
    }
    (rate, Duration::from_nanos(p99))
}

fn main() {
    let quick = cfg!(debug_assertions);
    let system = actix::System::new();
    system.block_on(async {
        println!("links    packets/s into the world model    p99 frame -> model");
        let mut base = None;
        for links in [10usize, 100, 1_000, 10_000] {
            let wall = if quick {
                Duration::from_millis(100)
            } else {
                Duration::from_secs(2)
            };
            let (rate, p99) = measure(links, wall).await;
            let ratio = rate / *base.get_or_insert(rate);
            println!(
                "{links:6}   {rate:14.0}  ({ratio:4.2}x of 10 links)   {:10.1} µs",
                p99.as_secs_f64() * 1e6
            );
        }
    });
}
