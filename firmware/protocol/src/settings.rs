//! The global settings structure (thesis 6.3): one packed struct made of per-module sub-structs.
//!
//! Its [`Default`] is the factory "EEPROM image". The host mirrors it byte for byte and changes it
//! one field at a time with [`SettingsUpdate`](crate::packets::SettingsUpdate) packets, whose
//! offset and length come from [`Settings::field`] (computed by the compiler, never typed in).

use crate::layout::{Layout, TypeInfo};
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
    }
}

const _: () = assert!(core::mem::size_of::<Settings>() <= 255 - 3);

/// Hash of the settings layout, sent in the hello packet; a host refuses to write settings into a
/// layout whose hash it does not know.
pub const SETTINGS_LAYOUT_HASH: u64 = Settings::LAYOUT.hash;

/// Why a settings write was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SettingsError {
    /// The range reaches past the end of the settings structure.
    OutOfBounds,
    /// The range starts or ends inside a value, which would leave it half-written.
    NotOnFieldBoundary,
    /// The data length differs from the declared length.
    LengthMismatch,
    /// The value starting at this byte offset is outside its documented range (see [`RULES`]).
    OutOfRange {
        /// Offset of the offending leaf value inside [`Settings`].
        offset: u16,
    },
}

impl SettingsError {
    /// The Nack reason a robot answers this refusal with.
    pub fn nack_reason(self) -> crate::packets::NackReason {
        use crate::packets::NackReason;
        match self {
            Self::OutOfBounds | Self::NotOnFieldBoundary => NackReason::BadSettingsRange,
            Self::LengthMismatch => NackReason::BadLength,
            Self::OutOfRange { .. } => NackReason::BadSettingValue,
        }
    }

    /// The offending field's offset for the Nack, or [`Nack::NO_FIELD`](crate::packets::Nack::NO_FIELD).
    pub fn field_offset(self) -> u16 {
        match self {
            Self::OutOfRange { offset } => offset,
            _ => crate::packets::Nack::NO_FIELD,
        }
    }
}

impl core::fmt::Display for SettingsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::OutOfBounds => f.write_str("settings range out of bounds"),
            Self::NotOnFieldBoundary => f.write_str("settings range splits a field"),
            Self::LengthMismatch => f.write_str("settings data length mismatch"),
            Self::OutOfRange { offset } => match Settings::LAYOUT.path_of(usize::from(*offset)) {
                Some(path) => write!(f, "{path} out of range"),
                None => write!(f, "settings offset {offset} out of range"),
            },
        }
    }
}

/// The documented range of one settings value; a range on an array applies to every element.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Range {
    /// A number in `[min, max]`; a float must also be finite (no NaN, no infinity).
    Number {
        /// Smallest valid value.
        min: f64,
        /// Largest valid value.
        max: f64,
    },
    /// NUL-padded printable ASCII: bytes `0x20..=0x7E`, then only NULs.
    Text,
}

/// The validity rule of one settings field, the source of [`Settings::validate`] and of the
/// protocol document's settings table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldRule {
    /// Dotted path of the field.
    pub path: &'static str,
    /// Valid values.
    pub range: Range,
    /// Another field this one must stay below (`strict`) or not exceed, element by element.
    pub bound_by: Option<Bound>,
    /// What a code means, for fields holding enum codes; empty otherwise.
    pub note: &'static str,
}

/// A cross-field constraint: this field `< other` (strict) or `<= other`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bound {
    /// Dotted path of the bounding field.
    pub other: &'static str,
    /// Whether equality is refused.
    pub strict: bool,
}

const fn num(path: &'static str, min: f64, max: f64) -> FieldRule {
    FieldRule {
        path,
        range: Range::Number { min, max },
        bound_by: None,
        note: "",
    }
}

const fn below(rule: FieldRule, other: &'static str, strict: bool) -> FieldRule {
    FieldRule {
        bound_by: Some(Bound { other, strict }),
        ..rule
    }
}

const fn noted(rule: FieldRule, note: &'static str) -> FieldRule {
    FieldRule { note, ..rule }
}

const U16: f64 = u16::MAX as f64;
/// Bound on gains and feed-forward factors: far beyond any tuning, short of overflowing a duty.
const GAIN: f64 = 1.0e6;
/// Scheduler periods: 0.1 ms (faster starves the loop) to 1 s (slower cannot control a wheel).
const PERIOD_MIN_US: f64 = 100.0;
const PERIOD_MAX_US: f64 = 1.0e6;

/// Every settings field's valid range, in offset order; [`Settings::validate`] checks exactly these.
pub const RULES: &[FieldRule] = &[
    num("identity.robot_id", 1.0, U16),
    FieldRule {
        path: "identity.name",
        range: Range::Text,
        bound_by: None,
        note: "",
    },
    num("geometry.wheel_diameter_m", 0.001, 1.0),
    num("geometry.wheel_gauge_m", 0.001, 2.0),
    num("geometry.ticks_per_rev", 1.0, U16),
    num("scheduler.main_period_us", PERIOD_MIN_US, PERIOD_MAX_US),
    num("scheduler.line_period_us", PERIOD_MIN_US, PERIOD_MAX_US),
    num("scheduler.ir_slot_us", PERIOD_MIN_US, PERIOD_MAX_US),
    num("motor.max_pwm", 1.0, 1000.0),
    below(num("motor.min_pwm", 0.0, 1000.0), "motor.max_pwm", false),
    num("speed_meter.timeout_us", 1_000.0, 10_000_000.0),
    num("wheel_pid.kp", 0.0, GAIN),
    num("wheel_pid.ki", 0.0, GAIN),
    num("wheel_pid.kd", 0.0, GAIN),
    num("wheel_pid.i_limit", 0.0, GAIN),
    num("wheel_pid.out_limit", 0.0, GAIN),
    num("speed_pid.kp", 0.0, GAIN),
    num("speed_pid.ki", 0.0, GAIN),
    num("speed_pid.kd", 0.0, GAIN),
    num("speed_pid.i_limit", 0.0, GAIN),
    num("speed_pid.out_limit", 0.0, GAIN),
    num("balance_pid.kp", 0.0, GAIN),
    num("balance_pid.ki", 0.0, GAIN),
    num("balance_pid.kd", 0.0, GAIN),
    num("balance_pid.i_limit", 0.0, GAIN),
    num("balance_pid.out_limit", 0.0, GAIN),
    num("line_pid.kp", 0.0, GAIN),
    num("line_pid.ki", 0.0, GAIN),
    num("line_pid.kd", 0.0, GAIN),
    num("line_pid.i_limit", 0.0, GAIN),
    num("line_pid.out_limit", 0.0, GAIN),
    num("locomotion.accel_distance_m", 0.0, 10.0),
    num("locomotion.decel_distance_m", 0.0, 10.0),
    below(
        num("locomotion.min_speed_mps", 0.0, 10.0),
        "locomotion.max_speed_mps",
        false,
    ),
    num("locomotion.max_speed_mps", 0.001, 10.0),
    num("locomotion.pwm_per_mps", 0.0, GAIN),
    num("locomotion.coast_s", 0.0, 1.0),
    num("line_sensor.white", 0.0, U16),
    below(
        num("line_sensor.black", 0.0, U16),
        "line_sensor.white",
        true,
    ),
    num("line_sensor.spot_pitch_um", 1.0, U16),
    num("line_sensor.lost_threshold", 0.0, 1000.0),
    num("line_follow.speed_mps", 0.001, 10.0),
    num("line_follow.red_factor", 0.0, 10.0),
    num("line_follow.blue_factor", 0.0, 10.0),
    num("line_follow.lost_timeout_ms", 0.0, U16),
    num("colour.mark_ratio", 1.0, 1000.0),
    num("colour.min_clear", 0.0, U16),
    num("proximity.led_count", 1.0, 6.0),
    num("proximity.power_levels", 1.0, 4.0),
    num("proximity.led_angle_deg", -180.0, 180.0),
    num("proximity.range_mm", 1.0, U16),
    num("proximity.report_period_ms", 1.0, U16),
    noted(
        num("reflector.mode", 0.0, 2.0),
        "0 none, 1 full state, 2 reduced state",
    ),
    num("reflector.period_ms", 1.0, U16),
    noted(
        num("watchdog.timeout_ms", 0.0, U16),
        "0 disables the watchdog",
    ),
    noted(
        num("log.level", 0.0, 4.0),
        "0 silent, 1 error, 2 warn, 3 info, 4 debug",
    ),
];

/// Reads the primitive `ty` at `offset` of `bytes` as a number.
fn number_at(bytes: &[u8], offset: usize, ty: &TypeInfo) -> Option<f64> {
    let b = bytes.get(offset..offset + ty.size)?;
    Some(match ty.name {
        "u8" => f64::from(b[0]),
        "i8" => f64::from(b[0] as i8),
        "u16" => f64::from(u16::from_le_bytes(b.try_into().ok()?)),
        "i16" => f64::from(i16::from_le_bytes(b.try_into().ok()?)),
        "u32" => f64::from(u32::from_le_bytes(b.try_into().ok()?)),
        "i32" => f64::from(i32::from_le_bytes(b.try_into().ok()?)),
        "f32" => f64::from(f32::from_le_bytes(b.try_into().ok()?)),
        _ => return None,
    })
}

/// Index of the first byte that breaks NUL-padded printable ASCII, if any.
fn bad_text_byte(bytes: &[u8]) -> Option<usize> {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    let printable = bytes[..end].iter().position(|b| !(0x20..=0x7E).contains(b));
    printable.or_else(|| bytes[end..].iter().position(|&b| b != 0).map(|k| end + k))
}

impl Default for IdentitySettings {
    fn default() -> Self {
        let mut name = [0u8; 12];
        name[..10].copy_from_slice(b"PocketBot2");
        Self { robot_id: 1, name }
    }
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            identity: IdentitySettings::default(),
            geometry: GeometrySettings {
                wheel_diameter_m: 0.009,
                wheel_gauge_m: 0.026,
                ticks_per_rev: 40,
            },
            scheduler: SchedulerSettings {
                main_period_us: 5_000,
                line_period_us: 2_000,
                ir_slot_us: 4_000,
            },
            motor: MotorSettings {
                max_pwm: 1000,
                min_pwm: 60,
            },
            speed_meter: SpeedMeterSettings { timeout_us: 60_000 },
            wheel_pid: PidSettings {
                kp: 2500.0,
                ki: 12000.0,
                kd: 0.0,
                i_limit: 600.0,
                out_limit: 1000.0,
            },
            speed_pid: PidSettings {
                kp: 2500.0,
                ki: 12000.0,
                kd: 0.0,
                i_limit: 600.0,
                out_limit: 1000.0,
            },
            balance_pid: PidSettings {
                kp: 150.0,
                ki: 600.0,
                kd: 0.0,
                i_limit: 0.3,
                out_limit: 0.6,
            },
            line_pid: PidSettings {
                kp: 40.0,
                ki: 0.0,
                kd: 0.6,
                i_limit: 0.0,
                out_limit: 0.4,
            },
            locomotion: LocomotionSettings {
                accel_distance_m: 0.02,
                decel_distance_m: 0.025,
                min_speed_mps: 0.03,
                max_speed_mps: 0.5,
                pwm_per_mps: 1400.0,
                coast_s: 0.06,
            },
            line_sensor: LineSensorSettings {
                white: [3000; 8],
                black: [300; 8],
                spot_pitch_um: 3000,
                lost_threshold: 250,
            },
            line_follow: LineFollowSettings {
                speed_mps: 0.2,
                red_factor: 0.5,
                blue_factor: 1.5,
                lost_timeout_ms: 400,
            },
            colour: ColourSettings {
                mark_ratio: 1.6,
                min_clear: 200,
            },
            proximity: ProximitySettings {
                led_count: 6,
                power_levels: 4,
                led_angle_deg: [30, 0, -30, 150, 180, -150],
                range_mm: [30, 60, 100, 150],
                report_period_ms: 500,
            },
            reflector: ReflectorSettings {
                mode: 1,
                period_ms: 50,
            },
            watchdog: WatchdogSettings { timeout_ms: 500 },
            log: LogSettings { level: 3 },
        }
    }
}

impl Settings {
    /// Size of the settings structure in bytes.
    pub const SIZE: usize = core::mem::size_of::<Self>();

    /// (offset, length) of a field by dotted path, e.g. `"line_pid.kp"` or `"line_sensor.white[2]"`.
    pub fn field(path: &str) -> Option<(usize, usize)> {
        Self::LAYOUT.field(path)
    }

    /// The structure's bytes as stored in EEPROM and sent on the wire.
    pub fn as_bytes(&self) -> &[u8] {
        bytemuck::bytes_of(self)
    }

    /// Checks that `[offset, offset + len)` covers whole values inside the structure.
    pub fn check_range(offset: usize, len: usize) -> Result<(), SettingsError> {
        let end = offset.checked_add(len).ok_or(SettingsError::OutOfBounds)?;
        if end > Self::SIZE {
            return Err(SettingsError::OutOfBounds);
        }
        if !Self::LAYOUT.is_leaf_boundary(offset) || !Self::LAYOUT.is_leaf_boundary(end) {
            return Err(SettingsError::NotOnFieldBoundary);
        }
        Ok(())
    }

    /// Overwrites the bytes at `offset` with `data` after checking the range.
    pub fn write(&mut self, offset: usize, data: &[u8]) -> Result<(), SettingsError> {
        Self::check_range(offset, data.len())?;
        bytemuck::bytes_of_mut(self)[offset..offset + data.len()].copy_from_slice(data);
        Ok(())
    }

    /// Writes `data` at `offset` into a copy, validates the copy, and only then commits it:
    /// a refused write leaves the settings unchanged.
    pub fn update(&mut self, offset: usize, data: &[u8]) -> Result<(), SettingsError> {
        let mut copy = *self;
        copy.write(offset, data)?;
        copy.validate()?;
        *self = copy;
        Ok(())
    }

    /// Checks every field against its documented range ([`RULES`]), naming the first offender.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let bytes = self.as_bytes();
        for rule in RULES {
            // Every rule path resolves; a unit test walks them all.
            let Some((offset, ty)) = Self::LAYOUT.field_type(rule.path) else {
                continue;
            };
            let (elem, count) = ty.array.unwrap_or((ty, 1));
            let refuse = |k: usize| SettingsError::OutOfRange {
                offset: (offset + k * elem.size) as u16,
            };
            if rule.range == Range::Text {
                if let Some(k) = bad_text_byte(&bytes[offset..offset + ty.size]) {
                    return Err(refuse(k));
                }
                continue;
            }
            let bound = rule
                .bound_by
                .and_then(|b| Some((b, Self::LAYOUT.field_type(b.other)?)));
            for k in 0..count {
                let v = number_at(bytes, offset + k * elem.size, elem).ok_or(refuse(k))?;
                if let Range::Number { min, max } = rule.range {
                    if !(v.is_finite() && v >= min && v <= max) {
                        return Err(refuse(k));
                    }
                }
                if let Some((b, (other_offset, other_ty))) = bound {
                    let (other_elem, _) = other_ty.array.unwrap_or((other_ty, 1));
                    let other = number_at(bytes, other_offset + k * other_elem.size, other_elem)
                        .ok_or(refuse(k))?;
                    if v > other || (b.strict && v == other) {
                        return Err(refuse(k));
                    }
                }
            }
        }
        Ok(())
    }

    /// The dotted path of the field at `offset`, e.g. for a Nack's field offset.
    pub fn path_of(offset: usize) -> Option<crate::layout::FieldPath> {
        Self::LAYOUT.path_of(offset)
    }

    /// The bytes at `[offset, offset + len)` after checking the range.
    pub fn read(&self, offset: usize, len: usize) -> Result<&[u8], SettingsError> {
        Self::check_range(offset, len)?;
        Ok(&self.as_bytes()[offset..offset + len])
    }

    /// The robot name as text, up to the first NUL.
    pub fn name(&self) -> &str {
        let name = &self.identity.name;
        let end = name.iter().position(|&b| b == 0).unwrap_or(name.len());
        core::str::from_utf8(&name[..end]).unwrap_or("")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_offsets_match_the_struct() {
        let s = Settings::default();
        let (off, len) = Settings::field("line_pid.kd").unwrap();
        assert_eq!(len, 4);
        let bytes = &s.as_bytes()[off..off + len];
        assert_eq!(f32::from_le_bytes(bytes.try_into().unwrap()), 0.6);
        let (off, len) = Settings::field("proximity.range_mm[1]").unwrap();
        assert_eq!(
            u16::from_le_bytes(s.as_bytes()[off..off + len].try_into().unwrap()),
            60
        );
        assert_eq!(
            Settings::field("watchdog"),
            Some((Settings::SIZE - 3, 2)),
            "watchdog sits before the 1-byte log settings"
        );
    }

    #[test]
    fn write_changes_exactly_one_field() {
        let mut s = Settings::default();
        let (off, _) = Settings::field("speed_pid.ki").unwrap();
        s.write(off, &3.5f32.to_le_bytes()).unwrap();
        let ki = s.speed_pid.ki;
        assert_eq!(ki, 3.5);
        let mut expected = Settings::default();
        expected.speed_pid.ki = 3.5;
        assert_eq!(s, expected);
    }

    #[test]
    fn bad_ranges_are_refused_and_change_nothing() {
        let mut s = Settings::default();
        let (off, _) = Settings::field("speed_pid.ki").unwrap();
        assert_eq!(
            s.write(off + 1, &[0, 0, 0, 0]),
            Err(SettingsError::NotOnFieldBoundary)
        );
        assert_eq!(
            s.write(off, &[0, 0]),
            Err(SettingsError::NotOnFieldBoundary)
        );
        assert_eq!(
            s.write(Settings::SIZE - 1, &[0, 0]),
            Err(SettingsError::OutOfBounds)
        );
        assert_eq!(s.write(usize::MAX, &[0]), Err(SettingsError::OutOfBounds));
        assert_eq!(s, Settings::default());
    }

    #[test]
    fn whole_sub_structs_can_be_written() {
        let mut s = Settings::default();
        let (off, len) = Settings::field("line_pid").unwrap();
        let pid = PidSettings {
            kp: 1.0,
            ki: 2.0,
            kd: 3.0,
            i_limit: 4.0,
            out_limit: 5.0,
        };
        assert_eq!(len, core::mem::size_of::<PidSettings>());
        s.write(off, bytemuck::bytes_of(&pid)).unwrap();
        assert_eq!(s.line_pid, pid);
    }

    #[test]
    fn defaults_are_valid() {
        assert_eq!(Settings::default().validate(), Ok(()));
    }

    #[test]
    fn every_leaf_has_exactly_one_rule_in_offset_order() {
        let mut leaves = std::vec::Vec::new();
        Settings::LAYOUT
            .for_each_leaf(&mut |path, offset, _| leaves.push((path.join("."), offset)));
        let rules: std::vec::Vec<_> = RULES
            .iter()
            .map(|r| {
                let (offset, _) = Settings::field(r.path).unwrap_or_else(|| panic!("{}", r.path));
                if let Some(b) = r.bound_by {
                    assert!(Settings::field(b.other).is_some(), "{}", b.other);
                }
                (r.path.to_string(), offset)
            })
            .collect();
        assert_eq!(rules, leaves);
    }

    fn refused(path: &str, value: &[u8]) -> SettingsError {
        let mut s = Settings::default();
        let (off, _) = Settings::field(path).unwrap();
        let e = s.update(off, value).unwrap_err();
        assert_eq!(s, Settings::default(), "{path}");
        e
    }

    fn out_of_range(path: &str) -> SettingsError {
        let (off, _) = Settings::field(path).unwrap();
        SettingsError::OutOfRange { offset: off as u16 }
    }

    #[test]
    fn each_class_of_bad_value_is_refused_naming_its_field() {
        for (path, value) in [
            ("scheduler.main_period_us", &0u32.to_le_bytes()[..]),
            ("scheduler.main_period_us", &2_000_000u32.to_le_bytes()[..]),
            ("geometry.ticks_per_rev", &0u16.to_le_bytes()[..]),
            ("geometry.wheel_diameter_m", &f32::NAN.to_le_bytes()[..]),
            ("geometry.wheel_gauge_m", &f32::INFINITY.to_le_bytes()[..]),
            ("speed_pid.kp", &(-1.0f32).to_le_bytes()[..]),
            ("reflector.mode", &[3][..]),
            ("log.level", &[9][..]),
            ("identity.robot_id", &0u16.to_le_bytes()[..]),
            ("line_sensor.black[7]", &3000u16.to_le_bytes()[..]),
        ] {
            assert_eq!(refused(path, value), out_of_range(path), "{path}");
        }
        assert_eq!(
            refused("motor.max_pwm", &10u16.to_le_bytes()),
            out_of_range("motor.min_pwm")
        );
        assert_eq!(
            refused("identity.name", b"bad\0name\0\0\0\0"),
            out_of_range("identity.name[4]")
        );
    }

    #[test]
    fn refusals_map_to_nack_reasons_and_paths() {
        use crate::packets::{Nack, NackReason};
        let e = out_of_range("line_sensor.white[2]");
        assert_eq!(e.nack_reason(), NackReason::BadSettingValue);
        assert_eq!(
            Settings::path_of(usize::from(e.field_offset()))
                .unwrap()
                .to_string(),
            "line_sensor.white[2]"
        );
        assert_eq!(e.to_string(), "line_sensor.white[2] out of range");
        assert_eq!(
            SettingsError::LengthMismatch.nack_reason(),
            NackReason::BadLength
        );
        assert_eq!(SettingsError::LengthMismatch.field_offset(), Nack::NO_FIELD);
    }

    #[test]
    fn an_update_must_carry_the_length_it_declares() {
        use crate::packets::SettingsUpdate;
        let u = SettingsUpdate::new(0, &[1, 0]).unwrap();
        assert_eq!(u.check_carried(5), Ok(()));
        assert_eq!(u.check_carried(4), Err(SettingsError::LengthMismatch));
        assert_eq!(u.check_carried(6), Err(SettingsError::LengthMismatch));
        let mut liar = u;
        liar.len = 200;
        assert_eq!(liar.check_carried(203), Err(SettingsError::LengthMismatch));
    }

    #[test]
    fn a_valid_update_is_applied() {
        let mut s = Settings::default();
        let (off, _) = Settings::field("geometry.ticks_per_rev").unwrap();
        s.update(off, &80u16.to_le_bytes()).unwrap();
        assert_eq!({ s.geometry.ticks_per_rev }, 80);
    }

    #[test]
    fn default_name_reads_back() {
        assert_eq!(Settings::default().name(), "PocketBot2");
    }
}
