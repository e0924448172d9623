//! [`MoveCommand`]: a move for a robot's queue as the host names it, before it becomes one of the
//! movement packets (`StraightMovement`, `RotationMovement`, `ArcMovement`) with a move id.

/// A move for the robot's queue (thesis 6.5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MoveCommand {
    /// Straight, signed metres at `speed_mps`.
    Straight {
        /// Distance.
        distance_m: f32,
        /// Cruise speed.
        speed_mps: f32,
    },
    /// Turn in place, signed degrees (CCW positive).
    Rotate {
        /// Angle.
        angle_deg: f32,
        /// Wheel speed.
        speed_mps: f32,
    },
    /// Arc of `radius_m` turning `angle_deg`.
    Arc {
        /// Radius of the centre's path.
        radius_m: f32,
        /// Heading change.
        angle_deg: f32,
        /// Outer wheel speed.
        speed_mps: f32,
    },
}
