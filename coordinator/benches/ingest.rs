//! State frames into the world model, for 10, 100, 1,000 and 10,000 robot links fed by a
//! synthetic packet source (no physics): frame bytes → robot actor (checksum, decode, odometry)
//! → `StateBatch` → world model, the path the supervisor takes.
//!
//! The robot actors are spread over shard arbiters beside the system arbiter
//! (`Shards::beside_system`: one per core but one), as the coordinator does for robots on a real
//! clock; the world model is written on the system arbiter, like the supervisor's. The source is
//! a thread of its own that stamps each frame with its send time, so latency is measured end to
//! end, from the frame entering its link to the model holding it. Per link count, in one run:
//!
//! - saturation: the source keeps a window of frames in flight, as many as the pipeline takes;
//! - the offered load of 10,000 links × 50 Hz: 500,000 frames/s, paced (due frames sent every
//!   100 µs), spread round-robin over the links; p50 and p99 of frame → world model, and p99 in
//!   each fifth of the phase (median and worst), since one stall of a 2-core machine's scheduler
//!   can decide the p99 of a whole phase;
//! - a bare tokio channel carrying the same number of the same frames from the same source to a
//!   task on the system arbiter, and the saturation rate as a fraction of it.
//!
//! Built without optimisations (`cargo test --benches`), every phase runs only a few milliseconds.
//! `INGEST_LINKS=N` runs only the row for N links.

/// The coordinator binary's allocator, so the bench measures what it runs.
#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use actix::prelude::*;
use coordinator::world_model::WorldModel;
use protocol::RobotState;
use robot_actor::link::scripted::{Feed, Scripted};
use robot_actor::link::LinkEvent;
use robot_actor::{RobotConfig, Shards, StateBatch};
use tokio::sync::mpsc;

/// The offered load: 10,000 links at 50 Hz.
const OFFERED_PER_S: f64 = 500_000.0;

/// What the world-model side has taken so far.
#[derive(Default)]
struct Taken {
    /// Frames applied.
    frames: AtomicU64,
    /// When the latest was applied, nanoseconds after the epoch.
    last_ns: AtomicU64,
    /// Send time after the epoch and frame → model latency of each frame, nanoseconds, while
    /// recording.
    latencies: Mutex<Vec<(u64, u64)>>,
    /// Whether latencies are being recorded: only at the offered load, so the saturation phase
    /// does not also pay for growing the record.
    recording: AtomicBool,
}

/// Applies batches to the world model, as the supervisor does, and records latencies.
struct Ingest {
    model: WorldModel,
    epoch: Instant,
    taken: Arc<Taken>,
}

impl Actor for Ingest {
    type Context = Context<Self>;
}

impl Handler<StateBatch> for Ingest {
    type Result = ();
    fn handle(&mut self, batch: StateBatch, _: &mut Context<Self>) {
        let mut latencies = self
            .taken
            .recording
            .load(Ordering::Relaxed)
            .then(|| self.taken.latencies.lock().unwrap());
        let mut now = 0;
        for u in &batch.0 {
            self.model.apply(u);
            let sent =
                (u64::from(u.state.link.tx_packets) << 32) | u64::from(u.state.link.rx_packets);
            now = self.epoch.elapsed().as_nanos() as u64;
            if let Some(l) = latencies.as_mut() {
                l.push((sent, now.saturating_sub(sent)));
            }
        }
        self.taken
            .frames
            .fetch_add(batch.0.len() as u64, Ordering::Relaxed);
        self.taken.last_ns.store(now, Ordering::Relaxed);
    }
}

/// A full state frame from robot `id`, stamped with the time since `epoch`.
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

/// How the source sends.
#[derive(Clone, Copy)]
enum Pace {
    /// As fast as the pipeline takes them, at most this many frames in flight.
    Saturate { window: u64 },
    /// This many frames per second.
    Offered(f64),
}

/// Sends frames round-robin over `sinks` for `wall` (or `count` frames, whichever is first),
/// paced by `pace` against `taken`; returns how many it sent.
fn source(
    epoch: Instant,
    sinks: &[(u16, mpsc::UnboundedSender<LinkEvent>)],
    pace: Pace,
    taken: &Taken,
    wall: Duration,
) -> u64 {
    let start = Instant::now();
    let base = taken.frames.load(Ordering::Relaxed);
    let mut sent = 0u64;
    while start.elapsed() < wall {
        let due = match pace {
            Pace::Saturate { window } => taken.frames.load(Ordering::Relaxed) - base + window,
            Pace::Offered(rate) => (start.elapsed().as_secs_f64() * rate) as u64,
        };
        while sent < due {
            let (id, sink) = &sinks[sent as usize % sinks.len()];
            let seq = (sent / sinks.len() as u64) as i32;
            let _ = sink.send(LinkEvent::Packet(state_frame(epoch, *id, seq)));
            sent += 1;
        }
        match pace {
            Pace::Saturate { .. } => std::thread::yield_now(),
            Pace::Offered(_) => std::thread::sleep(Duration::from_micros(100)),
        }
    }
    sent
}

/// Runs `source` on a thread of its own and waits (on the caller's arbiter) until the model has
/// taken every frame it sent.
async fn drive(
    epoch: Instant,
    sinks: Arc<Vec<(u16, mpsc::UnboundedSender<LinkEvent>)>>,
    pace: Pace,
    taken: Arc<Taken>,
    wall: Duration,
) -> u64 {
    let base = taken.frames.load(Ordering::Relaxed);
    let (done, sent) = tokio::sync::oneshot::channel();
    let t = Arc::clone(&taken);
    std::thread::spawn(move || {
        let _ = done.send(source(epoch, &sinks, pace, &t, wall));
    });
    let sent = sent.await.expect("the source thread finishes");
    while taken.frames.load(Ordering::Relaxed) < base + sent {
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    sent
}

/// One row of the table.
struct Row {
    links: usize,
    saturation: f64,
    offered_rate: f64,
    p50: Duration,
    p99: Duration,
    /// p99 of each of [`WINDOWS`] equal spans of send time at the offered load: median, worst.
    window_p99: (Duration, Duration),
    bare: f64,
}

/// Spans the offered phase's p99 is also taken over, so one scheduler stall on a 2-core machine
/// shows as one bad window beside the others instead of standing for the whole phase.
const WINDOWS: usize = 5;

fn percentile(sorted: &[u64], p: usize) -> Duration {
    Duration::from_nanos(
        sorted
            .get((sorted.len() * p / 100).min(sorted.len().saturating_sub(1)))
            .copied()
            .unwrap_or(0),
    )
}

/// The coordinator's shards; `INGEST_SHARDS=N` sets their number instead (to compare layouts).
fn shards() -> Shards {
    std::env::var("INGEST_SHARDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .map_or_else(Shards::beside_system, Shards::new)
}

async fn measure(links: usize, wall: Duration) -> Row {
    let shards = shards();
    let feed: Feed = Arc::new(Mutex::new(Vec::new()));
    let epoch = Instant::now();
    let taken = Arc::new(Taken::default());
    let model = WorldModel::new(Arc::new(world::Track::default()));
    for id in 1..=links as u16 {
        model.add(id);
    }
    let ingest = Ingest {
        model: model.clone(),
        epoch,
        taken: Arc::clone(&taken),
    }
    .start();
    let mut robots = Vec::new();
    for id in 1..=links as u16 {
        let robot = shards.start(
            Arc::new(Scripted {
                id,
                feed: Arc::clone(&feed),
            }),
            RobotConfig {
                ping_period: Duration::from_secs(3600),
                link_timeout: Duration::from_secs(3600),
                ..RobotConfig::default()
            },
        );
        robot.subscribe_batches(ingest.clone().recipient());
        robots.push(robot);
    }
    for r in &robots {
        r.connected().await.expect("hello");
    }
    let mut sinks = feed.lock().unwrap().clone();
    sinks.sort_by_key(|(id, _)| *id);
    let sinks = Arc::new(sinks);

    // (a) Saturation: enough in flight that every shard always has work.
    let window = (4 * links as u64).max(20_000);
    let t0 = epoch.elapsed().as_nanos() as u64;
    let base = taken.frames.load(Ordering::Relaxed);
    let sent = drive(
        epoch,
        Arc::clone(&sinks),
        Pace::Saturate { window },
        Arc::clone(&taken),
        wall,
    )
    .await;
    let took = taken.frames.load(Ordering::Relaxed) - base;
    let saturation = took as f64 / ((taken.last_ns.load(Ordering::Relaxed) - t0) as f64 * 1e-9);

    // (b) The offered load, paced; only its latencies are kept.
    {
        let mut l = taken.latencies.lock().unwrap();
        // Written once here, so recording takes no page faults.
        l.clear();
        l.resize((OFFERED_PER_S * wall.as_secs_f64() * 1.1) as usize, (0, 0));
        l.clear();
    }
    taken.recording.store(true, Ordering::Relaxed);
    let t0 = epoch.elapsed().as_nanos() as u64;
    let base = taken.frames.load(Ordering::Relaxed);
    drive(
        epoch,
        Arc::clone(&sinks),
        Pace::Offered(OFFERED_PER_S),
        Arc::clone(&taken),
        wall,
    )
    .await;
    let offered_rate = (taken.frames.load(Ordering::Relaxed) - base) as f64
        / ((taken.last_ns.load(Ordering::Relaxed) - t0) as f64 * 1e-9);
    taken.recording.store(false, Ordering::Relaxed);
    let record = std::mem::take(&mut *taken.latencies.lock().unwrap());
    let span = (wall.as_nanos() as u64 / WINDOWS as u64).max(1);
    let mut windows = vec![Vec::new(); WINDOWS];
    for &(sent, latency) in &record {
        let k = (sent.saturating_sub(t0) / span) as usize;
        windows[k.min(WINDOWS - 1)].push(latency);
    }
    let mut window_p99: Vec<Duration> = windows
        .iter_mut()
        .filter(|w| !w.is_empty())
        .map(|w| {
            w.sort_unstable();
            percentile(w, 99)
        })
        .collect();
    window_p99.sort_unstable();
    let window_p99 = (
        window_p99
            .get(window_p99.len() / 2)
            .copied()
            .unwrap_or_default(),
        window_p99.last().copied().unwrap_or_default(),
    );
    let mut l: Vec<u64> = record.into_iter().map(|(_, latency)| latency).collect();
    l.sort_unstable();
    let (p50, p99) = (percentile(&l, 50), percentile(&l, 99));

    for r in &robots {
        r.close();
    }
    drop(shards);

    // (c) The same number of the same frames through one bare channel.
    let bare = bare_channel(epoch, links, sent).await;
    Row {
        links,
        saturation,
        offered_rate,
        p50,
        p99,
        window_p99,
        bare,
    }
}

/// Frames per second through one tokio channel from the same source (a thread) to a task on this
/// arbiter that only counts them: `count` frames, addressed round-robin as for `links` robots.
async fn bare_channel(epoch: Instant, links: usize, count: u64) -> f64 {
    let (tx, mut rx) = mpsc::unbounded_channel::<LinkEvent>();
    let taken = Arc::new(Taken::default());
    let counter = Arc::clone(&taken);
    actix::spawn(async move {
        while rx.recv().await.is_some() {
            let n = counter.frames.fetch_add(1, Ordering::Relaxed) + 1;
            if n == count {
                counter
                    .last_ns
                    .store(epoch.elapsed().as_nanos() as u64, Ordering::Relaxed);
            }
        }
    });
    let t0 = epoch.elapsed().as_nanos() as u64;
    let t = Arc::clone(&taken);
    let (done, finished) = tokio::sync::oneshot::channel();
    std::thread::spawn(move || {
        for k in 0..count {
            let id = (k % links as u64) as u16 + 1;
            let seq = (k / links as u64) as i32;
            let _ = tx.send(LinkEvent::Packet(state_frame(epoch, id, seq)));
        }
        let _ = done.send(());
    });
    finished.await.expect("the source thread finishes");
    while t.frames.load(Ordering::Relaxed) < count {
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    count as f64 / ((t.last_ns.load(Ordering::Relaxed) - t0) as f64 * 1e-9)
}

fn main() {
    let quick = cfg!(debug_assertions);
    let wall = if quick {
        Duration::from_millis(20)
    } else {
        Duration::from_secs(2)
    };
    let system = actix::System::new();
    system.block_on(async {
        let shards = shards().len();
        println!(
            "ingest: {shards} shard arbiter(s), offered load {OFFERED_PER_S:.0} frames/s, \
             {:.1} s per phase",
            wall.as_secs_f64()
        );
        println!(
            " links  saturation frames/s  bare channel frames/s  fraction   \
             at offered: frames/s      p50 µs     p99 µs   p99 of {WINDOWS} windows: median, worst µs"
        );
        // `INGEST_LINKS=10000` measures one link count only (for profiling).
        let only: Option<usize> = std::env::var("INGEST_LINKS")
            .ok()
            .and_then(|v| v.parse().ok());
        for links in [10usize, 100, 1_000, 10_000] {
            if only.is_some_and(|n| n != links) {
                continue;
            }
            let r = measure(links, wall).await;
            println!(
                "{:6}  {:19.0}  {:21.0}  {:8.3}   {:19.0}  {:10.1} {:10.1}   {:26.1} {:10.1}",
                r.links,
                r.saturation,
                r.bare,
                r.saturation / r.bare,
                r.offered_rate,
                r.p50.as_secs_f64() * 1e6,
                r.p99.as_secs_f64() * 1e6,
                r.window_p99.0.as_secs_f64() * 1e6,
                r.window_p99.1.as_secs_f64() * 1e6
            );
        }
    });
}
