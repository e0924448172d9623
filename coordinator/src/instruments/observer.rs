//! The observer: one actor that watches every robot for the recorder, the control panel, the
//! trajectory plot and replay's check, so none of them costs the supervisor anything.
//!
//! It keeps its own [`WorldModel`], fed the same `StateUpdated` stream as the supervisor's. The
//! model's view of a robot depends only on that robot's own updates, in order, so the view after a
//! robot's k-th update is the same in a recorded run and in its replay, whatever the interleaving
//! of robots and timers: a world snapshot names, per robot, how many updates it includes, and
//! replay checks each robot's view at exactly that count.

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use crate::twin::SimHandle;
use actix::prelude::*;
use behaviours::RobotView;
use robot_actor::{RobotEvent, RobotEventKind, StateUpdated};
use serde_json::{json, Value};
use tokio::sync::broadcast;
use tokio::time::Instant;
use world::robot;
use world::Track;

use crate::instruments::record::{fox_pose, fox_time, layout_json, Recorder, Topic};
use world_model::WorldModel;

/// How often a world snapshot is taken (recorded, sent to the panel).
pub const SNAPSHOT_PERIOD: Duration = Duration::from_millis(100);
/// A trail point is kept once the robot has moved this far from the previous one.
const TRAIL_STEP_M: f64 = 0.005;

/// What a run is observed for, beyond the report.
#[derive(Default)]
pub struct Instruments {
    /// Record to this MCAP file.
    pub record: Option<PathBuf>,
    /// Serve the control panel.
    pub panel: Option<crate::instruments::panel::PanelOptions>,
    /// Keep each robot's trail for a trajectory plot.
    pub trails: bool,
}

/// A box in the world, for scenes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxShape {
    /// Size along its own x and y, metres.
    pub size: (f64, f64),
    /// Pose now: x, y, heading.
    pub pose: [f64; 3],
}

/// Everything the observer is started with.
pub struct ObserverSetup {
    /// The tape.
    pub track: Arc<Track>,
    /// Arena size, metres.
    pub arena: (f64, f64),
    /// Boxes at their start poses.
    pub boxes: Vec<BoxShape>,
    /// Where to record.
    pub recorder: Option<Arc<Recorder>>,
    /// Where to send panel frames.
    pub feed: Option<broadcast::Sender<Arc<str>>>,
    /// Replay: the (robot, update count) views to capture.
    pub wanted: Option<Vec<(u16, u64)>>,
    /// The simulation, for boxes' live poses and the robots' true poses.
    pub sim: Option<SimHandle>,
}

/// What the observer saw, handed over at the end.
#[derive(Clone, Debug, Default)]
pub struct Observed {
    /// Each robot's trail (world model pose), in id order.
    pub trails: BTreeMap<u16, Vec<[f64; 2]>>,
    /// Each robot's true trail, when simulated.
    pub truth_trails: BTreeMap<u16, Vec<[f64; 2]>>,
    /// Replay: the view captured at each wanted (robot, update count).
    pub captured: HashMap<(u16, u64), Value>,
    /// Snapshots taken.
    pub snapshots: u64,
}

/// Hands over what the observer saw.
#[derive(Message)]
#[rtype(result = "Observed")]
pub struct TakeObserved;

#[derive(Message)]
#[rtype(result = "()")]
struct Truth(Option<crate::twin::Truth>);

/// The observer actor.
pub struct Observer {
    setup: ObserverSetup,
    model: WorldModel,
    counts: HashMap<u16, u64>,
    wanted: HashMap<(u16, u64), ()>,
    observed: Observed,
    wheel_samples: BTreeMap<u16, Vec<[f64; 5]>>,
    encounters: Vec<Value>,
    track_lines: Vec<Vec<[f64; 2]>>,
    truth: Option<crate::twin::Truth>,
    t0: Instant,
    truth_pending: bool,
}

impl Observer {
    /// An observer whose times count from `t0`; each robot actor subscribes it as it starts.
    pub fn new(setup: ObserverSetup, t0: Instant) -> Self {
        let model = WorldModel::new(Arc::clone(&setup.track));
        let track_lines = track_lines(&setup.track);
        let wanted = setup.wanted.iter().flatten().map(|k| (*k, ())).collect();
        Self {
            setup,
            model,
            counts: HashMap::new(),
            wanted,
            observed: Observed::default(),
            wheel_samples: BTreeMap::new(),
            encounters: Vec::new(),
            track_lines,
            truth: None,
            t0,
            truth_pending: false,
        }
    }

    fn t(&self) -> f64 {
        (Instant::now() - self.t0).as_secs_f64()
    }

    fn snapshot(&mut self) {
        self.observed.snapshots += 1;
        // Rendering every robot as JSON costs more than simulating it at a thousand robots: do it
        // only for a recorder or an open panel page.
        let watched = self
            .setup
            .feed
            .as_ref()
            .is_some_and(|f| f.receiver_count() > 0);
        if self.setup.recorder.is_none() && !watched {
            self.encounters.clear();
            self.wheel_samples.clear();
            return;
        }
        let t = self.t();
        let views = self.model.views();
        let robots: Vec<Value> = views
            .iter()
            .map(|v| view_json(v, self.counts.get(&v.id).copied().unwrap_or(0)))
            .collect();
        let encounters = std::mem::take(&mut self.encounters);
        if let Some(rec) = &self.setup.recorder {
            // In simulation the latest ground truth goes beside the model (with its own time: it
            // was asked for after the previous snapshot), so a recording shows where each
            // estimate was wrong; replay compares only `robots`.
            let truth = self.truth.as_ref().map(|tr| {
                json!({"t": tr.now.as_secs_f64(),
                    "robots": tr.robots.iter().map(|(id, p)| json!([id, p.x, p.y, p.theta])).collect::<Vec<_>>()})
            });
            rec.json(
                Topic::World,
                &json!({"t": t, "robots": robots, "encounters": encounters, "truth": truth}),
            );
            let ns = (t * 1e9) as u64;
            // The tape, boxes and trails change slowly or not at all: once a second is enough for
            // Foxglove, which keeps an entity until it is replaced, and keeps the file small.
            let full = self.observed.snapshots % 10 == 1;
            rec.json(Topic::Scene, &self.scene(&views, ns, full));
            rec.json(
                Topic::Poses,
                &json!({"timestamp": fox_time(ns), "frame_id": "world",
                    "poses": views.iter().map(|v| fox_pose(v.pose.x, v.pose.y, v.pose.theta)).collect::<Vec<_>>()}),
            );
        }
        if let Some(feed) = &self.setup.feed {
            let truth = self.truth.as_ref().map(|tr| {
                json!({
                    "robots": tr.robots.iter().map(|(id, p)| json!({"id": id, "x": p.x, "y": p.y, "theta": p.theta})).collect::<Vec<_>>(),
                    "boxes": tr.obstacles.iter().map(|p| [p.x, p.y, p.theta]).collect::<Vec<_>>(),
                    "collisions": tr.robot_collisions,
                })
            });
            let wheels: BTreeMap<String, Vec<[f64; 5]>> = std::mem::take(&mut self.wheel_samples)
                .into_iter()
                .map(|(k, v)| (k.to_string(), v))
                .collect();
            let frame = json!({"type": "world", "t": t, "robots": robots,
                "encounters": encounters, "wheels": wheels, "truth": truth});
            // Nobody listening is fine: the page may not be open.
            let _ = feed.send(Arc::from(frame.to_string()));
        }
    }

    /// A `foxglove.SceneUpdate`: tape, boxes, robots with heading, and trails.
    fn scene(&self, views: &[RobotView], ns: u64, full: bool) -> Value {
        let ts = fox_time(ns);
        let ident = fox_pose(0.0, 0.0, 0.0);
        let black = json!({"r": 0.1, "g": 0.1, "b": 0.1, "a": 1.0});
        let mut entities = Vec::new();
        if full {
            entities.push(json!({
            "timestamp": ts, "frame_id": "world", "id": "track", "lifetime": fox_time(0),
            "frame_locked": false, "metadata": [], "arrows": [], "cubes": [], "texts": [],
            "lines": self.track_lines.iter().map(|l| json!({
                "type": 0, "pose": ident, "thickness": 0.019, "scale_invariant": false,
                "points": l.iter().map(|p| json!({"x": p[0], "y": p[1], "z": 0.0})).collect::<Vec<_>>(),
                "color": black, "colors": [], "indices": []})).collect::<Vec<_>>(),
            }));
        }
        let boxes: Vec<[f64; 3]> = match &self.truth {
            Some(t) => t.obstacles.iter().map(|p| [p.x, p.y, p.theta]).collect(),
            None => self.setup.boxes.iter().map(|b| b.pose).collect(),
        };
        for (i, (b, p)) in self
            .setup
            .boxes
            .iter()
            .zip(boxes)
            .enumerate()
            .filter(|_| full)
        {
            entities.push(json!({
                "timestamp": ts, "frame_id": "world", "id": format!("box-{i}"),
                "lifetime": fox_time(0), "frame_locked": false, "metadata": [], "arrows": [],
                "lines": [], "texts": [],
                "cubes": [{"pose": fox_pose(p[0], p[1], p[2]), "size": {"x": b.size.0, "y": b.size.1, "z": 0.03},
                    "color": {"r": 0.8, "g": 0.55, "b": 0.2, "a": 1.0}}]}));
        }
        for v in views {
            let (r, g, b) = robot_colour(v.id);
            let colour = json!({"r": r, "g": g, "b": b, "a": 1.0});
            let trail = self.observed.trails.get(&v.id);
            if full {
                entities.push(json!({
                    "timestamp": ts, "frame_id": "world", "id": format!("trail-{}", v.id),
                    "lifetime": fox_time(0), "frame_locked": false, "metadata": [], "cubes": [],
                    "arrows": [], "texts": [],
                    "lines": trail.map(|t| vec![json!({"type": 0, "pose": ident, "thickness": 0.003,
                        "scale_invariant": false, "color": colour, "colors": [], "indices": [],
                        "points": t.iter().map(|p| json!({"x": p[0], "y": p[1], "z": 0.001})).collect::<Vec<_>>()})]).unwrap_or_default(),
                }));
            }
            entities.push(json!({
                "timestamp": ts, "frame_id": "world", "id": format!("robot-{}", v.id),
                "lifetime": fox_time(0), "frame_locked": false, "metadata": [],
                "cubes": [{"pose": fox_pose(v.pose.x, v.pose.y, v.pose.theta),
                    "size": {"x": robot::LENGTH_M, "y": robot::WIDTH_M, "z": 0.02}, "color": colour}],
                "arrows": [{"pose": fox_pose(v.pose.x, v.pose.y, v.pose.theta), "shaft_length": 0.03,
                    "shaft_diameter": 0.004, "head_length": 0.012, "head_diameter": 0.01,
                    "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0}}],
                "texts": [{"pose": fox_pose(v.pose.x, v.pose.y + 0.035, 0.0), "billboard": true,
                    "font_size": 14.0, "scale_invariant": true, "color": colour, "text": format!("robot {}", v.id)}],
                "lines": [],
            }));
        }
        // Every primitive list present, empty or not, as Foxglove's SceneEntity has them all.
        for e in &mut entities {
            if let Value::Object(m) = e {
                for key in [
                    "metadata",
                    "arrows",
                    "cubes",
                    "spheres",
                    "cylinders",
                    "lines",
                    "triangles",
                    "texts",
                    "models",
                ] {
                    m.entry(key).or_insert_with(|| json!([]));
                }
            }
        }
        json!({"deletions": [], "entities": entities})
    }
}

/// The track as polylines, one per edge, points 10 mm apart at most.
pub fn track_lines(track: &Track) -> Vec<Vec<[f64; 2]>> {
    (0..track.edges().len())
        .map(|e| track.polyline(e, 0.01).iter().map(|p| [p.x, p.y]).collect())
        .collect()
}

/// A distinct colour per robot id, for scenes and plots.
pub fn robot_colour(id: u16) -> (f64, f64, f64) {
    const PALETTE: [(f64, f64, f64); 6] = [
        (0.12, 0.47, 0.71),
        (0.89, 0.10, 0.11),
        (0.20, 0.63, 0.17),
        (0.58, 0.40, 0.74),
        (1.00, 0.50, 0.00),
        (0.09, 0.75, 0.81),
    ];
    PALETTE[usize::from(id) % PALETTE.len()]
}

/// One robot's view as recorded in a world snapshot; replay compares these exactly.
pub fn view_json(v: &RobotView, updates: u64) -> Value {
    json!({
        "id": v.id, "connected": v.connected, "updates": updates,
        "pose": {"x": v.pose.x, "y": v.pose.y, "theta": v.pose.theta},
        "odometry": {"x": v.odometry.x, "y": v.odometry.y, "theta": v.odometry.theta},
        "pending_moves": v.pending_moves,
        "on_track": v.on_track.map(|p| json!([p.edge, p.along_m, p.offset_m])),
        "uncertainty": {"position_m": v.uncertainty.position_m, "heading_rad": v.uncertainty.heading_rad},
        "localisation": match v.localisation {
            behaviours::Localisation::Tracking => "tracking",
            behaviours::Localisation::Lost => "lost",
        },
        "state": layout_json(&v.state),
    })
}

fn event_name(kind: &RobotEventKind) -> &'static str {
    match kind {
        RobotEventKind::Connected(_) => "connected",
        RobotEventKind::LinkLost => "link_lost",
        RobotEventKind::MoveFinished { .. } => "move_finished",
        RobotEventKind::QueueEmpty => "queue_empty",
        RobotEventKind::Obstacle(_) => "obstacle",
        RobotEventKind::Encounter(_) => "encounter",
        RobotEventKind::Line(_) => "line",
        RobotEventKind::WatchdogStop => "watchdog_stop",
        RobotEventKind::Overrun(_) => "overrun",
        RobotEventKind::Bump(_) => "bump",
        RobotEventKind::Reflex(_) => "reflex",
        RobotEventKind::Refused(_) => "refused",
        #[allow(unreachable_patterns)]
        _ => "other",
    }
}

impl Actor for Observer {
    type Context = Context<Self>;

    fn started(&mut self, ctx: &mut Self::Context) {
        ctx.run_interval(SNAPSHOT_PERIOD, |act, ctx| {
            act.snapshot();
            if let Some(sim) = act.setup.sim.clone() {
                if !act.truth_pending && (act.setup.feed.is_some() || act.setup.recorder.is_some())
                {
                    act.truth_pending = true;
                    let me = ctx.address();
                    tokio::spawn(async move { me.do_send(Truth(sim.truth().await)) });
                }
            }
        });
    }
}

impl Handler<StateUpdated> for Observer {
    type Result = ();
    fn handle(&mut self, u: StateUpdated, _: &mut Context<Self>) {
        let n = {
            let c = self.counts.entry(u.robot_id).or_insert(0);
            *c += 1;
            *c
        };
        if self.model.robots().get(&u.robot_id).is_none() {
            self.model.add(u.robot_id);
        }
        self.model.apply(&u);
        let view = self.model.robots().get(&u.robot_id).map(|v| v.clone());
        let Some(view) = view else { return };
        if self.wanted.contains_key(&(u.robot_id, n)) {
            self.observed
                .captured
                .insert((u.robot_id, n), view_json(&view, n));
        }
        let trail = self.observed.trails.entry(u.robot_id).or_default();
        let here = [view.pose.x, view.pose.y];
        if trail
            .last()
            .is_none_or(|p| (p[0] - here[0]).hypot(p[1] - here[1]) >= TRAIL_STEP_M)
        {
            trail.push(here);
        }
        if self.setup.feed.is_some() {
            let w = u.state.wheels;
            let t = self.t();
            let (lt, lm, rt, rm) = (
                w.left_target_mps,
                w.left_mps,
                w.right_target_mps,
                w.right_mps,
            );
            self.wheel_samples.entry(u.robot_id).or_default().push([
                t,
                f64::from(lt),
                f64::from(lm),
                f64::from(rt),
                f64::from(rm),
            ]);
        }
    }
}

impl Handler<RobotEvent> for Observer {
    type Result = ();
    fn handle(&mut self, e: RobotEvent, _: &mut Context<Self>) {
        let t = (e.at - self.t0).as_secs_f64();
        if let RobotEventKind::LinkLost = e.kind {
            self.model.lost(e.robot_id);
        }
        if let RobotEventKind::Encounter(enc) = &e.kind {
            let (seen, side, range_mm) = (enc.robot_id, enc.side, enc.range_mm);
            self.encounters
                .push(json!({"t": t, "observer": e.robot_id, "seen": seen,
                "side": side, "range_mm": range_mm}));
        }
        if let Some(rec) = &self.setup.recorder {
            rec.json(
                Topic::Events,
                &json!({"t": t, "robot": e.robot_id, "kind": event_name(&e.kind),
                    "detail": format!("{:?}", e.kind)}),
            );
        }
    }
}

impl Handler<Truth> for Observer {
    type Result = ();
    fn handle(&mut self, t: Truth, _: &mut Context<Self>) {
        self.truth_pending = false;
        if let Some(t) = t.0 {
            for (id, p) in &t.robots {
                let trail = self.observed.truth_trails.entry(*id).or_default();
                if trail
                    .last()
                    .is_none_or(|q| (q[0] - p.x).hypot(q[1] - p.y) >= TRAIL_STEP_M)
                {
                    trail.push([p.x, p.y]);
                }
            }
            self.truth = Some(t);
        }
    }
}

impl Handler<TakeObserved> for Observer {
    type Result = MessageResult<TakeObserved>;
    fn handle(&mut self, _: TakeObserved, _: &mut Context<Self>) -> Self::Result {
        MessageResult(std::mem::take(&mut self.observed))
    }
}
