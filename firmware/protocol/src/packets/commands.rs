//! Commands from the host: moves, stopping, teleoperation, line following and calibration, the
//! LED, the IR message word and the state reflector.

use crate::wire_struct;

wire_struct! {
    /// Drive straight (thesis fig. 9.2; code 0x40 and the first two fields as in the thesis).
    pub struct StraightMovement {
        /// Signed distance in metres (negative = backwards).
        pub distance_m: f32,
        /// Cruise speed in m/s.
        pub speed_mps: f32,
        /// Host-chosen id reported in [`MoveFinished`](super::MoveFinished).
        pub move_id: u16,
    }
}

wire_struct! {
    /// Turn in place.
    pub struct RotationMovement {
        /// Signed angle in degrees (positive = counter-clockwise).
        pub angle_deg: f32,
        /// Cruise wheel speed in m/s.
        pub speed_mps: f32,
        /// Host-chosen id reported in [`MoveFinished`](super::MoveFinished).
        pub move_id: u16,
    }
}

wire_struct! {
    /// Drive along a circular arc.
    pub struct ArcMovement {
        /// Radius of the robot centre's path in metres; the centre lies to the left for positive
        /// angles.
        pub radius_m: f32,
        /// Signed heading change in degrees (positive = counter-clockwise).
        pub angle_deg: f32,
        /// Cruise speed of the outer wheel in m/s.
        pub speed_mps: f32,
        /// Host-chosen id reported in [`MoveFinished`](super::MoveFinished).
        pub move_id: u16,
    }
}

wire_struct! {
    /// Drop every queued move; the running one stops smoothly.
    pub struct ClearQueue {
        /// Moves with this id or a later one (in the host's wrapping order) stay queued; 0 drops
        /// them all. The host sets it to its next move's id, so a ClearQueue sent again after a
        /// loss never drops a move queued after it.
        pub keep_from: u16,
    }
}

wire_struct! {
    /// Stop now: motors off, queue cleared, line following and teleop off.
    pub struct Stop {
        /// As in [`ClearQueue`]: moves with this id or a later one stay queued (and start, after
        /// the stop); 0 drops them all.
        pub keep_from: u16,
    }
}

wire_struct! {
    /// Teleop: hold these wheel speeds with the wheel PIDs.
    pub struct WheelSpeeds {
        /// Left wheel speed, m/s.
        pub left_mps: f32,
        /// Right wheel speed, m/s.
        pub right_mps: f32,
    }
}

wire_struct! {
    /// Teleop: apply these duties directly, no control loop.
    pub struct MotorPower {
        /// Left duty, permille.
        pub left_pwm: i16,
        /// Right duty, permille.
        pub right_pwm: i16,
    }
}

wire_struct! {
    /// Start or stop line following.
    pub struct LineFollow {
        /// 1 = follow, 0 = stop following.
        pub enable: u8,
        /// Following speed in m/s; 0 keeps the configured speed.
        pub speed_mps: f32,
    }
}

wire_struct! {
    /// A line sensor calibration step.
    pub struct LineCalibration {
        /// A [`CalibrationAction`](super::CalibrationAction) code.
        pub action: u8,
    }
}

wire_struct! {
    /// Set the RGB status LED.
    pub struct SetLed {
        /// Red.
        pub red: u8,
        /// Green.
        pub green: u8,
        /// Blue.
        pub blue: u8,
    }
}

wire_struct! {
    /// Attach a message to the robot's IR frames (0 = none); nearby robots report it.
    pub struct IrMessage {
        /// Message word.
        pub message: u16,
    }
}

wire_struct! {
    /// Configure the state reflector.
    pub struct ReflectorConfig {
        /// A [`ReflectorMode`](super::ReflectorMode) code.
        pub mode: u8,
        /// Period between state packets, milliseconds (minimum 1).
        pub period_ms: u16,
    }
}
