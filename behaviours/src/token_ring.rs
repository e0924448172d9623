//! `token_ring` (thesis A.3): three or more robots follow a round track; one carries a token (its
//! LED orange). The carrier runs faster than the rest; when it comes up behind the next robot and
//! its front receiver identifies that robot by its IR frames, the token passes to it. A box on the
//! track is driven around: a robot that finds it stops, leaves the tape to the right, passes it
//! and rejoins. The host starts the robots one by one, sets their speeds, and after each round of
//! the token reverses the team's direction (every robot turns on the spot and follows the other
//! way).
//!
//! Success: the token went round the team the given number of times, and every robot's encoders
//! measured at least half a loop per round (2.9 m for the default three rounds of the ring's
//! 1.94 m loop). To hand the token on, each carrier must close up on the robot ahead while the
//! others run at half its speed; on seeds 1 to 10 every robot drove more than two loops in three
//! rounds, and half a loop per round leaves room for detours and waits. A robot whose wheels are
//! driven for 3 s without an encoder pulse fails the run at once (see [`behaviour_api::evidence`]).

use std::collections::BTreeMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::time::Duration;

use protocol::packets::Side;

use behaviour_api::event::{Event, FrontSighting};
use behaviour_api::evidence::Odometer;
use behaviour_api::moves::{Leg, Legs};
use behaviour_api::team::Team;
use behaviour_api::track_loop::TrackLoop;
use behaviour_api::{
    params, Behaviour, BehaviourConfig, Intent, Register, RobotView, Verdict, WorldSnapshot,
};

/// The carrier's LED, and everyone else's.
const TOKEN_RGB: [u8; 3] = [255, 110, 0];
const PLAIN_RGB: [u8; 3] = [0, 0, 40];
/// A follower stops when the robot ahead is this close (sensor to sensor) and goes on past the
/// second figure.
const STOP_GAP: f64 = 0.11;
const GO_GAP: f64 = 0.15;
/// The token passes only to the robot ahead within this distance along the track.
const PASS_RANGE: f64 = 0.25;
/// Any robot in front within this distance counts as ahead, whatever its bearing.
const NEAR: f64 = 0.2;
/// A robot off the tape counts as ahead within this half-angle of the heading.
const AHEAD_CONE: f64 = 40.0 * PI / 180.0;
/// Following speed with an unknown obstacle close ahead.
const CREEP_MPS: f32 = 0.03;
/// Manoeuvre speed (detours, turning round).
const MANOEUVRE_MPS: f32 = 0.05;
/// Detour geometry: sideways offset from the tape, and the length driven beside it (from 7 mm
/// short of a 40 mm box to clear of it with the robot's length and a margin).
const DETOUR_SIDE: f64 = 0.05;
const DETOUR_ALONG: f64 = 0.125;
/// No other robot may be this close to where a detour rejoins the tape when it starts.
const REJOIN_CLEAR: f64 = 0.15;
/// How far the front receiver sees a reflection at each power level: half the default reach of
/// the level (the light goes there and back).
const REFLECT_REACH_M: [f64; 4] = {
    let r = world::robot::IR_RANGE_M;
    [r[0] / 2.0, r[1] / 2.0, r[2] / 2.0, r[3] / 2.0]
};
/// Slack for the world model's error when asking whether a known body explains a reflection.
const MODEL_SLACK_M: f64 = 0.03;
/// Half a robot's length: from its centre to its front, where the emitter and receiver sit.
const HALF_LEN: f64 = world::robot::LENGTH_M / 2.0;
/// A manoeuvre's next move waits until the wheels have read zero speed this long: a wheel
/// creeping slower than the speed meter resolves reads zero for a moment, and a move planned
/// from there is off by the rest of the creep (and a reversing wheel miscounts it).
const SETTLE: Duration = Duration::from_millis(100);
/// Robots start this long after one another.
const START_STAGGER: Duration = Duration::from_secs(1);
/// Nothing may take longer than this without a token pass.
const PASS_LIMIT: Duration = Duration::from_secs(90);
/// A front sighting bounds the gap this long: a robot in view is reported again every report
/// period (500 ms by default) with the weakest power seen in it, and one out of view is not.
const SIGHTING_FRESH: Duration = Duration::from_millis(600);
/// The share of the loop every robot's encoders must measure per round of the token.
const LOOP_SHARE_PER_ROUND: f64 = 0.5;

#[derive(Clone, Debug, Default)]
struct Bot {
    /// The detour or turn under way, driven closed-loop one move at a time.
    legs: Legs,
    /// Since when the robot's wheels have read zero speed, if they do.
    still_since: Option<Duration>,
    started: bool,
    /// The last robot its front receiver identified.
    front_sighting: Option<FrontSighting>,
}

/// The token ring behaviour.
#[derive(Clone, Debug)]
pub struct TokenRing {
    track: TrackLoop,
    tape: std::sync::Arc<world::Track>,
    speed: f32,
    rounds: u32,
    order: Vec<u16>,
    bots: BTreeMap<u16, Bot>,
    holder: u16,
    passes: u32,
    /// +1 along the track's edges, −1 against them.
    direction: f64,
    /// Passes after which the direction is reversed next.
    reverse_at: u32,
    turning: bool,
    reversals: u32,
    detours: u32,
    last_pass: Duration,
    odometer: Odometer,
    verdict: Option<Verdict>,
}

params! {
    /// Parameters of `token_ring`.
    pub struct TokenRingParams {
        /// Whether the team reverses after every round.
        reverse: bool = true;
        /// Token rounds to complete.
        rounds: u32 = 3, 1 => 50;
        /// The carrier's speed, m/s (the others run at half).
        speed: f32 = 0.12, 0.08 => 0.3;
    }
}

impl Register for TokenRing {
    type Params = TokenRingParams;

    /// Builds it.
    ///
    /// # Errors
    /// Fewer than two robots, or a track that is not one closed loop.
    fn build(p: TokenRingParams, cfg: &BehaviourConfig) -> Result<Self, String> {
        let track = TrackLoop::new(&cfg.track)?;
        let (speed, rounds, reverse) = (p.speed, p.rounds, p.reverse);
        if cfg.robots.len() < 2 {
            return Err("a token ring needs at least two robots".into());
        }
        let n = cfg.robots.len() as u32;
        Ok(Self {
            track,
            tape: cfg.track.clone(),
            speed,
            rounds,
            order: cfg.robots.clone(),
            bots: cfg.robots.iter().map(|&id| (id, Bot::default())).collect(),
            holder: cfg.robots[0],
            passes: 0,
            direction: 1.0,
            reverse_at: if reverse { n } else { u32::MAX },
            turning: false,
            reversals: 0,
            detours: 0,
            last_pass: Duration::ZERO,
            odometer: Odometer::new(),
            verdict: None,
        })
    }
}

impl TokenRing {
    fn speed_of(&self, id: u16) -> f32 {
        if id == self.holder {
            self.speed
        } else {
            self.speed * 0.5
        }
    }

    /// The nearest robot ahead of `me` in the direction of travel and its distance (along the
    /// tape when both are on it, straight-line within a cone ahead otherwise).
    fn ahead(&self, me: &RobotView, world: &WorldSnapshot) -> Option<(u16, f64)> {
        let mut best: Option<(u16, f64)> = None;
        for other in world.robots.iter().filter(|o| o.id != me.id) {
            let d = self
                .track
                .gap(me, other, self.direction > 0.0)
                .unwrap_or(f64::INFINITY);
            // Off the tape (detouring) or close by, a robot in front counts by straight-line
            // distance: anywhere in the front half within `NEAR`, within the cone farther out.
            let (off, straight) = me.bearing_to(other);
            let d = if (off < FRAC_PI_2 && straight < NEAR) || off < AHEAD_CONE {
                d.min(straight)
            } else {
                d
            };
            if !d.is_finite() {
                continue;
            }
            if best.is_none_or(|(_, b)| d < b) {
                best = Some((other.id, d));
            }
        }
        best
    }

    /// The most a fresh front sighting lets the gap to the robot in front be, sensor to sensor. A
    /// follower whose model is off along the tape (odometry cannot see a shove along it, and the
    /// line sensor cannot either) still stops short of the robot its receiver sees.
    fn sighted_gap(&self, id: u16, now: Duration) -> f64 {
        self.bots
            .get(&id)
            .and_then(|b| b.front_sighting)
            .map_or(f64::INFINITY, |s| s.gap_bound(now, SIGHTING_FRESH))
    }

    /// Whether a body the world model knows (another robot, an arena wall) can account for a
    /// reflection the front receiver sees at power `level`. One that none can is an unknown
    /// obstacle, however close the next robot along the tape is: a robot beside the box, or
    /// just past it, must not make a follower drive into the box.
    fn reflection_explained(&self, me: &RobotView, world: &WorldSnapshot, level: u8) -> bool {
        let Some(reach) = REFLECT_REACH_M.get(usize::from(level).wrapping_sub(1)) else {
            return true;
        };
        let reach = reach + MODEL_SLACK_M;
        let (s, c) = me.pose.theta.sin_cos();
        let front = (me.pose.x + HALF_LEN * c, me.pose.y + HALF_LEN * s);
        let robot_there = world.robots.iter().filter(|o| o.id != me.id).any(|o| {
            let (dx, dy) = (o.pose.x - front.0, o.pose.y - front.1);
            dx * c + dy * s > -HALF_LEN && dx.hypot(dy) - HALF_LEN < reach
        });
        // Distance along the heading from the front to the arena's walls.
        let (w, h) = world.arena;
        let to_wall = |p: f64, d: f64, far: f64| {
            if d > 1e-9 {
                (far - p) / d
            } else if d < -1e-9 {
                -p / d
            } else {
                f64::INFINITY
            }
        };
        let wall = to_wall(front.0, c, w).min(to_wall(front.1, s, h));
        robot_there || wall < reach
    }

    /// Starts a manoeuvre; its moves go out one at a time, each from the robot's pose when the
    /// last has finished, so a move the safety check holds is simply tried again later instead
    /// of leaving the robot halfway.
    fn send(&mut self, id: u16, legs: &[Leg], world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        if let Some(bot) = self.bots.get_mut(&id) {
            bot.legs = Legs::new(MANOEUVRE_MPS);
            for leg in legs {
                bot.legs.push(*leg);
            }
        }
        self.pump(id, world, team).into_iter().collect()
    }

    /// The robot's next manoeuvre move, if none is running and the robot has settled: a turn
    /// is reported finished while the wheels still coast, and a leg planned from that pose would
    /// be off by the rest of the coast.
    fn pump(&mut self, id: u16, world: &WorldSnapshot, team: &Team) -> Option<Intent> {
        let pose = world.robot(id)?.pose;
        let bot = self.bots.get_mut(&id)?;
        let settled = bot
            .still_since
            .is_some_and(|t| world.time.saturating_sub(t) >= SETTLE);
        if !team.idle(id) || !settled {
            return None;
        }
        let command = bot.legs.next(pose)?;
        tracing::debug!(robot = id, ?command, ?pose, "manoeuvre move");
        Some(Intent::Move {
            robot: id,
            command,
            tag: 0,
        })
    }

    /// Whether the robot is on a manoeuvre: a move out or legs still to drive.
    fn busy(&self, id: u16, team: &Team) -> bool {
        !team.idle(id) || self.bots.get(&id).is_some_and(|b| !b.legs.is_empty())
    }

    fn leds(&self) -> Vec<Intent> {
        self.order
            .iter()
            .map(|&robot| Intent::Led {
                robot,
                rgb: if robot == self.holder {
                    TOKEN_RGB
                } else {
                    PLAIN_RGB
                },
            })
            .collect()
    }

    /// Around the box on the robot's right: back off a little, step aside, pass, step back onto
    /// the tape where it continues past the box, face along it.
    fn detour(&mut self, view: &RobotView, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let p = view.pose;
        let (s, c) = p.theta.sin_cos();
        let (rx, ry) = (s, -c);
        let ahead = nalgebra::Point2::new(p.x + DETOUR_ALONG * c, p.y + DETOUR_ALONG * s);
        // Rejoin on the tape itself where it is near, so the line sensor finds it under its
        // centre; facing along it in the direction of travel.
        let (rejoin, heading) = match self.tape.nearest(ahead) {
            Some(n) if n.distance_m < 0.03 => {
                let t = n.tangent * n.tangent.dot(&nalgebra::Vector2::new(c, s)).signum();
                (n.point, t.y.atan2(t.x))
            }
            _ => (ahead, p.theta),
        };
        let legs = [
            Leg::Straight(-0.01),
            Leg::To {
                x: p.x + DETOUR_SIDE * rx,
                y: p.y + DETOUR_SIDE * ry,
            },
            Leg::To {
                x: rejoin.x + DETOUR_SIDE * rx,
                y: rejoin.y + DETOUR_SIDE * ry,
            },
            Leg::To {
                x: rejoin.x,
                y: rejoin.y,
            },
            Leg::Face(heading),
        ];
        self.detours += 1;
        self.send(view.id, &legs, world, team)
    }

    fn finish(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let n = self.order.len() as f64;
        self.odometer.observe(world);
        let needed = LOOP_SHARE_PER_ROUND * f64::from(self.rounds) * self.track.length_m();
        let ids = self.order.iter().copied();
        let least_m = self.odometer.least_m(ids.clone());
        if let Some(id) = ids
            .clone()
            .find(|id| self.odometer.distance_m(*id) < needed)
        {
            let measured = self.odometer.distance_m(id);
            return self.fail(format!(
                "robot {id}: the token went round {} times but its encoders measured \
                 {measured:.2} m, short of the {needed:.2} m (half a loop per round) that \
                 carrying and following it takes",
                self.rounds
            ));
        }
        self.verdict = Some(
            Verdict::success(format!(
                "the token went round {} robots {} times ({} passes, {} reversals, {} detours), \
                 each robot at least {least_m:.2} m by its encoders",
                self.order.len(),
                self.rounds,
                self.passes,
                self.reversals,
                self.detours
            ))
            .with("passes", f64::from(self.passes))
            .with("least_encoder_distance_m", least_m)
            .with("reversals", f64::from(self.reversals))
            .with("detours", f64::from(self.detours))
            .with(
                "seconds_per_round",
                world.time.as_secs_f64() / (f64::from(self.passes) / n),
            ),
        );
        Vec::new()
    }

    fn fail(&mut self, why: String) -> Vec<Intent> {
        let least_m = self.odometer.least_m(self.order.iter().copied());
        self.verdict = Some(
            Verdict::failure(why)
                .with("passes", f64::from(self.passes))
                .with("least_encoder_distance_m", least_m),
        );
        Vec::new()
    }

    /// One step of the team: the run's limits, the team turning round, and each robot's
    /// following, detour or held move.
    fn step(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        self.odometer.observe(world);
        if let Some(stall) = self.odometer.stall() {
            return self.fail(stall.to_string());
        }
        if let Some(why) = self.overdue(world, team) {
            return self.fail(why);
        }
        if let Some(out) = self.turn_round(world, team) {
            return out;
        }
        let mut out = Vec::new();
        for (k, id) in self.order.clone().into_iter().enumerate() {
            self.drive(k, id, world, team, &mut out);
        }
        out
    }

    /// Why the run must stop: no token pass for too long, or an aborted manoeuvre. Notes which
    /// robots stand still.
    fn overdue(&mut self, world: &WorldSnapshot, team: &Team) -> Option<String> {
        for view in &world.robots {
            if let Some(bot) = self.bots.get_mut(&view.id) {
                let w = view.state.wheels;
                bot.still_since = if w.left_mps == 0.0 && w.right_mps == 0.0 {
                    bot.still_since.or(Some(world.time))
                } else {
                    None
                };
            }
        }
        if world.time.saturating_sub(self.last_pass) > PASS_LIMIT {
            return Some(format!(
                "no token pass for {} s after {} passes",
                PASS_LIMIT.as_secs(),
                self.passes
            ));
        }
        if let Some(id) = team.ids().find(|id| team.interrupted(*id) > 0) {
            return Some(format!("robot {id}: a manoeuvre was aborted"));
        }
        None
    }

    /// The whole team turning round: once the token has been round and nobody is mid-detour,
    /// every robot faces about; while it turns, only its moves go out.
    fn turn_round(&mut self, world: &WorldSnapshot, team: &Team) -> Option<Vec<Intent>> {
        let mut out = Vec::new();
        if self.turning {
            if self.order.iter().all(|id| !self.busy(*id, team)) {
                self.turning = false;
                self.direction = -self.direction;
                self.reversals += 1;
            } else {
                for id in self.order.clone() {
                    out.extend(self.pump(id, world, team));
                }
                return Some(out);
            }
        }
        // Turn the whole team round once the token has been round, when nobody is mid-detour.
        if self.passes >= self.reverse_at && self.order.iter().all(|id| !self.busy(*id, team)) {
            self.reverse_at += self.order.len() as u32;
            self.turning = true;
            for id in self.order.clone() {
                if let Some(view) = world.robot(id) {
                    out.push(Intent::Stop { robot: id });
                    out.extend(self.send(id, &[Leg::Face(view.pose.theta + PI)], world, team));
                }
            }
            return Some(out);
        }
        None
    }

    /// Robot `id` (the `k`-th in the ring): a held move tried again, its staggered start, a
    /// detour round an unknown obstacle, or its following speed kept to the gap ahead. `out`
    /// holds what this step has sent so far.
    fn drive(
        &mut self,
        k: usize,
        id: u16,
        world: &WorldSnapshot,
        team: &Team,
        out: &mut Vec<Intent>,
    ) {
        let Some(view) = world.robot(id) else {
            return;
        };
        let Some(bot) = self.bots.get(&id) else {
            return;
        };
        if !team.idle(id) {
            return;
        }
        if !bot.legs.is_empty() {
            // A held move: try it again.
            out.extend(self.pump(id, world, team));
            return;
        }
        if !bot.started {
            if world.time < START_STAGGER * k as u32 {
                return;
            }
            if let Some(b) = self.bots.get_mut(&id) {
                b.started = true;
            }
        }
        let ahead = self.ahead(view, world);
        let gap = ahead
            .map_or(f64::INFINITY, |(_, d)| d)
            .min(self.sighted_gap(id, world.time));
        let level = view.state.proximity.front_obstacle;
        let unknown = level > 0 && !self.reflection_explained(view, world, level);
        if level == 1 && unknown {
            out.push(Intent::FollowLine {
                robot: id,
                speed: None,
            });
            // One detour at a time: the box's surroundings hold one robot off the tape. A
            // move sent in this same step counts too (the team's books see it once this
            // step returns).
            let moving = |o: u16| {
                out.iter()
                    .any(|i| matches!(i, Intent::Move { robot, .. } if *robot == o))
            };
            let someone_detouring = self
                .order
                .iter()
                .any(|o| *o != id && (self.busy(*o, team) || moving(*o)));
            // The tape past the box, where the detour comes back, must be free.
            let (s, c) = view.pose.theta.sin_cos();
            let rejoin = (view.pose.x + 0.12 * c, view.pose.y + 0.12 * s);
            let rejoin_clear = world
                .robots
                .iter()
                .filter(|r| r.id != id)
                .all(|r| (r.pose.x - rejoin.0).hypot(r.pose.y - rejoin.1) > REJOIN_CLEAR);
            if !someone_detouring && rejoin_clear {
                out.push(Intent::Stop { robot: id });
                out.extend(self.detour(view, world, team));
            }
            return;
        }
        let current = team.following(id);
        let mut want = if gap < STOP_GAP {
            None
        } else if gap > GO_GAP || current.is_some() {
            Some(self.speed_of(id))
        } else {
            current
        };
        if unknown && (2..=3).contains(&level) {
            want = want.map(|v| v.min(CREEP_MPS));
        }
        out.push(Intent::FollowLine {
            robot: id,
            speed: want,
        });
    }
}

impl Behaviour for TokenRing {
    fn start(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        self.last_pass = world.time;
        let mut out = self.leds();
        out.extend(self.step(world, team));
        out
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
        if let (Event::Sighting(e), Some(b)) = (event, self.bots.get_mut(&robot)) {
            if let Some(front) = FrontSighting::of(e, world.time) {
                b.front_sighting = Some(front);
            }
        }
        match event {
            // The carrier's front receiver identified the robot ahead of it.
            Event::Sighting(e)
                if robot == self.holder && e.side == Side::Front && !self.turning =>
            {
                let Some(view) = world.robot(robot) else {
                    return Vec::new();
                };
                let seen = e.robot;
                match self.ahead(view, world) {
                    Some((next, d)) if next == seen && d < PASS_RANGE => {}
                    _ => return Vec::new(),
                }
                self.holder = seen;
                self.passes += 1;
                self.last_pass = world.time;
                tracing::debug!(
                    from = robot,
                    to = seen,
                    passes = self.passes,
                    "token passed"
                );
                let mut out = self.leds();
                // New speeds at once: the new carrier pulls away, the old one falls back.
                for id in [robot, seen] {
                    if team.following(id).is_some() {
                        out.push(Intent::FollowLine {
                            robot: id,
                            speed: Some(self.speed_of(id)),
                        });
                    }
                }
                if self.passes >= self.rounds * self.order.len() as u32 {
                    out.extend(self.finish(world));
                }
                out
            }
            Event::MoveFinished { .. } => self.pump(robot, world, team).into_iter().collect(),
            Event::LinkLost => self.fail(format!("robot {robot} lost its link")),
            _ => Vec::new(),
        }
    }

    fn on_held(
        &mut self,
        intent: &Intent,
        _reason: &str,
        _world: &WorldSnapshot,
        _team: &mut Team,
    ) -> Vec<Intent> {
        // A held move never ran: the leg stays, and the next snapshot tries it again.
        if let Intent::Move { robot, .. } = intent {
            if let Some(bot) = self.bots.get_mut(robot) {
                bot.legs.held();
            }
        }
        Vec::new()
    }

    fn verdict(&self) -> Option<Verdict> {
        self.verdict.clone()
    }

    fn progress(&self) -> Vec<(String, f64)> {
        vec![("passes".into(), f64::from(self.passes))]
    }
}
