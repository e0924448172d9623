//! `traffic_control`: robots on a track graph with forks, merges, sidings and single-lane sections
//! serve a stream of goal nodes each (lifelong tasks), without collisions or deadlock.
//!
//! Planning is multi-agent path finding on the track graph (nodes = junctions and marks, edges =
//! tape): LaCAM over PIBT (`mapf`), complete for one-shot instances, from where every robot stands
//! to its current goal; a robot without a task keeps its node as goal and is pushed aside when in
//! the way. The plan is executed as an action dependency graph: a robot drives into a node only
//! after every robot the plan put there before it has driven out, so robots that are slower or
//! faster than the plan assumed never meet. When a robot reaches its goal it gets its next task
//! and the team is planned again. With `replan=lifelong`, the default, that happens at the next
//! snapshot while the team keeps moving: from each robot's committed node (the one it stands on,
//! or the end of the edge it is driving, whose drive is kept as its first action, so that a robot
//! sent into the node it left still waits for it to arrive), one plan for all robots that reached
//! their goals since the last. With `replan=barrier` no new action starts until every robot
//! stands on a node, then the team is planned from there.
//!
//! Each edge is driven by the robot's own locomotion (a turn onto the tape's direction, then a
//! straight or an arc of the tape's radius), planned from the world model's pose, which the tape
//! under the line sensor keeps corrected.
//!
//! Starts: a robot within 2 cm of a node stands on it; any other within 3 cm of the tape drives
//! along its nearest edge to a free end node (the one ahead, else the one behind; two robots on
//! one edge each take the end on their side). A robot farther from the tape, or with no free
//! node to drive to, is refused with where it is and what is in the way.
//!
//! Recovery: a segment held back by the safety check is planned again from the robot's pose at
//! the next snapshot; held for 4 s, or with no robot finishing an edge for 20 s (time a robot is
//! lost does not count), no new action starts, every robot goes to a node (held robots, and from
//! the second recovery on every driving robot, back to the node they came from; the others finish
//! their edge) and the team is planned again from there. Three recoveries in a row without a task
//! done fail the run, saying what each robot is doing or waiting for. A robot the world model
//! loses keeps its leg; its dropped moves are not failures, and once found it drives the leg on
//! from its new pose.
//!
//! Success: the tasks asked for are done (default [`TASKS_PER_ROBOT`] per robot, 12 on
//! `junction` and 18 on `grid`, which the coordinator's default 600 s fits with a margin),
//! without deadlock, and every robot's encoders measured at least 90 % of the tape length of the
//! edges it reported driving, less 2 cm for where it stood on its first node (a robot whose moves
//! end without its wheels turning has not driven them). A robot whose wheels are driven for 3 s
//! without an encoder pulse fails the run at once (see [`behaviour_api::evidence`]).

use std::f64::consts::FRAC_PI_2;
use std::sync::Arc;
use std::time::{Duration, Instant};

use behaviour_api::{MoveCommand, Pose};
use mapf::{lacam, Adg, Graph, Solution};
use nalgebra::{Point2, Vector2};
use petgraph::graph::NodeIndex;
use protocol::packets::MoveOutcome;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use world::graph::TrackGraph;
use world::Track;

use behaviour_api::event::Event;
use behaviour_api::evidence::{Odometer, EVIDENCE_SHARE};
use behaviour_api::moves::{wrap, Manoeuvre};
use behaviour_api::team::Team;
use behaviour_api::{
    params, Behaviour, BehaviourConfig, Intent, Localisation, LocalisationEvent, Register, Verdict,
    WorldSnapshot,
};

mod driving;
mod hooks;
mod placing;
mod planning;
mod recovery;
mod setup;
#[cfg(test)]
mod tests;

pub use setup::TrafficControlParams;

/// Driving speed along edges.
const DRIVE_MPS: f32 = 0.1;
/// Length of one driven segment: each is planned afresh from the corrected pose.
const LOOKAHEAD: f64 = 0.08;
/// Longest segment the `segment_m` parameter may ask for: beyond it a heading error of a few
/// degrees puts the end of a segment centimetres off the tape before the next is planned.
const MAX_SEGMENT_M: f64 = 0.25;
/// A segment bends the heading by at most twice this; beyond it the robot turns first.
const MAX_BEND: f64 = 35.0 * std::f64::consts::PI / 180.0;
/// A segment is queued behind the running one only if that one ends heading along the tape
/// within this.
const FLOW_ALIGN: f64 = 10.0 * std::f64::consts::PI / 180.0;
/// No robot finishing an edge for this long (simulated, lost time not counted) starts a recovery.
const STALL_LIMIT: Duration = Duration::from_secs(20);
/// A robot's segment held back by the safety check for this long starts a recovery.
const HOLD_LIMIT: Duration = Duration::from_secs(4);
/// Recoveries in a row without a task done before the run fails.
const MAX_RECOVERIES: u32 = 3;
/// How far from a node a robot standing on it may be, for judging the distance it drove and
/// for taking a start pose as standing on the node.
const NODE_SLACK_M: f64 = 0.02;
/// Farthest a start pose may be from the tape: a robot drives onto the nearest edge from there.
const REACH_M: f64 = 0.03;
/// Default tasks per robot (rounded up for the team): 600 s, the coordinator's default duration,
/// fits them on `junction` (12 tasks, about 3.6 a minute with a slow tail) and `grid` (18, about
/// 19 a minute) with a margin.
pub const TASKS_PER_ROBOT: f64 = 1.5;
/// A robot standing this near a lost one (centres), with the lost one ahead of it, backs away by
/// `MAKE_ROOM_M` until the lost one is found: the search turns on the spot sweep a circle of 29 mm
/// plus the lost robot's widened uncertainty, and the safety check holds every turn that could
/// touch a robot waiting beside it.
const MAKE_ROOM_NEAR_M: f64 = 0.15;
const MAKE_ROOM_M: f32 = 0.08;
const MAKE_ROOM_MPS: f32 = 0.03;
/// Tag of the moves that make room and return.
const MAKE_ROOM_TAG: u32 = 1;
/// Search budget per plan; deterministic, unlike a time limit.
const MAX_EXPANSIONS: u64 = 2_000_000;

/// How the team is planned again when robots reach their goals.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Replan {
    /// No new action starts until every robot stands on a node, then the whole team is planned
    /// from there.
    Barrier,
    /// At the next snapshot, the team is planned from its committed configuration (each robot's
    /// node, or the end of the edge it is driving, whose drive is kept) while it keeps moving.
    Lifelong,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Driving from the start poses onto nodes.
    Placing,
    /// Executing a plan.
    Running,
    /// A robot reached its goal (barrier replanning) or a recovery: no new actions start;
    /// replan once all are on nodes.
    Draining,
}

/// An edge being driven, one short segment at a time.
#[derive(Clone, Copy, Debug, PartialEq)]
struct EdgeDrive {
    /// ADG action index, `None` for a drive outside the plan (onto the first node, or back to
    /// the node it came from in a recovery).
    index: Option<usize>,
    /// Track edge.
    edge: usize,
    /// Driven from its `from` node to its `to` node.
    forward: bool,
    /// Node it ends at.
    to: u32,
    /// The segment in flight ends at the node.
    last: bool,
    /// Backed straight onto the node, keeping the heading (a robot placed between another robot
    /// and the node ahead of it on a straight edge).
    back: bool,
}

#[derive(Clone, Debug)]
struct Bot {
    id: u16,
    /// The node the robot stands on, or is driving from.
    node: u32,
    goal: u32,
    /// The edge being driven.
    driving: Option<EdgeDrive>,
    /// Its leg ended without a move (it already stood on the node): completed at the next step.
    at_end: bool,
    tasks_done: u32,
    /// Its goal was reached and no new one given yet: with lifelong replanning a robot may be
    /// sent on from its goal by the plan before the next one is made.
    reached: bool,
    /// Tape length of the edges it finished driving, metres.
    edges_m: f64,
    /// A segment was held back by the safety check: plan it again.
    retry: bool,
    /// Since when its segments are being held back, and the latest reason.
    held_since: Option<Duration>,
    held_why: String,
    /// Moves were sent since the last held one.
    fresh_hold: bool,
    /// Why the world model lost it, while it is lost.
    lost: Option<String>,
    /// The last segment sent, while it is a single forward move of the leg being driven: its
    /// planned start and end, so that the segment after it can be sent before it ends.
    tail: Option<(Pose, Pose)>,
    rng: ChaCha8Rng,
    /// Has a task (false once its quota is done: it only keeps out of the way).
    active: bool,
    /// Backed away from a lost robot, to return when it is found.
    making_room: Option<MakeRoom>,
}

/// A robot keeping out of a lost one's way.
#[derive(Clone, Copy, Debug)]
struct MakeRoom {
    /// The lost robot.
    lost: u16,
    /// Where the robot stood before it backed away.
    from: Pose,
    /// Driving back to `from`.
    returning: bool,
}

/// The traffic control behaviour.
pub struct TrafficControl {
    track: Arc<Track>,
    graph: TrackGraph,
    mapf: Graph,
    bots: Vec<Bot>,
    adg: Option<Adg>,
    phase: Phase,
    seed: u64,
    target_tasks: u32,
    quota: Option<u32>,
    tasks: u32,
    replans: u32,
    held: u32,
    /// Recoveries since the last task done, and in all.
    recoveries: u32,
    recoveries_total: u32,
    scripted: bool,
    replan_mode: Replan,
    /// Lifelong replanning: a robot reached its goal since the last plan.
    replan_due: bool,
    /// Plans made while robots were driving (lifelong replanning).
    replans_live: u32,
    /// Length of one driven segment.
    segment_m: f64,
    /// Keep the next segment of an edge queued behind the running one, so the robot drives the
    /// edge without slowing between segments.
    flow: bool,
    plan_time_max: Duration,
    last_progress: Duration,
    started: Duration,
    /// The time of the latest snapshot seen.
    now: Duration,
    odometer: Odometer,
    verdict: Option<Verdict>,
}
