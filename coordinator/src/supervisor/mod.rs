//! The supervisor actor (thesis 3.1): one place that knows every robot. It keeps the world model
//! (odometry poses and reflected states in a `DashMap` others read without asking it, the robots'
//! places on the track, the encounter log), feeds the behaviour snapshots and events, checks every
//! intent for safety before it reaches a robot, and stops the team when the behaviour fails.

use std::sync::Arc;
use std::time::Duration;

use actix::prelude::*;
use behaviours::{
    BehaviourConfig, Encounter, Entry, Intent, LocalisationEvent, MoveOutcome, Reply, Verdict,
    WorldSnapshot,
};
use robot_actor::actor::{Command, Enqueue};
use robot_actor::{Pose, Robot, RobotEvent, RobotEventKind, StateBatch, StateUpdated};
use tokio::sync::oneshot;
use tokio::time::Instant;
use tracing::{debug, info, warn};
use world::Track;

use crate::behaviour_actor::{
    BehaviourActor, FromRobot, Held, Localised, Panicked, Snapshot, Start,
};
use world_model::relocalise::{Action, Relocaliser, FOLLOW_MOST_M};
use world_model::safety::{self, Safety};
use world_model::{Transition, WorldModel};

mod behaviour;
mod intents;
mod localisation;

pub use intents::{EStop, PanelIntent};

/// Behaviour restarts allowed before the experiment fails.
pub const MAX_RESTARTS: u32 = 3;
/// Time between stopping every robot after a behaviour panic and starting it again.
pub const RESTART_DELAY: Duration = Duration::from_millis(500);

/// How an experiment ended.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// The behaviour's verdict (or the supervisor's, if the behaviour could not finish).
    pub verdict: Verdict,
    /// Intents held back by the safety check: (time, intent, reason).
    pub held: Vec<(Duration, Intent, String)>,
    /// Every encounter reported.
    pub encounters: Vec<Encounter>,
    /// Behaviour restarts after a panic.
    pub restarts: u32,
    /// The world model's view of every robot at the end.
    pub views: Vec<behaviours::RobotView>,
    /// Each robot's localisation record (lost episodes, time lost, worst uncertainty).
    pub localisation: Vec<(u16, world_model::LocalisationStats)>,
    /// Every robot link lost or (re)connected during the experiment, in order.
    pub links: Vec<LinkRecord>,
    /// Drives the robots' proximity reflexes stopped.
    pub reflexes: u32,
}

/// A robot's link lost, or the robot (re)connected, during an experiment.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct LinkRecord {
    /// The robot.
    pub robot: u16,
    /// `"lost"` or `"connected"`.
    pub what: &'static str,
    /// Experiment time, seconds (0 before the behaviour started).
    pub at_s: f64,
    /// Wall-clock time, milliseconds since the Unix epoch: lines up with other processes' logs.
    pub unix_ms: u64,
}

/// Ends the experiment now (Ctrl-C, time limit): every robot is stopped.
#[derive(Message)]
#[rtype(result = "()")]
pub struct Abort(pub String);

#[derive(Message)]
#[rtype(result = "()")]
struct Tick;

/// The supervisor.
pub struct Supervisor {
    robots: Vec<(u16, Robot)>,
    model: WorldModel,
    arena: (f64, f64),
    encounters_new: Vec<Encounter>,
    encounters: Vec<Encounter>,
    behaviour_entry: Entry,
    config: BehaviourConfig,
    behaviour: Option<Addr<BehaviourActor>>,
    started_at: Instant,
    snapshot_period: Duration,
    safety: Safety,
    held: Vec<(Duration, Intent, String)>,
    reflexes: u32,
    links: Vec<LinkRecord>,
    restarts: u32,
    /// The behaviour's latest figures of its work, for a run stopped before its verdict.
    progress: Vec<(String, f64)>,
    done: Option<oneshot::Sender<Outcome>>,
    started: bool,
    /// Where each robot's queued moves will take it, and when the last one was sent.
    planned: std::collections::HashMap<u16, Plan>,
    /// The behaviour's (or the re-localiser's) tag of each move in flight, by robot and the
    /// number the supervisor sent it under.
    move_tags: std::collections::HashMap<(u16, u32), u32>,
    /// The number the next move is sent under.
    next_move: u32,
    /// Lost robots being re-localised; every intent for them is held meanwhile.
    relocalising: std::collections::HashMap<u16, Relocaliser>,
    /// Searches each robot's re-localisation has run that found nothing.
    searches: std::collections::HashMap<u16, u32>,
    /// The number of the first move each routine under way may have sent: ends of moves sent
    /// before it are not the routine's.
    routine_from: std::collections::HashMap<u16, u32>,
    /// Robots moved aside for a lost robot's search, by id: for whom, from where, how far.
    making_room: std::collections::HashMap<u16, localisation::Room>,
    /// Robots whose link came back but whose first state report has not: the behaviour hears
    /// of the link only with it, as until then the robot's intents are held as lost.
    reconnected: std::collections::HashMap<u16, RobotEvent>,
    /// Per robot: its link's longest recent round trip and when its latest state arrived, for
    /// judging a moving robot where it will be when a command lands.
    timing: std::collections::HashMap<u16, (Option<Duration>, Instant)>,
}

/// The tag of the re-localisation routine's moves (the behaviour never hears of them).
const RELOCALISATION_TAG: u32 = u32::MAX;

/// A robot that is moving within this distance (centre to centre) of a lost robot, plus twice
/// the lost robot's uncertainty, is stopped too: the lost one may be anywhere in that reach.
const LOST_REACH_M: f64 = 0.06;
/// A lost robot is searched for this many times before the run ends with it lost and not found.
const SEARCHES: u32 = 3;
/// How much a lost robot's uncertainty may grow over its sweep (12–16 cm of driving).
const SWEEP_SIGMA_GROWTH_M: f64 = 0.003;

/// A robot whose queue the robot reports empty this long after the last move was sent has done
/// them all (the report of the newest move has certainly arrived by then).
const PLAN_SETTLE: Duration = Duration::from_millis(300);

/// The moves sent to one robot that have not finished, as the poses each will end at.
///
/// Moves are relative, so each is chained from the end of the one before. A robot that is kept
/// flowing (the next segment queued before the last ends) never empties its queue, and the chain
/// would add up every segment's correction of the tape's lateral offset into a path the robot
/// never drives (160 mm off after 20 segments down a lattice's column, held at the arena's
/// border). So the chain is anchored again at each finished move: the rest is moved rigidly by
/// the difference between where the finished move was to end and where the world model has the
/// robot. Moves are known by the number the supervisor gave them, which travels in their tag.
#[derive(Clone, Debug)]
struct Plan {
    /// Number and end pose of each unfinished move, oldest first; never empty.
    ends: std::collections::VecDeque<(u32, Pose)>,
    /// When the last one was sent.
    sent: Instant,
}

impl Plan {
    /// Where the last queued move will leave the robot.
    fn end(&self) -> Pose {
        self.ends.back().map(|&(_, p)| p).unwrap_or_default()
    }

    /// Move `number` finished with the robot at `at` (and every one before it, which the robot
    /// drove first): the rest follows from there. `false` when no move is left.
    fn finished(&mut self, number: u32, at: Pose) -> bool {
        let Some(k) = self.ends.iter().position(|&(n, _)| n == number) else {
            return !self.ends.is_empty();
        };
        let (_, done) = self.ends[k];
        self.ends.drain(..=k);
        for (_, e) in &mut self.ends {
            *e = at.compose(e.relative_to(done));
        }
        !self.ends.is_empty()
    }
}

impl Supervisor {
    /// A supervisor over connected robots, running the behaviour `entry` builds.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        robots: Vec<(u16, Robot)>,
        track: Arc<Track>,
        arena: (f64, f64),
        entry: Entry,
        config: BehaviourConfig,
        snapshot_period: Duration,
        safety: Safety,
        done: oneshot::Sender<Outcome>,
    ) -> Self {
        Self {
            robots,
            model: WorldModel::new(track),
            arena,
            encounters_new: Vec::new(),
            encounters: Vec::new(),
            behaviour_entry: entry,
            config,
            behaviour: None,
            started_at: Instant::now(),
            snapshot_period,
            safety,
            held: Vec::new(),
            reflexes: 0,
            progress: Vec::new(),
            links: Vec::new(),
            restarts: 0,
            done: Some(done),
            started: false,
            planned: Default::default(),
            move_tags: Default::default(),
            next_move: 0,
            relocalising: Default::default(),
            making_room: Default::default(),
            searches: Default::default(),
            routine_from: Default::default(),
            reconnected: Default::default(),
            timing: Default::default(),
        }
    }

    /// The live world model, readable from any thread without messaging the supervisor.
    pub fn model(&self) -> WorldModel {
        self.model.clone()
    }

    /// The world now, handing over the encounters gathered since the last snapshot.
    fn snapshot(&mut self) -> WorldSnapshot {
        let mut world = self.snapshot_peek();
        world.encounters = std::mem::take(&mut self.encounters_new);
        world
    }

    fn robot(&self, id: u16) -> Option<&Robot> {
        self.robots.iter().find(|(i, _)| *i == id).map(|(_, r)| r)
    }

    fn note_link(&mut self, robot: u16, what: &'static str) {
        let unix_ms = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as u64);
        let at_s = if self.started {
            (Instant::now() - self.started_at).as_secs_f64()
        } else {
            0.0
        };
        self.links.push(LinkRecord {
            robot,
            what,
            at_s,
            unix_ms,
        });
    }

    fn stop_all(&mut self) {
        self.planned.clear();
        for (_, r) in &self.robots {
            r.addr().do_send(Command::Stop);
        }
    }

    /// The failure of a run stopped before the behaviour's verdict, with the behaviour's latest
    /// figures of its work.
    fn unfinished(&self, why: String) -> Verdict {
        let mut verdict = Verdict::failure(why);
        verdict.metrics = self.progress.clone();
        verdict
    }

    fn finish(&mut self, verdict: Verdict, ctx: &mut Context<Self>) {
        self.stop_all();
        if let Some(done) = self.done.take() {
            info!(success = verdict.success, "{}", verdict.summary);
            let _ = done.send(Outcome {
                verdict,
                held: std::mem::take(&mut self.held),
                encounters: self.encounters.clone(),
                restarts: self.restarts,
                views: self.model.views(),
                localisation: self.model.localisation_stats(Instant::now()),
                links: std::mem::take(&mut self.links),
                reflexes: self.reflexes,
            });
        }
        // The supervisor lives on, keeping the world model current while the robots brake and
        // the report is taken, but runs the behaviour no more.
        self.behaviour = None;
        let _ = ctx;
    }
}

impl Actor for Supervisor {
    type Context = Context<Self>;

    fn started(&mut self, ctx: &mut Self::Context) {
        self.started_at = Instant::now();
        for (id, robot) in &self.robots {
            // In batches: robots on shard arbiters send one message per pass of their arbiter.
            robot.subscribe_batches(ctx.address().recipient());
            robot.subscribe_events(ctx.address().recipient());
            self.model.add(*id);
        }
        ctx.run_interval(self.snapshot_period, |_, ctx| ctx.notify(Tick));
    }
}

impl Handler<StateUpdated> for Supervisor {
    type Result = ();
    fn handle(&mut self, u: StateUpdated, ctx: &mut Context<Self>) {
        self.on_state(u, ctx);
    }
}

impl Handler<StateBatch> for Supervisor {
    type Result = ();
    fn handle(&mut self, batch: StateBatch, ctx: &mut Context<Self>) {
        for u in batch.0 {
            self.on_state(u, ctx);
        }
    }
}

impl Supervisor {
    /// One state update: into the world model, then the localisation's consequences.
    fn on_state(&mut self, u: StateUpdated, ctx: &mut Context<Self>) {
        self.timing.insert(u.robot_id, (u.rtt, u.at));
        let transition = self.model.apply(&u);
        if let Some(e) = self.reconnected.remove(&u.robot_id) {
            self.tell_behaviour(e, ctx);
        }
        // Robots are only stopped and re-localised while a behaviour runs them.
        if !self.started || self.done.is_none() {
            return;
        }
        if let Some(Transition::Lost(why)) = transition {
            self.on_lost(u.robot_id, why, ctx);
        } else if self.relocalising.contains_key(&u.robot_id) {
            self.relocalise(u.robot_id, transition, ctx);
        }
    }
}

impl Handler<Tick> for Supervisor {
    type Result = ();
    fn handle(&mut self, _: Tick, ctx: &mut Context<Self>) {
        if self.done.is_none() {
            return;
        }
        if !self.started {
            // Start once every robot has reported a state, so the behaviour sees real poses.
            if self.model.all_connected() {
                self.started = true;
                self.started_at = Instant::now();
                self.start_behaviour(ctx);
            }
            return;
        }
        let now = Instant::now();
        let model = &self.model;
        self.planned.retain(|id, plan| {
            now - plan.sent < PLAN_SETTLE
                || model.robots().get(id).is_some_and(|v| v.pending_moves > 0)
        });
        if let Some(b) = self.behaviour.clone() {
            let world = self.snapshot();
            let reply = b.send(Snapshot(world));
            ctx.spawn(
                reply
                    .into_actor(self)
                    .map(|r, act, ctx| act.on_reply(r, ctx)),
            );
        }
    }
}

impl Handler<Abort> for Supervisor {
    type Result = ();
    fn handle(&mut self, msg: Abort, ctx: &mut Context<Self>) {
        let verdict = self.unfinished(msg.0);
        self.finish(verdict, ctx);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(x: f64, y: f64, theta: f64) -> Pose {
        Pose { x, y, theta }
    }

    fn close(a: Pose, b: Pose) -> bool {
        (a.x - b.x).abs() < 1e-9 && (a.y - b.y).abs() < 1e-9 && (a.theta - b.theta).abs() < 1e-9
    }

    #[test]
    fn a_finished_move_anchors_the_rest_of_the_chain_where_the_robot_is() {
        // Three 0.1 m moves east from the origin; the first ends 5 mm north of its plan and
        // turned by 0.1 rad: the two after it follow from there, not from the plan.
        let mut plan = Plan {
            ends: [
                (7, pose(0.1, 0.0, 0.0)),
                (8, pose(0.2, 0.0, 0.0)),
                (9, pose(0.3, 0.0, 0.0)),
            ]
            .into(),
            sent: Instant::now(),
        };
        let at = pose(0.1, 0.005, 0.1);
        assert!(plan.finished(7, at));
        let (s, c) = 0.1f64.sin_cos();
        assert!(
            close(plan.end(), pose(0.1 + 0.2 * c, 0.005 + 0.2 * s, 0.1)),
            "{:?}",
            plan.end()
        );
        // A number the chain does not hold (a move of an earlier plan) changes nothing.
        let before = plan.end();
        assert!(plan.finished(3, pose(5.0, 5.0, 0.0)));
        assert!(close(plan.end(), before));
        // The last move finishing (its finish overtook the one before) empties the chain.
        assert!(!plan.finished(9, pose(0.3, 0.0, 0.0)));
        assert!(plan.ends.is_empty());
    }
}
