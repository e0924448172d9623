//! The PocketBot2's geometry, defined once for every host crate: the simulator builds its bodies
//! and sensors from it, the world model places the line sensor with it, the safety check sizes
//! footprints with it. The firmware keeps its own copy in the robot's settings (it is `no_std` and
//! depends on no host crate); a unit test in the simulator pins the two together.
//!
//! Values are the thesis's (ch. 8) where it gives them, in metres and degrees.

/// Body length along the heading, metres (thesis: 48 mm).
pub const LENGTH_M: f64 = 0.048;
/// Body width across the heading, metres (thesis: 32 mm).
pub const WIDTH_M: f64 = 0.032;
/// Radius of the circle around the body: the body fits inside it at any heading, metres.
pub const RADIUS_M: f64 = 0.028_844_410_203_711_914; // hypot(0.024, 0.016)

/// How far ahead of the body centre the line sensor's centre sits, along the heading, metres: the
/// tape the robot sees is this far in front of the pose odometry reports.
pub const LINE_SENSOR_AHEAD_M: f64 = 0.016;
/// Distance between neighbouring line sensor spots, metres.
pub const LINE_SPOT_PITCH_M: f64 = 0.003;

/// Wheel diameter, metres (the settings' `geometry.wheel_diameter_m`).
pub const WHEEL_DIAMETER_M: f64 = 0.009;
/// Distance between the wheels' contact points (the wheel base or gauge), metres (the settings'
/// `geometry.wheel_gauge_m`).
pub const WHEEL_GAUGE_M: f64 = 0.026;

/// Directions of the six IR LEDs relative to the heading, degrees counter-clockwise: the front
/// three, then the rear three. An LED's index is the `led` of the packets that name one.
pub const IR_LED_ANGLE_DEG: [f64; 6] = [30.0, 0.0, -30.0, 150.0, 180.0, -150.0];
/// Half-angle of each IR LED's cone, degrees (thesis 7.1: ±15°).
pub const IR_CONE_HALF_DEG: f64 = 15.0;
/// Reach of each IR power level (1 to 4) to another robot's receiver, metres.
pub const IR_RANGE_M: [f64; 4] = [0.030, 0.060, 0.100, 0.150];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radius_encloses_the_body() {
        assert!((RADIUS_M - (LENGTH_M / 2.0).hypot(WIDTH_M / 2.0)).abs() < 1e-15);
    }
}
