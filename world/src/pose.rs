//! A pose in the plane and angle wrapping, shared by the simulator's ground truth, the robot
//! actor's odometry and the coordinator's world model, so the three agree on one type.

use std::f64::consts::{PI, TAU};

/// Position and heading in the plane.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pose {
    /// x, metres.
    pub x: f64,
    /// y, metres.
    pub y: f64,
    /// Heading, radians counter-clockwise from +x, unwrapped (counts whole turns): a robot's
    /// odometry and true heading keep every turn it made.
    pub theta: f64,
}

impl Pose {
    /// `local`, a pose in this pose's frame (x ahead, y to the left), in the world frame.
    pub fn compose(self, local: Pose) -> Pose {
        let (s, c) = self.theta.sin_cos();
        Pose {
            x: self.x + c * local.x - s * local.y,
            y: self.y + s * local.x + c * local.y,
            theta: self.theta + local.theta,
        }
    }

    /// This pose in `origin`'s frame: `origin.compose(self.relative_to(origin))` is `self`.
    pub fn relative_to(self, origin: Pose) -> Pose {
        let (s, c) = origin.theta.sin_cos();
        let (dx, dy) = (self.x - origin.x, self.y - origin.y);
        Pose {
            x: c * dx + s * dy,
            y: -s * dx + c * dy,
            theta: self.theta - origin.theta,
        }
    }
}

/// Wraps an angle in radians into (−π, π].
///
/// A half turn is +π whichever way it was reached, so the sign of a turn computed from it does
/// not depend on rounding; every other angle comes out as `(a + π) mod 2π − π`, bit for bit.
pub fn wrap_angle(a: f64) -> f64 {
    let w = (a + PI).rem_euclid(TAU) - PI;
    if w == -PI {
        PI
    } else {
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn composing_a_relative_pose_gives_the_pose_back() {
        let origin = Pose {
            x: 1.0,
            y: -2.0,
            theta: 0.7,
        };
        let p = Pose {
            x: 1.3,
            y: -1.5,
            theta: -2.1,
        };
        let local = p.relative_to(origin);
        let back = origin.compose(local);
        assert!((back.x - p.x).abs() < 1e-12 && (back.y - p.y).abs() < 1e-12);
        assert!((back.theta - p.theta).abs() < 1e-12);
        // A point straight ahead of a robot facing +y lies at +y.
        let ahead = Pose {
            x: 0.0,
            y: 0.0,
            theta: PI / 2.0,
        }
        .compose(Pose {
            x: 0.1,
            y: 0.0,
            theta: 0.0,
        });
        assert!(ahead.x.abs() < 1e-12 && (ahead.y - 0.1).abs() < 1e-12);
    }

    #[test]
    fn wraps_into_minus_pi_exclusive_to_pi_inclusive() {
        assert_eq!(wrap_angle(0.0), 0.0);
        assert_eq!(wrap_angle(PI), PI);
        assert_eq!(wrap_angle(-PI), PI);
        assert_eq!(wrap_angle(3.0 * PI), PI);
        assert!((wrap_angle(TAU + 0.5) - 0.5).abs() < 1e-12);
        assert!((wrap_angle(-TAU - 0.5) + 0.5).abs() < 1e-12);
        for k in -1000..1000 {
            let w = wrap_angle(f64::from(k) * 0.37);
            assert!(w > -PI && w <= PI, "{k}: {w}");
        }
    }

    #[test]
    fn agrees_bit_for_bit_with_the_plain_formula_off_the_half_turn() {
        for k in -10_000..10_000 {
            let a = f64::from(k) * 0.001_3;
            let plain = (a + PI).rem_euclid(TAU) - PI;
            if plain != -PI {
                assert_eq!(wrap_angle(a).to_bits(), plain.to_bits(), "{a}");
            }
        }
    }
}
