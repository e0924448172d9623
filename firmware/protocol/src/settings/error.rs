//! Why a settings write was refused, and the Nack that says so.

use super::Settings;
use crate::layout::Layout;

/// Why a settings write was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SettingsError {
    /// The range reaches past the end of the settings structure.
    OutOfBounds,
    /// The range starts or ends inside a value, which would leave it half-written.
    NotOnFieldBoundary,
    /// The data length differs from the declared length.
    LengthMismatch,
    /// The value starting at this byte offset is outside its documented range (see
    /// [`RULES`](super::RULES)).
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
