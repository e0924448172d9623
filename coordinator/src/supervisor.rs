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
use simulator::world::Track;
use tokio::sync::oneshot;
use tokio::time::Instant;
use tracing::{debug, info, warn};

use crate::behaviour_actor::{
    BehaviourActor, FromRobot, Held, Localised, Panicked, Snapshot, Start,
};
use world_model::relocalise::{Action, Relocaliser};
use world_model::safety::{self, Safety};
use world_model::{Transition, WorldModel};

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
    /// Robots whose link came back but whose first state report has not: the behaviour hears
    /// of the link only with it, as until then the robot's intents are held as lost.
    reconnected: std::collections::HashMap<u16, RobotEvent>,
}

/// The tag of the re-localisation routine's moves (the behaviour never hears of them).
const RELOCALISATION_TAG: u32 = u32::MAX;

/// A robot that is moving within this distance (centre to centre) of a lost robot, plus twice
/// the lost robot's uncertainty, is stopped too: the lost one may be anywhere in that reach.
const LOST_REACH_M: f64 = 0.06;
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
            progress: Vec::new(),
            links: Vec::new(),
            restarts: 0,
            done: Some(done),
            started: false,
            planned: Default::default(),
            move_tags: Default::default(),
            next_move: 0,
            relocalising: Default::default(),
            reconnected: Default::default(),
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
            });
        }
        // The supervisor lives on, keeping the world model current while the robots brake and
        // the report is taken, but runs the behaviour no more.
        self.behaviour = None;
        let _ = ctx;
    }

    fn start_behaviour(&mut self, ctx: &mut Context<Self>) {
        if self.done.is_none() {
            return;
        }
        let behaviour = match self.behaviour_entry.build(&self.config) {
            Ok(b) => BehaviourActor::new(b).start(),
            Err(why) => {
                self.finish(Verdict::failure(format!("behaviour not built: {why}")), ctx);
                return;
            }
        };
        self.behaviour = Some(behaviour.clone());
        let world = self.snapshot();
        let reply = behaviour.send(Start(world));
        ctx.spawn(
            reply
                .into_actor(self)
                .map(|r, act, ctx| act.on_reply(r, ctx)),
        );
    }

    fn on_reply(
        &mut self,
        reply: Result<Result<Reply, Panicked>, MailboxError>,
        ctx: &mut Context<Self>,
    ) {
        if self.done.is_none() {
            // The experiment is over: late intents must not move a stopped robot.
            return;
        }
        match reply {
            Ok(Ok(reply)) => {
                if !reply.progress.is_empty() {
                    self.progress = reply.progress;
                }
                // Most replies to events carry no intent: the snapshot (a pointer per robot) is
                // taken only for one that does.
                if !reply.intents.is_empty() {
                    self.carry_out_all(reply.intents, ctx);
                }
                if let Some(verdict) = reply.verdict {
                    self.finish(verdict, ctx);
                }
            }
            Ok(Err(Panicked(why))) => {
                warn!(why, "behaviour panicked: stopping every robot");
                self.stop_all();
                self.restarts += 1;
                if self.restarts > MAX_RESTARTS {
                    self.finish(
                        Verdict::failure(format!(
                            "behaviour panicked {} times: {why}",
                            self.restarts
                        )),
                        ctx,
                    );
                } else {
                    // Restart only once the stop has reached every robot and its last events
                    // (the aborted moves) have gone by: they belong to the old instance.
                    self.behaviour = None;
                    ctx.run_later(RESTART_DELAY, |act, ctx| act.start_behaviour(ctx));
                }
            }
            Err(e) => warn!(error = %e, "behaviour unreachable"),
        }
    }

    /// Carries out a reply's intents in order and tells the behaviour which were held.
    fn carry_out_all(&mut self, intents: Vec<Intent>, ctx: &mut Context<Self>) {
        let world = self.snapshot_peek();
        // Once a robot's move is held, its later moves in the same reply are held too: they were
        // planned from where the held one would have left it.
        let mut held_robots: Vec<u16> = Vec::new();
        let before = self.held.len();
        for intent in intents {
            let id = intent.robot();
            if held_robots.contains(&id) && matches!(intent, Intent::Move { .. }) {
                self.held
                    .push((world.time, intent, "follows a held move".into()));
                continue;
            }
            if !self.carry_out(intent, &world) {
                held_robots.push(id);
            }
        }
        // The behaviour hears what did not reach its robots.
        if self.held.len() > before {
            if let Some(b) = self.behaviour.clone() {
                let held = self.held[before..]
                    .iter()
                    .map(|(_, i, why)| (*i, why.clone()))
                    .collect();
                let reply = b.send(Held { held, world });
                ctx.spawn(
                    reply
                        .into_actor(self)
                        .map(|r, act, ctx| act.on_reply(r, ctx)),
                );
            }
        }
    }

    /// A robot's sensing contradicted the model: stop it and every robot moving within its
    /// reach, hold its intents, tell the behaviour, and start re-localising it.
    fn on_lost(&mut self, id: u16, why: String, ctx: &mut Context<Self>) {
        let world = self.snapshot_peek();
        let Some(view) = world.robot(id).cloned() else {
            return;
        };
        warn!(
            robot = id,
            why, "robot lost: stopping it and re-localising it"
        );
        // The sweep stays where the safety check lets the lost robot's footprint go: its
        // circumscribed circle, the margin and its uncertainty (with room for it to grow a
        // little on the way) inside the arena.
        let clear = (self.safety.length_m / 2.0).hypot(self.safety.width_m / 2.0)
            + self.safety.margin_m
            + safety::UNCERTAINTY_SIGMAS * (view.uncertainty.position_m + SWEEP_SIGMA_GROWTH_M);
        let (w, h) = self.arena;
        let room = ([clear, clear], [w - clear, h - clear]);
        let (routine, first) = Relocaliser::start(&view, self.model.track(), room, Instant::now());
        self.relocalising.insert(id, routine);
        self.act(id, first, &world);
        let reach = LOST_REACH_M + safety::UNCERTAINTY_SIGMAS * view.uncertainty.position_m;
        let near: Vec<u16> = world
            .robots
            .iter()
            .filter(|o| o.id != id && !self.relocalising.contains_key(&o.id))
            .filter(|o| {
                let moving = o.pending_moves > 0
                    || o.state.wheels.left_mps.abs() > 0.005
                    || o.state.wheels.right_mps.abs() > 0.005;
                let planned = self.planned.get(&o.id).map_or(o.pose, Plan::end);
                let within = |p: Pose| (p.x - view.pose.x).hypot(p.y - view.pose.y) < reach;
                moving && (within(o.pose) || within(planned))
            })
            .map(|o| o.id)
            .collect();
        for other in near {
            info!(robot = other, lost = id, "stopping a robot near a lost one");
            self.planned.remove(&other);
            if let Some(r) = self.robot(other) {
                r.addr().do_send(Command::Stop);
            }
        }
        self.tell(id, LocalisationEvent::Lost { why }, ctx);
    }

    fn tell(&mut self, id: u16, event: LocalisationEvent, ctx: &mut Context<Self>) {
        if let Some(b) = self.behaviour.clone() {
            let reply = b.send(Localised {
                robot: id,
                event,
                world: self.snapshot_peek(),
            });
            ctx.spawn(
                reply
                    .into_actor(self)
                    .map(|r, act, ctx| act.on_reply(r, ctx)),
            );
        }
    }

    /// Carries out one step of a re-localisation routine.
    fn act(&mut self, id: u16, action: Action, world: &WorldSnapshot) {
        match action {
            Action::Stop => {
                self.planned.remove(&id);
                if let Some(r) = self.robot(id) {
                    r.addr().do_send(Command::Stop);
                }
            }
            Action::Moves(moves) => {
                tracing::debug!(robot = id, ?moves, "re-localisation moves");
                let mut held = Vec::new();
                for command in moves {
                    let intent = Intent::Move {
                        robot: id,
                        command,
                        tag: RELOCALISATION_TAG,
                    };
                    let number = self.next_move;
                    if !held.is_empty() || !self.carry_out_checked(intent, world) {
                        held.push(command);
                    } else {
                        self.disown_move(id, number);
                    }
                }
                if !held.is_empty() {
                    if let Some(r) = self.relocalising.get_mut(&id) {
                        r.held(held, Instant::now());
                    }
                }
            }
        }
    }

    /// Advances the routine of a lost robot after a state update or a transition.
    fn relocalise(&mut self, id: u16, transition: Option<Transition>, ctx: &mut Context<Self>) {
        let now = Instant::now();
        let world = self.snapshot_peek();
        let Some(view) = world.robot(id).cloned() else {
            return;
        };
        let track = Arc::clone(self.model.track());
        let Some(routine) = self.relocalising.get_mut(&id) else {
            return;
        };
        let action = match transition {
            Some(Transition::Fixed) => {
                info!(robot = id, "lost robot found a tape: aligning it");
                Some(routine.fixed(now))
            }
            _ => routine.poll(&view, &track, now),
        };
        if routine.aligned() {
            if view.localisation == behaviours::Localisation::Tracking {
                info!(robot = id, "robot re-localised");
                self.relocalising.remove(&id);
                self.tell(id, LocalisationEvent::Found, ctx);
                return;
            }
            warn!(
                robot = id,
                "back on the tape, but it does not match: it stays stopped"
            );
            routine.give_up();
        }
        if let Some(action) = action {
            self.act(id, action, &world);
        }
    }

    /// The world as it is, without consuming the new encounters.
    fn snapshot_peek(&self) -> WorldSnapshot {
        WorldSnapshot {
            time: Instant::now() - self.started_at,
            robots: behaviours::Robots(self.model.shared_views()),
            encounters: Vec::new(),
            arena: self.arena,
        }
    }

    /// Checks and sends one intent; `false` when it was held back (the robot is lost, or the
    /// safety check refused it).
    fn carry_out(&mut self, intent: Intent, world: &WorldSnapshot) -> bool {
        let id = intent.robot();
        let drives = matches!(
            intent,
            Intent::Move { .. } | Intent::FollowLine { .. } | Intent::WheelSpeeds { .. }
        );
        if drives && self.relocalising.contains_key(&id) {
            let reason = format!("robot {id} is lost: it is being re-localised");
            self.held.push((world.time, intent, reason));
            return false;
        }
        // The robot's watchdog has stopped it; a command would be lost, or (queued in a link
        // that comes back) carried out from a stale plan.
        if world.robot(id).is_some_and(|r| !r.connected) {
            let reason = format!("robot {id}'s link is lost");
            self.held.push((world.time, intent, reason));
            return false;
        }
        self.carry_out_checked(intent, world)
    }

    /// Passes one intent through the safety check and sends it.
    fn carry_out_checked(&mut self, intent: Intent, world: &WorldSnapshot) -> bool {
        let id = intent.robot();
        let from = self.planned.get(&id).map(Plan::end);
        let others: Vec<(u16, Pose)> = self
            .planned
            .iter()
            .filter(|(other, _)| **other != id)
            .map(|(other, plan)| (*other, plan.end()))
            .collect();
        if let Err(reason) = self.safety.check_planned(&intent, world, from, &others) {
            warn!(?intent, reason, "intent held back");
            self.held.push((world.time, intent, reason));
            return false;
        }
        match intent {
            Intent::Move { command, .. } => {
                let start = from
                    .or_else(|| world.robot(id).map(|r| r.pose))
                    .unwrap_or_default();
                let end = safety::end_pose(start, command);
                let now = Instant::now();
                let plan = self.planned.entry(id).or_insert_with(|| Plan {
                    ends: Default::default(),
                    sent: now,
                });
                plan.ends.push_back((self.next_move, end));
                plan.sent = now;
            }
            Intent::Led { .. } | Intent::IrMessage { .. } => {}
            _ => {
                self.planned.remove(&id);
            }
        }
        let Some(robot) = self.robot(intent.robot()) else {
            return true;
        };
        let addr = robot.addr().clone();
        match intent {
            Intent::Move { command, tag, .. } => {
                let number = self.next_move;
                self.next_move = self.next_move.wrapping_add(1);
                self.move_tags.insert((id, number), tag);
                addr.do_send(Enqueue::tagged(command, number));
            }
            Intent::FollowLine { speed, .. } => addr.do_send(Command::FollowLine(speed)),
            Intent::WheelSpeeds { left, right, .. } => {
                addr.do_send(Command::WheelSpeeds(left, right))
            }
            Intent::ClearQueue { .. } => addr.do_send(Command::ClearQueue),
            Intent::Stop { .. } => addr.do_send(Command::Stop),
            Intent::Led { rgb, .. } => addr.do_send(Command::Led(rgb[0], rgb[1], rgb[2])),
            Intent::IrMessage { message, .. } => addr.do_send(Command::IrMessage(message)),
        }
        true
    }

    /// The move sent to `robot` under `number`, if one was, is not the behaviour's: its finish
    /// keeps no tag, and the behaviour does not hear of it.
    fn disown_move(&mut self, robot: u16, number: u32) {
        self.move_tags.remove(&(robot, number));
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

impl Handler<RobotEvent> for Supervisor {
    type Result = ();
    fn handle(&mut self, mut e: RobotEvent, ctx: &mut Context<Self>) {
        // A finished move that is not the behaviour's (the panel's, the re-localisation's, or
        // one queued before a link was lost) has no tag here and is not its news: under any tag
        // it could stand for one of the behaviour's own moves.
        let mut foreign = false;
        if let RobotEventKind::MoveFinished { tag, .. } = &mut e.kind {
            let number = *tag;
            let at = self.model.robots().get(&e.robot_id).map(|v| v.pose);
            if let (Some(plan), Some(at)) = (self.planned.get_mut(&e.robot_id), at) {
                if !plan.finished(number, at) {
                    self.planned.remove(&e.robot_id);
                }
            }
            // The behaviour hears of its move under its own tag.
            match self.move_tags.remove(&(e.robot_id, number)) {
                Some(behaviours_tag) => *tag = behaviours_tag,
                None => foreign = true,
            }
        }
        match &e.kind {
            RobotEventKind::Encounter(enc) => {
                let encounter = Encounter {
                    observer: e.robot_id,
                    seen: enc.robot_id,
                    side: behaviours::Side::try_from(enc.side).unwrap_or(behaviours::Side::Front),
                    relative_heading_deg: enc.relative_heading_deg,
                    range_mm: enc.range_mm,
                    at: e.at - self.started_at,
                };
                self.encounters.push(encounter);
                self.encounters_new.push(encounter);
            }
            RobotEventKind::LinkLost => {
                // Its moves in flight fail without finishing.
                self.move_tags.retain(|&(robot, _), _| robot != e.robot_id);
                // A link lost again before its first report: the behaviour hears of the loss
                // only, not of a connection it never could use.
                self.reconnected.remove(&e.robot_id);
                self.model.lost(e.robot_id);
                self.note_link(e.robot_id, "lost");
                warn!(robot = e.robot_id, "link lost; the robot actor reconnects");
            }
            RobotEventKind::Connected(_) => {
                self.note_link(e.robot_id, "connected");
                if self
                    .model
                    .robots()
                    .get(&e.robot_id)
                    .is_some_and(|v| !v.connected)
                {
                    self.reconnected.insert(e.robot_id, e);
                    return;
                }
            }
            _ => {}
        }
        // While a robot is re-localised its moves are the routine's (or ones the stop dropped):
        // the behaviour does not hear of them.
        if let Some(routine) = self.relocalising.get_mut(&e.robot_id) {
            match &e.kind {
                RobotEventKind::MoveFinished { outcome, .. } => {
                    routine.move_finished(*outcome == MoveOutcome::Completed);
                    self.relocalise(e.robot_id, None, ctx);
                    return;
                }
                RobotEventKind::QueueEmpty => return,
                _ => {}
            }
        }
        if foreign {
            debug!(robot = e.robot_id, ?e.kind, "a move the supervisor did not send ended");
            return;
        }
        self.tell_behaviour(e, ctx);
    }
}

impl Supervisor {
    fn tell_behaviour(&mut self, e: RobotEvent, ctx: &mut Context<Self>) {
        if let Some(b) = &self.behaviour {
            let msg = FromRobot {
                robot: e.robot_id,
                kind: e.kind,
                world: self.snapshot_peek(),
            };
            let reply = b.send(msg);
            ctx.spawn(
                reply
                    .into_actor(self)
                    .map(|r, act, ctx| act.on_reply(r, ctx)),
            );
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

/// A command from the control panel: checked by the safety check like a behaviour's intent, then
/// sent; the error says why it was held. The behaviour does not hear a panel move's finish.
#[derive(Message)]
#[rtype(result = "Result<(), String>")]
pub struct PanelIntent(pub Intent);

impl Handler<PanelIntent> for Supervisor {
    type Result = Result<(), String>;
    fn handle(&mut self, msg: PanelIntent, _: &mut Context<Self>) -> Self::Result {
        let world = self.snapshot_peek();
        let intent = msg.0;
        let id = intent.robot();
        let number = self.next_move;
        if self.carry_out(intent, &world) {
            self.disown_move(id, number);
            Ok(())
        } else {
            Err(self.held.last().map(|h| h.2.clone()).unwrap_or_default())
        }
    }
}

/// The panel's emergency stop: every robot stops and the behaviour is over.
#[derive(Message)]
#[rtype(result = "()")]
pub struct EStop;

impl Handler<EStop> for Supervisor {
    type Result = ();
    fn handle(&mut self, _: EStop, ctx: &mut Context<Self>) {
        // Also when the behaviour is already over: the panel may have moved robots since.
        self.stop_all();
        let verdict = self.unfinished("emergency stop from the control panel".into());
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
