//! Move sequences computed from poses: drive to a point, turn to a heading. Behaviours plan
//! manoeuvres off the tape with these and hand them to the robots' own locomotion, either all at
//! once ([`Manoeuvre`], open-loop) or one move at a time from the robot's latest pose ([`Legs`]).

use std::collections::VecDeque;
use std::f64::consts::PI;

use protocol::MoveCommand;
use world::Pose;

pub use world::wrap_angle as wrap;

/// Moves and the pose they are meant to end at, built step by step from a start pose.
#[derive(Clone, Debug, PartialEq)]
pub struct Manoeuvre {
    /// The moves so far.
    pub moves: Vec<MoveCommand>,
    /// Where they end.
    pub end: Pose,
    speed_mps: f32,
}

impl Manoeuvre {
    /// An empty route from `start`, driving and turning at `speed_mps`.
    pub fn from(start: Pose, speed_mps: f32) -> Self {
        Self {
            moves: Vec::new(),
            end: start,
            speed_mps,
        }
    }

    /// Turns in place to `heading` (the short way); turns under 0.5° are skipped.
    pub fn turn_to(mut self, heading: f64) -> Self {
        let d = wrap(heading - self.end.theta);
        if d.abs() > 0.5f64.to_radians() {
            self.moves.push(MoveCommand::Rotate {
                angle_deg: d.to_degrees() as f32,
                speed_mps: self.speed_mps,
            });
        }
        self.end.theta = heading;
        self
    }

    /// Drives straight by `d` metres (negative backs up).
    pub fn straight(mut self, d: f64) -> Self {
        if d.abs() > 1e-4 {
            self.moves.push(MoveCommand::Straight {
                distance_m: d as f32,
                speed_mps: self.speed_mps,
            });
        }
        let (s, c) = self.end.theta.sin_cos();
        self.end.x += d * c;
        self.end.y += d * s;
        self
    }

    /// Turns towards `(x, y)` and drives there.
    pub fn to(self, x: f64, y: f64) -> Self {
        let (dx, dy) = (x - self.end.x, y - self.end.y);
        let d = dx.hypot(dy);
        if d < 1e-4 {
            return self;
        }
        self.turn_to(dy.atan2(dx)).straight(d)
    }

    /// Backs straight onto `(x, y)`, which must lie behind the robot: its heading is kept.
    pub fn back_to(self, x: f64, y: f64) -> Self {
        let (s, c) = self.end.theta.sin_cos();
        let along = (x - self.end.x) * c + (y - self.end.y) * s;
        self.straight(along)
    }
}

/// A point closer than this counts as reached.
const REACHED_M: f64 = 0.004;
/// Once driven towards, a point closer than this is not worth another turn.
const NEAR_M: f64 = 0.015;
/// Headings within this of the wanted one need no turn: the wheels' encoders resolve about 1.6°
/// of turn per pulse, and a turn much smaller than a few pulses overshoots.
const ALIGNED_RAD: f64 = 5.0 * PI / 180.0;
/// Turns smaller than this go slowly, so that the wheels' coast after the move is short.
const SMALL_TURN_RAD: f64 = 20.0 * PI / 180.0;
/// Speed of small turns, m/s at the wheels.
const SMALL_TURN_MPS: f32 = 0.03;
/// Turns, and drives, spent on one leg before it counts as done as far as it can be.
const MAX_TURNS: u8 = 3;
const MAX_DRIVES: u8 = 2;

/// One leg of a manoeuvre planned in world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Leg {
    /// Straight by a signed distance from wherever the robot is.
    Straight(f64),
    /// Turn to face the point, then drive to it.
    To {
        /// Metres.
        x: f64,
        /// Metres.
        y: f64,
    },
    /// Turn in place to a heading, radians.
    Face(f64),
}

/// Legs driven closed-loop: each move is computed from the robot's pose once the previous one
/// has finished and the robot has come to rest, so a turn that came out a few degrees off is
/// corrected on the next leg instead of being carried through the rest of the manoeuvre (an
/// open-loop detour around a box once ended 23 mm beside the tape, and the line follower then
/// took the tape the wrong way).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Legs {
    legs: VecDeque<Leg>,
    turns: u8,
    drives: u8,
    /// What the last move was, for [`Legs::held`]: a turn (`true`) or a drive.
    last_turn: bool,
    speed_mps: f32,
}

impl Legs {
    /// No legs; moves at `speed_mps`.
    pub fn new(speed_mps: f32) -> Self {
        Self {
            speed_mps,
            ..Self::default()
        }
    }

    /// Appends a leg.
    pub fn push(&mut self, leg: Leg) {
        self.legs.push_back(leg);
    }

    /// Puts a leg before the ones still to drive (a back-off before a held turn); the leg it
    /// goes before starts afresh after it.
    pub fn push_front(&mut self, leg: Leg) {
        self.legs.push_front(leg);
        self.turns = 0;
        self.drives = 0;
    }

    /// Whether every leg is done.
    pub fn is_empty(&self) -> bool {
        self.legs.is_empty()
    }

    /// Drops every leg.
    pub fn clear(&mut self) {
        self.legs.clear();
        self.turns = 0;
        self.drives = 0;
    }

    /// The next move from `pose` (where the robot rests), or `None` once every leg is done.
    pub fn next(&mut self, pose: Pose) -> Option<MoveCommand> {
        loop {
            let leg = *self.legs.front()?;
            let err = match leg {
                Leg::Straight(d) => {
                    if self.drives > 0 {
                        self.pop();
                        continue;
                    }
                    return Some(self.drive(d));
                }
                Leg::To { x, y } => {
                    let (dx, dy) = (x - pose.x, y - pose.y);
                    let d = dx.hypot(dy);
                    let err = wrap(dy.atan2(dx) - pose.theta);
                    if d < REACHED_M || (self.drives > 0 && d < NEAR_M) || self.drives >= MAX_DRIVES
                    {
                        self.pop();
                        continue;
                    }
                    if err.abs() <= ALIGNED_RAD || self.turns >= MAX_TURNS {
                        return Some(self.drive(d * err.cos()));
                    }
                    err
                }
                Leg::Face(h) => {
                    let err = wrap(h - pose.theta);
                    if err.abs() <= ALIGNED_RAD || self.turns >= MAX_TURNS {
                        self.pop();
                        continue;
                    }
                    err
                }
            };
            self.turns += 1;
            self.last_turn = true;
            let speed_mps = if err.abs() < SMALL_TURN_RAD {
                SMALL_TURN_MPS.min(self.speed_mps)
            } else {
                self.speed_mps
            };
            return Some(MoveCommand::Rotate {
                angle_deg: err.to_degrees() as f32,
                speed_mps,
            });
        }
    }

    /// The last move from [`Legs::next`] never ran (the safety check held it): it does not
    /// count.
    pub fn held(&mut self) {
        if self.last_turn {
            self.turns = self.turns.saturating_sub(1);
        } else {
            self.drives = self.drives.saturating_sub(1);
        }
    }

    fn drive(&mut self, d: f64) -> MoveCommand {
        self.drives += 1;
        self.last_turn = false;
        MoveCommand::Straight {
            distance_m: d as f32,
            speed_mps: self.speed_mps,
        }
    }

    fn pop(&mut self) {
        self.legs.pop_front();
        self.turns = 0;
        self.drives = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn a_route_ends_where_it_says() {
        let r = Manoeuvre::from(
            Pose {
                x: 0.0,
                y: 0.0,
                theta: 0.0,
            },
            0.1,
        )
        .to(0.0, 0.1)
        .to(0.2, 0.1)
        .turn_to(-FRAC_PI_2)
        .back_to(0.2, 0.3);
        assert_eq!(r.moves.len(), 6);
        assert!((r.end.x - 0.2).abs() < 1e-12 && (r.end.y - 0.3).abs() < 1e-12);
        assert!(matches!(
            r.moves[0],
            MoveCommand::Rotate { angle_deg, .. } if (angle_deg - 90.0).abs() < 1e-4
        ));
        assert!(matches!(
            r.moves[5],
            MoveCommand::Straight { distance_m, .. } if (distance_m + 0.2).abs() < 1e-6
        ));
        assert_eq!(wrap(3.0 * PI), PI);
    }

    /// Drives a command on an ideal unicycle whose turns come out `slip` short.
    fn drive(p: &mut Pose, m: MoveCommand, slip: f64) {
        match m {
            MoveCommand::Straight { distance_m, .. } => {
                p.x += f64::from(distance_m) * p.theta.cos();
                p.y += f64::from(distance_m) * p.theta.sin();
            }
            MoveCommand::Rotate { angle_deg, .. } => {
                p.theta += f64::from(angle_deg).to_radians() * (1.0 - slip);
            }
            _ => unreachable!("legs only drive and turn"),
        }
    }

    #[test]
    fn legs_correct_short_turns_on_the_way() {
        let mut legs = Legs::new(0.08);
        legs.push(Leg::Straight(-0.01));
        legs.push(Leg::To { x: -0.01, y: -0.05 });
        legs.push(Leg::To { x: 0.115, y: -0.05 });
        legs.push(Leg::To { x: 0.115, y: 0.0 });
        legs.push(Leg::Face(0.0));
        let mut p = Pose {
            x: 0.0,
            y: 0.0,
            theta: 0.0,
        };
        let mut moves = 0;
        while let Some(m) = legs.next(p) {
            // Every turn comes out 15 % short, as turns in place on a slippery floor do.
            drive(&mut p, m, 0.15);
            moves += 1;
            assert!(moves < 30, "legs never end");
        }
        assert!((p.x - 0.115).hypot(p.y) < 0.006, "ended at {p:?}");
        assert!(
            wrap(p.theta).abs() < ALIGNED_RAD + 1e-9,
            "heading {}",
            p.theta
        );
    }
}
