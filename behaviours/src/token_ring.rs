//! `token_ring` (thesis A.3): three or more robots follow a round track; one carries a token (its
//! LED orange). The carrier runs faster than the rest; when it comes up behind the next robot and
//! its front receiver identifies that robot by its IR frames, the token passes to it. A box on the
//! track is driven around: a robot that finds it stops, leaves the tape to the right, passes it
//! and rejoins. The host starts the robots one by one, sets their speeds, and after each round of
//! the token reverses the team's direction (every robot turns on the spot and follows the other
//! way). Success: the token went round the team the given number of times.

use std::collections::BTreeMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::time::Duration;

use protocol::packets::MoveOutcome;
use robot_actor::RobotEventKind;

use crate::api::{Behaviour, BehaviourConfig, Intent, RobotView, Verdict, WorldSnapshot};
use crate::moves::Route;
use crate::track_loop::TrackLoop;

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
const MANOEUVRE_MPS: f32 = 0.08;
/// Detour geometry: sideways offset from the tape, and the length driven beside it (from 7 mm
/// short of a 40 mm box to clear of it with the robot's length and a margin).
const DETOUR_SIDE: f64 = 0.05;
const DETOUR_ALONG: f64 = 0.125;
/// No other robot may be this close to where a detour rejoins the tape when it starts.
const REJOIN_CLEAR: f64 = 0.15;
/// Robots start this long after one another.
const START_STAGGER: Duration = Duration::from_secs(1);
/// Nothing may take longer than this without a token pass.
const PASS_LIMIT: Duration = Duration::from_secs(90);

#[derive(Clone, Debug, Default)]
struct Bot {
    /// Speed last sent; `None` when not following.
    following: Option<f32>,
    /// Moves sent and not yet finished (at most one: moves go one at a time).
    outstanding: usize,
    /// Moves of a detour or a turn not yet sent; a held one goes back to the front.
    queue: std::collections::VecDeque<robot_actor::MoveCommand>,
    aborted: bool,
    started: bool,
}

/// The token ring behaviour.
#[derive(Clone, Debug)]
pub struct TokenRing {
    track: TrackLoop,
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
    verdict: Option<Verdict>,
}

impl TokenRing {
    /// Builds it. Parameters: `speed` (the carrier's, m/s, default 0.12; the others run at half),
    /// `rounds` (token rounds to complete, default 3), `reverse` (reverse after every round,
    /// default true).
    ///
    /// # Errors
    /// Fewer than two robots, a track that is not one closed loop, or a parameter out of range.
    pub fn new(cfg: &BehaviourConfig) -> Result<Self, String> {
        let track = TrackLoop::new(&cfg.track)?;
        let speed: f32 = cfg.param_in("speed", 0.12, 0.08..=0.3)?;
        let rounds: u32 = cfg.param_in("rounds", 3, 1..=50)?;
        let reverse: bool = cfg.param("reverse", true)?;
        if cfg.robots.len() < 2 {
            return Err("a token ring needs at least two robots".into());
        }
        let n = cfg.robots.len() as u32;
        Ok(Self {
            track,
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
            verdict: None,
        })
    }

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
        let mine = me.on_track.map(|(e, o, _)| self.track.coordinate(e, o));
        let mut best: Option<(u16, f64)> = None;
        for other in world.robots.iter().filter(|o| o.id != me.id) {
            let theirs = other.on_track.map(|(e, o, _)| self.track.coordinate(e, o));
            let d = match (mine, theirs) {
                (Some(a), Some(b)) if self.direction > 0.0 => self.track.ahead(a, b),
                (Some(a), Some(b)) => self.track.ahead(b, a),
                _ => f64::INFINITY,
            };
            // Off the tape (detouring) or close by, a robot in front counts by straight-line
            // distance: anywhere in the front half within `NEAR`, within the cone farther out.
            let (dx, dy) = (other.pose.x - me.pose.x, other.pose.y - me.pose.y);
            let bearing = dy.atan2(dx) - me.pose.theta;
            let off = bearing.sin().atan2(bearing.cos()).abs();
            let straight = dx.hypot(dy);
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

    fn follow(&mut self, id: u16, speed: Option<f32>) -> Option<Intent> {
        let bot = self.bots.get_mut(&id)?;
        if bot.following == speed {
            return None;
        }
        bot.following = speed;
        Some(Intent::FollowLine { robot: id, speed })
    }

    /// Queues a manoeuvre; its moves go out one at a time, so a move the safety check holds is
    /// simply tried again later instead of leaving the robot halfway.
    fn send(&mut self, id: u16, route: Route) -> Vec<Intent> {
        if let Some(bot) = self.bots.get_mut(&id) {
            bot.queue.extend(route.moves);
            bot.following = None;
        }
        self.pump(id).into_iter().collect()
    }

    /// The robot's next queued move, if none is running.
    fn pump(&mut self, id: u16) -> Option<Intent> {
        let bot = self.bots.get_mut(&id)?;
        if bot.outstanding > 0 {
            return None;
        }
        let command = bot.queue.pop_front()?;
        bot.outstanding = 1;
        Some(Intent::Move { robot: id, command })
    }

    fn busy(&self, id: u16) -> bool {
        self.bots
            .get(&id)
            .is_some_and(|b| b.outstanding > 0 || !b.queue.is_empty())
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

    /// Around the box on the robot's right: back off a little, step aside, pass, step back.
    fn detour(&mut self, view: &RobotView) -> Vec<Intent> {
        let h = view.pose.theta;
        let route = Route::from(view.pose, MANOEUVRE_MPS)
            .straight(-0.01)
            .turn_to(h - FRAC_PI_2)
            .straight(DETOUR_SIDE)
            .turn_to(h)
            .straight(DETOUR_ALONG)
            .turn_to(h + FRAC_PI_2)
            .straight(DETOUR_SIDE)
            .turn_to(h);
        self.detours += 1;
        self.send(view.id, route)
    }

    fn finish(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let n = self.order.len() as f64;
        self.verdict = Some(
            Verdict::success(format!(
                "the token went round {} robots {} times ({} passes, {} reversals, {} detours)",
                self.order.len(),
                self.rounds,
                self.passes,
                self.reversals,
                self.detours
            ))
            .with("passes", f64::from(self.passes))
            .with("reversals", f64::from(self.reversals))
            .with("detours", f64::from(self.detours))
            .with(
                "seconds_per_round",
                world.time.as_secs_f64() / (f64::from(self.passes) / n),
            ),
        );
        self.order
            .iter()
            .map(|&robot| Intent::Stop { robot })
            .collect()
    }

    fn fail(&mut self, why: String) -> Vec<Intent> {
        self.verdict = Some(Verdict::failure(why).with("passes", f64::from(self.passes)));
        self.order
            .iter()
            .map(|&robot| Intent::Stop { robot })
            .collect()
    }

    fn step(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let mut out = Vec::new();
        if world.time.saturating_sub(self.last_pass) > PASS_LIMIT {
            return self.fail(format!(
                "no token pass for {} s after {} passes",
                PASS_LIMIT.as_secs(),
                self.passes
            ));
        }
        if let Some((id, _)) = self.bots.iter().find(|(_, b)| b.aborted) {
            return self.fail(format!("robot {id}: a manoeuvre was aborted"));
        }
        if self.turning {
            if self.order.iter().all(|id| !self.busy(*id)) {
                self.turning = false;
                self.direction = -self.direction;
                self.reversals += 1;
            } else {
                return out;
            }
        }
        // Turn the whole team round once the token has been round, when nobody is mid-detour.
        if self.passes >= self.reverse_at && self.order.iter().all(|id| !self.busy(*id)) {
            self.reverse_at += self.order.len() as u32;
            self.turning = true;
            for id in self.order.clone() {
                if let Some(view) = world.robot(id) {
                    let route = Route::from(view.pose, MANOEUVRE_MPS).turn_to(view.pose.theta + PI);
                    out.push(Intent::Stop { robot: id });
                    out.extend(self.send(id, route));
                }
            }
            return out;
        }
        for (k, id) in self.order.clone().into_iter().enumerate() {
            let Some(view) = world.robot(id) else {
                continue;
            };
            let Some(bot) = self.bots.get(&id) else {
                continue;
            };
            if bot.outstanding > 0 {
                continue;
            }
            if !bot.queue.is_empty() {
                // A held move: try it again.
                out.extend(self.pump(id));
                continue;
            }
            if !bot.started {
                if world.time < START_STAGGER * k as u32 {
                    continue;
                }
                if let Some(b) = self.bots.get_mut(&id) {
                    b.started = true;
                }
            }
            let ahead = self.ahead(view, world);
            let gap = ahead.map_or(f64::INFINITY, |(_, d)| d);
            let level = view.state.proximity.front_obstacle;
            if level == 1 && gap > 0.15 {
                out.extend(self.follow(id, None));
                // One detour at a time: the box's surroundings hold one robot off the tape.
                let someone_detouring = self.order.iter().any(|o| *o != id && self.busy(*o));
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
                    out.extend(self.detour(view));
                }
                continue;
            }
            let current = self.bots.get(&id).and_then(|b| b.following);
            let mut want = if gap < STOP_GAP {
                None
            } else if gap > GO_GAP || current.is_some() {
                Some(self.speed_of(id))
            } else {
                current
            };
            if gap > 0.15 && (2..=3).contains(&level) {
                want = want.map(|v| v.min(CREEP_MPS));
            }
            out.extend(self.follow(id, want));
        }
        out
    }
}

impl Behaviour for TokenRing {
    fn start(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        self.last_pass = world.time;
        let mut out = self.leds();
        out.extend(self.step(world));
        out
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
        match event {
            // The carrier's front receiver identified the robot ahead of it.
            RobotEventKind::Encounter(e)
                if robot == self.holder && e.side == 0 && !self.turning =>
            {
                let Some(view) = world.robot(robot) else {
                    return Vec::new();
                };
                let seen = e.robot_id;
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
                    let running = self.bots.get(&id).is_some_and(|b| b.following.is_some());
                    if running {
                        let v = self.speed_of(id);
                        out.extend(self.follow(id, Some(v)));
                    }
                }
                if self.passes >= self.rounds * self.order.len() as u32 {
                    out.extend(self.finish(world));
                }
                out
            }
            RobotEventKind::MoveFinished { outcome, .. } => {
                if let Some(bot) = self.bots.get_mut(&robot) {
                    bot.outstanding = bot.outstanding.saturating_sub(1);
                    if *outcome != MoveOutcome::Completed {
                        bot.aborted = true;
                    }
                }
                self.pump(robot).into_iter().collect()
            }
            RobotEventKind::LinkLost => self.fail(format!("robot {robot} lost its link")),
            _ => Vec::new(),
        }
    }

    fn on_held(&mut self, intent: &Intent, _reason: &str, _world: &WorldSnapshot) -> Vec<Intent> {
        // A held move never ran: it goes back to the front of the robot's queue and is tried
        // again at the next snapshot.
        if let Intent::Move { robot, command } = intent {
            if let Some(bot) = self.bots.get_mut(robot) {
                bot.outstanding = bot.outstanding.saturating_sub(1);
                bot.queue.push_front(*command);
            }
        }
        Vec::new()
    }

    fn verdict(&self) -> Option<Verdict> {
        self.verdict.clone()
    }
}
