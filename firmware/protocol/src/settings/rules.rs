//! The documented range of every settings field, and [`Settings::validate`], which checks them.

use super::{Settings, SettingsError};
use crate::layout::{Layout, TypeInfo};

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
    noted(
        num("bump.threshold_mg", 0.0, U16),
        "0 disables jolt detection",
    ),
    num("bump.min_moved_mm", 0.0, 255.0),
    noted(num("bump.idle_ticks", 0.0, 255.0), "0 disables"),
    noted(
        num("reflex.power_level", 0.0, 4.0),
        "1 the weakest (about 15 mm); 0 disables",
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

impl Settings {
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
}
