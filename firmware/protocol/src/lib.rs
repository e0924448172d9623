#![doc = include_str!("../README.md")]
#![cfg_attr(not(test), no_std)]
#![warn(missing_docs)]

pub mod command;
pub mod frame;
pub mod layout;
pub mod packets;
pub mod settings;
pub mod slip;
pub mod state;

pub use command::MoveCommand;
pub use frame::{decode, encode, Frame, Header, HEADER_LEN, MAX_PACKET, MAX_PAYLOAD};
pub use layout::FieldPath;
pub use layout::{FieldInfo, Layout, TypeInfo};
pub use packets::{AnyPacket, Packet, PacketType};
pub use settings::{Settings, SettingsError, SETTINGS_LAYOUT_HASH};
pub use state::{ReducedState, RobotState};

/// Version of the wire protocol spoken by this crate; carried in the hello packet.
///
/// Version 2 added `field_offset` to the Nack packet and the Nack reasons 5 to 7. Version 3
/// stamps every event with the robot's time and a number (and adds `EventReplay`), makes moves,
/// `Stop` and `ClearQueue` safe to send again after a loss (`last_move_id`, `keep_from`), and
/// reports the newest event number in the state.
pub const PROTOCOL_VERSION: u16 = 3;

/// Everything that can go wrong encoding or decoding; variant names say phase and cause.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Error {
    /// The output buffer cannot hold the encoded packet or frame.
    EncodeBufferTooSmall,
    /// Fewer bytes than a header.
    DecodeTooShort,
    /// More bytes than the largest packet.
    DecodeOversized,
    /// The header's payload length disagrees with the frame length.
    DecodeLengthMismatch,
    /// The bytes do not sum to zero.
    DecodeBadChecksum,
    /// The type code is not in the table.
    DecodeUnknownType(u8),
    /// The payload length is not one this packet type allows.
    DecodeBadPayloadLength(PacketType),
    /// A SLIP frame exceeded the decoder's buffer and was dropped.
    SlipOverflow,
    /// A SLIP escape byte was followed by something other than `ESC_END` or `ESC_ESC`.
    SlipBadEscape,
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::EncodeBufferTooSmall => f.write_str("output buffer too small"),
            Self::DecodeTooShort => f.write_str("frame shorter than a header"),
            Self::DecodeOversized => f.write_str("frame longer than the largest packet"),
            Self::DecodeLengthMismatch => f.write_str("payload length disagrees with frame length"),
            Self::DecodeBadChecksum => f.write_str("bad checksum"),
            Self::DecodeUnknownType(t) => write!(f, "unknown packet type {t:#04x}"),
            Self::DecodeBadPayloadLength(t) => write!(f, "bad payload length for {}", t.name()),
            Self::SlipOverflow => f.write_str("SLIP frame overflowed the buffer"),
            Self::SlipBadEscape => f.write_str("invalid SLIP escape"),
        }
    }
}

impl core::error::Error for Error {}
