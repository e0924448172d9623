//! The supervisor's predictive safety check: an intent that would drive a robot into another robot
//! or out of the arena is held back. Poses are the world model's; the check looks along the
//! straight path a move or a wheel-speed command would take.

use behaviours::{Intent, MoveCommand, WorldSnapshot};

/// Tunables of the check.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Safety {
    /// Robots are discs of this radius for the check, metres (a 48 × 32 mm body fits in 29 mm).
    pub radius_m: f64,
    /// How far ahead a wheel-speed command is extrapolated, seconds.
    pub horizon_s: f64,
}

impl Default for Safety {
    fn default() -> Self {
        Self {
            radius_m: 0.03,
            horizon_s: 0.5,
        }
    }
}

impl Safety {
    /// `Ok` when the intent is safe in `world`, else why not.
    pub fn check(&self, intent: &Intent, world: &WorldSnapshot) -> Result<(), String> {
        let Some(me) = world.robot(intent.robot()) else {
            return Err(format!("robot {} is not in the experiment", intent.robot()));
        };
        let p = me.pose;
        let (s, c) = p.theta.sin_cos();
        let travel = match *intent {
            Intent::Move {
                command: MoveCommand::Straight { distance_m, .. },
                ..
            } => f64::from(distance_m),
            Intent::Move {
                command:
                    MoveCommand::Arc {
                        radius_m,
                        angle_deg,
                        ..
                    },
                ..
            } => {
                // The chord of the arc, as a straight-line stand-in.
                2.0 * f64::from(radius_m) * (f64::from(angle_deg).to_radians() * 0.5).sin().abs()
            }
            Intent::WheelSpeeds { left, right, .. } => {
                f64::from(left + right) * 0.5 * self.horizon_s
            }
            _ => return Ok(()),
        };
        if travel == 0.0 {
            return Ok(());
        }
        let end = (p.x + travel * c, p.y + travel * s);
        let r = self.radius_m;
        let (w, h) = world.arena;
        if end.0 < r || end.1 < r || end.0 > w - r || end.1 > h - r {
            return Err(format!(
                "robot {} would leave the arena at ({:.3}, {:.3})",
                me.id, end.0, end.1
            ));
        }
        for other in world.robots.iter().filter(|o| o.id != me.id) {
            let d = segment_point_distance((p.x, p.y), end, (other.pose.x, other.pose.y));
            if d < 2.0 * r {
                return Err(format!(
                    "robot {} would pass {:.0} mm from robot {}",
                    me.id,
                    d * 1e3,
                    other.id
                ));
            }
        }
        Ok(())
    }
}

fn segment_point_distance(a: (f64, f64), b: (f64, f64), p: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a.0 + t * dx - p.0).hypot(a.1 + t * dy - p.1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use behaviours::{Pose, RobotView};

    fn world(robots: &[(u16, f64, f64, f64)]) -> WorldSnapshot {
        WorldSnapshot {
            time: Default::default(),
            robots: robots
                .iter()
                .map(|&(id, x, y, theta)| RobotView {
                    id,
                    connected: true,
                    pose: Pose { x, y, theta },
                    odometry: Default::default(),
                    state: Default::default(),
                    pending_moves: 0,
                    on_track: None,
                })
                .collect(),
            encounters: Vec::new(),
            arena: (1.0, 1.0),
        }
    }

    fn straight(robot: u16, d: f32) -> Intent {
        Intent::Move {
            robot,
            command: MoveCommand::Straight {
                distance_m: d,
                speed_mps: 0.2,
            },
        }
    }

    #[test]
    fn holds_back_a_move_into_another_robot_or_a_wall() {
        let s = Safety::default();
        let w = world(&[(1, 0.3, 0.5, 0.0), (2, 0.45, 0.5, 0.0), (3, 0.3, 0.2, 0.0)]);
        assert!(
            s.check(&straight(1, 0.1), &w).is_err(),
            "robot 2 is in the way"
        );
        assert!(
            s.check(&straight(1, -0.1), &w).is_ok(),
            "backing away is fine"
        );
        assert!(s.check(&straight(3, 0.5), &w).is_ok());
        assert!(s.check(&straight(3, 0.8), &w).is_err(), "out of the arena");
        let spin = Intent::Move {
            robot: 1,
            command: MoveCommand::Rotate {
                angle_deg: 90.0,
                speed_mps: 0.1,
            },
        };
        assert!(s.check(&spin, &w).is_ok());
        assert!(s
            .check(
                &Intent::WheelSpeeds {
                    robot: 1,
                    left: 0.3,
                    right: 0.3
                },
                &w
            )
            .is_err());
    }
}
