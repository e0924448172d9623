//! Re-localising a lost robot. The world model says when what a robot senses contradicts it; the
//! supervisor then stops the robot and runs this routine, which finds the tape the robot should
//! be beside and puts the robot back on it, facing the way it drove:
//!
//! 1. wait for the wheels to stop;
//! 2. face across the tape (whichever way is nearer the robot's heading) and creep first towards
//!    the side the model puts the tape on, through it, then back through to the other side, as
//!    far as the model's uncertainty reaches beyond the tape and beyond the model's mean (the
//!    model fixes the position across the first tape the sensor sees, see
//!    [`crate::model::Transition::Fixed`]);
//! 3. stop there, drive the centre onto the tape and face along it;
//! 4. follow the tape with the firmware's line follower for a few centimetres: the follower
//!    steers the robot along the tape whatever its heading was off by (a bump turns a robot by
//!    up to 20°, and a creep on the model's heading then leaves the tape), and the model, which
//!    matches a follower's readings to the tape, tracks the robot again on it. The follow goes
//!    on until the robot drives straight along the tape: then it faces along it, which the
//!    supervisor gives the model as a measurement of its heading
//!    ([`crate::WorldModel::faces_along_tape`]).
//!
//! If the sweep finds no tape, the robot stays stopped and lost: it is safer where it stands than
//! driving on a guess.

use std::time::Duration;

use behaviour_api::{MoveCommand, Pose, RobotView};
use nalgebra::{Point2, Vector2};
use tokio::time::Instant;
use world::robot::LINE_SENSOR_AHEAD_M;
use world::wrap_angle;
use world::Track;

use crate::model::RELOCATE_M;

/// Speed of the search and of the moves back onto the tape: slow enough that the sensor sees a
/// 6 mm tape in several samples and the robot stops within a few millimetres.
pub const SEARCH_MPS: f32 = 0.03;
/// Turning speed (wheel speed) of the routine's turns.
const TURN_MPS: f32 = 0.03;
/// Longest wait for the wheels to stop after a stop command.
const BRAKE_LIMIT: Duration = Duration::from_millis(600);
/// Below this wheel speed a robot counts as stopped.
const STOPPED_MPS: f32 = 0.005;
/// The follow along the tape once the robot faces along it, and the longest it may take (a
/// follower that lost the tape stands still).
const CREEP_M: f32 = 0.03;
const FOLLOW_LIMIT: Duration = Duration::from_secs(4);
/// The follow goes on past [`CREEP_M`] until the robot drives straight along the tape: over the
/// last [`SETTLE_M`] its odometry turned less than [`SETTLE_RAD`] and the tape sits under the
/// sensor's middle. Then it faces along the tape, a measurement of its heading that the turns
/// the follower made to get there cannot spoil; at most [`FOLLOW_MOST_M`] in all.
const SETTLE_M: f64 = 0.015;
const SETTLE_RAD: f64 = 2.0 * std::f64::consts::PI / 180.0;
const SETTLE_LINE_UM: i16 = 1600;
/// The longest follow of the routine, metres.
pub const FOLLOW_MOST_M: f64 = 0.08;
/// `LineState::flags` bit: no spot sees the line.
const LINE_LOST: u8 = 1;
/// A search that starts in a junction zone first drives this far beyond the zone's edge.
const LEAVE_MARGIN_M: f64 = 0.015;
/// A routine whose moves are outstanding while the robot has stood with an empty queue this long
/// has lost their ends (a stop that came after them dropped them): it goes on without them.
const STALLED_AFTER: Duration = Duration::from_millis(1500);
/// A move the safety check holds is tried again this much later, at most this many times.
const RETRY_AFTER: Duration = Duration::from_millis(500);
const MAX_RETRIES: u32 = 20;
/// A held sweep leg is halved at every this many holds of the routine, but not below this length.
const SHORTEN_AFTER: u32 = 4;
const SHORTEST_LEG_M: f32 = 0.01;

/// What the routine asks the supervisor to do for its robot.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    /// Stop the robot and drop its queue.
    Stop,
    /// Queue these moves (checked by the safety check; held ones are reported back).
    Moves(Vec<MoveCommand>),
    /// Follow the tape under the sensor with the firmware's line follower at this speed, m/s.
    Follow(f32),
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Step {
    /// Waiting for the wheels to stop, then `next`.
    Braking { since: Instant, then: After },
    /// Sweeping across the tape.
    Sweeping,
    /// Driving onto the tape and facing along it.
    Aligning,
    /// Following the tape from where the odometry was, since when.
    Following { from: Pose, since: Instant },
    /// Followed it: the robot stands on the tape, facing along it (measured so when `settled`).
    Followed { settled: bool },
    /// The routine gave up: the robot stays stopped.
    GaveUp,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum After {
    Sweep,
    Align,
}

/// The routine for one lost robot.
#[derive(Clone, Debug)]
pub struct Relocaliser {
    /// The robot.
    pub robot: u16,
    /// Unit tangent of the tape nearest to where the robot was lost, and that nearest point.
    tape: Vector2<f64>,
    tape_at: Point2<f64>,
    /// Heading when it was lost: it faces the same way along the tape afterwards.
    heading: f64,
    /// How far to each side the sweep goes.
    reach_m: f64,
    /// Where the sweep starts being away from a junction zone the robot was lost in: the unit
    /// direction along the tape away from the junction and how far to drive along it first.
    leave: Option<(Vector2<f64>, f64)>,
    /// Where the robot's centre may go without its footprint leaving the arena: lower and upper
    /// corners.
    room: ([f64; 2], [f64; 2]),
    step: Step,
    /// Moves of this routine still queued on the robot.
    outstanding: usize,
    /// When a held move may be tried again, and how often it was.
    retry_at: Option<Instant>,
    retries: u32,
    /// Moves to try again.
    pending: Vec<MoveCommand>,
    /// While following: distance followed and odometry heading at each update, over the last
    /// [`SETTLE_M`] or a little more.
    trail: std::collections::VecDeque<(f64, f64)>,
    /// Since when the robot has stood with an empty queue while moves of the routine are
    /// outstanding.
    idle_since: Option<Instant>,
    /// The turns of the alignment under way, sent again if the reflex stops its nudge.
    align_turns: Vec<MoveCommand>,
}

impl Relocaliser {
    /// Starts the routine for a robot lost at `view` whose centre may move within `room` (lower
    /// and upper corners), on a track with these `junctions` (centre and radius of the zones
    /// where the tape cannot fix a robot); the first action is the stop.
    pub fn start(
        view: &RobotView,
        track: &Track,
        junctions: &[(Point2<f64>, f64)],
        room: ([f64; 2], [f64; 2]),
        now: Instant,
    ) -> (Self, Action) {
        let centre = Point2::new(view.pose.x, view.pose.y);
        let heading = Vector2::new(view.pose.theta.cos(), view.pose.theta.sin());
        let nearest = track.nearest(centre);
        let tape = nearest.as_ref().map_or(heading, |n| n.tangent);
        let tape_at = nearest.map_or(centre, |n| n.point);
        // Inside a junction zone no sighting is taken as a fix (its tapes run too close to
        // tell apart), so a sweep there finds nothing however often it is tried: the search
        // first drives along the tape out of the zone, away from the junction.
        let leave = junctions
            .iter()
            .find(|(j, r)| (centre - j).norm() < r + LEAVE_MARGIN_M)
            .map(|(j, r)| {
                let from = centre - j;
                let away = if from.norm() < 1e-6 {
                    if tape.dot(&heading) >= 0.0 {
                        tape
                    } else {
                        -tape
                    }
                } else if tape.dot(&from) >= 0.0 {
                    tape
                } else {
                    -tape
                };
                (away, (r + LEAVE_MARGIN_M - from.dot(&away)).max(0.0))
            });
        let reach_m = (3.0 * view.uncertainty.position_m).clamp(0.04, RELOCATE_M);
        (
            Self {
                robot: view.id,
                tape,
                tape_at,
                heading: view.pose.theta,
                reach_m,
                leave,
                room,
                step: Step::Braking {
                    since: now,
                    then: After::Sweep,
                },
                outstanding: 0,
                retry_at: None,
                retries: 0,
                pending: Vec::new(),
                trail: Default::default(),
                idle_since: None,
                align_turns: Vec::new(),
            },
            Action::Stop,
        )
    }

    /// Gives up: the robot stays stopped where it is.
    pub fn give_up(&mut self) {
        self.step = Step::GaveUp;
        self.pending.clear();
        self.retry_at = None;
    }

    /// Whether the routine gave up.
    pub fn gave_up(&self) -> bool {
        self.step == Step::GaveUp
    }

    /// While the routine's follow along the tape drives the robot: how far ahead it may yet take
    /// it (the follow is the robot's own, so the others keep clear of the whole of it).
    pub fn follow_reach(&self) -> Option<f64> {
        matches!(self.step, Step::Following { .. }).then_some(FOLLOW_MOST_M)
    }

    /// Whether the robot is back on the tape, facing along it, with the routine's moves done.
    pub fn aligned(&self) -> bool {
        matches!(self.step, Step::Followed { .. })
    }

    /// Whether the robot ended its follow driving straight along the tape, centred on it: it
    /// faces along the tape, whatever its odometry says.
    pub fn settled(&self) -> bool {
        self.step == Step::Followed { settled: true }
    }

    /// The model fixed the robot's position across a tape: stop the sweep there.
    pub fn fixed(&mut self, now: Instant) -> Action {
        self.pending.clear();
        self.outstanding = 0;
        self.retry_at = None;
        self.step = Step::Braking {
            since: now,
            then: After::Align,
        };
        Action::Stop
    }

    /// One of the robot's moves ended. Aborted ones are those a stop dropped (the behaviour's
    /// when the robot was found lost, the sweep's when it found the tape): not counted.
    pub fn move_finished(&mut self, completed: bool) {
        if !completed {
            return;
        }
        self.outstanding = self.outstanding.saturating_sub(1);
        if self.outstanding == 0 && self.step == Step::Sweeping && self.pending.is_empty() {
            // The whole sweep went by without a tape.
            self.step = Step::GaveUp;
        }
    }

    /// The robot's proximity reflex stopped one of the routine's moves (and dropped the rest):
    /// something stands close in its way, and this search cannot go on from here. (Searching the
    /// other side from there drove a pusher stopped by the box back into its neighbour: the
    /// search's moves are checked with the lost robot's 1σ.)
    ///
    /// While aligning, the robot already stands on the tape it found: a reflex that stops the
    /// nudge onto it (a robot or a box close ahead on the tape) costs only the nudge, and the
    /// turn along the tape is sent again. Giving up there searched afresh from the same spot,
    /// found the tape at once and met the same reflex, three times in half a second (165089
    /// `token_ring`).
    pub fn blocked(&mut self, now: Instant) {
        self.outstanding = 0;
        if self.step == Step::Aligning {
            let turns: Vec<MoveCommand> = std::mem::take(&mut self.align_turns);
            if !turns.is_empty() {
                self.pending = turns;
                self.retry_at = Some(now);
            }
            return;
        }
        self.give_up();
    }

    /// Some of the routine's moves were held by the safety check: the robot stands; try them
    /// again a little later.
    ///
    /// A sweep leg held again and again stands against something that does not go away (often a
    /// robot that waits for this one's exclusion zone to clear): every fourth hold it is halved,
    /// down to 1 cm, so the side towards it is searched as far as the safety check lets the
    /// robot go instead of not at all.
    pub fn held(&mut self, mut moves: Vec<MoveCommand>, now: Instant) {
        self.outstanding = self.outstanding.saturating_sub(moves.len());
        self.retries += 1;
        if self.step == Step::Sweeping && self.retries % SHORTEN_AFTER == 0 {
            if let Some(MoveCommand::Straight { distance_m, .. }) = moves.first_mut() {
                if distance_m.abs() / 2.0 >= SHORTEST_LEG_M {
                    *distance_m /= 2.0;
                }
            }
        }
        self.pending = moves;
        if self.retries > MAX_RETRIES {
            self.step = Step::GaveUp;
            self.pending.clear();
        } else {
            self.retry_at = Some(now + RETRY_AFTER);
        }
    }

    /// The follow along the tape was held (it would drive into another robot): the routine
    /// stands aligned and starts it again a little later, counted like a held move.
    pub fn follow_held(&mut self, now: Instant) {
        self.step = Step::Aligning;
        self.held(Vec::new(), now);
    }

    /// The next action, given the robot's latest view.
    pub fn poll(&mut self, view: &RobotView, track: &Track, now: Instant) -> Option<Action> {
        if let Some(at) = self.retry_at {
            if now < at {
                return None;
            }
            self.retry_at = None;
            // A held follow has no moves to send again: the step below starts it.
            if !self.pending.is_empty() {
                let moves = std::mem::take(&mut self.pending);
                self.outstanding += moves.len();
                return Some(Action::Moves(moves));
            }
        }
        self.catch_stall(view, now);
        match self.step {
            Step::Aligning if self.outstanding == 0 && self.pending.is_empty() => {
                self.step = Step::Following {
                    from: view.odometry,
                    since: now,
                };
                self.trail.clear();
                return Some(Action::Follow(SEARCH_MPS));
            }
            Step::Following { from, since } => {
                let driven = (view.odometry.x - from.x).hypot(view.odometry.y - from.y);
                let settled = self.settled_at(driven, view);
                if !settled
                    && driven < FOLLOW_MOST_M
                    && now.saturating_duration_since(since) < FOLLOW_LIMIT
                {
                    return None;
                }
                self.step = Step::Followed { settled };
                return Some(Action::Stop);
            }
            _ => {}
        }
        let Step::Braking { since, then } = self.step else {
            return None;
        };
        if !stands(view) && now.saturating_duration_since(since) < BRAKE_LIMIT {
            return None;
        }
        let moves = match then {
            After::Sweep => {
                self.step = Step::Sweeping;
                self.sweep(view.pose)
            }
            After::Align => {
                self.step = Step::Aligning;
                let moves = self.align(view.pose, track);
                self.align_turns = moves
                    .iter()
                    .filter(|m| matches!(m, MoveCommand::Rotate { .. }))
                    .copied()
                    .collect();
                moves
            }
        };
        self.outstanding += moves.len();
        Some(Action::Moves(moves))
    }

    /// Moves outstanding while the robot stands with an empty queue: their ends will not come
    /// (a stop sent after them dropped them, and a dropped move's end counts for nothing). After
    /// [`STALLED_AFTER`] the routine goes on as if they had ended: a sweep that ran out found no
    /// tape, an alignment drives on to the follow. Without it the routine waited for good, the
    /// robot stopped and every intent for it held, until the run's time ran out.
    fn catch_stall(&mut self, view: &RobotView, now: Instant) {
        let idle = matches!(self.step, Step::Sweeping | Step::Aligning)
            && self.outstanding > 0
            && self.pending.is_empty()
            && view.state.locomotion.queue_len == 0
            && stands(view);
        if !idle {
            self.idle_since = None;
            return;
        }
        let since = *self.idle_since.get_or_insert(now);
        if now.saturating_duration_since(since) < STALLED_AFTER {
            return;
        }
        self.idle_since = None;
        self.outstanding = 0;
        if self.step == Step::Sweeping {
            self.step = Step::GaveUp;
        }
    }

    /// Takes one update of the follow, `driven` along it so far: whether the robot has followed
    /// [`CREEP_M`] and now drives straight along the tape, centred on it.
    fn settled_at(&mut self, driven: f64, view: &RobotView) -> bool {
        let theta = view.odometry.theta;
        self.trail.push_back((driven, theta));
        while self.trail.len() > 2 && driven - self.trail[1].0 >= SETTLE_M {
            self.trail.pop_front();
        }
        let line = view.state.line;
        let spans = self
            .trail
            .front()
            .is_some_and(|&(d, _)| driven - d >= SETTLE_M);
        let turned = self
            .trail
            .iter()
            .map(|&(_, t)| wrap_angle(t - theta).abs())
            .fold(0.0, f64::max);
        driven >= f64::from(CREEP_M)
            && spans
            && turned < SETTLE_RAD
            && line.flags & LINE_LOST == 0
            && line.position_um.abs() <= SETTLE_LINE_UM
    }

    /// Face across the tape, the way nearer the robot's heading; out to the side the model puts
    /// the tape on, through it as far as the reach, back through to the reach on the other side,
    /// and back. The sensor leads the centre by 16 mm, so each leg goes that much farther: the
    /// sensor then covers the reach on both sides. Near the arena's edge a side is searched only
    /// as far as the robot can go (the safety check would hold the whole leg).
    fn sweep(&self, pose: Pose) -> Vec<MoveCommand> {
        let across = Vector2::new(-self.tape.y, self.tape.x);
        let reach = self.reach_m + LINE_SENSOR_AHEAD_M;
        let mut moves = Vec::new();
        let mut at = [pose.x, pose.y];
        let mut theta = pose.theta;
        if let Some((away, by)) = self.leave {
            let by = by.min(room_along(at, [away.x, away.y], self.room));
            if by > 0.002 {
                let facing = away.y.atan2(away.x);
                moves.push(turn_to(theta, facing));
                moves.push(straight(by as f32));
                theta = facing;
                at = [at[0] + away.x * by, at[1] + away.y * by];
            }
        }
        // Turning the short way keeps the corners' sweep away from a robot beside this one.
        let heading = Vector2::new(theta.cos(), theta.sin());
        let dir = if heading.dot(&across) >= 0.0 {
            across
        } else {
            -across
        };
        // A robot lost well off the tape (beside a box it pushed) is searched for up to the
        // tape and beyond it, the way it is most likely to be, before the other side.
        let start = Point2::new(at[0], at[1]);
        let to_tape = (self.tape_at - start).dot(&dir);
        let ahead = (to_tape.max(0.0) + reach).min(room_along(at, [dir.x, dir.y], self.room));
        let behind = (reach - to_tape.min(0.0)).min(room_along(at, [-dir.x, -dir.y], self.room));
        let (first, second) = if to_tape >= 0.0 {
            (ahead, -behind)
        } else {
            (-behind, ahead)
        };
        // A turn of a degree or two means nothing to a robot whose heading is lost by 15° or
        // more, and beside a neighbour the safety check holds any turn of a lost robot.
        let facing = dir.y.atan2(dir.x);
        if wrap_angle(facing - theta).abs() > SMALL_TURN_RAD {
            moves.push(turn_to(theta, facing));
        }
        moves.extend([
            straight(first as f32),
            straight((second - first) as f32),
            straight(-second as f32),
        ]);
        moves
    }

    /// Drive the centre onto the tape the model now places the robot beside, face along it the
    /// way the robot drove, and creep forward so the sensor runs along it.
    fn align(&self, pose: Pose, track: &Track) -> Vec<MoveCommand> {
        let centre = Point2::new(pose.x, pose.y);
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let Some(n) = track.nearest(centre) else {
            return Vec::new();
        };
        let onto = heading.dot(&(n.point - centre)) as f32;
        let before = Vector2::new(self.heading.cos(), self.heading.sin());
        let along = if n.tangent.dot(&before) >= 0.0 {
            n.tangent
        } else {
            -n.tangent
        };
        let mut moves = Vec::new();
        if onto.abs() > 0.002 {
            moves.push(straight(onto));
        }
        moves.push(turn_to(pose.theta, along.y.atan2(along.x)));
        moves
    }
}

/// Whether both of the robot's wheels have stopped.
fn stands(view: &RobotView) -> bool {
    let w = view.state.wheels;
    w.left_mps.abs() < STOPPED_MPS && w.right_mps.abs() < STOPPED_MPS
}

/// How far from `at` along the unit `dir` a point stays within `room` (lower and upper corners);
/// 0 when it is outside already.
fn room_along(at: [f64; 2], dir: [f64; 2], room: ([f64; 2], [f64; 2])) -> f64 {
    let mut t = f64::INFINITY;
    for a in 0..2 {
        if dir[a] > 1e-12 {
            t = t.min((room.1[a] - at[a]) / dir[a]);
        } else if dir[a] < -1e-12 {
            t = t.min((room.0[a] - at[a]) / dir[a]);
        }
    }
    t.max(0.0)
}

/// The sweep skips a turn to face across the tape smaller than this.
const SMALL_TURN_RAD: f64 = 2.0 * std::f64::consts::PI / 180.0;

fn straight(distance_m: f32) -> MoveCommand {
    MoveCommand::Straight {
        distance_m,
        speed_mps: SEARCH_MPS,
    }
}

fn turn_to(from: f64, to: f64) -> MoveCommand {
    let a = wrap_angle(to - from);
    MoveCommand::Rotate {
        angle_deg: a.to_degrees() as f32,
        speed_mps: TURN_MPS,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use world::presets;

    const ROOM: ([f64; 2], [f64; 2]) = ([0.0, 0.0], [10.0, 10.0]);

    /// Finishes `n` moves of the routine.
    fn finish(r: &mut Relocaliser, n: usize) {
        for _ in 0..n {
            r.move_finished(true);
        }
    }

    /// The distances of moves that must all be straight.
    fn straights(moves: &[MoveCommand]) -> Vec<f32> {
        moves
            .iter()
            .map(|m| match m {
                MoveCommand::Straight { distance_m, .. } => *distance_m,
                other => panic!("{other:?}"),
            })
            .collect()
    }

    fn view(x: f64, y: f64, theta: f64) -> RobotView {
        RobotView {
            id: 1,
            pose: Pose { x, y, theta },
            uncertainty: behaviour_api::PoseUncertainty {
                position_m: 0.02,
                heading_rad: 0.05,
            },
            ..Default::default()
        }
    }

    /// The routine started for `lost` in `room` on the 4 × 4 grid, and the sweep it sends once
    /// the robot has stopped.
    fn swept(lost: &RobotView, room: ([f64; 2], [f64; 2])) -> (Relocaliser, Vec<MoveCommand>) {
        let world = presets::grid(4, 4, 1);
        let now = Instant::now();
        let (mut r, _) = Relocaliser::start(lost, &world.track, &[], room, now);
        let Some(Action::Moves(sweep)) = r.poll(lost, &world.track, now) else {
            panic!("a stopped robot sweeps at once");
        };
        (r, sweep)
    }

    /// Lost 25 mm beside a tape along x: stop, sweep across it towards the tape first, as far as
    /// three sigmas beyond it, and once the tape fixes the position, onto it and facing the way
    /// the robot drove.
    #[test]
    fn the_routine_sweeps_across_the_tape_then_puts_the_robot_back_on_it() {
        let world = presets::grid(4, 4, 1);
        let now = Instant::now();
        let lost = view(0.3, 0.225, 0.1);
        let (mut r, first) = Relocaliser::start(&lost, &world.track, &[], ROOM, now);
        assert_eq!(first, Action::Stop);
        let Some(Action::Moves(sweep)) = r.poll(&lost, &world.track, now) else {
            panic!("a stopped robot sweeps at once");
        };
        let MoveCommand::Rotate { angle_deg, .. } = sweep[0] else {
            panic!("{sweep:?}");
        };
        // The tape runs along x: from a heading of 0.1 rad, face +y, the nearer way across it.
        assert!((f64::from(angle_deg) - (90.0 - 0.1f64.to_degrees())).abs() < 1e-3);
        // The tape is 25 mm behind: back through it to 60 mm (3σ) and the sensor's 16 mm
        // beyond, then forwards to as far on the other side of the model's mean, and back.
        let reaches = straights(&sweep[1..]);
        assert_eq!(reaches, vec![-0.101, 0.177, -0.076]);
        // The tape is found: stop, then align from the fixed pose (facing +y, centre 16 mm
        // below the tape at y = 0.2).
        assert_eq!(r.fixed(now), Action::Stop);
        let fixed = view(0.3, 0.184, std::f64::consts::FRAC_PI_2);
        let Some(Action::Moves(align)) = r.poll(&fixed, &world.track, now) else {
            panic!("aligning");
        };
        let MoveCommand::Straight { distance_m, .. } = align[0] else {
            panic!("{align:?}");
        };
        assert!((distance_m - 0.016).abs() < 1e-4, "{distance_m}");
        let MoveCommand::Rotate { angle_deg, .. } = align[1] else {
            panic!("{align:?}");
        };
        assert!(
            (angle_deg + 90.0).abs() < 1e-3,
            "faces +x as it drove: {angle_deg}"
        );
        assert!(!r.aligned());
        finish(&mut r, align.len());
        // Then it follows the tape for a few centimetres, and stops.
        assert_eq!(
            r.poll(&fixed, &world.track, now),
            Some(Action::Follow(SEARCH_MPS))
        );
        assert!(!r.aligned());
        assert_eq!(r.poll(&fixed, &world.track, now), None);
        let mut on = fixed.clone();
        on.odometry.x += 0.031;
        assert_eq!(r.poll(&on, &world.track, now), Some(Action::Stop));
        assert!(r.aligned() && !r.gave_up());
    }

    /// A sweep leg the safety check keeps holding is halved every few holds, so the side it
    /// points at is searched as far as the robot may go rather than not at all.
    #[test]
    fn a_sweep_leg_held_again_and_again_is_shortened() {
        let world = presets::grid(4, 4, 1);
        let now = Instant::now();
        let lost = view(0.3, 0.225, 0.1);
        let (mut r, sweep) = swept(&lost, ROOM);
        finish(&mut r, 2);
        let mut pending = sweep[2..].to_vec();
        let through = straights(&pending)[0];
        let mut t = now;
        let mut legs = Vec::new();
        for _ in 0..3 * SHORTEN_AFTER {
            r.held(pending.clone(), t);
            t += RETRY_AFTER;
            let Some(Action::Moves(again)) = r.poll(&lost, &world.track, t) else {
                panic!("tried again");
            };
            legs.push(straights(&again)[0]);
            pending = again;
        }
        let n = SHORTEN_AFTER as usize;
        assert_eq!(legs[0], through, "{legs:?}");
        assert_eq!(legs[n - 1], through / 2.0, "{legs:?}");
        assert_eq!(legs[2 * n - 1], through / 4.0, "{legs:?}");
        assert_eq!(legs[3 * n - 1], through / 8.0, "{legs:?}");
        // The rest of the sweep still follows, unchanged.
        assert_eq!(straights(&pending)[1], straights(&sweep[3..])[0]);
        assert!(!r.gave_up());
    }

    /// Near the arena's edge the sweep goes only as far as the robot may: the side towards the
    /// wall is searched up to it, the other side in full.
    #[test]
    fn a_sweep_by_the_wall_stops_at_the_room_the_robot_has() {
        // Lost beside the tape at y = 0.2, its centre allowed no lower than y = 0.18.
        let lost = view(0.3, 0.205, 0.0);
        let (_, sweep) = swept(&lost, ([0.05, 0.18], [1.0, 1.0]));
        let legs = straights(&sweep[1..]);
        // Facing +y: first down towards the tape, which the side towards y = 0.18 leaves 25 mm
        // for, then up to the full 76 mm.
        let expected = [-0.025, 0.101, -0.076];
        assert!(
            legs.iter().zip(expected).all(|(l, e)| (l - e).abs() < 1e-4),
            "{legs:?}"
        );
    }

    /// A robot lost 10 cm beside the tape (beside a box it pushed) is searched for up to the
    /// tape and beyond it first, then as far on its other side.
    #[test]
    fn a_robot_lost_well_off_the_tape_is_searched_for_towards_it_first() {
        // The tape along y = 0.2 lies 10 cm below; the robot faces +y.
        let lost = view(0.3, 0.3, 1.5);
        let (_, sweep) = swept(&lost, ROOM);
        let legs = straights(&sweep[1..]);
        let expected = [-0.176, 0.252, -0.076];
        assert!(
            legs.iter().zip(expected).all(|(l, e)| (l - e).abs() < 1e-4),
            "to the tape and 76 mm beyond, then 76 mm beyond the mean: {legs:?}"
        );
    }

    /// A sweep that ends without a tape gives up: the robot stays where it stopped.
    #[test]
    fn a_sweep_that_finds_nothing_gives_up() {
        let lost = view(0.3, 0.3, 0.0);
        let (mut r, sweep) = swept(&lost, ROOM);
        // The stop's aborted moves do not count.
        r.move_finished(false);
        for _ in &sweep {
            assert!(!r.gave_up());
            r.move_finished(true);
        }
        assert!(r.gave_up());
    }

    /// Lost at a fork, where no sighting fixes a robot: the search first drives along the tape
    /// out of the junction's zone, then sweeps across the tape there.
    #[test]
    fn a_search_that_starts_in_a_junction_zone_first_leaves_it() {
        let world = presets::preset("junction").unwrap();
        let model = crate::WorldModel::new(std::sync::Arc::new(world.track.clone()));
        let fork = model
            .junctions()
            .iter()
            .copied()
            .find(|(j, _)| (j.x - 0.45).abs() < 1e-6 && (j.y - 0.15).abs() < 1e-6)
            .expect("the fork F is a junction");
        let now = Instant::now();
        // 1.5 cm east of the fork, facing west-south-west.
        let lost = view(0.465, 0.15, 3.6);
        let (mut r, _) = Relocaliser::start(&lost, &world.track, model.junctions(), ROOM, now);
        let Some(Action::Moves(moves)) = r.poll(&lost, &world.track, now) else {
            panic!("a stopped robot searches at once");
        };
        // Faces east, away from the fork, and drives out of its zone before it sweeps.
        let MoveCommand::Rotate { angle_deg, .. } = moves[0] else {
            panic!("{moves:?}");
        };
        let facing = wrap_angle(3.6 + f64::from(angle_deg).to_radians());
        assert!(facing.abs() < 0.01, "{facing}");
        let MoveCommand::Straight { distance_m, .. } = moves[1] else {
            panic!("{moves:?}");
        };
        let end = 0.465 + f64::from(distance_m);
        assert!(end - 0.45 > fork.1, "ends at {end}, zone {:?}", fork);
        assert!(end - 0.45 < fork.1 + 0.03, "ends at {end}, zone {:?}", fork);
        assert!(
            matches!(moves[2], MoveCommand::Rotate { .. }) && moves.len() == 6,
            "{moves:?}"
        );
        // Away from every junction, the sweep starts where the robot stands.
        let plain = view(0.65, 0.15, 0.0);
        let (mut r, _) = Relocaliser::start(&plain, &world.track, model.junctions(), ROOM, now);
        let Some(Action::Moves(moves)) = r.poll(&plain, &world.track, now) else {
            panic!("a stopped robot searches at once");
        };
        assert_eq!(moves.len(), 4, "{moves:?}");
    }

    /// A robot lost on the grid, fixed across a tape and aligned along it: its routine has just
    /// started the follow. Returns the routine and the robot's view there.
    fn following(track: &Track, now: Instant) -> (Relocaliser, RobotView) {
        let lost = view(0.3, 0.225, 0.1);
        let (mut r, _) = swept(&lost, ROOM);
        r.fixed(now);
        let fixed = view(0.3, 0.184, std::f64::consts::FRAC_PI_2);
        let Some(Action::Moves(align)) = r.poll(&fixed, track, now) else {
            panic!("aligning");
        };
        finish(&mut r, align.len());
        assert_eq!(r.follow_reach(), None, "not before the follow");
        assert_eq!(r.poll(&fixed, track, now), Some(Action::Follow(SEARCH_MPS)));
        (r, fixed)
    }

    /// The follow goes on past the creep while the follower still turns the robot onto the
    /// tape, and ends once it drives straight along it (then it faces along the tape); one that
    /// never settles ends at the longest follow, not settled.
    #[test]
    fn the_follow_ends_once_the_robot_drives_straight_along_the_tape() {
        let world = presets::grid(4, 4, 1);
        let now = Instant::now();
        let follow = |turning_mm: u32| {
            let (mut r, fixed) = following(&world.track, now);
            // The follower turns it by half a degree per millimetre for `turning_mm`.
            let mut v = fixed.clone();
            for mm in 1..200 {
                v.odometry.x = f64::from(mm) * 0.001;
                v.odometry.theta = -(f64::from(mm.min(turning_mm)) * 0.5).to_radians();
                if let Some(a) = r.poll(&v, &world.track, now) {
                    assert_eq!(a, Action::Stop);
                    return (mm, r.settled());
                }
            }
            panic!("the follow never ended");
        };
        // Straight from the start: it ends at the creep.
        assert_eq!(follow(0), (30, true));
        // Turning for 40 mm: it ends once 15 mm of it turned less than 2°.
        let (mm, settled) = follow(40);
        assert!(settled && (50..=52).contains(&mm), "{mm}");
        // Turning all the way: it ends at the longest follow, not settled.
        assert_eq!(follow(500), (80, false));
    }

    /// The reflex stops the nudge onto the tape (something close ahead on it): the robot
    /// stands on the tape it found, so the routine sends the turn along the tape again and goes
    /// on to the follow instead of searching afresh; in a sweep the same stop still ends it.
    #[test]
    fn a_nudge_onto_the_tape_stopped_by_the_reflex_costs_only_the_nudge() {
        let world = presets::grid(4, 4, 1);
        let now = Instant::now();
        let lost = view(0.3, 0.225, 0.1);
        let (mut r, _) = swept(&lost, ROOM);
        r.fixed(now);
        let fixed = view(0.3, 0.184, 0.3);
        let Some(Action::Moves(align)) = r.poll(&fixed, &world.track, now) else {
            panic!("aligning");
        };
        let turns: Vec<MoveCommand> = align
            .iter()
            .filter(|m| matches!(m, MoveCommand::Rotate { .. }))
            .copied()
            .collect();
        assert!(align.len() > turns.len() && !turns.is_empty(), "{align:?}");
        r.blocked(now);
        assert!(!r.gave_up());
        assert_eq!(
            r.poll(&fixed, &world.track, now),
            Some(Action::Moves(turns.clone()))
        );
        finish(&mut r, turns.len());
        assert_eq!(
            r.poll(&fixed, &world.track, now),
            Some(Action::Follow(SEARCH_MPS))
        );
        let (mut sweeping, _) = swept(&lost, ROOM);
        sweeping.blocked(now);
        assert!(sweeping.gave_up());
    }

    /// Sweep moves whose ends never come (a later stop dropped them) while the robot stands
    /// with an empty queue: after a while the sweep counts as run out; a robot that still has
    /// moves queued is waited for.
    #[test]
    fn a_sweep_whose_moves_were_dropped_does_not_wait_for_ever() {
        let world = presets::grid(4, 4, 1);
        let now = Instant::now();
        let lost = view(0.3, 0.225, 0.1);
        let (mut r, sweep) = swept(&lost, ROOM);
        assert!(!sweep.is_empty());
        let mut queued = lost.clone();
        queued.state.locomotion.queue_len = 2;
        let later = now + STALLED_AFTER + Duration::from_millis(100);
        assert_eq!(r.poll(&queued, &world.track, now), None);
        assert_eq!(r.poll(&queued, &world.track, later), None);
        assert!(!r.gave_up(), "a robot with moves queued is waited for");
        // Standing with an empty queue from `later` on.
        assert_eq!(r.poll(&lost, &world.track, later), None);
        assert!(!r.gave_up(), "not at once");
        r.poll(&lost, &world.track, later + STALLED_AFTER);
        assert!(r.gave_up(), "the sweep ran out");
    }

    /// A follow the supervisor held is started again after the retry pause, and only a follow
    /// under way says how far ahead it may take the robot.
    #[test]
    fn a_held_follow_is_started_again_later() {
        let world = presets::grid(4, 4, 1);
        let now = Instant::now();
        let (mut r, fixed) = following(&world.track, now);
        assert_eq!(r.follow_reach(), Some(FOLLOW_MOST_M));
        r.follow_held(now);
        assert_eq!(r.follow_reach(), None);
        assert_eq!(
            r.poll(&fixed, &world.track, now),
            None,
            "waits before it tries again"
        );
        let later = now + RETRY_AFTER;
        assert_eq!(
            r.poll(&fixed, &world.track, later),
            Some(Action::Follow(SEARCH_MPS))
        );
    }
}
