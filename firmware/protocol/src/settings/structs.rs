//! The settings structure: one packed sub-struct per firmware module, and [`Settings`], the whole.

use crate::wire_struct;

wire_struct! {
    /// Who the robot is.
    pub struct IdentitySettings {
        /// Unique robot id, carried in hello packets and IR frames.
        pub robot_id: u16,
        /// Human-readable name, NUL-padded ASCII.
        pub name: [u8; 12],
    }
}

wire_struct! {
    /// Wheel geometry used by locomotion and odometry (thesis 9.8.1).
    pub struct GeometrySettings {
        /// Wheel diameter in metres.
        pub wheel_diameter_m: f32,
        /// Distance between the wheels' contact points in metres.
        pub wheel_gauge_m: f32,
        /// Encoder pulses per wheel revolution.
        pub ticks_per_rev: u16,
    }
}

wire_struct! {
    /// Periods of the scheduler channels (thesis 11.1).
    pub struct SchedulerSettings {
        /// Main control loop period in microseconds.
        pub main_period_us: u32,
        /// Line sensor sampling period in microseconds.
        pub line_period_us: u32,
        /// Duration of one IR transmit slot in microseconds.
        pub ir_slot_us: u32,
    }
}

wire_struct! {
    /// Motor driver limits.
    pub struct MotorSettings {
        /// Largest PWM duty the firmware commands, in permille.
        pub max_pwm: u16,
        /// Smallest duty that turns a wheel; added to non-zero commands to cross static friction.
        pub min_pwm: u16,
    }
}

wire_struct! {
    /// Wheel speed measurement by fixed Δs (thesis 11.5).
    pub struct SpeedMeterSettings {
        /// A wheel with no encoder edge for this long reads zero speed, in microseconds.
        pub timeout_us: u32,
    }
}

wire_struct! {
    /// Gains and limits of one discrete PID controller (thesis 11.2.1).
    pub struct PidSettings {
        /// Proportional gain.
        pub kp: f32,
        /// Integral gain (per second).
        pub ki: f32,
        /// Derivative gain (seconds).
        pub kd: f32,
        /// Bound on the integral term's contribution to the output (anti-windup).
        pub i_limit: f32,
        /// Bound on the output magnitude.
        pub out_limit: f32,
    }
}

wire_struct! {
    /// Move execution: the speed profile f(s) of thesis fig. 11.6 and the feed-forward.
    pub struct LocomotionSettings {
        /// Distance over which a move ramps from `min_speed_mps` to its cruise speed.
        pub accel_distance_m: f32,
        /// Distance before the end of a move over which it ramps down to `min_speed_mps`.
        pub decel_distance_m: f32,
        /// Speed at the start and end of the profile.
        pub min_speed_mps: f32,
        /// Upper bound on any commanded speed.
        pub max_speed_mps: f32,
        /// Feed-forward PWM permille per m/s of wheel speed.
        pub pwm_per_mps: f32,
        /// A move ends this many seconds of travel early, so the wheels coast onto its target.
        pub coast_s: f32,
    }
}

wire_struct! {
    /// Line sensor calibration and detection (thesis 11.3).
    pub struct LineSensorSettings {
        /// Ambient-suppressed reading of each spot over white floor.
        pub white: [u16; 8],
        /// Ambient-suppressed reading of each spot over black tape.
        pub black: [u16; 8],
        /// Distance between neighbouring spots in micrometres.
        pub spot_pitch_um: u16,
        /// Largest spot darkness (permille) below which the line counts as lost.
        pub lost_threshold: u16,
    }
}

wire_struct! {
    /// Line following (thesis 11.2).
    pub struct LineFollowSettings {
        /// Default following speed in m/s.
        pub speed_mps: f32,
        /// Speed factor on red-marked segments (slow down).
        pub red_factor: f32,
        /// Speed factor on blue-marked segments (speed up).
        pub blue_factor: f32,
        /// How long the line may stay lost before following stops, in milliseconds.
        pub lost_timeout_ms: u16,
    }
}

wire_struct! {
    /// Colour sensor classification of marked segments.
    pub struct ColourSettings {
        /// A channel must exceed each other channel by this factor to count as a mark.
        pub mark_ratio: f32,
        /// Minimum clear-channel reading for any mark.
        pub min_clear: u16,
    }
}

wire_struct! {
    /// Proximity logical layer (thesis 7.2).
    pub struct ProximitySettings {
        /// Number of directed IR LEDs in the transmit cycle.
        pub led_count: u8,
        /// Number of transmit power levels (1 = weakest).
        pub power_levels: u8,
        /// Direction of each LED relative to the robot's heading, in degrees (CCW positive).
        pub led_angle_deg: [i16; 6],
        /// Nominal reach of each power level over another robot's receiver, in millimetres.
        pub range_mm: [u16; 4],
        /// An encounter or obstacle is reported again after this long, in milliseconds.
        pub report_period_ms: u16,
    }
}

wire_struct! {
    /// State reflector (thesis 6.4, 9.7).
    pub struct ReflectorSettings {
        /// A [`ReflectorMode`](crate::packets::ReflectorMode) code.
        pub mode: u8,
        /// Period between state packets in milliseconds.
        pub period_ms: u16,
    }
}

wire_struct! {
    /// Link watchdog (thesis 2.3.2).
    pub struct WatchdogSettings {
        /// Motors stop when no host packet arrives for this long, in milliseconds; 0 disables.
        pub timeout_ms: u16,
    }
}

wire_struct! {
    /// Debug log (thesis 6.2.3).
    pub struct LogSettings {
        /// Messages above this level are not sent; see [`LogLevel`](crate::packets::LogLevel).
        pub level: u8,
    }
}

wire_struct! {
    /// Bump detection: the robot reports being moved by something other than its wheels.
    pub struct BumpSettings {
        /// An acceleration the wheel speeds do not explain by more than this is a jolt, in
        /// milli-g; 0 disables jolt detection.
        pub threshold_mg: u16,
        /// A jolt is reported only when it moved the robot at least this far, in millimetres:
        /// a robot's own starts, stops and pushes jolt the accelerometer too (the wheel speeds
        /// lag), but move it nowhere their wheels do not say.
        pub min_moved_mm: u8,
        /// Encoder pulses, summed over both wheels, that turn while the robot stands idle with
        /// its wheels stopped before it reports a bump; 0 disables.
        pub idle_ticks: u8,
    }
}

wire_struct! {
    /// The proximity reflex: the robot stops a drive into something close ahead or behind,
    /// whatever its host believes.
    pub struct ReflexSettings {
        /// A drive forwards (backwards) stops when the front (rear) receiver gets the robot's own
        /// light back at this power level or a weaker one (1 = the weakest, a surface within about
        /// 15 mm); 0 disables the reflex.
        pub power_level: u8,
    }
}

wire_struct! {
    /// Every adjustable parameter of the robot, one sub-struct per module.
    pub struct Settings {
        /// Identity.
        pub identity: IdentitySettings,
        /// Wheel geometry.
        pub geometry: GeometrySettings,
        /// Scheduler periods.
        pub scheduler: SchedulerSettings,
        /// Motor limits.
        pub motor: MotorSettings,
        /// Speed measurement.
        pub speed_meter: SpeedMeterSettings,
        /// Per-wheel speed PID (teleop and line following).
        pub wheel_pid: PidSettings,
        /// Robot-speed PID of the locomotion chain.
        pub speed_pid: PidSettings,
        /// Wheel-balance controller holding the left:right trajectory ratio.
        pub balance_pid: PidSettings,
        /// Line-position PID whose output is the wheel-speed difference.
        pub line_pid: PidSettings,
        /// Move execution.
        pub locomotion: LocomotionSettings,
        /// Line sensor.
        pub line_sensor: LineSensorSettings,
        /// Line following.
        pub line_follow: LineFollowSettings,
        /// Colour sensor.
        pub colour: ColourSettings,
        /// Proximity sensing.
        pub proximity: ProximitySettings,
        /// State reflector.
        pub reflector: ReflectorSettings,
        /// Link watchdog.
        pub watchdog: WatchdogSettings,
        /// Debug log.
        pub log: LogSettings,
        /// Bump detection.
        pub bump: BumpSettings,
        /// Proximity reflex.
        pub reflex: ReflexSettings,
    }
}
