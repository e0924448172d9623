//! Move sequences computed from poses: drive to a point, turn to a heading. Behaviours plan
//! manoeuvres off the tape with these and hand them to the robots' own locomotion.

use std::f64::consts::{PI, TAU};

use robot_actor::{MoveCommand, Pose};

/// Wraps an angle into (−π, π].
pub fn wrap(a: f64) -> f64 {
    let w = (a + PI).rem_euclid(TAU) - PI;
    if w == -PI {
        PI
    } else {
        w
    }
}

/// Moves and the pose they are meant to end at, built step by step from a start pose.
#[derive(Clone, Debug, PartialEq)]
pub struct Route {
    /// The moves so far.
    pub moves: Vec<MoveCommand>,
    /// Where they end.
    pub end: Pose,
    speed_mps: f32,
}

impl Route {
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn a_route_ends_where_it_says() {
        let r = Route::from(
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
}
