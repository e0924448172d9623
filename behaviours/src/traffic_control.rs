//! `traffic_control`: robots on a track graph with forks, merges, sidings and single-lane sections
//! serve a stream of goal nodes each (lifelong tasks), without collisions or deadlock.
//!
//! Planning is multi-agent path finding on the track graph (nodes = junctions and marks, edges =
//! tape): LaCAM over PIBT (`mapf`), complete for one-shot instances, from where every robot stands
//! to its current goal; a robot without a task keeps its node as goal and is pushed aside when in
//! the way. The plan is executed as an action dependency graph: a robot drives into a node only
//! after every robot the plan put there before it has driven out, so robots that are slower or
//! faster than the plan assumed never meet. When a robot reaches its goal it gets its next task;
//! at the next moment every robot stands on a node, the team is planned again.
//!
//! Each edge is driven by the robot's own locomotion (a turn onto the tape's direction, then a
//! straight or an arc of the tape's radius), planned from the world model's pose, which the tape
//! under the line sensor keeps corrected.

use std::sync::Arc;
use std::time::{Duration, Instant};

use mapf::{lacam, Adg, Graph};
use nalgebra::{Point2, Vector2};
use petgraph::graph::NodeIndex;
use protocol::packets::MoveOutcome;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use robot_actor::{MoveCommand, Pose, RobotEventKind};
use simulator::world::graph::TrackGraph;
use simulator::world::Track;

use crate::api::{Behaviour, BehaviourConfig, Intent, Verdict, WorldSnapshot};
use crate::moves::{wrap, Route};

/// Driving speed along edges.
const DRIVE_MPS: f32 = 0.1;
/// Length of one driven segment: each is planned afresh from the corrected pose.
const LOOKAHEAD: f64 = 0.08;
/// A segment bends the heading by at most twice this; beyond it the robot turns first.
const MAX_BEND: f64 = 35.0 * std::f64::consts::PI / 180.0;
/// No robot finishing an edge for this long (simulated) is a deadlock.
const STALL_LIMIT: Duration = Duration::from_secs(30);
/// Search budget per plan; deterministic, unlike a time limit.
const MAX_EXPANSIONS: u64 = 2_000_000;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Driving from the start poses onto nodes.
    Placing,
    /// Executing a plan.
    Running,
    /// A robot reached its goal: no new actions start; replan once all are on nodes.
    Draining,
}

/// An edge being driven, one short segment at a time.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Leg {
    /// ADG action index, `None` for the drive onto the first node.
    index: Option<usize>,
    /// Track edge.
    edge: usize,
    /// Driven from its `from` node to its `to` node.
    forward: bool,
    /// Node it ends at.
    to: u32,
    /// The segment in flight ends at the node.
    last: bool,
}

#[derive(Clone, Debug)]
struct Bot {
    id: u16,
    /// The node the robot stands on, or is driving from.
    node: u32,
    goal: u32,
    /// Moves sent and not yet finished.
    outstanding: usize,
    /// The edge being driven.
    driving: Option<Leg>,
    tasks_done: u32,
    /// A segment was held back by the safety check: plan it again.
    retry: bool,
    rng: ChaCha8Rng,
    /// Has a task (false once its quota is done: it only keeps out of the way).
    active: bool,
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
    scripted: bool,
    plan_time_max: Duration,
    last_progress: Duration,
    started: Duration,
    verdict: Option<Verdict>,
}

impl TrafficControl {
    /// Builds it. Parameters: `tasks` (tasks to complete in all, default 100), `quota` (tasks per
    /// robot after which it only keeps out of the way; default unlimited), `goals` (a
    /// comma-separated list of node ids, one per robot: each robot's single task, for scripted
    /// scenarios such as a swap through a single-lane section).
    ///
    /// # Errors
    /// A track without edges, unknown goal nodes, or a parameter out of range.
    pub fn new(cfg: &BehaviourConfig) -> Result<Self, String> {
        if cfg.track.edges().is_empty() {
            return Err("traffic control needs a track".into());
        }
        let graph = TrackGraph::new(&cfg.track);
        let mapf = Graph::from_petgraph(&graph.graph).map_err(|e| e.to_string())?;
        let target_tasks: u32 = cfg.param("tasks", 100)?;
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
                outstanding: 0,
                driving: None,
                tasks_done: 0,
                retry: false,
                rng: ChaCha8Rng::seed_from_u64(cfg.seed ^ (u64::from(id) << 32)),
                active: true,
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
            scripted: scripted.is_some(),
            plan_time_max: Duration::ZERO,
            last_progress: Duration::ZERO,
            started: Duration::ZERO,
            verdict: None,
        })
    }

    fn position(&self, node: u32) -> Point2<f64> {
        self.track.nodes()[node as usize].position
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

    /// The next segment of `leg` from `pose`: a turn onto the tape if the robot faces away from
    /// it, then an arc (or straight) through a point `LOOKAHEAD` further along the tape, or the
    /// end node when that is nearer. Each segment is planned from the world model's pose, which
    /// the tape under the sensor keeps corrected, so errors of one segment are taken out by the
    /// next instead of adding up over a long curve.
    fn segment(&self, pose: Pose, leg: &mut Leg) -> Route {
        let len = self.track.edge_length(leg.edge);
        let here = self.track.nearest_on(leg.edge, Point2::new(pose.x, pose.y));
        let done = if leg.forward {
            here.offset_m
        } else {
            len - here.offset_m
        };
        let remaining = (len - done).max(0.0);
        let ahead = (done + LOOKAHEAD).min(len);
        leg.last = remaining <= LOOKAHEAD + 0.01;
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
        let mut route = Route::from(pose, DRIVE_MPS);
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

    /// Sends robot `k` the next segment of its leg.
    fn drive(&mut self, k: usize, world: &WorldSnapshot) -> Vec<Intent> {
        let (Some(mut leg), Some(view)) = (self.bots[k].driving, world.robot(self.bots[k].id))
        else {
            return Vec::new();
        };
        let route = self.segment(view.pose, &mut leg);
        self.bots[k].driving = Some(leg);
        if route.moves.is_empty() {
            leg.last = true;
            self.bots[k].driving = Some(leg);
            return Vec::new();
        }
        self.send(k, route)
    }

    fn send(&mut self, k: usize, route: Route) -> Vec<Intent> {
        let id = self.bots[k].id;
        self.bots[k].outstanding += route.moves.len();
        route
            .moves
            .into_iter()
            .map(|command| Intent::Move { robot: id, command })
            .collect()
    }

    /// Start poses are edge middles: each robot drives to the node ahead of it, or backs to
    /// the one behind (on a straight) when another robot takes the one ahead.
    fn place(&mut self, world: &WorldSnapshot) -> Result<Vec<Intent>, String> {
        let mut taken: Vec<u32> = Vec::new();
        let mut out = Vec::new();
        for k in 0..self.bots.len() {
            let id = self.bots[k].id;
            let view = world
                .robot(id)
                .ok_or_else(|| format!("robot {id} is not in the world"))?;
            let p = view.pose;
            let near = self
                .track
                .nearest(Point2::new(p.x, p.y))
                .ok_or("the track is empty")?;
            let edge = &self.track.edges()[near.edge];
            let heading = Vector2::new(p.theta.cos(), p.theta.sin());
            let towards_to = near.tangent.dot(&heading) >= 0.0;
            let (ahead, behind) = if towards_to {
                (edge.to as u32, edge.from as u32)
            } else {
                (edge.from as u32, edge.to as u32)
            };
            if !taken.contains(&ahead) {
                taken.push(ahead);
                self.bots[k].node = ahead;
                self.bots[k].driving = Some(Leg {
                    index: None,
                    edge: near.edge,
                    forward: towards_to,
                    to: ahead,
                    last: false,
                });
                out.extend(self.drive(k, world));
            } else if !taken.contains(&behind) && !edge.is_arc() {
                taken.push(behind);
                self.bots[k].node = behind;
                let q = self.position(behind);
                out.extend(self.send(k, Route::from(p, DRIVE_MPS).back_to(q.x, q.y)));
            } else {
                return Err(format!(
                    "robot {id}: both ends of its edge are taken by other robots"
                ));
            }
        }
        Ok(out)
    }

    /// A new goal for robot `k`: a random node that is no other robot's goal nor its own node.
    fn new_task(&mut self, k: usize) {
        let n = self.mapf.num_vertices() as u32;
        let used: Vec<u32> = self
            .bots
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != k)
            .map(|(_, b)| b.goal)
            .collect();
        let here = self.bots[k].node;
        let free: Vec<u32> = (0..n).filter(|v| *v != here && !used.contains(v)).collect();
        let bot = &mut self.bots[k];
        bot.goal = if free.is_empty() {
            here
        } else {
            free[bot.rng.gen_range(0..free.len())]
        };
    }

    /// Goals for everyone at a goal, then a plan for the whole team from where it stands.
    fn replan(&mut self) -> Result<(), String> {
        for k in 0..self.bots.len() {
            let b = &mut self.bots[k];
            if b.active && b.goal == b.node && self.scripted {
                // A scripted robot that starts on its goal has nothing to do but keep clear.
                b.tasks_done += 1;
                self.tasks += 1;
                b.active = false;
            }
            let b = &self.bots[k];
            let at_goal = b.goal == b.node || b.goal == u32::MAX;
            if at_goal && b.active {
                self.new_task(k);
            } else if !b.active {
                self.bots[k].goal = self.bots[k].node;
            }
        }
        // Goals must differ: a robot whose goal another holds waits where it is this round.
        let mut seen: Vec<u32> = Vec::new();
        for k in 0..self.bots.len() {
            if seen.contains(&self.bots[k].goal) {
                self.bots[k].goal = self.bots[k].node;
            }
            seen.push(self.bots[k].goal);
        }
        let starts: Vec<u32> = self.bots.iter().map(|b| b.node).collect();
        let goals: Vec<u32> = self.bots.iter().map(|b| b.goal).collect();
        let t = Instant::now();
        let plan = lacam::solve(
            &self.mapf,
            &starts,
            &goals,
            &lacam::Options {
                seed: self.seed.wrapping_add(u64::from(self.replans)),
                time_limit: None,
                max_expansions: Some(MAX_EXPANSIONS),
            },
        )
        .map_err(|e| format!("planning failed: {e}"))?;
        self.plan_time_max = self.plan_time_max.max(t.elapsed());
        self.adg = Some(Adg::new(&plan).map_err(|e| format!("plan not executable: {e}"))?);
        self.replans += 1;
        Ok(())
    }

    /// Starts every action the dependency graph allows.
    fn dispatch(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let mut out = Vec::new();
        if self.phase != Phase::Running {
            return out;
        }
        for k in 0..self.bots.len() {
            if self.bots[k].driving.is_some() || self.bots[k].outstanding > 0 {
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
                from = %self.track.nodes()[action.from as usize].id,
                to = %self.track.nodes()[action.to as usize].id,
                pose = ?(view.pose.x, view.pose.y, view.pose.theta.to_degrees()),
                "drive"
            );
            self.bots[k].driving = Some(Leg {
                index: Some(action.index),
                edge,
                forward,
                to: action.to,
                last: false,
            });
            out.extend(self.drive(k, world));
        }
        out
    }

    fn finish(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let minutes = world.time.saturating_sub(self.started).as_secs_f64() / 60.0;
        self.verdict = Some(
            Verdict::success(format!(
                "{} tasks done by {} robots, {:.1} per minute, {} plans",
                self.tasks,
                self.bots.len(),
                f64::from(self.tasks) / minutes.max(1e-9),
                self.replans
            ))
            .with("tasks", f64::from(self.tasks))
            .with(
                "tasks_per_minute",
                f64::from(self.tasks) / minutes.max(1e-9),
            )
            .with("plans", f64::from(self.replans))
            .with("held_segments", f64::from(self.held))
            .with("plan_time_max_ms", self.plan_time_max.as_secs_f64() * 1e3),
        );
        self.bots
            .iter()
            .map(|b| Intent::Stop { robot: b.id })
            .collect()
    }

    fn fail(&mut self, why: String) -> Vec<Intent> {
        self.verdict = Some(
            Verdict::failure(why)
                .with("tasks", f64::from(self.tasks))
                .with("plans", f64::from(self.replans)),
        );
        self.bots
            .iter()
            .map(|b| Intent::Stop { robot: b.id })
            .collect()
    }

    fn step(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        if world.time.saturating_sub(self.last_progress) > STALL_LIMIT {
            return self.fail(format!(
                "deadlock: no robot finished an edge for {} s ({} tasks done)",
                STALL_LIMIT.as_secs(),
                self.tasks
            ));
        }
        let mut out = Vec::new();
        for k in 0..self.bots.len() {
            if self.bots[k].retry && self.bots[k].outstanding == 0 {
                self.bots[k].retry = false;
                out.extend(self.drive(k, world));
            }
        }
        let all_still = self
            .bots
            .iter()
            .all(|b| b.outstanding == 0 && b.driving.is_none());
        match self.phase {
            Phase::Placing if all_still => {
                self.phase = Phase::Draining;
            }
            _ => {}
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
        }
        out.extend(self.dispatch(world));
        out
    }

    /// Robot `k` finished driving an action.
    fn arrived(&mut self, k: usize, index: usize, node: u32, world: &WorldSnapshot) -> Vec<Intent> {
        self.bots[k].node = node;
        self.last_progress = world.time;
        if let Some(adg) = self.adg.as_mut() {
            if let Err(e) = adg.complete(k, index) {
                return self.fail(format!("robot {}: {e}", self.bots[k].id));
            }
        }
        let b = &mut self.bots[k];
        if b.active && node == b.goal {
            b.tasks_done += 1;
            self.tasks += 1;
            if self.quota.is_some_and(|q| b.tasks_done >= q) {
                b.active = false;
            }
            // Every robot now finishes the edge it is on; then the team is planned again. With
            // the last task done, the plan runs to its end first, so every robot stands on its
            // final node when the experiment ends.
            if self.tasks < self.target_tasks {
                self.phase = Phase::Draining;
            }
        }
        if self.adg.as_ref().is_some_and(|a| a.is_done()) {
            self.phase = Phase::Draining;
        }
        let mut out = self.step(world);
        out.extend(self.dispatch(world));
        out
    }
}

impl Behaviour for TrafficControl {
    fn start(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        self.started = world.time;
        self.last_progress = world.time;
        match self.place(world) {
            Ok(out) => out,
            Err(e) => self.fail(e),
        }
    }

    fn on_snapshot(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        if self.verdict.is_some() {
            return Vec::new();
        }
        self.step(world)
    }

    fn on_event(
        &mut self,
        robot: u16,
        event: &RobotEventKind,
        world: &WorldSnapshot,
    ) -> Vec<Intent> {
        if self.verdict.is_some() {
            return Vec::new();
        }
        let Some(k) = self.bots.iter().position(|b| b.id == robot) else {
            return Vec::new();
        };
        match event {
            RobotEventKind::MoveFinished { outcome, .. } => {
                if *outcome != MoveOutcome::Completed {
                    return self.fail(format!("robot {robot}: a move ended {outcome:?}"));
                }
                let bot = &mut self.bots[k];
                bot.outstanding = bot.outstanding.saturating_sub(1);
                if bot.outstanding == 0 {
                    match bot.driving {
                        Some(leg) if leg.last => {
                            self.bots[k].driving = None;
                            return match leg.index {
                                Some(index) => self.arrived(k, index, leg.to, world),
                                None => {
                                    self.last_progress = world.time;
                                    self.step(world)
                                }
                            };
                        }
                        Some(_) => return self.drive(k, world),
                        None => {
                            if self.phase == Phase::Placing {
                                self.last_progress = world.time;
                            }
                            return self.step(world);
                        }
                    }
                }
                Vec::new()
            }
            RobotEventKind::LinkLost => self.fail(format!("robot {robot} lost its link")),
            _ => Vec::new(),
        }
    }

    fn on_held(&mut self, intent: &Intent, _reason: &str, _world: &WorldSnapshot) -> Vec<Intent> {
        // The plan keeps robots apart by construction; a held segment means the world model saw
        // a robot closer than the plan assumed (a pose error). The robot waits and the segment is
        // planned again at the next snapshot; a lasting disagreement ends as a stall.
        if let Intent::Move { robot, .. } = intent {
            if let Some(bot) = self.bots.iter_mut().find(|b| b.id == *robot) {
                bot.outstanding = bot.outstanding.saturating_sub(1);
                if bot.outstanding == 0 && bot.driving.is_some() {
                    bot.retry = true;
                }
            }
            self.held += 1;
        }
        Vec::new()
    }

    fn verdict(&self) -> Option<Verdict> {
        self.verdict.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use simulator::world::presets;

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
            let (u, v) = (
                t.graph.node(u).unwrap().index() as u32,
                t.graph.node(v).unwrap().index() as u32,
            );
            let (edge, forward) = t.edge_between(u, v).unwrap();
            let mut leg = Leg {
                index: Some(0),
                edge,
                forward,
                to: v,
                last: false,
            };
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
}
