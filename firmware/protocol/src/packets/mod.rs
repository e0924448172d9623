//! Every packet of the protocol version [`PROTOCOL_VERSION`](crate::PROTOCOL_VERSION) as a packed plain-old-data struct, and the small enums
//! carried inside them as `u8` codes.
//!
//! Encoding and decoding are casts of these structs (thesis 9.5); see [`PacketType`] for the table
//! of codes and [`crate::frame`] for the header and checksum.

mod codes;
mod commands;
mod events;
mod session;
mod settings_io;

use crate::layout::Layout;
use crate::state::{ReducedState, RobotState};

pub use codes::{
    BumpCause, CalibrationAction, DriveMode, LogLevel, Mark, MoveOutcome, NackReason,
    ReflectorMode, Side,
};
pub use commands::{
    ArcMovement, ClearQueue, IrMessage, LineCalibration, LineFollow, MotorPower, ReflectorConfig,
    RotationMovement, SetLed, Stop, StraightMovement, WheelSpeeds,
};
pub use events::{
    Bump, Event, LineEvent, LoopOverrun, MoveFinished, Obstacle, QueueEmpty, Reflex,
    RobotEncountered, WatchdogStop,
};
pub use session::{EventReplay, Hello, HelloRequest, Log, Nack, Ping, Pong};
pub use settings_io::{
    SettingsData, SettingsRead, SettingsRestoreDefaults, SettingsSave, SettingsSaved,
    SettingsUpdate,
};

/// Largest settings chunk carried by one update or read-back packet.
pub const SETTINGS_CHUNK: usize = 32;
/// Longest log text carried by one log packet.
pub const LOG_TEXT: usize = 64;

/// A packet struct with its type code.
pub trait Packet: bytemuck::Pod {
    /// The type code in the header.
    const TYPE: PacketType;
    /// Shortest valid payload; equal to the struct size unless the packet has a variable tail.
    const MIN_PAYLOAD: usize = core::mem::size_of::<Self>();
    /// Payload bytes this value puts on the wire.
    fn payload_len(&self) -> usize {
        core::mem::size_of::<Self>()
    }
}

macro_rules! packets {
    ($( $(#[$doc:meta])* $code:literal => $name:ident($ty:ty) $(, tail $min:expr, $len:expr)? ;)*) => {
        /// Packet type codes of the current protocol version.
        ///
        #[doc = include_str!("../codes.md")]
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        #[repr(u8)]
        pub enum PacketType { $($(#[$doc])* $name = $code,)* }

        impl PacketType {
            /// Every packet type, in code order.
            pub const ALL: &'static [PacketType] = &[$(PacketType::$name,)*];

            /// The type for a header code.
            pub fn from_code(code: u8) -> Option<Self> {
                match code { $($code => Some(Self::$name),)* _ => None }
            }

            /// Valid payload lengths `(min, max)` for this type.
            pub fn payload_range(self) -> (usize, usize) {
                match self { $(Self::$name => (<$ty as Packet>::MIN_PAYLOAD, core::mem::size_of::<$ty>()),)* }
            }

            /// Type name.
            pub fn name(self) -> &'static str {
                match self { $(Self::$name => stringify!($name),)* }
            }

            /// Layout of the payload struct, for documentation and tools.
            pub fn layout(self) -> &'static crate::layout::TypeInfo {
                match self { $(Self::$name => const { &<$ty as Layout>::LAYOUT },)* }
            }
        }

        $(
            impl Packet for $ty {
                const TYPE: PacketType = PacketType::$name;
                $(
                    const MIN_PAYLOAD: usize = $min;
                    fn payload_len(&self) -> usize { let f: fn(&Self) -> usize = $len; f(self) }
                )?
            }
        )*

        /// Any decoded packet.
        #[derive(Clone, Copy, Debug, PartialEq)]
        #[allow(clippy::large_enum_variant)]
        pub enum AnyPacket { $($(#[$doc])* $name($ty),)* }

        impl AnyPacket {
            /// Decodes a payload whose type and length were already checked.
            pub(crate) fn from_checked(t: PacketType, payload: &[u8]) -> Self {
                match t { $(PacketType::$name => Self::$name(crate::frame::cast_payload::<$ty>(payload)),)* }
            }

            /// The packet's type.
            pub fn packet_type(&self) -> PacketType {
                match self { $(Self::$name(_) => PacketType::$name,)* }
            }

            /// Encodes into `buf`, returning the frame length.
            pub fn encode(&self, buf: &mut [u8]) -> Result<usize, crate::Error> {
                match self { $(Self::$name(p) => crate::frame::encode(p, buf),)* }
            }
        }

        $(
            impl From<$ty> for AnyPacket {
                fn from(p: $ty) -> Self { Self::$name(p) }
            }
        )*
    };
}

packets! {
    /// Full robot state, robot → host.
    0x01 => State(RobotState);
    /// Reduced state, robot → host.
    0x02 => ReducedState(ReducedState);
    /// Identity and layouts, robot → host.
    0x03 => Hello(Hello);
    /// Ping answer, robot → host.
    0x04 => Pong(Pong);
    /// Settings read-back, robot → host.
    0x05 => SettingsData(SettingsData), tail 3, |p: &SettingsData| 3 + p.bytes().len();
    /// Debug log text, robot → host.
    0x06 => Log(Log), tail 9, |p: &Log| 9 + p.text().len();
    /// Command refused, robot → host.
    0x07 => Nack(Nack);
    /// Event: a move ended, robot → host.
    0x10 => MoveFinished(MoveFinished);
    /// Event: the queue ran empty, robot → host.
    0x11 => QueueEmpty(QueueEmpty);
    /// Event: obstacle reflection, robot → host.
    0x12 => Obstacle(Obstacle);
    /// Event: another robot identified, robot → host.
    0x13 => RobotEncountered(RobotEncountered);
    /// Event: line lost or found, robot → host.
    0x14 => LineEvent(LineEvent);
    /// Event: watchdog stopped the robot, robot → host.
    0x15 => WatchdogStop(WatchdogStop);
    /// Event: main loop overrun, robot → host.
    0x16 => LoopOverrun(LoopOverrun);
    /// Event: settings saved, robot → host.
    0x17 => SettingsSaved(SettingsSaved);
    /// Event: the robot felt a bump, robot → host.
    0x18 => Bump(Bump);
    /// Event: the proximity reflex stopped the robot, robot → host.
    0x19 => Reflex(Reflex);
    /// Straight move, host → robot (thesis code).
    0x40 => StraightMovement(StraightMovement);
    /// Rotation in place, host → robot.
    0x41 => RotationMovement(RotationMovement);
    /// Arc move, host → robot.
    0x42 => ArcMovement(ArcMovement);
    /// Clear the move queue, host → robot.
    0x43 => ClearQueue(ClearQueue);
    /// Stop everything, host → robot.
    0x44 => Stop(Stop);
    /// Teleop wheel speeds, host → robot.
    0x45 => WheelSpeeds(WheelSpeeds);
    /// Teleop motor duties, host → robot.
    0x46 => MotorPower(MotorPower);
    /// Line following on/off, host → robot.
    0x47 => LineFollow(LineFollow);
    /// Line sensor calibration, host → robot.
    0x48 => LineCalibration(LineCalibration);
    /// Status LED colour, host → robot.
    0x49 => SetLed(SetLed);
    /// IR message word, host → robot.
    0x4A => IrMessage(IrMessage);
    /// Settings field write, host → robot.
    0x50 => SettingsUpdate(SettingsUpdate), tail 3, |p: &SettingsUpdate| 3 + p.bytes().len();
    /// Settings read request, host → robot.
    0x51 => SettingsRead(SettingsRead);
    /// Save settings to flash, host → robot.
    0x52 => SettingsSave(SettingsSave);
    /// Restore factory settings, host → robot.
    0x53 => SettingsRestoreDefaults(SettingsRestoreDefaults);
    /// State reflector configuration, host → robot.
    0x54 => ReflectorConfig(ReflectorConfig);
    /// Round-trip probe, host → robot.
    0x55 => Ping(Ping);
    /// Ask for a hello, host → robot.
    0x56 => HelloRequest(HelloRequest);
    /// Ask for events again, host → robot.
    0x57 => EventReplay(EventReplay);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The code table in the rustdoc is the one the code uses.
    #[test]
    fn doc_table_matches_the_enum() {
        let mut rows = 0;
        for line in include_str!("../codes.md").lines() {
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            let Some(code) = cells.get(1).and_then(|c| c.strip_prefix("`0x")) else {
                continue;
            };
            let code = u8::from_str_radix(code.trim_end_matches('`'), 16).unwrap();
            let name = cells[2].trim_matches('`');
            let t = PacketType::from_code(code).unwrap_or_else(|| panic!("{code:#x} unknown"));
            assert_eq!(t.name(), name, "code {code:#04x}");
            rows += 1;
        }
        assert_eq!(rows, PacketType::ALL.len());
    }

    #[test]
    fn codes_are_unique_and_round_trip() {
        for &t in PacketType::ALL {
            assert_eq!(PacketType::from_code(t as u8), Some(t));
            let (min, max) = t.payload_range();
            assert!(min <= max && max <= crate::MAX_PAYLOAD, "{t:?}");
        }
    }

    #[test]
    fn straight_movement_keeps_the_thesis_layout() {
        assert_eq!(PacketType::StraightMovement as u8, 0x40);
        assert_eq!(PacketType::State as u8, 0x01);
        let p = StraightMovement {
            distance_m: 1.0,
            speed_mps: 0.3,
            move_id: 0,
        };
        let b = bytemuck::bytes_of(&p);
        assert_eq!(&b[0..4], &1.0f32.to_le_bytes());
        assert_eq!(&b[4..8], &0.3f32.to_le_bytes());
    }

    #[test]
    fn log_text_is_cut_on_a_char_boundary() {
        let long = "é".repeat(40);
        let l = Log::new(LogLevel::Warn, "locomotion", &long);
        assert_eq!(l.text().len(), 64);
        assert_eq!(l.module(), "locomoti");
        assert_eq!(l.payload_len(), 9 + 64);
    }
}
