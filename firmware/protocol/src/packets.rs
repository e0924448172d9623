//! Every packet of the protocol version [`PROTOCOL_VERSION`](crate::PROTOCOL_VERSION) as a packed plain-old-data struct, and the small enums
//! carried inside them as `u8` codes.
//!
//! Encoding and decoding are casts of these structs (thesis 9.5); see [`PacketType`] for the table
//! of codes and [`crate::frame`] for the header and checksum.

use crate::layout::Layout;
use crate::settings::{Settings, SETTINGS_LAYOUT_HASH};
use crate::state::{ReducedState, RobotState};
use crate::wire_struct;

/// Largest settings chunk carried by one update or read-back packet.
pub const SETTINGS_CHUNK: usize = 32;
/// Longest log text carried by one log packet.
pub const LOG_TEXT: usize = 64;

macro_rules! code_enum {
    ($(#[$meta:meta])* pub enum $name:ident { $($(#[doc = $vdoc:literal])* $var:ident = $val:literal),* $(,)? }) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        #[repr(u8)]
        pub enum $name { $($(#[doc = $vdoc])* $var = $val),* }

        impl $name {
            /// Every variant, in code order.
            pub const ALL: &'static [Self] = &[$(Self::$var),*];

            /// The variant's name.
            pub fn name(self) -> &'static str {
                match self { $(Self::$var => stringify!($var)),* }
            }

            /// The variant's doc comment, lines joined.
            pub fn doc(self) -> &'static str {
                match self { $(Self::$var => concat!($($vdoc),*)),* }
            }
        }

        impl TryFrom<u8> for $name {
            type Error = u8;
            fn try_from(v: u8) -> Result<Self, u8> {
                match v { $($val => Ok(Self::$var),)* other => Err(other) }
            }
        }
    };
}

code_enum! {
    /// What the state reflector sends (thesis 9.7).
    pub enum ReflectorMode {
        /// Nothing.
        None = 0,
        /// The whole [`RobotState`].
        Full = 1,
        /// The [`ReducedState`].
        Reduced = 2,
    }
}

code_enum! {
    /// Who drives the motors right now.
    pub enum DriveMode {
        /// Motors off, nothing queued.
        Idle = 0,
        /// Executing the move queue.
        Moves = 1,
        /// Following the line.
        LineFollow = 2,
        /// Holding teleoperated wheel speeds.
        WheelSpeeds = 3,
        /// Applying teleoperated motor duties directly.
        MotorPower = 4,
    }
}

code_enum! {
    /// Which receiver saw an IR frame.
    pub enum Side {
        /// Front receiver.
        Front = 0,
        /// Rear receiver.
        Rear = 1,
    }
}

code_enum! {
    /// Colour mark on the track under the robot.
    pub enum Mark {
        /// White floor or black tape.
        None = 0,
        /// Red segment: slow down.
        Red = 1,
        /// Blue segment: speed up.
        Blue = 2,
    }
}

code_enum! {
    /// Verbosity of a log message (thesis 6.2.3); lower is more severe.
    pub enum LogLevel {
        /// Unrecoverable error.
        Error = 1,
        /// Something the host should know about.
        Warn = 2,
        /// Module start-up and normal operation.
        Info = 3,
        /// Detailed tracing.
        Debug = 4,
    }
}

code_enum! {
    /// Line sensor calibration step.
    pub enum CalibrationAction {
        /// Forget the extremes and start recording them while the robot is swept over the line.
        Start = 1,
        /// Stop recording and adopt the recorded extremes as white and black.
        Finish = 2,
        /// Restore the factory calibration.
        Reset = 3,
    }
}

code_enum! {
    /// How a move ended.
    pub enum MoveOutcome {
        /// Reached its distance or angle.
        Completed = 0,
        /// Removed by a clear-queue command before or while running.
        Cleared = 1,
        /// Aborted by a stop command or the watchdog.
        Stopped = 2,
    }
}

code_enum! {
    /// Why a command was not carried out.
    pub enum NackReason {
        /// The move queue is full.
        QueueFull = 1,
        /// A settings range was out of bounds or split a field.
        BadSettingsRange = 2,
        /// A parameter was not finite or out of its range.
        BadParameter = 3,
        /// Settings storage failed.
        StorageFailed = 4,
        /// The frame's type code is not in the table; the Nack's `packet_type` is that code.
        UnknownType = 5,
        /// The payload length is not one the type allows, or a settings update's `len` disagrees
        /// with the bytes it carries.
        BadLength = 6,
        /// A settings value is outside its documented range; the Nack names the field's offset.
        BadSettingValue = 7,
    }
}

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
    /// Drive straight (thesis fig. 9.2; code 0x40 and the first two fields as in the thesis).
    pub struct StraightMovement {
        /// Signed distance in metres (negative = backwards).
        pub distance_m: f32,
        /// Cruise speed in m/s.
        pub speed_mps: f32,
        /// Host-chosen id reported in [`MoveFinished`].
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
        /// Host-chosen id reported in [`MoveFinished`].
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
        /// Host-chosen id reported in [`MoveFinished`].
        pub move_id: u16,
    }
}

wire_struct! {
    /// Drop every queued move; the running one stops smoothly.
    pub struct ClearQueue {}
}

wire_struct! {
    /// Stop now: motors off, queue cleared, line following and teleop off.
    pub struct Stop {}
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
        /// A [`CalibrationAction`] code.
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
    /// Overwrite `len` bytes of the settings at `offset` (thesis fig. 9.3); variable length.
    pub struct SettingsUpdate {
        /// Byte offset into [`Settings`].
        pub offset: u16,
        /// Number of bytes used in `data`.
        pub len: u8,
        /// New bytes; only the first `len` travel on the wire.
        pub data: [u8; SETTINGS_CHUNK],
    }
}

wire_struct! {
    /// Ask for `len` bytes of the settings at `offset`, answered by [`SettingsData`].
    pub struct SettingsRead {
        /// Byte offset into [`Settings`].
        pub offset: u16,
        /// Number of bytes, at most [`SETTINGS_CHUNK`].
        pub len: u8,
    }
}

wire_struct! {
    /// Settings bytes read back from the robot; variable length.
    pub struct SettingsData {
        /// Byte offset into [`Settings`].
        pub offset: u16,
        /// Number of bytes used in `data`.
        pub len: u8,
        /// The bytes; only the first `len` travel on the wire.
        pub data: [u8; SETTINGS_CHUNK],
    }
}

wire_struct! {
    /// Store the current settings in non-volatile memory.
    pub struct SettingsSave {}
}

wire_struct! {
    /// Replace the settings by the factory image (not saved until [`SettingsSave`]).
    pub struct SettingsRestoreDefaults {}
}

wire_struct! {
    /// Configure the state reflector.
    pub struct ReflectorConfig {
        /// A [`ReflectorMode`] code.
        pub mode: u8,
        /// Period between state packets, milliseconds (minimum 1).
        pub period_ms: u16,
    }
}

wire_struct! {
    /// A queued move has ended.
    pub struct MoveFinished {
        /// The move's id.
        pub move_id: u16,
        /// A [`MoveOutcome`] code.
        pub outcome: u8,
    }
}

wire_struct! {
    /// The move queue ran empty.
    pub struct QueueEmpty {}
}

wire_struct! {
    /// The robot's own IR frame came back: something that is not a robot is close.
    pub struct Obstacle {
        /// A [`Side`] code.
        pub side: u8,
        /// Weakest power level whose reflection was seen (1 = weakest = closest).
        pub power_level: u8,
        /// LED whose light came back.
        pub led: u8,
    }
}

wire_struct! {
    /// Another robot's IR frame was received (thesis 7.2).
    pub struct RobotEncountered {
        /// The other robot's id.
        pub robot_id: u16,
        /// A [`Side`] code: which of our receivers saw it.
        pub side: u8,
        /// The other robot's LED that reached us (tells its orientation).
        pub led: u8,
        /// Weakest power level that reached us.
        pub power_level: u8,
        /// Estimated heading of the other robot relative to ours, degrees (CCW positive).
        pub relative_heading_deg: i16,
        /// Estimated distance, millimetres.
        pub range_mm: u16,
        /// Message word carried in its frames (0 = none).
        pub message: u16,
    }
}

wire_struct! {
    /// The line was lost or found again.
    pub struct LineEvent {
        /// 1 = lost, 0 = found.
        pub lost: u8,
        /// Line position before the change, micrometres.
        pub position_um: i16,
    }
}

wire_struct! {
    /// The link watchdog stopped the robot.
    pub struct WatchdogStop {
        /// How long the host had been silent, milliseconds.
        pub silent_ms: u32,
    }
}

wire_struct! {
    /// The main loop ran late by more than one period (thesis 11.1).
    pub struct LoopOverrun {
        /// How late, microseconds.
        pub late_us: u32,
    }
}

wire_struct! {
    /// Settings were written to non-volatile memory.
    pub struct SettingsSaved {
        /// Bytes written.
        pub size: u16,
    }
}

wire_struct! {
    /// A command was refused.
    pub struct Nack {
        /// Type code of the refused packet.
        pub packet_type: u8,
        /// A [`NackReason`] code.
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

impl SettingsUpdate {
    /// An update of `data` at `offset`; `None` if `data` is longer than a chunk.
    pub fn new(offset: u16, data: &[u8]) -> Option<Self> {
        chunk(data).map(|(len, buf)| Self {
            offset,
            len,
            data: buf,
        })
    }
    /// The used bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.data[..(self.len as usize).min(SETTINGS_CHUNK)]
    }

    /// Checks that `len` matches the data a frame of `payload_len` bytes actually carried; a
    /// shorter frame would otherwise write its zero-filled tail.
    pub fn check_carried(&self, payload_len: usize) -> Result<(), crate::SettingsError> {
        let len = usize::from(self.len);
        if len > SETTINGS_CHUNK || payload_len != 3 + len {
            return Err(crate::SettingsError::LengthMismatch);
        }
        Ok(())
    }
}

impl SettingsData {
    /// A read-back of `data` at `offset`; `None` if `data` is longer than a chunk.
    pub fn new(offset: u16, data: &[u8]) -> Option<Self> {
        chunk(data).map(|(len, buf)| Self {
            offset,
            len,
            data: buf,
        })
    }
    /// The used bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.data[..(self.len as usize).min(SETTINGS_CHUNK)]
    }
}

fn chunk(data: &[u8]) -> Option<(u8, [u8; SETTINGS_CHUNK])> {
    if data.len() > SETTINGS_CHUNK {
        return None;
    }
    let mut buf = [0u8; SETTINGS_CHUNK];
    buf[..data.len()].copy_from_slice(data);
    Some((data.len() as u8, buf))
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
        #[doc = include_str!("codes.md")]
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
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The code table in the rustdoc is the one the code uses.
    #[test]
    fn doc_table_matches_the_enum() {
        let mut rows = 0;
        for line in include_str!("codes.md").lines() {
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
