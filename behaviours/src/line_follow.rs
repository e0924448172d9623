//! `line_follow`: every robot follows a closed track at its own speed and keeps its distance to
//! the robot ahead, slowing down and stopping behind it, until each has driven its laps.
//!
//! The robots' firmware does the following; the host only sets speeds. The gap to the robot ahead
//! is the along-track distance from the world model (both robots on the tape), the straight-line
//! distance to a robot in front that is off the tape, and the range of the robot ahead's IR frames
//! as the front receiver reports them, whichever is least. A robot close behind one the world
//! model finds lost backs away 5 cm, so that the lost robot's search has room to turn, and waits
//! until it is found.
//!
//! Success: every robot's place on the tape advanced by the laps asked for, and its encoders
//! measured at least 90 % of that distance (laps × loop length × 0.9; 5.2 m for the default three
//! laps of the oval). A robot whose wheels are driven for 3 s without an encoder pulse fails the
//! run at once (see [`behaviour_api::evidence`]).

use std::collections::BTreeMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::time::Duration;

use protocol::packets::Side;

use behaviour_api::event::{Event, FrontSighting};
use behaviour_api::evidence::{Odometer, EVIDENCE_SHARE};
use behaviour_api::team::Team;
use behaviour_api::track_loop::TrackLoop;
use behaviour_api::MoveCommand;
use behaviour_api::{
    params, Behaviour, BehaviourConfig, Intent, Localisation, LocalisationEvent, Register,
    RobotView, Verdict, WorldSnapshot,
};

/// A robot ahead closer than this (sensor to sensor) stops the follower.
const STOP_GAP_M: f64 = 0.09;
/// Slowest commanded speed: below it the wheels' dead band makes following erratic.
const MIN_SPEED_MPS: f64 = 0.04;
/// An IR sighting counts this long.
const IR_FRESH: Duration = Duration::from_millis(400);
/// A robot off the tape counts as ahead within this half-angle of the heading.
const AHEAD_CONE_RAD: f64 = 40.0 * PI / 180.0;
/// A robot standing within this distance (centre to centre) behind one that is lost backs away
/// by `BACK_OFF_M`: the lost robot's search turns on the spot, sweeping a circle of 29 mm plus
/// its uncertainty, and may have to drive onto the tape where the follower stands.
const BACK_OFF_NEAR_M: f64 = 0.15;
const BACK_OFF_M: f32 = 0.05;
const BACK_OFF_MPS: f32 = 0.03;
/// Tag of the back-off move.
const BACK_OFF_TAG: u32 = 1;

#[derive(Clone, Debug, Default)]
struct Follower {
    /// Speed when the way is clear, m/s.
    cruise: f64,
    /// Speed last sent (0 = stopped).
    sent: f64,
    /// Loop coordinate at the last snapshot.
    last_s: Option<f64>,
    /// Metres driven along the loop.
    progress_m: f64,
    /// Latest front IR sighting of another robot.
    ir: Option<FrontSighting>,
    line_losses: u32,
    finished: bool,
}

/// The line-following behaviour.
#[derive(Clone, Debug)]
pub struct LineFollow {
    track: TrackLoop,
    laps: f64,
    spacing_m: f64,
    followers: BTreeMap<u16, Follower>,
    min_gap_m: f64,
    odometer: Odometer,
}

params! {
    /// Parameters of `line_follow`.
    pub struct LineFollowParams {
        /// Laps each robot drives along the tape.
        laps: f64 = 3.0, 0.01 => 100.0;
        /// Gap between sensors at which a follower starts slowing, metres.
        spacing: f64 = 0.18, STOP_GAP_M + 0.01 => 1.0;
        /// The first robot's cruise speed, m/s.
        speed: f64 = 0.15, MIN_SPEED_MPS => 0.5;
        /// Share by which each later robot is slower than the first, so that faster ones catch up.
        spread: f64 = 0.25, 0.0 => 0.8;
    }
}

impl Register for LineFollow {
    type Params = LineFollowParams;

    /// Builds it.
    ///
    /// # Errors
    /// A track that is not one closed loop.
    fn build(p: LineFollowParams, cfg: &BehaviourConfig) -> Result<Self, String> {
        let track = TrackLoop::new(&cfg.track)?;
        let (speed, laps, spacing_m, spread) = (p.speed, p.laps, p.spacing, p.spread);
        let n = cfg.robots.len().max(2) - 1;
        let followers = cfg
            .robots
            .iter()
            .enumerate()
            .map(|(k, &id)| {
                let cruise = (speed * (1.0 - spread * k as f64 / n as f64)).max(MIN_SPEED_MPS);
                (
                    id,
                    Follower {
                        cruise,
                        ..Default::default()
                    },
                )
            })
            .collect();
        Ok(Self {
            track,
            laps,
            spacing_m,
            followers,
            min_gap_m: f64::INFINITY,
            odometer: Odometer::new(),
        })
    }
}

impl LineFollow {
    /// Free distance ahead of robot `id`, sensor to sensor, from the world model and IR.
    fn gap_ahead(&self, id: u16, world: &WorldSnapshot) -> f64 {
        let Some(me) = world.robot(id) else {
            return f64::INFINITY;
        };
        let mut gap = f64::INFINITY;
        for other in world.robots.iter().filter(|o| o.id != id) {
            let d = self
                .track
                .gap(me, other, true)
                .unwrap_or_else(|| in_front(me, other, AHEAD_CONE_RAD));
            gap = gap.min(d);
        }
        if let Some(seen) = self.followers.get(&id).and_then(|f| f.ir) {
            gap = gap.min(seen.gap_bound(world.time, IR_FRESH));
        }
        gap
    }

    /// Whether a lost robot stands in front of robot `id` within the spacing: a follower waits
    /// behind it until it is found, since its search may come its way.
    fn behind_lost(&self, id: u16, world: &WorldSnapshot) -> bool {
        let Some(me) = world.robot(id) else {
            return false;
        };
        world
            .robots
            .iter()
            .filter(|o| o.id != id && o.localisation == Localisation::Lost)
            .any(|o| in_front(me, o, FRAC_PI_2) < self.spacing_m)
    }

    /// Ends the run as failed, with the laps and distances reached.
    fn fail(&self, why: String, team: &mut Team) {
        let fewest = self
            .followers
            .values()
            .map(|f| f.progress_m / self.track.length_m())
            .fold(f64::INFINITY, f64::min);
        let least_m = self.odometer.least_m(self.followers.keys().copied());
        team.finish(
            Verdict::failure(why)
                .with("laps_min", fewest)
                .with("least_encoder_distance_m", least_m),
        );
    }

    fn speed_for(&self, cruise: f64, gap: f64) -> f64 {
        let share = ((gap - STOP_GAP_M) / (self.spacing_m - STOP_GAP_M)).clamp(0.0, 1.0);
        let v = cruise * share;
        if v < MIN_SPEED_MPS {
            0.0
        } else {
            // Steps of 1 cm/s, so a slowly changing gap does not send a packet every snapshot.
            (v * 100.0).round() / 100.0
        }
    }
}

impl Behaviour for LineFollow {
    fn start(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        self.on_snapshot(world, team)
    }

    fn on_snapshot(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        self.odometer.observe(world);
        if let Some(stall) = self.odometer.stall() {
            self.fail(stall.to_string(), team);
            return Vec::new();
        }
        let mut intents = Vec::new();
        let ids: Vec<u16> = self.followers.keys().copied().collect();
        for id in ids {
            let gap = self.gap_ahead(id, world);
            self.min_gap_m = self.min_gap_m.min(gap);
            let Some(view) = world.robot(id) else {
                continue;
            };
            let s = self.track.position(view);
            let length = self.track.length_m();
            let laps = self.laps;
            let target = {
                let f = self.followers.get(&id).map(|f| (f.cruise, f.finished));
                match f {
                    Some((cruise, false)) if team.idle(id) && !self.behind_lost(id, world) => {
                        self.speed_for(cruise, gap)
                    }
                    _ => 0.0,
                }
            };
            let Some(f) = self.followers.get_mut(&id) else {
                continue;
            };
            if let (Some(before), Some(after)) = (f.last_s, s) {
                f.progress_m += self.track.forward(before, after).unwrap_or(0.0);
            }
            if s.is_some() {
                f.last_s = s;
            }
            if f.progress_m >= laps * length {
                f.finished = true;
            }
            let target = if f.finished { 0.0 } else { target };
            if (target - f.sent).abs() >= 0.01 || (target == 0.0) != (f.sent == 0.0) {
                f.sent = target;
                intents.push(Intent::FollowLine {
                    robot: id,
                    speed: (target > 0.0).then_some(target as f32),
                });
            }
        }
        if self.followers.values().all(|f| f.finished) {
            let fewest = self
                .followers
                .values()
                .map(|f| f.progress_m / self.track.length_m())
                .fold(f64::INFINITY, f64::min);
            let losses: u32 = self.followers.values().map(|f| f.line_losses).sum();
            let claimed = self.laps * self.track.length_m();
            let ids = self.followers.keys().copied();
            let least_m = self.odometer.least_m(ids.clone());
            let verdict = match self.odometer.short_of(ids, |_| claimed) {
                Some((id, measured, _)) => Verdict::failure(format!(
                    "robot {id}: its place on the tape went {:.0} laps but its encoders measured \
                     {measured:.2} m, short of the {:.2} m ({:.0} % of the laps) that driving them \
                     takes",
                    self.laps,
                    EVIDENCE_SHARE * claimed,
                    EVIDENCE_SHARE * 100.0
                )),
                None => Verdict::success(format!(
                    "every robot drove {:.0} laps, at least {least_m:.2} m by its encoders; \
                     closest approach {:.0} mm sensor to sensor",
                    self.laps,
                    self.min_gap_m * 1e3
                )),
            };
            team.finish(
                verdict
                    .with("laps_min", fewest)
                    .with("least_encoder_distance_m", least_m)
                    .with("min_gap_m", self.min_gap_m)
                    .with("line_losses", f64::from(losses)),
            );
        }
        intents
    }

    fn on_event(
        &mut self,
        robot: u16,
        event: &Event,
        world: &WorldSnapshot,
        _: &mut Team,
    ) -> Vec<Intent> {
        let Some(f) = self.followers.get_mut(&robot) else {
            return Vec::new();
        };
        match event {
            // Front receiver only: a robot behind is not in the way.
            Event::Sighting(seen) if seen.side == Side::Front => {
                f.ir = FrontSighting::of(seen, world.time);
            }
            Event::LineLost => f.line_losses += 1,
            // A robot whose link is lost has stopped (its watchdog) and one back has not
            // resumed: its speed is sent again, held by the supervisor until the link is back.
            Event::LinkLost | Event::Connected => f.sent = 0.0,
            // Its reflex stopped it, or its watchdog did (a burst of losses silenced the link
            // longer than its timeout): its speed is sent again, through the safety check.
            Event::Reflexed { .. } | Event::WatchdogStop => f.sent = 0.0,
            _ => {}
        }
        Vec::new()
    }

    fn on_localisation(
        &mut self,
        robot: u16,
        event: &LocalisationEvent,
        world: &WorldSnapshot,
        _: &mut Team,
    ) -> Vec<Intent> {
        match event {
            // A lost robot was stopped and its follow commands held, and the supervisor stopped
            // the robots moving near it: once it is found, everyone is sent its speed again at
            // the next snapshot.
            LocalisationEvent::Found => {
                for f in self.followers.values_mut() {
                    f.sent = 0.0;
                }
                Vec::new()
            }
            // Robots standing close behind it make room for its search (the safety check would
            // hold a turn that sweeps into them, and they wait behind a lost robot).
            LocalisationEvent::Lost { .. } => {
                let Some(lost) = world.robot(robot) else {
                    return Vec::new();
                };
                let mut out = Vec::new();
                for (&id, f) in &mut self.followers {
                    let Some(me) = world.robot(id).filter(|_| id != robot) else {
                        continue;
                    };
                    if in_front(me, lost, FRAC_PI_2) < BACK_OFF_NEAR_M {
                        f.sent = 0.0;
                        out.push(Intent::Stop { robot: id });
                        out.push(Intent::Move {
                            robot: id,
                            command: MoveCommand::Straight {
                                distance_m: -BACK_OFF_M,
                                speed_mps: BACK_OFF_MPS,
                            },
                            tag: BACK_OFF_TAG,
                        });
                    }
                }
                out
            }
        }
    }
}

/// Straight-line distance from `me` to `other` if `other` lies within `half_angle` of `me`'s
/// heading, else infinity.
fn in_front(me: &RobotView, other: &RobotView, half_angle: f64) -> f64 {
    match me.bearing_to(other) {
        (off, distance) if off < half_angle => distance,
        _ => f64::INFINITY,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use behaviour_api::testing::{world as snapshot, Harness};
    use std::sync::Arc;
    use world::presets;

    fn cfg(robots: Vec<u16>) -> BehaviourConfig {
        BehaviourConfig {
            robots,
            track: Arc::new(presets::preset("oval").unwrap().track),
            ..Default::default()
        }
    }

    #[test]
    fn a_follower_slows_then_stops_behind_the_robot_ahead() {
        let c = cfg(vec![1, 2]);
        let track = Arc::clone(&c.track);
        let mut h = Harness::new(LineFollow::from_config(&c).unwrap());
        // Both on the oval's lower straight (y = 0.15), robot 2 ahead of robot 1.
        let snap = |x2: f64| {
            let on = |x: f64| track.nearest(nalgebra::Point2::new(x, 0.15)).unwrap();
            let (a, b) = (on(0.30), on(x2));
            snapshot()
                .arena(1.0, 0.6)
                .robot(1, 0.30, 0.15, 0.0)
                .robot(2, x2, 0.15, 0.0)
                .on_track(1, a.edge, a.offset_m)
                .on_track(2, b.edge, b.offset_m)
                .build()
        };
        let far = h.start(&snap(0.70));
        assert!(far.contains(&Intent::FollowLine {
            robot: 1,
            speed: Some(0.15)
        }));
        let near = h.snapshot(&snap(0.44));
        let Some(Intent::FollowLine { speed: Some(v), .. }) = near.iter().find(|i| i.robot() == 1)
        else {
            panic!("robot 1 slows: {near:?}");
        };
        assert!(*v < 0.15 && *v > 0.0, "{v}");
        assert_eq!(h.team().following(1), Some(*v));
        let touching = h.snapshot(&snap(0.37));
        assert!(touching.contains(&Intent::FollowLine {
            robot: 1,
            speed: None
        }));
    }

    /// Robot 2 is lost 8 cm ahead of robot 1, whose follow command had stopped it: robot 1 backs
    /// away to make room for the search and stays stopped until robot 2 is found; then it
    /// follows again.
    #[test]
    fn a_follower_backs_away_from_a_lost_robot_and_waits_until_it_is_found() {
        let c = cfg(vec![1, 2]);
        let track = Arc::clone(&c.track);
        let mut h = Harness::new(LineFollow::from_config(&c).unwrap());
        let snap = |lost: bool, x1: f64| {
            let on = |x: f64| track.nearest(nalgebra::Point2::new(x, 0.15)).unwrap();
            let (a, b) = (on(x1), on(0.38));
            snapshot()
                .arena(1.0, 0.6)
                .robot(1, x1, 0.15, 0.0)
                .robot(2, 0.38, 0.15, 0.0)
                .on_track(1, a.edge, a.offset_m)
                .on_track(2, b.edge, b.offset_m)
                .with(2, |v| {
                    if lost {
                        v.localisation = Localisation::Lost;
                    }
                })
                .build()
        };
        h.start(&snap(false, 0.30));
        let lost = snap(true, 0.30);
        let out = h.localise(2, LocalisationEvent::Lost { why: "test".into() }, &lost);
        assert!(
            out.iter().any(|i| matches!(
                i,
                Intent::Move {
                    robot: 1,
                    command: MoveCommand::Straight { distance_m, .. },
                    ..
                } if *distance_m < 0.0
            )),
            "{out:?}"
        );
        // Backed off: the gap alone would let it follow again, but robot 2 is still lost.
        h.finish_move(1, BACK_OFF_TAG, &snap(true, 0.25));
        let waiting = h.snapshot(&snap(true, 0.25));
        assert!(
            !waiting.iter().any(|i| matches!(
                i,
                Intent::FollowLine {
                    robot: 1,
                    speed: Some(_)
                }
            )),
            "{waiting:?}"
        );
        h.localise(2, LocalisationEvent::Found, &snap(false, 0.25));
        let going = h.snapshot(&snap(false, 0.25));
        assert!(
            going.iter().any(|i| matches!(
                i,
                Intent::FollowLine {
                    robot: 1,
                    speed: Some(_)
                }
            )),
            "{going:?}"
        );
    }

    #[test]
    fn a_track_with_forks_is_refused_and_bad_parameters_are_named() {
        let mut c = cfg(vec![1]);
        c.track = Arc::new(presets::preset("junction").unwrap().track);
        assert!(LineFollow::from_config(&c).is_err());
        let mut c = cfg(vec![1]);
        c.params.insert("speed".into(), "fast".into());
        let e = LineFollow::from_config(&c).unwrap_err();
        assert!(e.contains("speed"), "{e}");
    }
}
