//! The global settings structure (thesis 6.3): one packed struct made of per-module sub-structs.
//!
//! Its [`Default`] is the factory "EEPROM image". The host mirrors it byte for byte and changes it
//! one field at a time with [`SettingsUpdate`](crate::packets::SettingsUpdate) packets, whose
//! offset and length come from [`Settings::field`] (computed by the compiler, never typed in).

mod defaults;
mod error;
mod rules;
mod structs;

use crate::layout::Layout;

pub use error::SettingsError;
pub use rules::{Bound, FieldRule, Range, RULES};
pub use structs::{
    BumpSettings, ColourSettings, GeometrySettings, IdentitySettings, LineFollowSettings,
    LineSensorSettings, LocomotionSettings, LogSettings, MotorSettings, PidSettings,
    ProximitySettings, ReflectorSettings, ReflexSettings, SchedulerSettings, Settings,
    SpeedMeterSettings, WatchdogSettings,
};

const _: () = assert!(core::mem::size_of::<Settings>() <= 255 - 3);

/// Hash of the settings layout, sent in the hello packet; a host refuses to write settings into a
/// layout whose hash it does not know.
pub const SETTINGS_LAYOUT_HASH: u64 = Settings::LAYOUT.hash;

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
            Some((Settings::SIZE - 8, 2)),
            "watchdog sits before the 1-byte log, the 4-byte bump and the 1-byte reflex settings"
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
