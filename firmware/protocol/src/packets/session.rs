//! Packets of the link's session: the robot's hello, the host's ping and its answer, refusals and
//! the robot's log.

use super::{LogLevel, LOG_TEXT};
use crate::layout::Layout;
use crate::settings::{Settings, SETTINGS_LAYOUT_HASH};
use crate::state::RobotState;
use crate::wire_struct;

wire_struct! {
    /// Sent by the robot on connect and on request: who it is and which layouts it speaks.
    pub struct Hello {
        /// Robot id.
        pub robot_id: u16,
        /// [`PROTOCOL_VERSION`](crate::PROTOCOL_VERSION) of the firmware.
        pub protocol_version: u16,
        /// Firmware version, major.minor.patch.
        pub firmware_version: [u8; 3],
        /// Hash of the [`Settings`] layout.
        pub settings_hash: u64,
        /// Hash of the [`RobotState`] layout.
        pub state_hash: u64,
        /// Size of the settings structure in bytes.
        pub settings_size: u16,
        /// Robot name, NUL-padded ASCII.
        pub name: [u8; 12],
    }
}

impl Hello {
    /// A hello for this build's layouts.
    pub fn new(settings: &Settings, firmware_version: [u8; 3]) -> Self {
        Self {
            robot_id: settings.identity.robot_id,
            protocol_version: crate::PROTOCOL_VERSION,
            firmware_version,
            settings_hash: SETTINGS_LAYOUT_HASH,
            state_hash: RobotState::LAYOUT.hash,
            settings_size: Settings::SIZE as u16,
            name: settings.identity.name,
        }
    }
}

wire_struct! {
    /// Host asks for a [`Hello`].
    pub struct HelloRequest {}
}

wire_struct! {
    /// Host asks for its events again: every event the robot still holds (its last 32) whose
    /// number is `from_seq` or later, in order, as they were first sent.
    pub struct EventReplay {
        /// The first event number wanted.
        pub from_seq: u16,
    }
}

wire_struct! {
    /// Round-trip probe from the host.
    pub struct Ping {
        /// Sequence number echoed in the pong.
        pub seq: u32,
        /// Host clock at sending, microseconds.
        pub host_time_us: u64,
    }
}

wire_struct! {
    /// Answer to a [`Ping`].
    pub struct Pong {
        /// Sequence number of the ping.
        pub seq: u32,
        /// Host clock from the ping, echoed.
        pub host_time_us: u64,
        /// Robot clock when the ping was handled, microseconds.
        pub robot_time_us: u64,
    }
}

wire_struct! {
    /// A command was refused.
    pub struct Nack {
        /// Type code of the refused packet.
        pub packet_type: u8,
        /// A [`NackReason`](super::NackReason) code.
        pub reason: u8,
        /// Offset in [`Settings`] of the offending field, or [`Nack::NO_FIELD`].
        pub field_offset: u16,
    }
}

impl Nack {
    /// `field_offset` when the refusal names no settings field.
    pub const NO_FIELD: u16 = 0xFFFF;
}

wire_struct! {
    /// A leveled debug message (thesis 6.2.3); variable length.
    pub struct Log {
        /// A [`LogLevel`] code.
        pub level: u8,
        /// Module tag, NUL-padded ASCII.
        pub module: [u8; 8],
        /// UTF-8 text; only the used part travels on the wire.
        pub text: [u8; LOG_TEXT],
    }
}

impl Log {
    /// A message, cut to [`LOG_TEXT`] bytes on a character boundary.
    pub fn new(level: LogLevel, module: &str, text: &str) -> Self {
        let mut m = [0u8; 8];
        let mb = module.as_bytes();
        let n = mb.len().min(8);
        m[..n].copy_from_slice(&mb[..n]);
        let mut t = [0u8; LOG_TEXT];
        let mut end = text.len().min(LOG_TEXT);
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        t[..end].copy_from_slice(&text.as_bytes()[..end]);
        Self {
            level: level as u8,
            module: m,
            text: t,
        }
    }
    /// The message text.
    pub fn text(&self) -> &str {
        nul_str(&self.text)
    }
    /// The module tag.
    pub fn module(&self) -> &str {
        nul_str(&self.module)
    }
}

fn nul_str(b: &[u8]) -> &str {
    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    match core::str::from_utf8(&b[..end]) {
        Ok(s) => s,
        Err(e) => core::str::from_utf8(&b[..e.valid_up_to()]).unwrap_or(""),
    }
}
