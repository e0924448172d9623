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
//! without an encoder pulse fails the run at once (see [`crate::evidence`]).

use std::f64::consts::FRAC_PI_2;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mapf::{lacam, Adg, Graph, Solution};
use nalgebra::{Point2, Vector2};
use petgraph::graph::NodeIndex;
use protocol::packets::MoveOutcome;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use robot_actor::{MoveCommand, Pose};
use world::graph::TrackGraph;
use world::Track;

use crate::api::{
    Behaviour, BehaviourConfig, Intent, Localisation, LocalisationEvent, Verdict, WorldSnapshot,
};
use crate::event::Event;
use crate::evidence::{Odometer, EVIDENCE_SHARE};
use crate::moves::{wrap, Manoeuvre};
use crate::team::Team;

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
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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

impl TrafficControl {
    /// Builds it. Parameters: `tasks` (tasks to complete in all, default [`TASKS_PER_ROBOT`] per
    /// robot), `quota` (tasks per robot after which it only keeps out of the way; default
    /// unlimited), `goals` (a comma-separated list of node ids, one per robot: each robot's
    /// single task, for scripted scenarios such as a swap through a single-lane section),
    /// `replan` (`lifelong`, the default, or `barrier`: see [`Replan`]), `segment_m` (length of
    /// one driven segment, default 0.08 m), `flow` (`true`, the default: the next segment of an
    /// edge is queued behind the running one, so that the robot does not slow down between
    /// them; `false`: each segment is sent once the last has ended).
    ///
    /// # Errors
    /// A track without edges, unknown goal nodes, or a parameter out of range.
    pub fn new(cfg: &BehaviourConfig) -> Result<Self, String> {
        if cfg.track.edges().is_empty() {
            return Err("traffic control needs a track".into());
        }
        let graph = TrackGraph::new(&cfg.track);
        let mapf = Graph::from_petgraph(&graph.graph).map_err(|e| e.to_string())?;
        let default_tasks = ((TASKS_PER_ROBOT * cfg.robots.len() as f64).ceil() as u32).max(1);
        let target_tasks: u32 = cfg.param("tasks", default_tasks)?;
        let quota: Option<u32> = match cfg.param_text("quota") {
            None => None,
            Some(q) => Some(
                q.parse()
                    .map_err(|_| format!("quota={q:?} is not a count"))?,
            ),
        };
        if target_tasks == 0 {
            return Err("tasks must be at least 1".into());
        }
        let replan_mode = match cfg.param_text("replan") {
            Some("barrier") => Replan::Barrier,
            None | Some("lifelong") => Replan::Lifelong,
            Some(other) => return Err(format!("replan={other:?}: expected lifelong or barrier")),
        };
        let segment_m: f64 = cfg.param("segment_m", LOOKAHEAD)?;
        if !(0.02..=MAX_SEGMENT_M).contains(&segment_m) {
            return Err(format!(
                "segment_m={segment_m}: expected 0.02 to {MAX_SEGMENT_M} m"
            ));
        }
        let flow: bool = cfg.param("flow", true)?;
        let scripted: Option<Vec<u32>> = match cfg.param_text("goals") {
            None => None,
            Some(list) => Some(
                list.split(',')
                    .map(|id| {
                        graph
                            .node(id.trim())
                            .map(|n| n.index() as u32)
                            .ok_or_else(|| format!("goals: no track node {:?}", id.trim()))
                    })
                    .collect::<Result<_, _>>()?,
            ),
        };
        if let Some(g) = &scripted {
            if g.len() != cfg.robots.len() {
                return Err(format!(
                    "goals: {} nodes for {} robots",
                    g.len(),
                    cfg.robots.len()
                ));
            }
        }
        let bots = cfg
            .robots
            .iter()
            .enumerate()
            .map(|(k, &id)| Bot {
                id,
                node: 0,
                goal: scripted.as_ref().map_or(u32::MAX, |g| g[k]),
                driving: None,
                at_end: false,
                tasks_done: 0,
                reached: false,
                edges_m: 0.0,
                retry: false,
                held_since: None,
                held_why: String::new(),
                fresh_hold: false,
                lost: None,
                tail: None,
                rng: ChaCha8Rng::seed_from_u64(cfg.seed ^ (u64::from(id) << 32)),
                active: true,
                making_room: None,
            })
            .collect();
        let (target_tasks, quota) = match &scripted {
            Some(g) => (g.len() as u32, Some(1)),
            None => (target_tasks, quota),
        };
        Ok(Self {
            track: Arc::clone(&cfg.track),
            graph,
            mapf,
            bots,
            adg: None,
            phase: Phase::Placing,
            seed: cfg.seed,
            target_tasks,
            quota,
            tasks: 0,
            replans: 0,
            held: 0,
            recoveries: 0,
            recoveries_total: 0,
            scripted: scripted.is_some(),
            replan_mode,
            replan_due: false,
            replans_live: 0,
            segment_m,
            flow,
            plan_time_max: Duration::ZERO,
            last_progress: Duration::ZERO,
            started: Duration::ZERO,
            now: Duration::ZERO,
            odometer: Odometer::new(),
            verdict: None,
        })
    }

    fn position(&self, node: u32) -> Point2<f64> {
        self.track.nodes()[node as usize].position
    }

    fn name(&self, node: u32) -> &str {
        &self.track.nodes()[node as usize].id
    }

    /// The track edge between nodes `u` and `v`, and whether it runs from `u` to `v`.
    fn edge_between(&self, u: u32, v: u32) -> Option<(usize, bool)> {
        let e = self
            .graph
            .graph
            .find_edge(NodeIndex::new(u as usize), NodeIndex::new(v as usize))
            .and_then(|e| self.graph.graph.edge_weight(e))?
            .edge;
        Some((e, self.track.edges()[e].from == u as usize))
    }

    /// The node a leg starts from.
    fn leg_from(&self, leg: &EdgeDrive) -> u32 {
        let e = &self.track.edges()[leg.edge];
        if leg.forward {
            e.from as u32
        } else {
            e.to as u32
        }
    }

    /// The same edge driven back to the node it started from, outside the plan.
    fn reversed(&self, leg: &EdgeDrive) -> EdgeDrive {
        EdgeDrive {
            index: None,
            edge: leg.edge,
            forward: !leg.forward,
            to: self.leg_from(leg),
            last: false,
            back: false,
        }
    }

    /// The next segment of `leg` from `pose`: a turn onto the tape if the robot faces away from
    /// it, then an arc (or straight) through a point `LOOKAHEAD` further along the tape, or the
    /// end node when that is nearer. Each segment is planned from the world model's pose, which
    /// the tape under the sensor keeps corrected, so errors of one segment are taken out by the
    /// next instead of adding up over a long curve.
    fn segment(&self, pose: Pose, leg: &mut EdgeDrive) -> Manoeuvre {
        if leg.back {
            leg.last = true;
            let q = self.position(leg.to);
            let route = Manoeuvre::from(pose, DRIVE_MPS).back_to(q.x, q.y);
            return route;
        }
        let len = self.track.edge_length(leg.edge);
        let here = self.track.nearest_on(leg.edge, Point2::new(pose.x, pose.y));
        let done = if leg.forward {
            here.offset_m
        } else {
            len - here.offset_m
        };
        let remaining = (len - done).max(0.0);
        let ahead = (done + self.segment_m).min(len);
        leg.last = remaining <= self.segment_m + 0.01;
        let target_offset = if leg.last {
            if leg.forward {
                len
            } else {
                0.0
            }
        } else if leg.forward {
            ahead
        } else {
            len - ahead
        };
        let (q, _) = self.track.point_at(leg.edge, target_offset);
        let q = if leg.last { self.position(leg.to) } else { q };
        let mut route = Manoeuvre::from(pose, DRIVE_MPS);
        let (dx, dy) = (q.x - pose.x, q.y - pose.y);
        let d = dx.hypot(dy);
        if d < 0.003 {
            return route;
        }
        let mut alpha = wrap(dy.atan2(dx) - pose.theta);
        if alpha.abs() > MAX_BEND {
            // Facing away (at a node, before a new edge): turn to the tape's direction first.
            let (_, t) = self.track.point_at(leg.edge, here.offset_m);
            let dir = if leg.forward { t } else { -t };
            route = route.turn_to(dir.y.atan2(dir.x));
            alpha = wrap(dy.atan2(dx) - route.end.theta);
            if alpha.abs() > MAX_BEND {
                return route.to(q.x, q.y);
            }
        }
        if alpha.abs() < 1e-3 {
            return route.straight(d);
        }
        // The circle through the robot, tangent to its heading, through q.
        let radius = d / (2.0 * alpha.sin().abs());
        route.moves.push(MoveCommand::Arc {
            radius_m: radius as f32,
            angle_deg: (2.0 * alpha).to_degrees() as f32,
            speed_mps: DRIVE_MPS,
        });
        route.end = Pose {
            x: q.x,
            y: q.y,
            theta: route.end.theta + 2.0 * alpha,
        };
        route
    }

    /// Sends robot `k` the next segment of its leg. A leg whose end the robot already stands on
    /// needs no move: it is completed at the next step.
    fn drive(&mut self, k: usize, world: &WorldSnapshot) -> Vec<Intent> {
        if self.bots[k].lost.is_some() || self.bots[k].making_room.is_some() {
            return Vec::new();
        }
        let (Some(mut leg), Some(view)) = (self.bots[k].driving, world.robot(self.bots[k].id))
        else {
            return Vec::new();
        };
        let mut route = self.segment(view.pose, &mut leg);
        if route.moves.is_empty() {
            leg.last = true;
            self.bots[k].driving = Some(leg);
            self.bots[k].at_end = true;
            return Vec::new();
        }
        self.bots[k].tail = None;
        if self.flow && !leg.last && !leg.back {
            // A route that turns on the spot first ends where the turn's coast leaves it (degrees
            // off): the segment after it is planned from rest, where the tape has corrected that.
            if let Some(end) = self.flowing_end(&route, &leg) {
                // Two segments queued from the start, so that the first joint flows too.
                let mut next_leg = leg;
                let next = self.segment(end, &mut next_leg);
                if self.flowing_end(&next, &next_leg).is_some() {
                    route.moves.extend(next.moves);
                    leg = next_leg;
                    self.bots[k].tail = (!leg.last).then_some((end, next.end));
                }
            }
        }
        self.bots[k].driving = Some(leg);
        self.send(k, route)
    }

    /// Robot `k` finished a segment and its tail runs: queues the segment after the tail,
    /// planned from where the tail will end (the tail's planned motion from the robot's pose
    /// now), when that is one forward move along the tape. Anything else (a turn first) waits
    /// for the robot to stop and is planned from where it then stands.
    fn drive_ahead(&mut self, k: usize, world: &WorldSnapshot) -> Vec<Intent> {
        let (Some((from, to)), Some(mut leg), Some(view)) = (
            self.bots[k].tail.take(),
            self.bots[k].driving,
            world.robot(self.bots[k].id),
        ) else {
            return Vec::new();
        };
        // A tail is only kept for a leg that goes on after it (`drive`, `on_held`, `lose` and
        // `recover` clear it otherwise).
        let start = view.pose.compose(to.relative_to(from));
        let route = self.segment(start, &mut leg);
        // A queued segment that would end across the tape (a short last one from a start a few
        // millimetres aside bends hard) waits to be planned from rest.
        if self.flowing_end(&route, &leg).is_none() {
            return Vec::new();
        }
        self.bots[k].tail = (!leg.last).then_some((start, route.end));
        self.bots[k].driving = Some(leg);
        self.send(k, route)
    }

    /// Where `route` ends, when it is one move driving forward that ends heading along the tape
    /// of `leg`: a segment another can be queued behind, or that can itself be queued.
    fn flowing_end(&self, route: &Manoeuvre, leg: &EdgeDrive) -> Option<Pose> {
        forward_move(route).filter(|&end| self.along_tape(leg, end))
    }

    /// Whether a segment ending at `end` leaves the robot heading along the tape of `leg`
    /// (within [`FLOW_ALIGN`]), so the next can follow at speed. A segment that ends across the
    /// tape (the arc from a pose with a heading error ends with the opposite error) is followed
    /// from rest: two such arcs flowed into each other at speed swing the robot from one bend
    /// into the opposite one, and in physics a robot doing that lost its pose.
    fn along_tape(&self, leg: &EdgeDrive, end: Pose) -> bool {
        let here = self.track.nearest_on(leg.edge, Point2::new(end.x, end.y));
        let (_, tangent) = self.track.point_at(leg.edge, here.offset_m);
        let dir = if leg.forward { tangent } else { -tangent };
        wrap(end.theta - dir.y.atan2(dir.x)).abs() <= FLOW_ALIGN
    }

    fn send(&mut self, k: usize, route: Manoeuvre) -> Vec<Intent> {
        self.bots[k].fresh_hold = true;
        Intent::moves(self.bots[k].id, route.moves, 0)
    }

    /// Puts every robot on a node of its own. A robot within `NODE_SLACK_M` of a node stands on
    /// it; any other drives along its nearest edge to an end node no other robot holds (the one
    /// ahead first, else the one behind, backing on a straight). Two robots on one edge each take
    /// the end on their side, so they never cross. A robot farther than `REACH_M` from the tape,
    /// or with no free end to go to, is refused with where it is.
    fn place(&mut self, world: &WorldSnapshot) -> Result<Vec<Intent>, String> {
        let nodes = self.track.nodes();
        let mut starts = Vec::with_capacity(self.bots.len());
        for b in &self.bots {
            let id = b.id;
            let view = world
                .robot(id)
                .ok_or_else(|| format!("robot {id} is not in the world"))?;
            let p = view.pose;
            let at = Point2::new(p.x, p.y);
            let near = self.track.nearest(at).ok_or("the track is empty")?;
            if near.distance_m > REACH_M {
                let e = &self.track.edges()[near.edge];
                return Err(format!(
                    "robot {id} starts at ({:.3}, {:.3}) m, {:.1} cm from the nearest tape (edge \
                     {}-{}); traffic control drives a robot onto the track only from within {:.0} \
                     cm of it: place the robot on a node or an edge",
                    p.x,
                    p.y,
                    near.distance_m * 100.0,
                    nodes[e.from].id,
                    nodes[e.to].id,
                    REACH_M * 100.0
                ));
            }
            let on_node = (0..nodes.len())
                .map(|v| (v, (nodes[v].position - at).norm()))
                .filter(|(_, d)| *d <= NODE_SLACK_M)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(v, _)| v as u32);
            starts.push((p, near, on_node));
        }
        let mut owner: Vec<Option<u16>> = vec![None; nodes.len()];
        let mut placed = vec![false; self.bots.len()];
        for (k, (_, _, on_node)) in starts.iter().enumerate() {
            if let Some(v) = *on_node {
                if owner[v as usize].is_none() {
                    owner[v as usize] = Some(self.bots[k].id);
                    self.bots[k].node = v;
                    placed[k] = true;
                }
            }
        }
        let mut out = Vec::new();
        for k in 0..self.bots.len() {
            if placed[k] {
                continue;
            }
            let id = self.bots[k].id;
            let (p, near, _) = &starts[k];
            let edge = &self.track.edges()[near.edge];
            let (from, to) = (edge.from as u32, edge.to as u32);
            let heading = Vector2::new(p.theta.cos(), p.theta.sin());
            let towards_to = near.tangent.dot(&heading) >= 0.0;
            let sharing: Vec<(u16, f64)> = (0..self.bots.len())
                .filter(|&j| j != k && !placed[j] && starts[j].1.edge == near.edge)
                .map(|j| (self.bots[j].id, starts[j].1.offset_m))
                .collect();
            let before = sharing.iter().any(|(_, o)| *o < near.offset_m);
            let after = sharing.iter().any(|(_, o)| *o >= near.offset_m);
            let candidates: Vec<u32> = match (before, after) {
                (false, false) if towards_to => vec![to, from],
                (false, false) => vec![from, to],
                (false, true) => vec![from],
                (true, false) => vec![to],
                (true, true) => {
                    return Err(format!(
                        "robot {id} starts at ({:.3}, {:.3}) m between robots {} on edge {}-{}: \
                         neither end is free to drive to without passing another robot",
                        p.x,
                        p.y,
                        sharing
                            .iter()
                            .map(|(j, _)| j.to_string())
                            .collect::<Vec<_>>()
                            .join(" and "),
                        self.name(from),
                        self.name(to)
                    ))
                }
            };
            let Some(&target) = candidates.iter().find(|v| owner[**v as usize].is_none()) else {
                let held = candidates
                    .iter()
                    .map(|v| {
                        format!(
                            "{} by robot {}",
                            self.name(*v),
                            owner[*v as usize].unwrap_or_default()
                        )
                    })
                    .collect::<Vec<_>>()
                    .join(", ");
                return Err(format!(
                    "robot {id} starts at ({:.3}, {:.3}) m on edge {}-{}, and the nodes it could \
                     drive to are taken ({held}): move it to a free node or edge",
                    p.x,
                    p.y,
                    self.name(from),
                    self.name(to)
                ));
            };
            owner[target as usize] = Some(id);
            self.bots[k].node = target;
            let forward = target == to;
            let facing = forward == towards_to;
            self.bots[k].driving = Some(EdgeDrive {
                index: None,
                edge: near.edge,
                forward,
                to: target,
                last: false,
                back: !facing && !edge.is_arc(),
            });
            out.extend(self.drive(k, world));
        }
        Ok(out)
    }

    /// A new goal for robot `k`, planned from `here`: a random node that is no other robot's
    /// goal nor `here`.
    fn new_task(&mut self, k: usize, here: u32) {
        let n = self.mapf.num_vertices() as u32;
        let used: std::collections::HashSet<u32> = self
            .bots
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != k)
            .map(|(_, b)| b.goal)
            .collect();
        let free: Vec<u32> = (0..n).filter(|v| *v != here && !used.contains(v)).collect();
        let bot = &mut self.bots[k];
        bot.reached = false;
        bot.goal = if free.is_empty() {
            here
        } else {
            free[bot.rng.gen_range(0..free.len())]
        };
    }

    /// Goals for everyone at a goal, then a plan for the whole team from where it stands.
    fn replan(&mut self) -> Result<(), String> {
        let starts: Vec<u32> = self.bots.iter().map(|b| b.node).collect();
        let goals = self.assign_goals(&starts);
        let plan = self.solve(&starts, &goals)?;
        self.adg = Some(Adg::new(&plan).map_err(|e| format!("plan not executable: {e}"))?);
        self.replans += 1;
        self.replan_due = false;
        Ok(())
    }

    /// New tasks for the robots standing on their goals, and the goals to plan for: each robot's
    /// own, or the node it is planned from (`starts`) while its goal is another's.
    fn assign_goals(&mut self, starts: &[u32]) -> Vec<u32> {
        for (k, &here) in starts.iter().enumerate() {
            let driving = self.bots[k].driving.is_some();
            let b = &mut self.bots[k];
            if b.active && b.goal == here && self.scripted && !driving {
                // A scripted robot that starts on its goal has nothing to do but keep clear.
                b.tasks_done += 1;
                self.tasks += 1;
                b.active = false;
            }
            if !b.active {
                // A robot whose quota is done keeps clear where it is; with lifelong replanning
                // one the plan has sent on from its last goal keeps that goal, so that the last
                // plan, run to its end, brings it back (barrier plans start with it standing on
                // it, as it stops there).
                if !(b.reached && self.replan_mode == Replan::Lifelong) {
                    b.goal = here;
                }
                continue;
            }
            // A robot driving to its goal keeps it: reaching it is counted on arrival.
            if b.reached || b.goal == u32::MAX || (!driving && b.goal == here) {
                self.new_task(k, here);
            }
        }
        // Goals must differ: a robot whose goal another holds waits where it is this round. A
        // standing robot's goal becomes its node (it gets a new task next round, as before); a
        // driving one keeps its goal, so arriving on the node it drives to is not a task done.
        let mut goals: Vec<u32> = self.bots.iter().map(|b| b.goal).collect();
        let mut seen = std::collections::HashSet::with_capacity(goals.len());
        for k in 0..self.bots.len() {
            if seen.contains(&goals[k]) {
                goals[k] = starts[k];
                if self.bots[k].driving.is_none() {
                    self.bots[k].goal = starts[k];
                }
            }
            seen.insert(goals[k]);
        }
        goals
    }

    /// A plan from `starts` to `goals`.
    fn solve(&mut self, starts: &[u32], goals: &[u32]) -> Result<Solution, String> {
        let t = Instant::now();
        let plan = lacam::solve(
            &self.mapf,
            starts,
            goals,
            &lacam::Options {
                seed: self.seed.wrapping_add(u64::from(self.replans)),
                time_limit: None,
                max_expansions: Some(MAX_EXPANSIONS),
                // Swap solves narrow-aisle warehouses, but on `junction` its plans (robots backing
                // out to let others pass) kept the 100-task run from finishing in 3,000 s.
                swap: false,
            },
        )
        .map_err(|e| format!("planning failed: {e}"))?;
        self.plan_time_max = self.plan_time_max.max(t.elapsed());
        Ok(plan)
    }

    /// Lifelong replanning: new tasks for the robots on their goals and a plan for the team while
    /// it keeps moving. Each robot is planned from its committed node: the one it stands on, or
    /// the end of the edge it is driving. That drive is kept as the robot's first action of the
    /// new plan (its path gets the edge's start node in front, standing robots' paths a wait),
    /// so the dependency graph makes any robot the plan sends into that start node wait until
    /// the drive is complete, as the old plan did. Committed nodes are distinct (a robot drives
    /// into a node only once its previous occupant has arrived elsewhere) and so are the start
    /// nodes, so the prefixed plan is a valid one.
    ///
    /// Returns false, planning nothing, while some robot drives outside the plan.
    fn replan_lifelong(&mut self) -> Result<bool, String> {
        if self
            .bots
            .iter()
            .any(|b| b.driving.is_some_and(|l| l.index.is_none()))
        {
            return Ok(false);
        }
        let committed: Vec<u32> = self
            .bots
            .iter()
            .map(|b| b.driving.map_or(b.node, |l| l.to))
            .collect();
        let goals = self.assign_goals(&committed);
        let mut plan = self.solve(&committed, &goals)?;
        for (b, path) in self.bots.iter().zip(plan.paths.iter_mut()) {
            path.insert(0, b.node);
        }
        self.adg = Some(Adg::new(&plan).map_err(|e| format!("plan not executable: {e}"))?);
        for b in &mut self.bots {
            if let Some(leg) = b.driving.as_mut() {
                leg.index = Some(0);
            }
        }
        self.replans += 1;
        self.replans_live += 1;
        self.replan_due = false;
        Ok(true)
    }

    /// Starts every action the dependency graph allows.
    fn dispatch(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let mut out = Vec::new();
        if self.phase != Phase::Running {
            return out;
        }
        for k in 0..self.bots.len() {
            let b = &self.bots[k];
            if b.driving.is_some()
                || !team.idle(b.id)
                || b.lost.is_some()
                || b.making_room.is_some()
            {
                continue;
            }
            let Some(action) = self.adg.as_ref().and_then(|a| a.ready(k)) else {
                continue;
            };
            let Some(view) = world.robot(self.bots[k].id) else {
                continue;
            };
            let Some((edge, forward)) = self.edge_between(action.from, action.to) else {
                continue;
            };
            tracing::debug!(
                t = world.time.as_secs_f64(),
                robot = self.bots[k].id,
                from = %self.name(action.from),
                to = %self.name(action.to),
                pose = ?(view.pose.x, view.pose.y, view.pose.theta.to_degrees()),
                "drive"
            );
            self.bots[k].driving = Some(EdgeDrive {
                index: Some(action.index),
                edge,
                forward,
                to: action.to,
                last: false,
                back: false,
            });
            out.extend(self.drive(k, world));
        }
        out
    }

    /// What each robot is doing or waiting for, for a verdict that explains a stop.
    fn explain(&self) -> String {
        let mut lines = Vec::new();
        for (k, b) in self.bots.iter().enumerate() {
            let line = if let Some(why) = &b.lost {
                format!("robot {} is lost ({why})", b.id)
            } else if let Some(m) = b.making_room {
                format!("robot {} keeps out of lost robot {}'s way", b.id, m.lost)
            } else if let Some(leg) = b.driving {
                let route = format!("{}->{}", self.name(self.leg_from(&leg)), self.name(leg.to));
                if b.held_since.is_some() {
                    format!(
                        "robot {} on {route}: its segment is held back ({})",
                        b.id, b.held_why
                    )
                } else {
                    format!("robot {} is driving {route}", b.id)
                }
            } else if let Some(adg) = self.adg.as_ref().filter(|_| self.phase == Phase::Running) {
                let next = adg.completed(k);
                match adg.actions(k).get(next) {
                    None => format!(
                        "robot {} stands on {}, its plan done",
                        b.id,
                        self.name(b.node)
                    ),
                    Some(a) => match adg.dependency(k, next) {
                        Some((j, i)) if adg.completed(j) <= i => {
                            let d = adg.actions(j)[i];
                            format!(
                                "robot {} on {} waits to enter {} until robot {} has driven {}->{}",
                                b.id,
                                self.name(b.node),
                                self.name(a.to),
                                self.bots[j].id,
                                self.name(d.from),
                                self.name(d.to)
                            )
                        }
                        _ => format!(
                            "robot {} on {} is free to drive to {}",
                            b.id,
                            self.name(b.node),
                            self.name(a.to)
                        ),
                    },
                }
            } else {
                format!("robot {} stands on {}", b.id, self.name(b.node))
            };
            lines.push(line);
        }
        lines.join("; ")
    }

    /// No progress: stop starting actions, bring every robot to a node (a robot whose segment
    /// is held, or every driving robot from the second recovery on, drives back to the node it
    /// came from; the others finish their edges) and plan the team again from there. Fails
    /// once `MAX_RECOVERIES` recoveries in a row brought no task done.
    fn recover(&mut self, world: &WorldSnapshot, why: String, team: &Team) -> Vec<Intent> {
        self.recoveries += 1;
        if self.recoveries > MAX_RECOVERIES {
            let summary = format!(
                "deadlock: {why}, after {MAX_RECOVERIES} replans from where the robots stood \
                 without a task done ({} tasks done): {}",
                self.tasks,
                self.explain()
            );
            return self.fail(summary);
        }
        self.recoveries_total += 1;
        tracing::info!(
            t = world.time.as_secs_f64(),
            recovery = self.recoveries,
            %why,
            state = %self.explain(),
            "traffic control recovers"
        );
        self.last_progress = world.time;
        self.phase = Phase::Draining;
        let mut out = Vec::new();
        for k in 0..self.bots.len() {
            let b = &self.bots[k];
            let Some(leg) = b.driving else { continue };
            if b.lost.is_some() || !(b.held_since.is_some() || self.recoveries > 1) {
                continue;
            }
            let back = self.reversed(&leg);
            let b = &mut self.bots[k];
            b.driving = Some(back);
            b.tail = None;
            b.held_since = None;
            b.at_end = false;
            if team.idle(b.id) {
                b.retry = false;
                out.extend(self.drive(k, world));
            }
        }
        out
    }

    fn finish(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let minutes = world.time.saturating_sub(self.started).as_secs_f64() / 60.0;
        self.odometer.observe(world);
        // A robot stands within a couple of centimetres of its node, so a robot that drove a
        // single short edge may have been that much short of it; the slack is given once.
        let claimed = |id: u16| {
            let edges_m = self
                .bots
                .iter()
                .find(|b| b.id == id)
                .map_or(0.0, |b| b.edges_m);
            (edges_m - NODE_SLACK_M / EVIDENCE_SHARE).max(0.0)
        };
        let ids = self.bots.iter().map(|b| b.id);
        if let Some((id, measured, claim)) = self.odometer.short_of(ids, claimed) {
            return self.fail(format!(
                "robot {id}: its encoders measured {measured:.2} m, short of the {:.2} m that the \
                 edges it reported driving take ({:.0} % of their tape, less {:.0} cm)",
                EVIDENCE_SHARE * claim,
                EVIDENCE_SHARE * 100.0,
                NODE_SLACK_M * 100.0
            ));
        }
        let driven: f64 = self
            .bots
            .iter()
            .map(|b| self.odometer.distance_m(b.id))
            .sum();
        self.verdict = Some(
            Verdict::success(format!(
                "{} tasks done by {} robots, {:.1} per minute, {} plans, {} recoveries; \
                 {driven:.1} m driven by the encoders",
                self.tasks,
                self.bots.len(),
                f64::from(self.tasks) / minutes.max(1e-9),
                self.replans,
                self.recoveries_total
            ))
            .with("tasks", f64::from(self.tasks))
            .with("encoder_distance_m", driven)
            .with(
                "tasks_per_minute",
                f64::from(self.tasks) / minutes.max(1e-9),
            )
            .with("plans", f64::from(self.replans))
            .with("live_plans", f64::from(self.replans_live))
            .with("recoveries", f64::from(self.recoveries_total))
            .with("held_segments", f64::from(self.held))
            .with("plan_time_max_ms", self.plan_time_max.as_secs_f64() * 1e3),
        );
        Vec::new()
    }

    fn fail(&mut self, why: String) -> Vec<Intent> {
        self.verdict = Some(
            Verdict::failure(why)
                .with("tasks", f64::from(self.tasks))
                .with("plans", f64::from(self.replans))
                .with("recoveries", f64::from(self.recoveries_total)),
        );
        Vec::new()
    }

    /// Robot `k` reached the end of `leg`.
    fn complete_leg(
        &mut self,
        k: usize,
        leg: EdgeDrive,
        world: &WorldSnapshot,
    ) -> Result<(), String> {
        self.bots[k].node = leg.to;
        self.last_progress = world.time;
        let Some(index) = leg.index else {
            return Ok(());
        };
        self.bots[k].edges_m += self.track.edge_length(leg.edge);
        if let Some(adg) = self.adg.as_mut() {
            adg.complete(k, index)
                .map_err(|e| format!("robot {}: {e}", self.bots[k].id))?;
        }
        let b = &mut self.bots[k];
        if b.active && leg.to == b.goal {
            b.tasks_done += 1;
            b.reached = true;
            self.tasks += 1;
            self.recoveries = 0;
            if self.quota.is_some_and(|q| b.tasks_done >= q) {
                b.active = false;
            }
            // Every robot now finishes the edge it is on; then the team is planned again. With
            // the last task done, robots with a quota (scripted goals) run the plan to its end,
            // so that one pushed aside returns to its goal; lifelong tasks end once every robot
            // has finished its edge (running the plan to its end took minutes: LaCAM's paths for
            // robots far from their goals can be long).
            // With lifelong replanning, robots keep driving and the team is planned again at the
            // next snapshot, from where each robot stands or is driving to.
            if self.tasks < self.target_tasks && self.replan_mode == Replan::Lifelong {
                self.replan_due = true;
            } else if self.tasks < self.target_tasks || self.quota.is_none() {
                self.phase = Phase::Draining;
            }
        }
        if self.adg.as_ref().is_some_and(|a| a.is_done()) {
            self.phase = Phase::Draining;
        }
        Ok(())
    }

    /// One round: arrivals, recovery, replanning and dispatch. Lifelong plans are made only at
    /// a `snapshot`, so that all robots reaching their goals since the last one share a plan.
    fn step(&mut self, world: &WorldSnapshot, team: &Team, snapshot: bool) -> Vec<Intent> {
        self.now = world.time;
        self.odometer.observe(world);
        if let Some(stall) = self.odometer.stall() {
            return self.fail(stall.to_string());
        }
        for k in 0..self.bots.len() {
            if !std::mem::take(&mut self.bots[k].at_end) {
                continue;
            }
            if let Some(leg) = self.bots[k].driving.take() {
                if let Err(e) = self.complete_leg(k, leg, world) {
                    return self.fail(e);
                }
            }
        }
        // A lost robot is the supervisor's to bring back: the wait is not a deadlock.
        if self.bots.iter().any(|b| b.lost.is_some()) {
            self.last_progress = world.time;
        }
        let mut out = Vec::new();
        let held_long = self.bots.iter().find(|b| {
            b.lost.is_none()
                && b.held_since
                    .is_some_and(|t| world.time.saturating_sub(t) >= HOLD_LIMIT)
        });
        if let Some(b) = held_long {
            let why = format!(
                "robot {}'s segment was held back for {} s ({})",
                b.id,
                HOLD_LIMIT.as_secs(),
                b.held_why
            );
            out.extend(self.recover(world, why, team));
        } else if world.time.saturating_sub(self.last_progress) > STALL_LIMIT {
            let why = format!("no robot finished an edge for {} s", STALL_LIMIT.as_secs());
            out.extend(self.recover(world, why, team));
        }
        if self.verdict.is_some() {
            return out;
        }
        out.extend(self.make_room(world, team));
        for k in 0..self.bots.len() {
            let b = &self.bots[k];
            if b.retry && team.idle(b.id) && b.lost.is_none() && b.making_room.is_none() {
                self.bots[k].retry = false;
                out.extend(self.drive(k, world));
            }
        }
        let all_still = self.bots.iter().all(|b| {
            team.idle(b.id) && b.driving.is_none() && b.lost.is_none() && b.making_room.is_none()
        });
        if self.phase == Phase::Placing && all_still {
            self.phase = Phase::Draining;
        }
        if self.phase == Phase::Draining && all_still {
            if self.tasks >= self.target_tasks {
                return self.finish(world);
            }
            if let Err(e) = self.replan() {
                return self.fail(e);
            }
            if self.tasks >= self.target_tasks {
                return self.finish(world);
            }
            self.phase = Phase::Running;
        } else if self.phase == Phase::Running && self.replan_due && snapshot {
            if let Err(e) = self.replan_lifelong() {
                return self.fail(e);
            }
        }
        out.extend(self.dispatch(world, team));
        out
    }

    /// Robot `k` is lost: its queued moves are dropped by the supervisor (the team forgets
    /// them), so their ends are not progress nor failure; its leg is kept for when it is found.
    fn lose(&mut self, k: usize, why: String) {
        let b = &mut self.bots[k];
        b.retry = false;
        b.held_since = None;
        if let Some(leg) = b.driving.as_mut() {
            leg.last = false;
        }
        b.tail = None;
        b.making_room = None;
        b.lost = Some(why);
    }

    /// Robots waiting just behind a lost one back away from it, and come back once it is found.
    ///
    /// Only a robot with no move under way is asked, and its leg (if any) is planned again from
    /// where it stands when it is back; the safety check still judges every move.
    fn make_room(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let mut out = Vec::new();
        for k in 0..self.bots.len() {
            let id = self.bots[k].id;
            if self.bots[k].lost.is_some() || !team.idle(id) {
                continue;
            }
            let Some(me) = world.robot(id) else { continue };
            if let Some(m) = self.bots[k].making_room {
                let still_lost = self.bots.iter().any(|b| b.id == m.lost && b.lost.is_some());
                if m.returning || still_lost {
                    continue;
                }
                let back = Vector2::new(m.from.x - me.pose.x, m.from.y - me.pose.y).norm();
                if back < 0.003 {
                    self.bots[k].making_room = None;
                    if self.bots[k].driving.is_some() {
                        out.extend(self.drive(k, world));
                    }
                    continue;
                }
                self.bots[k].making_room = Some(MakeRoom {
                    returning: true,
                    ..m
                });
                out.push(Intent::Move {
                    robot: id,
                    command: MoveCommand::Straight {
                        distance_m: back as f32,
                        speed_mps: MAKE_ROOM_MPS,
                    },
                    tag: MAKE_ROOM_TAG,
                });
                continue;
            }
            let lost_ahead = self.bots.iter().filter(|b| b.lost.is_some()).find_map(|b| {
                let (off, distance) = me.bearing_to(world.robot(b.id)?);
                (distance < MAKE_ROOM_NEAR_M && off < FRAC_PI_2).then_some(b.id)
            });
            let Some(lost) = lost_ahead else { continue };
            let b = &mut self.bots[k];
            tracing::debug!(robot = id, lost, "makes room for a lost robot");
            b.making_room = Some(MakeRoom {
                lost,
                from: me.pose,
                returning: false,
            });
            b.retry = false;
            b.held_since = None;
            b.tail = None;
            if let Some(leg) = b.driving.as_mut() {
                leg.last = false;
            }
            out.push(Intent::Move {
                robot: id,
                command: MoveCommand::Straight {
                    distance_m: -MAKE_ROOM_M,
                    speed_mps: MAKE_ROOM_MPS,
                },
                tag: MAKE_ROOM_TAG,
            });
        }
        out
    }
}

impl Behaviour for TrafficControl {
    fn start(&mut self, world: &WorldSnapshot, _: &mut Team) -> Vec<Intent> {
        self.started = world.time;
        self.last_progress = world.time;
        match self.place(world) {
            Ok(out) => out,
            Err(e) => self.fail(e),
        }
    }

    fn on_snapshot(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        self.step(world, team, true)
    }

    fn on_event(
        &mut self,
        robot: u16,
        event: &Event,
        world: &WorldSnapshot,
        team: &mut Team,
    ) -> Vec<Intent> {
        let Some(k) = self.bots.iter().position(|b| b.id == robot) else {
            return Vec::new();
        };
        match event {
            Event::MoveFinished { outcome, .. } => {
                if self.bots[k].lost.is_some() {
                    return Vec::new();
                }
                if let Some(m) = self.bots[k].making_room {
                    // Backed away: it waits. Back where it stood (or stopped on the way): its
                    // leg goes on from there.
                    if m.returning && team.idle(robot) {
                        self.bots[k].making_room = None;
                        if self.bots[k].driving.is_some() {
                            return self.drive(k, world);
                        }
                        return self.step(world, team, false);
                    }
                    return Vec::new();
                }
                if *outcome != MoveOutcome::Completed {
                    // The supervisor may stop a robot it lost before telling us so.
                    if world
                        .robot(robot)
                        .is_some_and(|v| v.localisation == Localisation::Lost)
                    {
                        self.lose(k, "the world model lost it".into());
                        return Vec::new();
                    }
                    return self.fail(format!("robot {robot}: a move ended {outcome:?}"));
                }
                self.bots[k].held_since = None;
                if team.outstanding(robot) == 1 && self.bots[k].tail.is_some() {
                    return self.drive_ahead(k, world);
                }
                if team.idle(robot) {
                    match self.bots[k].driving {
                        Some(leg) if leg.last => {
                            self.bots[k].driving = None;
                            if let Err(e) = self.complete_leg(k, leg, world) {
                                return self.fail(e);
                            }
                            return self.step(world, team, false);
                        }
                        Some(_) => return self.drive(k, world),
                        None => return self.step(world, team, false),
                    }
                }
                Vec::new()
            }
            Event::LinkLost => self.fail(format!("robot {robot} lost its link")),
            _ => Vec::new(),
        }
    }

    fn on_held(
        &mut self,
        intent: &Intent,
        reason: &str,
        world: &WorldSnapshot,
        team: &mut Team,
    ) -> Vec<Intent> {
        // The plan keeps robots apart by construction; a held segment means the world model saw
        // a robot closer than the plan assumed (a pose error). The segment is planned again from
        // the robot's pose at the next snapshot; held for `HOLD_LIMIT`, the team is replanned.
        if let Intent::Move { robot, .. } = intent {
            if let Some(bot) = self.bots.iter_mut().find(|b| b.id == *robot) {
                // Held while backing away (something behind): it waits where it stands, and is
                // not asked again. Held coming back (the found robot still near): its leg is
                // planned from where it stands.
                if let Some(m) = bot.making_room {
                    if m.returning {
                        bot.making_room = None;
                        if bot.driving.is_some() {
                            bot.retry = true;
                        }
                    }
                    self.held += 1;
                    return Vec::new();
                }
                // The segment did not reach the node even if earlier moves of it are driven.
                if let Some(leg) = bot.driving.as_mut() {
                    leg.last = false;
                }
                bot.tail = None;
                if bot.lost.is_none() {
                    bot.held_since.get_or_insert(world.time);
                    // The first held move of a batch says why; the rest only follow it.
                    if std::mem::take(&mut bot.fresh_hold) {
                        bot.held_why = reason.to_owned();
                    }
                    if team.idle(bot.id) && bot.driving.is_some() {
                        bot.retry = true;
                    }
                }
            }
            self.held += 1;
        }
        Vec::new()
    }

    fn on_localisation(
        &mut self,
        robot: u16,
        event: &LocalisationEvent,
        world: &WorldSnapshot,
        team: &mut Team,
    ) -> Vec<Intent> {
        let Some(k) = self.bots.iter().position(|b| b.id == robot) else {
            return Vec::new();
        };
        match event {
            LocalisationEvent::Lost { why } => {
                self.lose(k, why.clone());
                Vec::new()
            }
            LocalisationEvent::Found => {
                self.bots[k].lost = None;
                self.last_progress = world.time;
                let mut out = Vec::new();
                if self.bots[k].driving.is_some() && team.idle(robot) {
                    out.extend(self.drive(k, world));
                }
                out.extend(self.step(world, team, false));
                out
            }
        }
    }

    fn verdict(&self) -> Option<Verdict> {
        self.verdict.clone()
    }

    fn progress(&self) -> Vec<(String, f64)> {
        let minutes = self.now.saturating_sub(self.started).as_secs_f64() / 60.0;
        vec![
            ("tasks".into(), f64::from(self.tasks)),
            (
                "tasks_per_minute".into(),
                f64::from(self.tasks) / minutes.max(1e-9),
            ),
            ("plans".into(), f64::from(self.replans)),
            ("recoveries".into(), f64::from(self.recoveries_total)),
        ]
    }
}

/// Where `route` ends, when it is a single move driving forward along a straight or an arc: a
/// move the firmware can flow into the next.
fn forward_move(route: &Manoeuvre) -> Option<Pose> {
    match route.moves.as_slice() {
        [MoveCommand::Straight { distance_m, .. }] if *distance_m > 0.0 => Some(route.end),
        [MoveCommand::Arc { .. }] => Some(route.end),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use world::presets;

    #[test]
    fn goals_name_track_nodes_and_count_robots() {
        let w = presets::preset("junction").unwrap();
        let mut cfg = BehaviourConfig {
            robots: vec![1, 2],
            track: Arc::new(w.track),
            ..Default::default()
        };
        cfg.params.insert("goals".into(), "Y,T".into());
        assert!(TrafficControl::new(&cfg).is_ok());
        cfg.params.insert("goals".into(), "Y,nowhere".into());
        let e = TrafficControl::new(&cfg).err().unwrap();
        assert!(e.contains("nowhere"), "{e}");
        cfg.params.insert("goals".into(), "Y".into());
        assert!(TrafficControl::new(&cfg).is_err());
    }

    #[test]
    fn a_curve_is_driven_in_segments_that_stay_on_the_tape() {
        let w = presets::preset("junction").unwrap();
        let cfg = BehaviourConfig {
            robots: vec![1],
            track: Arc::new(w.track),
            ..Default::default()
        };
        let t = TrafficControl::new(&cfg).unwrap();
        for (u, v) in [("B", "D"), ("D", "B"), ("M", "P2"), ("F", "P1")] {
            let mut leg = leg_between(&t, u, v);
            let (edge, u, v) = (leg.edge, node(&t, u), leg.to);
            // A robot on u facing the wrong way: it turns, then follows the tape segment by
            // segment, each segment ending on the tape, until the last ends on v.
            let p = t.position(u);
            let mut pose = Pose {
                x: p.x,
                y: p.y,
                theta: 1.0,
            };
            for _ in 0..20 {
                let r = t.segment(pose, &mut leg);
                let end = Point2::new(r.end.x, r.end.y);
                assert!(t.track.nearest_on(edge, end).distance_m < 1e-6, "{r:?}");
                pose = r.end;
                if leg.last {
                    break;
                }
            }
            assert!(leg.last);
            assert!((Point2::new(pose.x, pose.y) - t.position(v)).norm() < 1e-6);
        }
    }

    use crate::testing::{world, Harness};
    /// The plan's drive of the edge from node `u` to node `v`.
    fn leg_between(t: &TrafficControl, u: &str, v: &str) -> EdgeDrive {
        let (u, v) = (node(t, u), node(t, v));
        let (edge, forward) = t.edge_between(u, v).unwrap();
        EdgeDrive {
            index: Some(0),
            edge,
            forward,
            to: v,
            last: false,
            back: false,
        }
    }

    /// Robot 1 of `t` on node `u` facing along the tape to `v`, about to drive that edge.
    fn on_edge_start(t: &mut TrafficControl, u: &str, v: &str) -> (usize, Pose) {
        let leg = leg_between(t, u, v);
        let (edge, forward, u) = (leg.edge, leg.forward, node(t, u));
        t.bots[0].driving = Some(leg);
        let len = t.track.edge_length(edge);
        let (_, tangent) = t.track.point_at(edge, if forward { 0.0 } else { len });
        let dir = if forward { tangent } else { -tangent };
        let p = t.position(u);
        let pose = Pose {
            x: p.x,
            y: p.y,
            theta: dir.y.atan2(dir.x),
        };
        (edge, pose)
    }

    fn at(pose: Pose) -> WorldSnapshot {
        snapshot(0, &[(1, pose.x, pose.y, pose.theta.to_degrees())])
    }

    #[test]
    fn an_edge_is_driven_with_the_next_segment_queued_behind_the_running_one() {
        let config = |flow: &str| BehaviourConfig {
            robots: vec![1],
            track: Arc::new(presets::preset("junction").unwrap().track),
            params: [("flow".to_string(), flow.to_string())].into(),
            ..Default::default()
        };
        let mut t = TrafficControl::new(&config("true")).unwrap();
        let (edge, start) = on_edge_start(&mut t, "B", "D");
        let forward_moves = |out: &[Intent]| {
            out.iter()
                .filter(|i| {
                    matches!(
                        i,
                        Intent::Move {
                            command: MoveCommand::Arc { .. } | MoveCommand::Straight { .. },
                            ..
                        }
                    )
                })
                .count()
        };
        // Two segments at once, so that the robot never waits at the first joint.
        let out = t.drive(0, &at(start));
        assert_eq!(forward_moves(&out), 2, "{out:?}");
        let (mut first_end, mut tail_end) = t.bots[0].tail.expect("a tail to queue behind");
        let mut segments = 2;
        loop {
            // The robot ended the running segment 5 mm to the left of where it was planned to:
            // the segment queued now is planned from where the tail will then end, and ends on
            // the tape.
            let off = first_end.compose(Pose {
                x: 0.0,
                y: 0.005,
                theta: 0.0,
            });
            let out = t.drive_ahead(0, &at(off));
            assert_eq!(forward_moves(&out), 1, "{out:?}");
            segments += 1;
            let leg = t.bots[0].driving.unwrap();
            let Some((from, to)) = t.bots[0].tail else {
                assert!(
                    leg.last,
                    "only the edge's last segment has nothing behind it"
                );
                break;
            };
            assert!(!leg.last);
            let end = Point2::new(to.x, to.y);
            assert!(t.track.nearest_on(edge, end).distance_m < 1e-6, "{to:?}");
            let predicted = off.compose(tail_end.relative_to(first_end));
            assert!((predicted.x - from.x).abs() < 1e-9 && (predicted.y - from.y).abs() < 1e-9);
            (first_end, tail_end) = (from, to);
            assert!(segments < 20, "the edge ends");
        }
        assert!(segments >= 3, "{segments} segments");

        // `flow=false` sends one segment at a time; the default flows.
        for (mut t, sent) in [
            (TrafficControl::new(&config("false")).unwrap(), 1),
            (junction(&[1]), 2),
        ] {
            let (_, start) = on_edge_start(&mut t, "B", "D");
            let out = t.drive(0, &at(start));
            assert_eq!(forward_moves(&out), sent, "{out:?}");
            assert_eq!(t.bots[0].tail.is_some(), sent == 2);
        }
    }

    fn junction(robots: &[u16]) -> TrafficControl {
        let w = presets::preset("junction").unwrap();
        let cfg = BehaviourConfig {
            robots: robots.to_vec(),
            track: Arc::new(w.track),
            ..Default::default()
        };
        TrafficControl::new(&cfg).unwrap()
    }

    /// A snapshot at `secs` with robots at `(id, x, y, heading in degrees)`.
    fn snapshot(secs: u64, robots: &[(u16, f64, f64, f64)]) -> WorldSnapshot {
        robots
            .iter()
            .fold(
                world().arena(1.6, 1.0).at(secs as f64),
                |w, &(id, x, y, deg)| w.robot(id, x, y, deg),
            )
            .build()
    }

    fn node(t: &TrafficControl, id: &str) -> u32 {
        t.graph.node(id).unwrap().index() as u32
    }

    fn moves_for(out: &[Intent], robot: u16) -> usize {
        out.iter()
            .filter(|i| matches!(i, Intent::Move { robot: r, .. } if *r == robot))
            .count()
    }

    #[test]
    fn a_robot_on_a_node_stands_there_and_is_planned_from_it() {
        let mut h = Harness::new(junction(&[1]));
        // C is at (0.8, 0.15): 1 cm off it still stands on it.
        let w = snapshot(0, &[(1, 0.81, 0.15, 90.0)]);
        let out = h.start(&w);
        assert!(
            h.behaviour().verdict.is_none(),
            "{:?}",
            h.behaviour().verdict
        );
        assert_eq!(moves_for(&out, 1), 0, "{out:?}");
        assert_eq!(h.behaviour().bots[0].node, node(h.behaviour(), "C"));
        // At the next snapshot the team is planned and the robot drives its first edge.
        let out = h.snapshot(&snapshot(1, &[(1, 0.81, 0.15, 90.0)]));
        assert_eq!(h.behaviour().phase, Phase::Running);
        assert!(moves_for(&out, 1) > 0, "{out:?}");
        assert!(h.behaviour().bots[0]
            .driving
            .is_some_and(|l| l.index.is_some()));
    }

    #[test]
    fn a_robot_on_an_edge_drives_to_the_node_ahead_or_the_free_one_behind() {
        let mut h = Harness::new(junction(&[1, 2]));
        // Robot 1 stands on C; robot 2 on the main line between F and C, heading for C, backs
        // to F.
        let w = snapshot(0, &[(1, 0.8, 0.15, 0.0), (2, 0.7, 0.15, 0.0)]);
        let out = h.start(&w);
        assert!(
            h.behaviour().verdict.is_none(),
            "{:?}",
            h.behaviour().verdict
        );
        assert_eq!(h.behaviour().bots[0].node, node(h.behaviour(), "C"));
        assert_eq!(h.behaviour().bots[1].node, node(h.behaviour(), "F"));
        let leg = h.behaviour().bots[1].driving.unwrap();
        assert!(leg.back && leg.to == node(h.behaviour(), "F"), "{leg:?}");
        match out.as_slice() {
            [Intent::Move {
                robot: 2,
                command: MoveCommand::Straight { distance_m, .. },
                ..
            }] => assert!((*distance_m + 0.25).abs() < 1e-3, "{out:?}"),
            _ => panic!("robot 2 backs to F: {out:?}"),
        }
        // Alone, it drives ahead to C.
        let mut h = Harness::new(junction(&[2]));
        let out = h.start(&snapshot(0, &[(2, 0.7, 0.15, 0.0)]));
        assert_eq!(h.behaviour().bots[0].node, node(h.behaviour(), "C"));
        assert!(!h.behaviour().bots[0].driving.unwrap().back);
        assert!(moves_for(&out, 2) > 0);
    }

    #[test]
    fn two_robots_on_one_edge_take_the_end_on_their_side() {
        let mut h = Harness::new(junction(&[1, 2]));
        // Both head for C; robot 1 is behind robot 2, so it goes back to F instead of passing.
        h.start(&snapshot(0, &[(1, 0.55, 0.15, 0.0), (2, 0.7, 0.15, 0.0)]));
        assert!(
            h.behaviour().verdict.is_none(),
            "{:?}",
            h.behaviour().verdict
        );
        assert_eq!(h.behaviour().bots[0].node, node(h.behaviour(), "F"));
        assert_eq!(h.behaviour().bots[1].node, node(h.behaviour(), "C"));
    }

    #[test]
    fn a_robot_off_the_tape_is_refused_with_where_it_is() {
        let mut h = Harness::new(junction(&[1, 7]));
        let out = h.start(&snapshot(0, &[(1, 0.8, 0.15, 0.0), (7, 0.8, 0.42, 0.0)]));
        let v = h.behaviour().verdict.clone().expect("refused");
        assert!(!v.success);
        assert!(
            v.summary.contains("robot 7")
                && v.summary.contains("(0.800, 0.420)")
                && v.summary.contains("12.0 cm"),
            "{}",
            v.summary
        );
        assert!(out.is_empty(), "nothing moves: {out:?}");
    }

    #[test]
    fn a_robot_with_both_ends_taken_is_refused_naming_who_holds_them() {
        let mut h = Harness::new(junction(&[1, 2, 3]));
        h.start(&snapshot(
            0,
            &[
                (1, 0.45, 0.15, 0.0),
                (2, 0.8, 0.15, 0.0),
                (3, 0.62, 0.15, 0.0),
            ],
        ));
        let v = h.behaviour().verdict.clone().expect("refused");
        assert!(
            v.summary.contains("robot 3") && v.summary.contains("C by robot 2"),
            "{}",
            v.summary
        );
    }

    #[test]
    fn a_lost_robot_keeps_its_leg_and_drives_it_again_when_found() {
        let mut h = Harness::new(junction(&[2]));
        let w = snapshot(0, &[(2, 0.7, 0.15, 0.0)]);
        let out = h.start(&w);
        let sent = moves_for(&out, 2);
        assert!(sent > 0);
        h.localise(
            2,
            LocalisationEvent::Lost {
                why: "tape where none is".into(),
            },
            &w,
        );
        // Its dropped moves end aborted: not a failure, not progress.
        for _ in 0..sent {
            let aborted = Event::MoveFinished {
                tag: 0,
                outcome: MoveOutcome::Stopped,
            };
            assert!(h.event(2, aborted, &w).is_empty());
        }
        // Lost for longer than a stall would take is no deadlock.
        let late = snapshot(120, &[(2, 0.7, 0.15, 0.0)]);
        h.snapshot(&late);
        assert!(
            h.behaviour().verdict.is_none(),
            "{:?}",
            h.behaviour().verdict
        );
        let found = snapshot(121, &[(2, 0.74, 0.16, 10.0)]);
        let out = h.localise(2, LocalisationEvent::Found, &found);
        assert!(moves_for(&out, 2) > 0, "{out:?}");
        assert_eq!(
            h.behaviour().bots[0].driving.unwrap().to,
            node(h.behaviour(), "C")
        );
    }

    #[test]
    fn a_robot_waiting_behind_a_lost_one_backs_away_and_returns_when_it_is_found() {
        let mut h = Harness::new(junction(&[2, 3]));
        let at = |secs, x3| snapshot(secs, &[(2, 0.7, 0.15, 0.0), (3, x3, 0.15, 0.0)]);
        let out = h.start(&at(0, 0.6));
        // Robot 3's moves are held, too near robot 2: it stands idle 10 cm behind it.
        let held: Vec<Intent> = out
            .into_iter()
            .filter(|i| matches!(i, Intent::Move { robot: 3, .. }))
            .collect();
        for i in held {
            h.hold(i, "too near robot 2", &at(0, 0.6));
        }
        assert!(h.team().idle(3));
        // How far robot 3 is sent straight to make room or come back, if it is.
        let room = |out: &[Intent]| {
            out.iter().find_map(|i| match i {
                Intent::Move {
                    robot: 3,
                    command: MoveCommand::Straight { distance_m, .. },
                    tag: MAKE_ROOM_TAG,
                } => Some(*distance_m),
                _ => None,
            })
        };
        let lost = LocalisationEvent::Lost {
            why: "tape where none is".into(),
        };
        h.localise(2, lost, &at(1, 0.6));
        let backing = h.snapshot(&at(1, 0.6));
        assert!(room(&backing).is_some_and(|d| d < 0.0), "{backing:?}");
        // Backed away, it waits while robot 2 is lost.
        assert!(h.finish_move(3, MAKE_ROOM_TAG, &at(2, 0.52)).is_empty());
        assert_eq!(moves_for(&h.snapshot(&at(3, 0.52)), 3), 0);
        // Robot 2 found: robot 3 drives back to where it stood, then on with its leg.
        let back = h.localise(2, LocalisationEvent::Found, &at(4, 0.52));
        assert!(
            room(&back).is_some_and(|d| (d - 0.08).abs() < 1e-3),
            "{back:?}"
        );
        let on = h.finish_move(3, MAKE_ROOM_TAG, &at(5, 0.6));
        assert!(moves_for(&on, 3) > 0, "{on:?}");
        assert!(h.behaviour().bots[1].making_room.is_none());
    }

    #[test]
    fn without_progress_the_team_recovers_then_fails_saying_who_waits_for_what() {
        let mut h = Harness::new(junction(&[1, 2]));
        let poses = [(1, 0.8, 0.15, 0.0), (2, 0.7, 0.15, 0.0)];
        h.start(&snapshot(0, &poses));
        // Robot 2's moves never finish; each stall is a recovery that sends it back and forth.
        let mut secs = 0;
        while h.behaviour().verdict.is_none() && secs < 1000 {
            secs += 1;
            h.snapshot(&snapshot(secs, &poses));
        }
        let v = h.behaviour().verdict.clone().expect("fails");
        assert!(!v.success);
        assert_eq!(h.behaviour().recoveries_total, MAX_RECOVERIES);
        assert!(
            v.summary.contains("deadlock") && v.summary.contains("robot 2 is driving"),
            "{}",
            v.summary
        );
        assert!(
            secs > STALL_LIMIT.as_secs() * u64::from(MAX_RECOVERIES + 1),
            "{secs}"
        );
    }

    #[test]
    fn a_segment_held_for_seconds_sends_the_robot_back_and_replans() {
        let mut h = Harness::new(junction(&[2]));
        let w = snapshot(0, &[(2, 0.7, 0.15, 0.0)]);
        let out = h.start(&w);
        for i in &out {
            h.hold(*i, "another robot in the way", &w);
        }
        assert!(h.behaviour().bots[0].retry);
        // Planned again from the pose at the next snapshot.
        let out = h.snapshot(&snapshot(1, &[(2, 0.7, 0.15, 0.0)]));
        assert!(moves_for(&out, 2) > 0);
        for (n, i) in out.iter().enumerate() {
            let reason = if n == 0 {
                "another robot in the way"
            } else {
                "follows a held move"
            };
            h.hold(*i, reason, &w);
        }
        assert_eq!(h.behaviour().bots[0].held_why, "another robot in the way");
        let out = h.snapshot(&snapshot(5, &[(2, 0.7, 0.15, 0.0)]));
        assert_eq!(h.behaviour().recoveries_total, 1);
        let leg = h.behaviour().bots[0].driving.unwrap();
        assert_eq!(
            leg.to,
            node(h.behaviour(), "F"),
            "it drives back where it came from"
        );
        assert!(moves_for(&out, 2) > 0, "{out:?}");
    }

    /// Two robots on `junction`, running: robot 1 stands on A, robot 2 left F for C and is at
    /// action `index` of the old plan. Returns the behaviour and the nodes A, F and C.
    fn one_standing_one_driving_f_to_c(index: usize) -> (TrafficControl, u32, u32, u32) {
        let mut t = junction(&[1, 2]);
        let (a, f, c) = (node(&t, "A"), node(&t, "F"), node(&t, "C"));
        let (edge, forward) = t.edge_between(f, c).unwrap();
        t.phase = Phase::Running;
        t.bots[0].node = a;
        t.bots[1].node = f;
        t.bots[1].driving = Some(EdgeDrive {
            index: Some(index),
            edge,
            forward,
            to: c,
            last: false,
            back: false,
        });
        (t, a, f, c)
    }

    #[test]
    fn a_lifelong_plan_keeps_a_drive_and_lets_no_robot_into_the_node_it_left_before_it_arrives() {
        let (mut t, a, f, c) = one_standing_one_driving_f_to_c(7);
        // Robot 1 has F as its goal; robot 2 drives to C, its goal.
        t.bots[0].goal = f;
        t.bots[1].goal = c;
        assert!(t.replan_lifelong().unwrap());
        assert_eq!(t.bots[1].driving.unwrap().index, Some(0));
        let adg = t.adg.as_mut().unwrap();
        assert_eq!((adg.actions(1)[0].from, adg.actions(1)[0].to), (f, c));
        assert_eq!((adg.actions(0)[0].from, adg.actions(0)[0].to), (a, f));
        assert_eq!(adg.dependency(0, 0), Some((1, 0)));
        assert_eq!(adg.ready(0), None);
        adg.complete(1, 0).unwrap();
        assert_eq!(adg.ready(0).map(|x| x.to), Some(f));
        // Neither goal was reached, so no task was given or counted.
        assert_eq!((t.bots[0].goal, t.bots[1].goal, t.tasks), (f, c, 0));
    }

    #[test]
    fn a_robot_sent_on_from_its_goal_gets_a_new_task_at_the_next_lifelong_plan() {
        let (mut t, _, f, c) = one_standing_one_driving_f_to_c(2);
        t.bots[0].goal = u32::MAX;
        // Robot 2 reached F, its goal, and the old plan sent it on towards C.
        t.bots[1].goal = f;
        t.bots[1].reached = true;
        assert!(t.replan_lifelong().unwrap());
        // A new task from C, where it is committed to: not counted again on reaching F.
        assert!(!t.bots[1].reached);
        assert_ne!(t.bots[1].goal, c);
        assert_eq!(t.tasks, 0);
        assert_ne!(t.bots[0].goal, t.bots[1].goal);
    }

    #[test]
    fn a_last_segment_whose_drive_was_held_does_not_count_as_arrived() {
        let mut h = Harness::new(junction(&[2]));
        // 5 cm before C, facing across the tape: a turn, then a straight onto C.
        let w = snapshot(0, &[(2, 0.75, 0.15, 90.0)]);
        let out = h.start(&w);
        assert_eq!(out.len(), 2, "{out:?}");
        h.hold(out[1], "another robot in the way", &w);
        let turned = snapshot(1, &[(2, 0.75, 0.15, 0.0)]);
        let out = h.finish_move(2, 0, &turned);
        assert!(
            h.behaviour().bots[0]
                .driving
                .is_some_and(|l| l.to == node(h.behaviour(), "C")),
            "still driving to C"
        );
        assert!(
            matches!(
                out.as_slice(),
                [Intent::Move {
                    robot: 2,
                    command: MoveCommand::Straight { .. },
                    ..
                }]
            ),
            "the straight is planned again: {out:?}"
        );
    }
}
