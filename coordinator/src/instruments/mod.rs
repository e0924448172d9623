//! Everything around a run, behind one door: the experiment asks for [`Instruments`] and gets a
//! [`Run`] back, and calls its hooks at a few points of [`crate::run_with`]. Behind it: the
//! MCAP recorder (a tap on every link and the observer's snapshots), replay's links and check,
//! recovery of a cut recording, the control panel, trajectory plots, and sweeps of many runs
//! (each a child process of the `coordinator` binary).
//!
//! # Layout
//! - `observer`: the actor that samples the world model for the recorder, the panel and plots.
//! - `record`: the MCAP writer and its layouts; `replay` and `recover` read recordings back.
//! - `panel`: the live web control panel.
//! - `plot`: the trajectory plot of a run.
//! - `sweep`: batches of runs over seeds and settings, with their statistics.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use crate::twin::SimHandle;
use actix::{Actor, Addr};
use anyhow::{Context as _, Result};
use behaviours::Verdict;
use robot_actor::link::Discovered;
use robot_actor::Robot;
use serde_json::json;
use tokio::sync::broadcast;
use tokio::time::Instant;
use world::World;

pub mod campaign;
pub mod observer;
pub mod panel;
pub mod plot;
pub mod record;
pub mod recover;
pub mod replay;
pub mod sweep;

pub use observer::Instruments;

use crate::instruments::observer::{
    track_lines, BoxShape, Observed, Observer, ObserverSetup, TakeObserved,
};
use crate::instruments::panel::{PanelContext, PanelServer};
use crate::instruments::record::{RecordStats, Recorder, RunInfo, Tap, Topic};
use crate::instruments::replay::{Recording, ReplayCheck};
use crate::plan::{Plan, Transport};
use crate::report::Report;
use crate::supervisor::Supervisor;

/// Everything a run produced.
#[derive(Debug)]
pub struct Run {
    /// The report.
    pub report: Report,
    /// Trails and replay captures.
    pub observed: Observed,
    /// A replay's comparison with its recording.
    pub replay: Option<ReplayCheck>,
    /// The recording written, and its totals.
    pub recording: Option<(PathBuf, RecordStats)>,
    /// Messages in the recording replayed, per topic, and whether it was cut short.
    pub replayed: Option<(std::collections::BTreeMap<String, u64>, Option<String>)>,
}

/// The recording's `/events`, for what happens to the robots from outside (a fault, a kick).
// Only simulated robots take faults and kicks: built without the simulator nothing notes them.
#[cfg_attr(not(feature = "sim"), allow(dead_code))]
#[derive(Clone)]
pub(crate) struct EventLog {
    recorder: Option<Arc<Recorder>>,
    t0: Instant,
}

impl EventLog {
    /// Notes `kind` happening to robot `robot` now.
    #[cfg_attr(not(feature = "sim"), allow(dead_code))]
    pub(crate) fn note(&self, robot: u16, kind: &str, detail: &str) {
        if let Some(rec) = &self.recorder {
            let t = (Instant::now() - self.t0).as_secs_f64();
            rec.json(
                Topic::Events,
                &json!({"t": t, "robot": robot, "kind": kind, "detail": detail}),
            );
        }
    }
}

pub(crate) struct Hooks {
    instruments: Instruments,
    recorder: Option<Arc<Recorder>>,
    replay: Option<Arc<Recording>>,
    t0: Instant,
    feed: Option<broadcast::Sender<Arc<str>>>,
    /// Bound when the hooks are made, served once the robots are connected.
    listener: Option<std::net::TcpListener>,
    panel: Option<PanelServer>,
    links: Option<tokio::task::JoinHandle<()>>,
}

impl Hooks {
    pub(crate) fn new(
        plan: &Plan,
        world_name: &str,
        robots: usize,
        instruments: Instruments,
    ) -> Result<Self> {
        // First, so that a busy panel address stops the run before anything starts.
        let listener = match &instruments.panel {
            Some(options) => Some(crate::instruments::panel::bind(options.addr)?),
            None => None,
        };
        let replay = match &plan.transport {
            Transport::Replay(path) => Some(Arc::new(crate::instruments::replay::load(path)?)),
            _ => None,
        };
        let recorder = match &instruments.record {
            Some(path) => Some(Recorder::create(
                path,
                &RunInfo {
                    behaviour: plan.behaviour.clone(),
                    world: world_name.to_string(),
                    robots,
                    seed: plan.seed,
                    params: plan.params.clone(),
                    simulated: matches!(plan.transport, Transport::Sim)
                        || replay.as_ref().is_some_and(|r| r.info.simulated),
                    addresses: match &plan.transport {
                        Transport::Addresses(a) => a.clone(),
                        _ => Vec::new(),
                    },
                    duration_s: Some(plan.duration.as_secs_f64()),
                    start_unix_ns: std::time::SystemTime::now()
                        .duration_since(std::time::UNIX_EPOCH)
                        .map_or(0, |d| d.as_nanos() as u64),
                },
            )?),
            None => None,
        };
        let t0 = recorder.as_ref().map_or_else(Instant::now, |r| r.t0());
        let feed = instruments.panel.as_ref().map(|_| broadcast::channel(64).0);
        Ok(Self {
            instruments,
            recorder,
            replay,
            t0,
            feed,
            listener,
            panel: None,
            links: None,
        })
    }

    /// A replay's links, starting now, and whether the recorded robots were simulated.
    pub(crate) fn replay_connectors(&mut self) -> Result<(Vec<Discovered>, bool)> {
        let rec = self
            .replay
            .as_ref()
            .context("replay transport without a recording")?;
        self.t0 = Instant::now();
        Ok((rec.connectors(self.t0), rec.info.simulated))
    }

    pub(crate) fn tap(&self, found: Vec<Discovered>, world: &World) -> Vec<Discovered> {
        let Some(rec) = &self.recorder else {
            return found;
        };
        found
            .into_iter()
            .enumerate()
            .map(|(i, d)| {
                let id = world.robots.get(i).map_or(0, |r| r.id);
                Discovered {
                    name: d.name,
                    connector: Arc::new(Tap::new(d.connector, i, id, Arc::clone(rec))),
                }
            })
            .collect()
    }

    /// Where faults and kicks are noted as they land: the recording's `/events`, when there is
    /// one.
    pub(crate) fn event_log(&self) -> EventLog {
        EventLog {
            recorder: self.recorder.clone(),
            t0: self.t0,
        }
    }

    /// Whether an instrument needs every reflected state: a run with none of them keeps the
    /// observer off the state stream, where its own world model would double the supervisor's.
    pub(crate) fn watches_states(&self) -> bool {
        self.recorder.is_some()
            || self.feed.is_some()
            || self.replay.is_some()
            || self.instruments.trails
    }

    pub(crate) fn observer(&self, world: &World, sim: Option<SimHandle>) -> Addr<Observer> {
        let setup = ObserverSetup {
            track: Arc::new(world.track.clone()),
            arena: (world.arena.width_m, world.arena.height_m),
            boxes: boxes(world),
            recorder: self.recorder.clone(),
            feed: self.feed.clone(),
            wanted: self.replay.as_ref().map(|r| r.wanted()),
            sim,
        };
        Observer::new(setup, self.t0).start()
    }

    pub(crate) async fn serve_panel(
        &mut self,
        supervisor: &Addr<Supervisor>,
        robots: &[(u16, Robot)],
        world: &World,
    ) -> Result<()> {
        let (Some(listener), Some(feed)) = (self.listener.take(), &self.feed) else {
            return Ok(());
        };
        let scene = json!({
            "arena": [world.arena.width_m, world.arena.height_m],
            "track": track_lines(&world.track),
            "boxes": boxes(world).iter().map(|b| json!({"size": [b.size.0, b.size.1], "pose": b.pose})).collect::<Vec<_>>(),
            "robots": robots.iter().map(|(id, _)| *id).collect::<Vec<_>>(),
            "body": [world::robot::LENGTH_M, world::robot::WIDTH_M],
            "replay": self.replay.is_some(),
        });
        let server = crate::instruments::panel::serve(
            listener,
            PanelContext {
                supervisor: supervisor.clone(),
                robots: robots.to_vec(),
                feed: feed.clone(),
                scene,
            },
        )?;
        eprintln!("coordinator: control panel at {}", server.url);
        self.panel = Some(server);
        self.links = Some(tokio::spawn(link_stats(robots.to_vec(), feed.clone())));
        Ok(())
    }

    pub(crate) async fn replay_to_end(&self) {
        if let Some(r) = &self.replay {
            tokio::time::sleep_until(self.t0 + r.end + Duration::from_millis(300)).await;
        }
    }

    pub(crate) async fn linger(&self, verdict: &Verdict) {
        // A run ended by Ctrl-C was asked to end: the panel goes with it.
        let interrupted = verdict.summary.contains("Ctrl-C");
        if self.panel.is_some()
            && !interrupted
            && self.instruments.panel.as_ref().is_some_and(|p| p.linger)
        {
            eprintln!(
                "coordinator: experiment over ({}); the panel stays up until Ctrl-C",
                verdict.summary
            );
            let _ = tokio::signal::ctrl_c().await;
        }
    }

    pub(crate) async fn finish(self, report: Report, observer: &Addr<Observer>) -> Result<Run> {
        if let Some(task) = &self.links {
            task.abort();
        }
        let observed = observer.send(TakeObserved).await.context("observer gone")?;
        let replay = self
            .replay
            .as_ref()
            .map(|r| crate::instruments::replay::check(r, &observed.captured));
        let recording = match &self.recorder {
            Some(rec) => {
                // The overall result (the behaviour's word overruled by the ground truth), the
                // behaviour's own word, and what the safety check held back.
                let t = (Instant::now() - self.t0).as_secs_f64();
                rec.json(
                    Topic::Events,
                    &json!({"t": t, "robot": 0, "kind": "verdict",
                        "detail": report.verdict.summary, "success": report.success(),
                        "behaviour_success": report.verdict.success,
                        "metrics": report.verdict.metrics, "held": report.held_intents}),
                );
                Some((rec.path().to_path_buf(), rec.finish()?))
            }
            None => None,
        };
        Ok(Run {
            report,
            observed,
            replay,
            recording,
            replayed: self
                .replay
                .as_ref()
                .map(|r| (r.counts.clone(), r.truncated.clone())),
        })
    }
}

/// The host's link statistics of every robot for the panel, twice a second.
async fn link_stats(robots: Vec<(u16, Robot)>, feed: broadcast::Sender<Arc<str>>) {
    let mut tick = tokio::time::interval(Duration::from_millis(500));
    loop {
        tick.tick().await;
        let mut links = serde_json::Map::new();
        for (id, robot) in &robots {
            let Ok(s) = robot.snapshot().await else {
                continue;
            };
            let l = s.link;
            let ms = |d: Option<Duration>| d.map(|d| d.as_secs_f64() * 1e3);
            links.insert(
                id.to_string(),
                json!({"in": l.packets_in, "out": l.packets_out, "checksum_errors": l.checksum_errors,
                    "dropped": l.dropped_frames, "rtt_ms": ms(l.rtt), "rtt_mean_ms": ms(l.rtt_mean),
                    "losses": l.losses, "reconnects": l.reconnects, "connected": s.connected}),
            );
        }
        // No page open is fine.
        let _ = feed.send(Arc::from(
            json!({"type": "links", "links": links}).to_string(),
        ));
    }
}

fn boxes(world: &World) -> Vec<BoxShape> {
    world
        .obstacles
        .iter()
        .map(|o| BoxShape {
            size: (o.width_m, o.height_m),
            pose: [o.position.x, o.position.y, o.heading_rad],
        })
        .collect()
}
