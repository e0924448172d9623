//! `cooperative_push` (thesis A.2): robots follow the track until one finds it blocked by a box
//! too heavy for one robot. That robot stops; the other comes up behind it and stops. Both then
//! leave the tape for two slots side by side on one side of the box, face it, and push it together
//! with one synchronised command, far enough that it is clear of the tape by more than a body
//! length. They back onto the tape one after the other and follow it again. A box still found on
//! the tape afterwards means the push failed; it is tried again, at most twice.
//!
//! The box is found by the front IR receiver: a robot with a reflection ahead (within 50 mm) and no
//! robot ahead in the world model creeps, and stops at the first reflection at the weakest power
//! level (within 15 mm); where the box is comes from the finder's pose and that reach.
//!
//! Success: the box gave way (every pusher's line sensor crossed the tape the box stood on), each
//! pusher's encoders measured at least 90 % of the push it was sent (134 mm of the default
//! 12 + 150 mm, slipping or not: a robot that never drove has not pushed), and after the push
//! the team lapped the track again without finding the box, each robot's encoders measuring at
//! least 90 % of those laps (1.75 m for the default lap of the push world's loop). A robot whose
//! wheels are driven for 3 s without an encoder pulse fails the run at once (see
//! [`behaviour_api::evidence`]).

use std::collections::BTreeMap;
use std::time::Duration;

use behaviour_api::Pose;
use nalgebra::{Point2, Vector2};
use protocol::packets::Side;

use behaviour_api::event::Event;
use behaviour_api::evidence::{Odometer, EVIDENCE_SHARE};
use behaviour_api::moves::Manoeuvre;
use behaviour_api::team::{HeldPolicy, Team};
use behaviour_api::track_loop::TrackLoop;
use behaviour_api::{
    params, Behaviour, BehaviourConfig, Intent, Register, RobotView, Verdict, WorldSnapshot,
};

/// Half the body length, metres.
const HALF_LEN: f64 = world::robot::LENGTH_M / 2.0;
/// Space between a waiting pusher's front and the box, metres.
const LANE_GAP: f64 = 0.012;
/// The approach lane runs this far below the slots: a robot turning there clears one waiting in
/// the next slot (its corners sweep a 29 mm circle), and one passing leaves 15 mm between their
/// bodies, room for the safety check's margins and for twice the uncertainty of each pose; any
/// lower and a turn in the lane would come too near the arena's edge.
const APPROACH_BELOW: f64 = 0.055;
/// Pushers stand this far either side of the box's centre line: 16 mm between their bodies, so
/// that the second can turn into its slot beside the first with room for a few millimetres of
/// pose error, while each still covers 12 mm of a 40 mm box.
const SLOT_OFFSET: f64 = 0.024;
/// The gap between the finder's front and the box in its first state report that sees the box at
/// the shortest reach (15 mm): the reach less the creep between the IR's sample and the report
/// (measured in the simulator: 12.7 mm). Pose and reading come from one report, so the link's
/// latency does not enter.
const SIGHTED_GAP: f64 = 0.0127;
/// A follower stops when the robot ahead is this close (sensor to sensor) and goes on past the
/// second figure.
const STOP_GAP: f64 = 0.12;
const GO_GAP: f64 = 0.16;
/// The helper backs onto the tape only once the finder is this far along it.
const REJOIN_GAP: f64 = 0.16;
/// Backing speed towards the tape, and how far the robot runs on after its sensor crosses it
/// (a report's latency at that speed, then braking).
const BACK_MPS: f32 = 0.03;
const BACK_OVERSHOOT: f64 = 0.002;
/// A tape report counts only once the robot has backed this far: after a push that moved the box
/// clear, the sensor stands well beyond the tape, and over a wall-clock link a report of the
/// push's own crossing can arrive late, with the robot still beside the other pusher.
const MIN_BACK_M: f64 = 0.02;
/// Line sensor ahead of the robot's centre, metres.
const SENSOR_AHEAD: f64 = world::robot::LINE_SENSOR_AHEAD_M;
/// Following speed with an unknown obstacle close ahead.
const CREEP_MPS: f32 = 0.03;
/// Speed of manoeuvres off the tape, and of the push.
const MANOEUVRE_MPS: f32 = 0.08;
const PUSH_MPS: f32 = 0.05;
/// A phase that takes longer than this has failed.
const PHASE_LIMIT: Duration = Duration::from_secs(30);
/// Attempts before giving up.
const MAX_PUSHES: u32 = 2;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    /// Following until someone finds the box.
    Approach,
    /// The finder has stopped; the helper closes up behind it.
    Gather,
    /// The finder drives to its slot.
    FinderToSlot,
    /// The helper drives to its slot.
    HelperToSlot,
    /// Both push.
    Push,
    /// The finder backs onto the tape and follows it.
    FinderRejoins,
    /// The helper waits for room, then backs onto the tape.
    HelperWaits,
    /// The helper backs onto the tape.
    HelperRejoins,
    /// Both follow the track again.
    Lapping,
}

/// Where the box is: its estimated centre, the tape's direction there and the push direction.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Site {
    centre: Point2<f64>,
    along: Vector2<f64>,
    push: Vector2<f64>,
}

impl Site {
    fn at(&self, along: f64, push: f64) -> Point2<f64> {
        self.centre + self.along * along + self.push * push
    }

    fn heading(v: Vector2<f64>) -> f64 {
        v.y.atan2(v.x)
    }
}

#[derive(Clone, Debug, Default)]
struct Bot {
    /// Loop coordinate at the last snapshot while lapping.
    last_s: Option<f64>,
    /// Metres lapped since rejoining.
    lapped_m: f64,
    /// The odometer's reading when lapping began.
    lap_odometer_m: Option<f64>,
    /// The odometer's reading when the push began.
    push_odometer_m: f64,
    /// Backing up towards the tape after the push, since then.
    backing: Option<Duration>,
    /// The odometer's reading when backing began.
    backing_odometer_m: f64,
    /// The line sensor crossed the tape during the push: the box gave way.
    crossed_tape: bool,
}

/// The cooperative pushing behaviour.
#[derive(Clone, Debug)]
pub struct CooperativePush {
    track: TrackLoop,
    speed: f32,
    push_m: f64,
    box_half: f64,
    laps: f64,
    bots: BTreeMap<u16, Bot>,
    phase: Phase,
    phase_since: Duration,
    finder: Option<u16>,
    site: Option<Site>,
    /// The finder's pose when it first saw the box at the shortest reach.
    sighted: Option<Pose>,
    pushes: u32,
    push_started: Duration,
    push_time: Option<Duration>,
    odometer: Odometer,
    verdict: Option<Verdict>,
}

params! {
    /// Parameters of `cooperative_push`.
    pub struct CooperativePushParams {
        /// Box width across the push, metres.
        r#box: f64 = 0.04, 0.01 => 0.1;
        /// Laps each pusher drives after the push.
        laps: f64 = 1.0, 0.01 => 20.0;
        /// How far the pushers drive into the box, metres (their wheels slip under the load, so the box moves less).
        push: f64 = 0.15, 0.02 => 0.3;
        /// Following speed, m/s.
        speed: f32 = 0.1, 0.04 => 0.3;
    }
}

impl Register for CooperativePush {
    type Params = CooperativePushParams;

    /// Builds it.
    ///
    /// # Errors
    /// A track that is not one closed loop, or no robot.
    fn build(p: CooperativePushParams, cfg: &BehaviourConfig) -> Result<Self, String> {
        let track = TrackLoop::new(&cfg.track)?;
        let (speed, push_m, box_m, laps) = (p.speed, p.push, p.r#box, p.laps);
        if cfg.robots.is_empty() {
            return Err("needs at least one robot".into());
        }
        Ok(Self {
            track,
            speed,
            push_m,
            box_half: box_m / 2.0,
            laps,
            bots: cfg.robots.iter().map(|&id| (id, Bot::default())).collect(),
            phase: Phase::Approach,
            phase_since: Duration::ZERO,
            finder: None,
            site: None,
            sighted: None,
            pushes: 0,
            push_started: Duration::ZERO,
            push_time: None,
            odometer: Odometer::new(),
            verdict: None,
        })
    }
}

impl CooperativePush {
    fn helper(&self) -> Option<u16> {
        self.bots
            .keys()
            .copied()
            .find(|id| Some(*id) != self.finder)
    }

    fn enter(&mut self, phase: Phase, world: &WorldSnapshot) {
        tracing::debug!(?phase, t = world.time.as_secs_f64(), "cooperative_push");
        self.phase = phase;
        self.phase_since = world.time;
    }

    fn fail(&mut self, why: String) -> Vec<Intent> {
        self.verdict = Some(
            Verdict::failure(why)
                .with("pushes", f64::from(self.pushes))
                .with("phase_reached", self.phase as u8 as f64),
        );
        Vec::new()
    }

    /// The route's moves, tagged with the phase they belong to.
    fn send(&self, id: u16, route: Manoeuvre) -> Vec<Intent> {
        Intent::moves(id, route.moves, self.phase as u32)
    }

    /// Along-track distance to the nearest robot ahead of `me`, sensor to sensor.
    fn gap_ahead(&self, me: &RobotView, world: &WorldSnapshot) -> f64 {
        world
            .robots
            .iter()
            .filter(|o| o.id != me.id)
            .filter_map(|o| self.track.gap(me, o, true))
            .fold(f64::INFINITY, f64::min)
    }

    /// Where the box must be, seen from the finder standing behind it.
    fn locate(&self, finder: &RobotView) -> Site {
        // From where the finder first reported the box at the shortest reach, not from where it
        // stopped or where the model had it when the sighting arrived: both depend on the
        // link's latency, a few millimetres that decide whether each pusher still covers the
        // box's corner.
        let (p, gap) = match (self.sighted, finder.state.proximity.front_obstacle) {
            (Some(p), _) => (p, SIGHTED_GAP),
            (None, 1) => (finder.pose, 0.007),
            (None, 2) => (finder.pose, 0.022),
            (None, _) => (finder.pose, 0.03),
        };
        let heading = Vector2::new(p.theta.cos(), p.theta.sin());
        let along = heading;
        let centre = Point2::new(p.x, p.y) + along * (HALF_LEN + gap + self.box_half);
        // Pushed to the robot's left: on a counter-clockwise loop, into the loop's middle.
        let push = Vector2::new(-along.y, along.x);
        Site {
            centre,
            along,
            push,
        }
    }

    /// Distance of a pusher's centre from the box centre, across the track, when waiting.
    fn lane(&self) -> f64 {
        -(self.box_half + LANE_GAP + HALF_LEN)
    }

    fn slot(&self, id: u16) -> f64 {
        if self.bots.len() == 1 {
            0.0
        } else if Some(id) == self.finder {
            SLOT_OFFSET
        } else {
            -SLOT_OFFSET
        }
    }

    /// From `pose` on the tape behind the box: down to an approach lane below the slots, along it,
    /// then a quarter turn and straight up into the slot. Arriving sideways along the slots'
    /// line would swing the 48 mm body into the robot already waiting there.
    fn to_slot(&self, id: u16, pose: Pose, site: &Site, back_up: f64) -> Manoeuvre {
        let here = Vector2::new(pose.x, pose.y) - site.centre.coords;
        let along_now = here.dot(&site.along) - back_up;
        let approach = self.lane() - APPROACH_BELOW;
        let down = site.at(along_now, approach);
        let below = site.at(self.slot(id), approach);
        let slot = site.at(self.slot(id), self.lane());
        Manoeuvre::from(pose, MANOEUVRE_MPS)
            .straight(-back_up)
            .to(down.x, down.y)
            .to(below.x, below.y)
            .to(slot.x, slot.y)
    }

    /// After the push: back up until the line sensor finds the tape. Odometry cannot say how far
    /// that is, because the wheels slipped while pushing; the tape can.
    fn start_backing(&mut self, id: u16) -> Vec<Intent> {
        let Some(bot) = self.bots.get_mut(&id) else {
            return Vec::new();
        };
        bot.backing = Some(Duration::ZERO);
        bot.backing_odometer_m = self.odometer.distance_m(id);
        vec![Intent::WheelSpeeds {
            robot: id,
            left: -BACK_MPS,
            right: -BACK_MPS,
        }]
    }

    /// How far the robot has backed since it began to, by its encoders.
    fn backed_m(&self, id: u16) -> f64 {
        let from = self.bots.get(&id).map_or(0.0, |b| b.backing_odometer_m);
        self.odometer.distance_m(id) - from
    }

    /// The sensor (16 mm ahead of the centre) has just crossed the tape backwards: stop, bring
    /// the centre onto the tape and face along it.
    fn on_tape(&mut self, id: u16, world: &WorldSnapshot) -> Vec<Intent> {
        let (Some(site), Some(view)) = (self.site, world.robot(id)) else {
            return Vec::new();
        };
        if let Some(bot) = self.bots.get_mut(&id) {
            bot.backing = None;
        }
        let route = Manoeuvre::from(view.pose, MANOEUVRE_MPS)
            .straight(SENSOR_AHEAD + BACK_OVERSHOOT)
            .turn_to(Site::heading(site.along));
        let mut out = vec![Intent::Stop { robot: id }];
        out.extend(self.send(id, route));
        out
    }

    /// One step of the team: the run's time limits, spacing while following, a box found, and
    /// the work of the current phase.
    fn step(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        self.odometer.observe(world);
        if let Some(why) = self.overdue(world, team) {
            return self.fail(why);
        }
        let mut out = self.spacing(world, team);
        if matches!(self.phase, Phase::Approach | Phase::Lapping) {
            let found = world.robots.iter().find(|v| {
                v.state.proximity.front_obstacle == 1
                    && self.bots.contains_key(&v.id)
                    && self.gap_ahead(v, world) > 0.15
            });
            if let Some(id) = found.map(|v| v.id) {
                out.extend(self.found_box(id, world));
                return out;
            }
        }
        let next = match self.phase {
            Phase::Approach | Phase::FinderRejoins | Phase::HelperRejoins => Ok(Vec::new()),
            Phase::Gather => self.gather(world, team),
            Phase::FinderToSlot => Ok(self.finder_to_slot(world, team)),
            Phase::HelperToSlot => Ok(if self.helper().is_some_and(|h| team.idle(h)) {
                self.start_push(world)
            } else {
                Vec::new()
            }),
            Phase::Push => self.pushed(world, team),
            Phase::HelperWaits => Ok(self.helper_waits(world)),
            // The verdict ends the run: the spacing intents of this step are not sent.
            Phase::Lapping => match self.lapping(world) {
                Ok(true) => return Vec::new(),
                other => other.map(|_| Vec::new()),
            },
        };
        match next {
            Err(why) => self.fail(why),
            Ok(intents) => {
                out.extend(intents);
                out
            }
        }
    }

    /// Why the run must stop: a stalled wheel, a phase over its time limit, a robot backing up
    /// for too long, an aborted manoeuvre.
    fn overdue(&mut self, world: &WorldSnapshot, team: &Team) -> Option<String> {
        if let Some(stall) = self.odometer.stall() {
            return Some(stall.to_string());
        }
        let limit = match self.phase {
            // Following is slowed by spacing; three times the lap time at full speed is plenty.
            Phase::Approach | Phase::Lapping => PHASE_LIMIT.max(Duration::from_secs_f64(
                3.0 * self.laps * self.track.length_m() / f64::from(self.speed),
            )),
            _ => PHASE_LIMIT,
        };
        if world.time.saturating_sub(self.phase_since) > limit {
            return Some(format!(
                "{:?} took longer than {:.0} s",
                self.phase,
                limit.as_secs_f64()
            ));
        }
        let backing_limit = Duration::from_secs_f64((self.push_m + 0.1) / f64::from(BACK_MPS));
        for b in self.bots.values_mut() {
            if let Some(since) = b.backing.as_mut() {
                if *since == Duration::ZERO {
                    *since = world.time.max(Duration::from_nanos(1));
                }
            }
        }
        if let Some((id, _)) = self.bots.iter().find(|(_, b)| {
            b.backing
                .is_some_and(|since| world.time.saturating_sub(since) > backing_limit)
        }) {
            return Some(format!("robot {id} backed up without finding the tape"));
        }
        if let Some(id) = team.ids().find(|id| team.interrupted(*id) > 0) {
            return Some(format!("robot {id}: a manoeuvre was aborted"));
        }
        None
    }

    /// Spacing while following: never run into the robot ahead.
    fn spacing(&self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let mut out = Vec::new();
        if matches!(self.phase, Phase::Approach | Phase::Gather | Phase::Lapping) {
            for view in &world.robots {
                if !self.bots.contains_key(&view.id) {
                    continue;
                }
                let following = team.following(view.id);
                if Some(view.id) == self.finder && self.phase == Phase::Gather {
                    continue;
                }
                let gap = self.gap_ahead(view, world);
                let mut want = if gap < STOP_GAP {
                    None
                } else if gap > GO_GAP || following.is_some() {
                    Some(self.speed)
                } else {
                    following
                };
                // Something close ahead that is not a robot: creep, so that the first sighting
                // at the shortest reach (15 mm) places it to within a few millimetres.
                let level = view.state.proximity.front_obstacle;
                if gap > 0.15 && (2..=3).contains(&level) {
                    want = want.map(|v| v.min(CREEP_MPS));
                }
                out.push(Intent::FollowLine {
                    robot: view.id,
                    speed: want,
                });
            }
        }
        out
    }

    /// Gathered behind the box: once both rest, the box is placed from the finder's sighting and
    /// the finder sets off for its slot.
    fn gather(&mut self, world: &WorldSnapshot, team: &Team) -> Result<Vec<Intent>, String> {
        let mut out = Vec::new();
        let settled = world.robots.iter().all(|r| {
            let w = r.state.wheels;
            let (l, rr) = (w.left_mps, w.right_mps);
            team.following(r.id).is_none() && l.abs() < 0.005 && rr.abs() < 0.005
        });
        if settled && world.time.saturating_sub(self.phase_since) > Duration::from_millis(300) {
            let Some(finder) = self.finder.and_then(|f| world.robot(f)) else {
                return Err("the robot that found the box is gone".into());
            };
            let site = self.locate(finder);
            tracing::debug!(x = site.centre.x, y = site.centre.y, "box located");
            self.site = Some(site);
            let route = self.to_slot(finder.id, finder.pose, &site, 0.015);
            let id = finder.id;
            out.extend(self.send(id, route));
            self.enter(Phase::FinderToSlot, world);
        }
        Ok(out)
    }

    /// The finder in its slot: the helper sets off for its own, or, alone, the push starts.
    fn finder_to_slot(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let mut out = Vec::new();
        if self.finder.is_some_and(|f| team.idle(f)) {
            match (self.helper(), self.site) {
                (Some(h), Some(site)) => {
                    if let Some(view) = world.robot(h) {
                        let route = self.to_slot(h, view.pose, &site, 0.0);
                        out.extend(self.send(h, route));
                    }
                    self.enter(Phase::HelperToSlot, world);
                }
                _ => out.extend(self.start_push(world)),
            }
        }
        out
    }

    /// The push ended: it counts only if the box gave way and each pusher drove its share; then
    /// the finder backs onto the tape first.
    fn pushed(&mut self, world: &WorldSnapshot, team: &Team) -> Result<Vec<Intent>, String> {
        let mut out = Vec::new();
        if team.all_idle() {
            self.push_time = Some(world.time.saturating_sub(self.push_started));
            // A box that gave way let the pushers' sensors, 8 mm behind their fronts, run
            // over the tape it stood on; wheels that only slipped did not.
            if let Some((id, _)) = self.bots.iter().find(|(_, b)| !b.crossed_tape) {
                return Err(format!(
                    "the box did not give way: robot {id} never reached the tape behind it \
                     ({} robot(s) pushing)",
                    self.bots.len()
                ));
            }
            // The box can give way to one robot's push while the other only stood
            // beside it: each must have driven its share.
            let sent = LANE_GAP + self.push_m;
            let odometer = &self.odometer;
            let short = self.bots.iter().find_map(|(&id, b)| {
                let driven = odometer.distance_m(id) - b.push_odometer_m;
                (driven < EVIDENCE_SHARE * sent).then_some((id, driven))
            });
            if let Some((id, driven)) = short {
                return Err(format!(
                    "robot {id} did not push: its encoders measured {:.0} mm of the {:.0} mm \
                     push it was sent (at least {:.0} mm needed)",
                    driven * 1e3,
                    sent * 1e3,
                    EVIDENCE_SHARE * sent * 1e3
                ));
            }
            if let Some(f) = self.finder {
                out.extend(self.start_backing(f));
            }
            self.enter(Phase::FinderRejoins, world);
        }
        Ok(out)
    }

    /// The helper backs onto the tape once the finder has left it room.
    fn helper_waits(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let mut out = Vec::new();
        let room = match (self.finder.and_then(|f| world.robot(f)), self.site) {
            (Some(f), Some(site)) => {
                let p = Vector2::new(f.pose.x, f.pose.y) - site.centre.coords;
                p.dot(&site.along) > REJOIN_GAP
            }
            _ => true,
        };
        if room {
            if let Some(h) = self.helper() {
                out.extend(self.start_backing(h));
            }
            self.enter(Phase::HelperRejoins, world);
        }
        out
    }

    /// Lapping after the push: each robot's laps along the tape, checked against its encoders;
    /// the verdict once all have lapped (`true` then).
    fn lapping(&mut self, world: &WorldSnapshot) -> Result<bool, String> {
        let length = self.track.length_m();
        for view in &world.robots {
            let odometer_m = self.odometer.distance_m(view.id);
            let Some(bot) = self.bots.get_mut(&view.id) else {
                continue;
            };
            bot.lap_odometer_m.get_or_insert(odometer_m);
            let s = self.track.position(view);
            if let (Some(before), Some(after)) = (bot.last_s, s) {
                bot.lapped_m += self.track.forward(before, after).unwrap_or(0.0);
            }
            if s.is_some() {
                bot.last_s = s;
            }
        }
        if self.bots.values().all(|b| b.lapped_m >= self.laps * length) {
            let claimed = self.laps * length;
            let lapped = |id: u16| {
                let from = self.bots.get(&id).and_then(|b| b.lap_odometer_m);
                self.odometer.distance_m(id) - from.unwrap_or(0.0)
            };
            let short = self
                .bots
                .keys()
                .map(|&id| (id, lapped(id)))
                .find(|(_, m)| *m < EVIDENCE_SHARE * claimed);
            let least = self
                .bots
                .keys()
                .map(|&id| lapped(id))
                .fold(f64::INFINITY, f64::min);
            if let Some((id, measured)) = short {
                return Err(format!(
                    "robot {id}: its place on the tape went {} lap(s) after the push but \
                     its encoders measured {measured:.2} m, short of the {:.2} m driving \
                     them takes",
                    self.laps,
                    EVIDENCE_SHARE * claimed
                ));
            }
            let mut v = Verdict::success(format!(
                "the box gave way to {} robots pushing together ({:.0} mm of drive) and \
                 the team has lapped {} more time(s) without finding it on the track, \
                 each robot at least {least:.2} m by its encoders",
                self.bots.len(),
                self.push_m * 1e3,
                self.laps
            ))
            .with("pushes", f64::from(self.pushes))
            .with("least_encoder_lap_m", least);
            if let Some(t) = self.push_time {
                v = v.with("push_time_s", t.as_secs_f64());
            }
            self.verdict = Some(v);
            return Ok(true);
        }
        Ok(false)
    }

    fn start_push(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        self.pushes += 1;
        self.push_started = world.time;
        self.enter(Phase::Push, world);
        let ids: Vec<u16> = self.bots.keys().copied().collect();
        for (&id, b) in self.bots.iter_mut() {
            b.push_odometer_m = self.odometer.distance_m(id);
        }
        // One command per robot in the same reply: the supervisor sends them back to back.
        let mut out = Vec::new();
        for id in ids {
            if let Some(view) = world.robot(id) {
                let route = Manoeuvre::from(view.pose, PUSH_MPS).straight(LANE_GAP + self.push_m);
                out.extend(self.send(id, route));
            }
        }
        out
    }

    /// A close reflection ahead with no robot there: the box.
    fn found_box(&mut self, robot: u16, world: &WorldSnapshot) -> Vec<Intent> {
        let Some(view) = world.robot(robot) else {
            return Vec::new();
        };
        if self.gap_ahead(view, world) < 0.15 {
            return Vec::new();
        }
        match self.phase {
            Phase::Approach => {}
            Phase::Lapping => {
                if self.pushes >= MAX_PUSHES {
                    return self.fail(format!(
                        "robot {robot} still finds the box on the track after {} pushes",
                        self.pushes
                    ));
                }
                for b in self.bots.values_mut() {
                    b.lapped_m = 0.0;
                    b.last_s = None;
                    b.lap_odometer_m = None;
                }
            }
            _ => return Vec::new(),
        }
        self.finder = Some(robot);
        self.sighted = Some(view.front_close_at.unwrap_or(view.pose));
        self.enter(Phase::Gather, world);
        vec![Intent::FollowLine { robot, speed: None }]
    }
}

impl Behaviour for CooperativePush {
    fn start(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        self.phase_since = world.time;
        self.step(world, team)
    }

    fn on_snapshot(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        self.step(world, team)
    }

    fn on_event(
        &mut self,
        robot: u16,
        event: &Event,
        world: &WorldSnapshot,
        team: &mut Team,
    ) -> Vec<Intent> {
        match event {
            Event::Obstacle(o) if o.side == Side::Front && o.is_close() => {
                self.found_box(robot, world)
            }
            // Finishing a rejoin hands the robot back to the tape.
            Event::MoveFinished { .. } if team.idle(robot) => {
                let follow = vec![Intent::FollowLine {
                    robot,
                    speed: Some(self.speed),
                }];
                match self.phase {
                    Phase::FinderRejoins if Some(robot) == self.finder => {
                        let next = if self.helper().is_some() {
                            Phase::HelperWaits
                        } else {
                            Phase::Lapping
                        };
                        self.enter(next, world);
                        follow
                    }
                    Phase::HelperRejoins if Some(robot) == self.helper() => {
                        self.enter(Phase::Lapping, world);
                        follow
                    }
                    _ => Vec::new(),
                }
            }
            Event::LineFound if self.bots.get(&robot).is_some_and(|b| b.backing.is_some()) => {
                if self.backed_m(robot) >= MIN_BACK_M {
                    self.on_tape(robot, world)
                } else {
                    Vec::new()
                }
            }
            Event::LineFound if self.phase == Phase::Push => {
                if let Some(b) = self.bots.get_mut(&robot) {
                    b.crossed_tape = true;
                }
                Vec::new()
            }
            Event::LinkLost => self.fail(format!("robot {robot} lost its link")),
            _ => Vec::new(),
        }
    }

    /// A manoeuvre planned around the box is not improvised when the supervisor refuses a step
    /// of it: the experiment stops with the reason.
    fn held_policy(&self) -> HeldPolicy {
        HeldPolicy::Fail
    }

    fn verdict(&self) -> Option<Verdict> {
        self.verdict.clone()
    }

    fn progress(&self) -> Vec<(String, f64)> {
        vec![("pushes".into(), f64::from(self.pushes))]
    }
}
