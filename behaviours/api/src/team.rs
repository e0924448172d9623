//! [`Team`]: the books a behaviour would otherwise keep for itself, kept once by the shell it
//! runs in and handed to every hook.
//!
//! The shell passes every intent the behaviour returns through [`Team::outgoing`] and every
//! robot event, held intent and localisation change through the matching method, so the team
//! knows, per robot, which tagged moves are still outstanding and at what speed it was last told
//! to follow the tape, and applies the behaviour's [`HeldPolicy`] to moves the supervisor's
//! safety check held back. The same code runs under [`crate::testing::Harness`].

use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

use protocol::packets::MoveOutcome;
use protocol::MoveCommand;

use crate::event::Event;
use crate::evidence::Odometer;
use crate::intent::Intent;
use crate::snapshot::{RobotView, WorldSnapshot};
use crate::track_loop::TrackLoop;
use crate::verdict::Verdict;

/// What happens to a move the supervisor's safety check held back (it never reached the robot).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HeldPolicy {
    /// The move is no longer outstanding and the behaviour's `on_held` decides.
    Tell,
    /// The move stays outstanding and is sent again with the next snapshot, until it passes or
    /// has been held for `patience`, which fails the run with the supervisor's reason.
    Retry {
        /// How long a move may stay held.
        patience: Duration,
    },
    /// The default: the move stays outstanding and is sent again with the next snapshot until
    /// it passes; held for `patience`, it is dropped and the behaviour's `on_held` re-plans (a
    /// robot in the way may only be passing, and over a slow link the check sees it late).
    RetryThenReplan {
        /// How long a move is sent again before the behaviour hears of it.
        patience: Duration,
    },
    /// The run fails at once with the supervisor's reason: for choreographies that cannot be
    /// improvised, such as a push planned around a box.
    Fail,
}

/// The default policy's patience: a few round trips of the slowest link profile and a robot
/// driving past at walking pace, short of the stall checks behaviours run on their robots.
pub const DEFAULT_HELD_PATIENCE: Duration = Duration::from_secs(2);

impl Default for HeldPolicy {
    fn default() -> Self {
        HeldPolicy::RetryThenReplan {
            patience: DEFAULT_HELD_PATIENCE,
        }
    }
}

/// A move waiting to be sent again under [`HeldPolicy::Retry`].
#[derive(Clone, Copy, Debug, PartialEq)]
struct Retry {
    command: MoveCommand,
    tag: u32,
}

/// One robot's books.
#[derive(Clone, Debug, Default, PartialEq)]
struct Member {
    /// Tags of the moves sent and not yet finished, in the order they were sent.
    outstanding: VecDeque<u32>,
    /// The follow speed last sent, while it is in force.
    following: Option<f32>,
    /// Held moves to send again, in order.
    retries: VecDeque<Retry>,
    /// Moves that ended other than completed, or stopped by the robot's own reflex.
    interrupted: u32,
    blocked: u32,
    /// When a move of this robot was first held since one last finished.
    held_since: Option<Duration>,
}

/// Per-robot outstanding moves, follow speeds and held moves, the run's verdict once given, and
/// questions about the team's places on the track.
#[derive(Clone, Debug, PartialEq)]
pub struct Team {
    members: BTreeMap<u16, Member>,
    policy: HeldPolicy,
    verdict: Option<Verdict>,
    odometer: Odometer,
}

impl Team {
    /// A team of `robots` under `policy`.
    pub fn new(robots: impl IntoIterator<Item = u16>, policy: HeldPolicy) -> Self {
        Self {
            members: robots
                .into_iter()
                .map(|id| (id, Member::default()))
                .collect(),
            policy,
            verdict: None,
            odometer: Odometer::new(),
        }
    }

    /// What each robot's encoders measured so far (distance, turning), for verdicts that need
    /// evidence of the work.
    pub fn odometer(&self) -> &Odometer {
        &self.odometer
    }

    /// Takes a snapshot into the odometer; a robot driven without its encoders counting (see
    /// [`Odometer::stall`]) fails the run.
    pub fn observe(&mut self, world: &WorldSnapshot) {
        self.odometer.observe(world);
        if let Some(stall) = self.odometer.stall() {
            self.fail(stall.to_string());
        }
    }

    /// Robot ids, ascending.
    pub fn ids(&self) -> impl Iterator<Item = u16> + Clone + '_ {
        self.members.keys().copied()
    }

    /// Moves of `robot` sent and not yet finished (held moves waiting for a retry included).
    pub fn outstanding(&self, robot: u16) -> usize {
        self.members.get(&robot).map_or(0, |m| m.outstanding.len())
    }

    /// Whether `robot` has no move outstanding.
    pub fn idle(&self, robot: u16) -> bool {
        self.outstanding(robot) == 0
    }

    /// Whether no robot has a move outstanding.
    pub fn all_idle(&self) -> bool {
        self.members.values().all(|m| m.outstanding.is_empty())
    }

    /// Whether a move tagged `tag` of `robot` is outstanding.
    pub fn has_outstanding(&self, robot: u16, tag: u32) -> bool {
        self.members
            .get(&robot)
            .is_some_and(|m| m.outstanding.contains(&tag))
    }

    /// Moves of `robot` that ended aborted, cleared or stopped, or were lost with its link.
    pub fn interrupted(&self, robot: u16) -> u32 {
        self.members.get(&robot).map_or(0, |m| m.interrupted)
    }

    /// Moves of `robot` its proximity reflex stopped short of something close (`Blocked`): the
    /// robot stands where it stopped, and a leg planned from its pose can be tried again.
    pub fn blocked(&self, robot: u16) -> u32 {
        self.members.get(&robot).map_or(0, |m| m.blocked)
    }

    /// The follow speed in force for `robot`, if it was told to follow and nothing has stopped
    /// it since (a move, a stop, wheel speeds, a lost link or a lost pose).
    pub fn following(&self, robot: u16) -> Option<f32> {
        self.members.get(&robot).and_then(|m| m.following)
    }

    /// A stop for every robot of the team (a verdict needs none: the supervisor then stops
    /// everyone itself).
    pub fn stop_all(&self) -> Vec<Intent> {
        self.ids().map(|robot| Intent::Stop { robot }).collect()
    }

    /// Ends the run as failed; the supervisor stops every robot.
    pub fn fail(&mut self, why: impl Into<String>) {
        self.finish(Verdict::failure(why));
    }

    /// Ends the run with `verdict` (the first verdict given stands).
    pub fn finish(&mut self, verdict: Verdict) {
        if self.verdict.is_none() {
            self.verdict = Some(verdict);
        }
    }

    /// The verdict, once given.
    pub fn verdict(&self) -> Option<&Verdict> {
        self.verdict.as_ref()
    }

    /// The nearest robot ahead of `robot` along `track` in its driving direction (`forward`:
    /// the way the loop's edges run), and the distance to it, sensor to sensor; robots off the
    /// tape are not counted.
    pub fn ahead(
        &self,
        robot: u16,
        world: &WorldSnapshot,
        track: &TrackLoop,
        forward: bool,
    ) -> Option<(u16, f64)> {
        let me = world.robot(robot)?;
        world
            .robots
            .iter()
            .filter(|o| o.id != robot)
            .filter_map(|o| Some((o.id, track.gap(me, o, forward)?)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// Keeps the books on the intents a behaviour returned and gives back those to send: a
    /// follow command equal to the one in force is dropped.
    pub fn outgoing(&mut self, intents: Vec<Intent>) -> Vec<Intent> {
        intents
            .into_iter()
            .filter(|intent| {
                let Some(m) = self.members.get_mut(&intent.robot()) else {
                    return true;
                };
                match *intent {
                    Intent::Move { tag, .. } => {
                        m.outstanding.push_back(tag);
                        m.following = None;
                    }
                    Intent::FollowLine { speed, .. } => {
                        if m.following == speed {
                            return false;
                        }
                        m.following = speed;
                    }
                    Intent::WheelSpeeds { .. } | Intent::Stop { .. } => m.following = None,
                    Intent::ClearQueue { .. }
                    | Intent::Led { .. }
                    | Intent::IrMessage { .. }
                    | Intent::Reflex { .. } => {}
                }
                true
            })
            .collect()
    }

    /// Keeps the books on a robot event; returns whether the behaviour should hear it. The end
    /// of a move the team does not count (one lost with the link or the robot's pose, or sent
    /// by an earlier instance of the behaviour) is not the behaviour's news.
    pub fn event(&mut self, robot: u16, event: &Event) -> bool {
        let Some(m) = self.members.get_mut(&robot) else {
            return true;
        };
        match *event {
            Event::MoveFinished { tag, outcome } => {
                let Some(k) = m.outstanding.iter().position(|t| *t == tag) else {
                    return false;
                };
                m.outstanding.remove(k);
                m.held_since = None;
                if outcome == MoveOutcome::Blocked {
                    m.blocked += 1;
                } else if outcome != MoveOutcome::Completed {
                    m.interrupted += 1;
                }
            }
            Event::LinkLost => {
                m.interrupted += m.outstanding.len() as u32;
                m.outstanding.clear();
                m.retries.clear();
                m.held_since = None;
                m.following = None;
            }
            // The robot stopped by itself: a follow command is in force no longer.
            Event::Connected | Event::WatchdogStop | Event::Reflexed { .. } => m.following = None,
            _ => {}
        }
        true
    }

    /// A robot was found lost: the supervisor stopped it, and its queued moves' ends go to the
    /// re-localisation routine, not to the behaviour, so they are no longer outstanding.
    pub fn lost(&mut self, robot: u16) {
        if let Some(m) = self.members.get_mut(&robot) {
            m.interrupted += m.outstanding.len() as u32;
            m.outstanding.clear();
            m.retries.clear();
            m.held_since = None;
            m.following = None;
        }
    }

    /// A lost robot was found again. While it was lost the supervisor stopped every robot moving
    /// near it, which the books do not show: no follow command is taken to be in force, so the
    /// behaviour's next ones go out again.
    pub fn found(&mut self) {
        for m in self.members.values_mut() {
            m.following = None;
        }
    }

    /// Applies the policy to an intent the supervisor held back at `now`; returns whether the
    /// behaviour should hear of it (`HeldPolicy::Tell`, or an intent that is not a move).
    pub fn held(&mut self, intent: &Intent, reason: &str, now: Duration) -> bool {
        let Some(m) = self.members.get_mut(&intent.robot()) else {
            return true;
        };
        let Intent::Move {
            robot,
            command,
            tag,
        } = *intent
        else {
            if matches!(intent, Intent::FollowLine { .. }) {
                m.following = None;
            }
            return true;
        };
        match self.policy {
            HeldPolicy::Tell => {
                forget(m, tag);
                true
            }
            HeldPolicy::Fail => {
                forget(m, tag);
                self.fail(format!(
                    "robot {robot}: the supervisor held back a move: {reason}"
                ));
                false
            }
            HeldPolicy::Retry { patience } => {
                let since = *m.held_since.get_or_insert(now);
                if now.saturating_sub(since) > patience {
                    forget(m, tag);
                    self.fail(format!(
                        "robot {robot}: a move was held for over {:.0} s: {reason}",
                        patience.as_secs_f64()
                    ));
                    return false;
                }
                // Still outstanding: it is sent again, not planned again.
                m.retries.push_back(Retry { command, tag });
                false
            }
            HeldPolicy::RetryThenReplan { patience } => {
                let since = *m.held_since.get_or_insert(now);
                if now.saturating_sub(since) > patience {
                    forget(m, tag);
                    // What the behaviour plans instead gets its own patience.
                    m.held_since = None;
                    return true;
                }
                m.retries.push_back(Retry { command, tag });
                false
            }
        }
    }

    /// The held moves to send again now, in order ([`HeldPolicy::Retry`]); they are still
    /// counted outstanding, so they go out without passing [`Team::outgoing`] again.
    pub fn retries(&mut self) -> Vec<Intent> {
        let mut out = Vec::new();
        for (&robot, m) in &mut self.members {
            for r in m.retries.drain(..) {
                out.push(Intent::Move {
                    robot,
                    command: r.command,
                    tag: r.tag,
                });
            }
        }
        out
    }
}

/// Drops one outstanding move tagged `tag`, the newest such: a held move was the last sent.
fn forget(m: &mut Member, tag: u32) {
    if let Some(k) = m.outstanding.iter().rposition(|t| *t == tag) {
        m.outstanding.remove(k);
    }
}

impl TrackLoop {
    /// How far `other` is ahead of `me` along the loop in the driving direction (`forward`: the
    /// way the edges run), sensor to sensor; `None` unless both are on the tape.
    pub fn gap(&self, me: &RobotView, other: &RobotView, forward: bool) -> Option<f64> {
        let a = self.position(me)?;
        let b = self.position(other)?;
        Some(if forward {
            self.ahead(a, b)
        } else {
            self.ahead(b, a)
        })
    }

    /// The loop coordinate of a robot's line sensor, if it is on the tape.
    pub fn position(&self, robot: &RobotView) -> Option<f64> {
        robot.on_track.map(|p| self.coordinate(p.edge, p.along_m))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::world as snapshot;
    use world::presets;

    const STEP: MoveCommand = MoveCommand::Straight {
        distance_m: 0.01,
        speed_mps: 0.1,
    };

    fn follow(robot: u16, speed: Option<f32>) -> Intent {
        Intent::FollowLine { robot, speed }
    }

    #[test]
    fn a_follow_speed_goes_out_once_until_something_stops_it() {
        let mut team = Team::new([1, 2], HeldPolicy::Tell);
        assert_eq!(team.outgoing(vec![follow(1, Some(0.1))]).len(), 1);
        assert!(team.outgoing(vec![follow(1, Some(0.1))]).is_empty());
        assert_eq!(
            team.outgoing(vec![follow(2, Some(0.1))]).len(),
            1,
            "per robot"
        );
        // A move takes the wheels from the follower: the same speed is a new command.
        team.outgoing(Intent::moves(1, [STEP], 0));
        assert_eq!(team.outgoing(vec![follow(1, Some(0.1))]).len(), 1);
        team.event(1, &Event::LinkLost);
        assert_eq!(team.following(1), None);
        team.outgoing(vec![follow(1, Some(0.1))]);
        team.lost(1);
        assert_eq!(team.outgoing(vec![follow(1, Some(0.1))]).len(), 1);
    }

    #[test]
    fn moves_are_counted_by_tag_and_ends_of_others_are_not_the_behaviours() {
        let mut team = Team::new([1], HeldPolicy::Tell);
        team.outgoing([Intent::moves(1, [STEP], 7), Intent::moves(1, [STEP], 8)].concat());
        assert_eq!(team.outstanding(1), 2);
        assert!(team.has_outstanding(1, 8));
        let end = |tag, outcome| Event::MoveFinished { tag, outcome };
        assert!(!team.event(1, &end(9, MoveOutcome::Completed)), "not sent");
        assert!(team.event(1, &end(7, MoveOutcome::Completed)));
        assert!(team.event(1, &end(8, MoveOutcome::Stopped)));
        assert!(team.all_idle());
        assert_eq!(team.interrupted(1), 1);
        // Lost with the link: their ends, should they come, are dropped.
        team.outgoing(Intent::moves(1, [STEP, STEP], 1));
        team.event(1, &Event::LinkLost);
        assert!(team.idle(1));
        assert_eq!(team.interrupted(1), 3);
        assert!(!team.event(1, &end(1, MoveOutcome::Stopped)));
        // Stopped by its own reflex: blocked, not interrupted, and no longer following.
        team.outgoing(Intent::moves(1, [STEP], 2));
        assert!(team.event(1, &end(2, MoveOutcome::Blocked)));
        assert_eq!((team.interrupted(1), team.blocked(1)), (3, 1));
        team.outgoing(vec![Intent::FollowLine {
            robot: 1,
            speed: Some(0.1),
        }]);
        team.event(
            1,
            &Event::Reflexed {
                side: protocol::packets::Side::Front,
            },
        );
        assert_eq!(team.following(1), None);
    }

    #[test]
    fn a_held_move_is_told_retried_replanned_or_fatal_as_the_policy_says() {
        let held = Intent::moves(1, [STEP], 3)[0];
        let now = Duration::from_secs(1);

        let mut tell = Team::new([1], HeldPolicy::Tell);
        tell.outgoing(vec![held]);
        assert!(tell.held(&held, "in the way", now));
        assert!(tell.idle(1) && tell.verdict().is_none());

        let patience = Duration::from_secs(2);
        let mut retry = Team::new([1], HeldPolicy::Retry { patience });
        retry.outgoing(vec![held]);
        assert!(!retry.held(&held, "in the way", now));
        assert_eq!(retry.outstanding(1), 1);
        assert_eq!(retry.retries(), vec![held]);
        assert!(retry.retries().is_empty(), "sent once");
        assert!(!retry.held(&held, "in the way", now + patience));
        assert!(retry.verdict().is_none(), "not yet held too long");
        retry.held(&held, "still in the way", now + patience * 2);
        let v = retry.verdict().expect("failed");
        assert!(
            !v.success && v.summary.contains("still in the way"),
            "{v:?}"
        );

        let mut replan = Team::new([1], HeldPolicy::RetryThenReplan { patience });
        replan.outgoing(vec![held]);
        assert!(!replan.held(&held, "in the way", now), "sent again first");
        assert_eq!(replan.retries(), vec![held]);
        assert!(!replan.held(&held, "in the way", now + patience));
        assert_eq!(replan.retries(), vec![held]);
        assert!(
            replan.held(&held, "still in the way", now + patience * 2),
            "the behaviour re-plans once patience is over"
        );
        assert!(replan.idle(1) && replan.retries().is_empty());
        assert!(replan.verdict().is_none(), "a re-plan, not a failure");

        let mut fail = Team::new([1], HeldPolicy::Fail);
        fail.outgoing(vec![held]);
        assert!(!fail.held(&held, "in the way", now));
        assert!(fail
            .verdict()
            .is_some_and(|v| v.summary.contains("robot 1")));
    }

    #[test]
    fn the_robot_ahead_is_the_nearest_along_the_loop_in_the_driving_direction() {
        let oval = presets::preset("oval").unwrap().track;
        let track = TrackLoop::new(&oval).unwrap();
        let on = |x: f64| oval.nearest(nalgebra::Point2::new(x, 0.15)).unwrap();
        let (a, b, c) = (on(0.3), on(0.5), on(0.45));
        let w = snapshot()
            .robot(1, 0.3, 0.15, 0.0)
            .robot(2, 0.5, 0.15, 0.0)
            .robot(3, 0.45, 0.15, 0.0)
            .robot(4, 0.6, 0.5, 0.0)
            .on_track(1, a.edge, a.offset_m)
            .on_track(2, b.edge, b.offset_m)
            .on_track(3, c.edge, c.offset_m)
            .build();
        let team = Team::new([1, 2, 3, 4], HeldPolicy::Tell);
        let (id, gap) = team.ahead(1, &w, &track, true).unwrap();
        assert_eq!(id, 3, "robot 4 is off the tape");
        assert!((gap - 0.15).abs() < 1e-9, "{gap}");
        let (id, _) = team.ahead(1, &w, &track, false).unwrap();
        assert_eq!(id, 2, "backwards, the nearest is the farthest forwards");
        assert_eq!(team.stop_all().len(), 4);
    }
}
