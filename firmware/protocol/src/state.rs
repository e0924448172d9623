//! The global robot state (thesis 6.4): one packed struct of per-module sub-structs, reflected to
//! the host whole ([`RobotState`]) or reduced ([`ReducedState`]) by the state reflector.

use crate::wire_struct;

wire_struct! {
    /// Total encoder pulses since boot; the sign follows the commanded wheel direction.
    pub struct EncoderState {
        /// Left wheel pulses (wraps at `i32` bounds).
        pub left_ticks: i32,
        /// Right wheel pulses (wraps at `i32` bounds).
        pub right_ticks: i32,
    }
}

wire_struct! {
    /// Measured and commanded wheel speeds and the PWM duty applied.
    pub struct WheelState {
        /// Left wheel speed from fixed Δs measurement, m/s.
        pub left_mps: f32,
        /// Right wheel speed from fixed Δs measurement, m/s.
        pub right_mps: f32,
        /// Left wheel speed set-point, m/s.
        pub left_target_mps: f32,
        /// Right wheel speed set-point, m/s.
        pub right_target_mps: f32,
        /// Left motor duty, permille (negative = backwards).
        pub left_pwm: i16,
        /// Right motor duty, permille (negative = backwards).
        pub right_pwm: i16,
    }
}

wire_struct! {
    /// Line sensor readings and the detected line.
    pub struct LineState {
        /// Calibrated darkness of each spot, permille (0 white, 1000 black), left to right.
        pub darkness: [u16; 8],
        /// Line position relative to the sensor centre in micrometres, positive to the right.
        pub position_um: i16,
        /// Bit 0: line lost; bit 1: line following active; bit 2: calibrating.
        pub flags: u8,
        /// Colour mark under the robot; see [`Mark`](crate::packets::Mark).
        pub mark: u8,
    }
}

wire_struct! {
    /// Proximity sensing summary.
    pub struct ProximityState {
        /// Weakest power level whose reflection the front receiver saw (0 = nothing).
        pub front_obstacle: u8,
        /// Weakest power level whose reflection the rear receiver saw (0 = nothing).
        pub rear_obstacle: u8,
        /// Id of the robot seen most recently (0 = none yet).
        pub last_robot_id: u16,
        /// Receiver side of the last sighting; see [`Side`](crate::packets::Side).
        pub last_robot_side: u8,
        /// Weakest power level of the last sighting.
        pub last_robot_power: u8,
        /// Number of encounters reported since boot.
        pub encounters: u16,
    }
}

wire_struct! {
    /// Raw colour sensor channels.
    pub struct ColourState {
        /// Red channel.
        pub red: u16,
        /// Green channel.
        pub green: u16,
        /// Blue channel.
        pub blue: u16,
        /// Clear channel.
        pub clear: u16,
    }
}

wire_struct! {
    /// Accelerometer, milli-g in the robot frame (x forward, y left, z up).
    pub struct AccelState {
        /// Forward acceleration.
        pub x_mg: i16,
        /// Leftward acceleration.
        pub y_mg: i16,
        /// Upward acceleration (about +1000 at rest).
        pub z_mg: i16,
    }
}

wire_struct! {
    /// Battery and temperature.
    pub struct PowerState {
        /// Battery voltage, millivolts.
        pub battery_mv: u16,
        /// Current drawn, milliamperes.
        pub current_ma: i16,
        /// Core temperature, tenths of a degree Celsius.
        pub temperature_dc: i16,
    }
}

wire_struct! {
    /// Locomotion module status.
    pub struct LocomotionState {
        /// A [`DriveMode`](crate::packets::DriveMode) code.
        pub mode: u8,
        /// Moves waiting in the queue, the running one included.
        pub queue_len: u8,
        /// Id of the running move (0 = none).
        pub active_move: u16,
        /// Distance done in the running move, metres.
        pub progress_m: f32,
        /// Id of the newest move taken since the last `Hello` (0 = none): the robot takes only the
        /// move after it (1 after a hello), so a copy or a move after a lost one is ignored.
        pub last_move_id: u16,
    }
}

wire_struct! {
    /// Link statistics as the robot sees them.
    pub struct LinkState {
        /// Packets received and accepted.
        pub rx_packets: u32,
        /// Packets queued for sending.
        pub tx_packets: u32,
        /// Frames dropped for bad checksum, length, type or framing.
        pub rx_errors: u16,
        /// Outgoing packets dropped because the send queue was full.
        pub tx_dropped: u16,
        /// Main loop overruns (thesis 11.1).
        pub overruns: u16,
        /// Number of the newest event sent (0 = none yet), so the host notices a lost last event.
        pub events_sent: u16,
    }
}

wire_struct! {
    /// Everything the robot senses, as reflected to the host by the full-mode state reflector.
    pub struct RobotState {
        /// Robot clock at sampling, milliseconds since boot (wraps).
        pub uptime_ms: u32,
        /// Encoder totals.
        pub encoders: EncoderState,
        /// Wheel speeds and duties.
        pub wheels: WheelState,
        /// Line sensor.
        pub line: LineState,
        /// Proximity sensing.
        pub proximity: ProximityState,
        /// Colour sensor.
        pub colour: ColourState,
        /// Accelerometer.
        pub accel: AccelState,
        /// Battery and temperature.
        pub power: PowerState,
        /// Locomotion.
        pub locomotion: LocomotionState,
        /// RGB status LED.
        pub led: [u8; 3],
        /// Link statistics.
        pub link: LinkState,
    }
}

wire_struct! {
    /// The reduced state (thesis 6.4): encoders, wheel speeds and line position, small enough to
    /// reflect at a high rate for PID tuning.
    pub struct ReducedState {
        /// Robot clock at sampling, milliseconds since boot (wraps).
        pub uptime_ms: u32,
        /// Encoder totals.
        pub encoders: EncoderState,
        /// Wheel speeds, set-points and duties.
        pub wheels: WheelState,
        /// Line position in micrometres, positive to the right.
        pub line_position_um: i16,
        /// Line flags as in [`LineState::flags`].
        pub line_flags: u8,
    }
}

/// `LineState::flags` bit: the line is lost.
pub const LINE_LOST: u8 = 1;
/// `LineState::flags` bit: line following is active.
pub const LINE_FOLLOWING: u8 = 2;
/// `LineState::flags` bit: calibration is recording.
pub const LINE_CALIBRATING: u8 = 4;

impl RobotState {
    /// The reduced view of this state.
    pub fn reduced(&self) -> ReducedState {
        ReducedState {
            uptime_ms: self.uptime_ms,
            encoders: self.encoders,
            wheels: self.wheels,
            line_position_um: self.line.position_um,
            line_flags: self.line.flags,
        }
    }
}

impl Default for RobotState {
    fn default() -> Self {
        bytemuck::Zeroable::zeroed()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reduced_copies_the_shared_fields() {
        let mut s = RobotState {
            uptime_ms: 7,
            ..Default::default()
        };
        s.encoders.left_ticks = -3;
        s.wheels.right_mps = 0.25;
        s.line.position_um = -1200;
        s.line.flags = LINE_LOST;
        let r = s.reduced();
        assert_eq!({ r.uptime_ms }, 7);
        assert_eq!({ r.encoders.left_ticks }, -3);
        assert_eq!({ r.wheels.right_mps }, 0.25);
        assert_eq!({ r.line_position_um }, -1200);
        assert_eq!(r.line_flags, LINE_LOST);
    }
}
