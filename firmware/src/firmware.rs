//! The embedded control system: owns the modules and the board, and turns the board's interrupts
//! (`tick`, `on_encoder_edge`, `on_ir_frame`, `on_link_bytes`/`on_link_packet`) into motor duties,
//! LED colours, IR frames and outgoing packets.
//!
//! Nothing here blocks or reads a clock: every entry point takes `now`, so the same code runs on a
//! microcontroller timer, in the simulator's physics time, and in host tests.

use heapless::{Deque, Vec};
use protocol::packets::Nack;
use protocol::packets::{
    self, AnyPacket, CalibrationAction, DriveMode, Hello, LogLevel, Mark, MoveOutcome, NackReason,
    Packet, PacketType, ReflectorMode, SETTINGS_CHUNK,
};
use protocol::settings::{Settings, SettingsError};
use protocol::slip::{self, SlipDecoder};
use protocol::state::{RobotState, LINE_CALIBRATING, LINE_FOLLOWING, LINE_LOST};
use protocol::{Error, Frame, MAX_PACKET};

use crate::hal::{Board, EncoderEdge, IrFrame, Side, Wheel};
use crate::line_follow::LineFollower;
use crate::line_sensor::{classify_mark, LineReading, LineSensor};
use crate::locomotion::{
    tick_m, DriveCommand, EnqueueError, Locomotion, LocomotionEvent, Move, MoveKind, WheelInputs,
};
use crate::pid::Pid;
use crate::proximity::{Proximity, ProximityEvent};
use crate::reflector::Reflector;
use crate::scheduler::{next_period, Channel, Scheduler};
use crate::speed::SpeedMeter;
use crate::time::{Duration, Instant};
use crate::watchdog::Watchdog;

/// Firmware version reported in the hello packet.
pub const FIRMWARE_VERSION: [u8; 3] = [0, 1, 0];
/// Outgoing packets buffered before new ones are dropped and counted.
pub const TX_QUEUE: usize = 24;

/// One encoded outgoing packet.
pub type OutPacket = Vec<u8, MAX_PACKET>;

/// What drives the motors.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Drive {
    Idle,
    Moves,
    LineFollow { speed_mps: f32 },
    WheelSpeeds { left: f32, right: f32 },
    MotorPower { left: i16, right: i16 },
}

impl Drive {
    fn mode(&self) -> DriveMode {
        match self {
            Drive::Idle => DriveMode::Idle,
            Drive::Moves => DriveMode::Moves,
            Drive::LineFollow { .. } => DriveMode::LineFollow,
            Drive::WheelSpeeds { .. } => DriveMode::WheelSpeeds,
            Drive::MotorPower { .. } => DriveMode::MotorPower,
        }
    }
}

/// The robot's embedded control system running on board `B`.
pub struct Firmware<B: Board> {
    board: B,
    settings: Settings,
    state: RobotState,
    scheduler: Scheduler,
    speed: [SpeedMeter; 2],
    wheel_pid: [Pid; 2],
    locomotion: Locomotion,
    line_sensor: LineSensor,
    line: LineReading,
    follower: LineFollower,
    proximity: Proximity,
    drive: Drive,
    reflector: Reflector,
    watchdog: Watchdog,
    slip: SlipDecoder,
    tx: Deque<OutPacket, TX_QUEUE>,
    ir_message: u16,
    last_main: Option<Instant>,
    now: Instant,
    started: bool,
    /// Why the stored settings were refused at boot, reported once the link runs.
    boot_refusal: Option<SettingsError>,
}

impl<B: Board> Firmware<B> {
    /// Boots on `board`: settings come from its storage, or the factory image if none is stored.
    pub fn new(mut board: B) -> Self {
        let mut settings = Settings::default();
        let mut image = [0u8; Settings::SIZE];
        let mut boot_refusal = None;
        if board.load(&mut image).is_ok() {
            let stored: Settings = bytemuck::pod_read_unaligned(&image);
            // A corrupt or out-of-range image would run the loops with nonsense (a zero period
            // floods overruns); the factory image is safe, and the host can write settings again.
            match stored.validate() {
                Ok(()) => settings = stored,
                Err(e) => boot_refusal = Some(e),
            }
        }
        board.set_pwm(0, 0);
        Self {
            board,
            settings,
            state: RobotState::default(),
            scheduler: Scheduler::new(),
            speed: [SpeedMeter::new(); 2],
            wheel_pid: [Pid::new(); 2],
            locomotion: Locomotion::new(),
            line_sensor: LineSensor::new(),
            line: LineReading {
                darkness: [0; 8],
                position_um: 0,
                lost: true,
            },
            follower: LineFollower::new(),
            proximity: Proximity::new(),
            drive: Drive::Idle,
            reflector: Reflector::new(),
            watchdog: Watchdog::new(),
            slip: SlipDecoder::new(),
            tx: Deque::new(),
            ir_message: 0,
            last_main: None,
            now: Instant::ZERO,
            started: false,
            boot_refusal,
        }
    }

    /// The board, for a simulator or test to inspect.
    pub fn board(&self) -> &B {
        &self.board
    }

    /// The board, for a simulator or test to feed.
    pub fn board_mut(&mut self) -> &mut B {
        &mut self.board
    }

    /// Powers down: hands the board back (for a simulated reboot).
    pub fn into_board(self) -> B {
        self.board
    }

    /// The live settings.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// The latest robot state.
    pub fn state(&self) -> &RobotState {
        &self.state
    }

    /// The robot id from the settings.
    pub fn robot_id(&self) -> u16 {
        self.settings.identity.robot_id
    }

    /// The earliest time `tick` has work to do, for a board that sleeps until then.
    pub fn next_deadline(&self) -> Option<Instant> {
        if !self.started {
            return Some(self.now);
        }
        let wd = self.watchdog_deadline();
        match (self.scheduler.next_due(), wd) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// When the watchdog would stop a moving robot: a board that sleeps until
    /// [`next_deadline`](Self::next_deadline) wakes exactly then, not every millisecond.
    fn watchdog_deadline(&self) -> Option<Instant> {
        if self.drive == Drive::Idle && self.locomotion.is_empty() {
            return None;
        }
        let timeout = Duration::from_millis(u64::from(self.settings.watchdog.timeout_ms));
        self.watchdog.deadline(timeout)
    }

    /// Timer entry point: runs every scheduler channel that is due and checks the watchdog.
    pub fn tick(&mut self, now: Instant) {
        self.now = now;
        if !self.started {
            self.start(now);
        }
        while let Some(edge) = self.board.pop_edge() {
            self.on_encoder_edge(edge.wheel, edge.at);
        }
        while let Some((channel, scheduled)) = self.scheduler.pop_due(now) {
            match channel {
                Channel::MainLoop => self.main_loop(scheduled, now),
                Channel::LineSensor => self.line_task(scheduled, now),
                Channel::IrTransmit => self.ir_transmit_task(scheduled, now),
                Channel::IrReport => self.ir_report_task(scheduled, now),
            }
        }
        let timeout = Duration::from_millis(u64::from(self.settings.watchdog.timeout_ms));
        if let Some(silent) = self.watchdog.check(now, timeout) {
            if self.drive != Drive::Idle || !self.locomotion.is_empty() {
                self.halt(MoveOutcome::Stopped);
                self.send(&packets::WatchdogStop {
                    silent_ms: silent.as_millis().min(u64::from(u32::MAX)) as u32,
                });
                crate::fw_log!(
                    self,
                    Warn,
                    "watchdog",
                    "host silent {} ms",
                    silent.as_millis()
                );
            }
        }
    }

    fn start(&mut self, now: Instant) {
        self.started = true;
        self.scheduler.schedule(Channel::MainLoop, now);
        self.scheduler.schedule(Channel::LineSensor, now);
        self.scheduler.schedule(Channel::IrTransmit, now);
        self.scheduler.schedule(Channel::IrReport, now);
        crate::fw_log!(self, Info, "boot", "robot {} up", self.robot_id());
        if let Some(e) = self.boot_refusal.take() {
            crate::fw_log!(self, Warn, "boot", "stored settings refused: {}", e);
        }
    }

    /// Encoder interrupt entry point: one edge of `wheel` captured at `at`.
    pub fn on_encoder_edge(&mut self, wheel: Wheel, at: Instant) {
        let timeout = Duration::from_micros(u64::from(self.settings.speed_meter.timeout_us));
        self.speed[wheel as usize].on_edge(at, timeout);
    }

    /// IR receiver entry point: `frame` arrived on the `side` receiver at `now`.
    pub fn on_ir_frame(&mut self, now: Instant, side: Side, frame: IrFrame) {
        let id = self.robot_id();
        self.proximity.on_frame(now, side, frame, id);
    }

    /// Link entry point for stream transports: SLIP-framed bytes from the host.
    pub fn on_link_bytes(&mut self, now: Instant, bytes: &[u8]) {
        for &b in bytes {
            match self.slip.push(b) {
                Ok(Some(frame)) => {
                    let mut copy = [0u8; MAX_PACKET];
                    let n = frame.len();
                    copy[..n].copy_from_slice(frame);
                    self.on_link_packet(now, &copy[..n]);
                }
                Ok(None) => {}
                Err(_) => self.rx_error(),
            }
        }
    }

    /// Link entry point for datagram transports (L2CAP): one whole packet from the host.
    pub fn on_link_packet(&mut self, now: Instant, bytes: &[u8]) {
        self.now = now;
        match Frame::parse(bytes) {
            Ok(frame) => {
                self.watchdog.feed(now);
                self.state.link.rx_packets = self.state.link.rx_packets.wrapping_add(1);
                self.handle(frame.packet(), frame.payload().len());
            }
            // The checksum held, so the type code is what the host sent: tell it, then drop.
            Err(Error::DecodeUnknownType(code)) => {
                self.rx_error();
                self.nack_code(code, NackReason::UnknownType, Nack::NO_FIELD);
            }
            Err(Error::DecodeBadPayloadLength(t)) => {
                self.rx_error();
                self.nack(t, NackReason::BadLength);
            }
            // A bad checksum or a short frame says nothing trustworthy about its type.
            Err(e) => {
                self.rx_error();
                crate::fw_log!(self, Debug, "protocol", "dropped frame: {}", e);
            }
        }
    }

    /// The link came up: introduce ourselves.
    pub fn on_link_connected(&mut self, now: Instant) {
        self.now = now;
        self.send_hello();
    }

    /// Takes the oldest outgoing packet, for datagram transports.
    pub fn pop_packet(&mut self) -> Option<OutPacket> {
        self.tx.pop_front()
    }

    /// Takes the oldest outgoing packet SLIP-encoded into `out`, returning the length used.
    pub fn pop_slip(&mut self, out: &mut [u8; slip::max_encoded_len(MAX_PACKET)]) -> Option<usize> {
        let p = self.tx.pop_front()?;
        slip::encode(&p, out).ok()
    }

    /// Whether packets are waiting to be sent.
    pub fn has_outgoing(&self) -> bool {
        !self.tx.is_empty()
    }

    /// Sends a log message if its level passes the configured verbosity (see [`fw_log!`](crate::fw_log)).
    pub fn log(&mut self, level: LogLevel, module: &str, args: core::fmt::Arguments<'_>) {
        if let Some(p) = crate::log::format(level, self.settings.log.level, module, args) {
            self.send(&p);
        }
    }

    fn rx_error(&mut self) {
        self.state.link.rx_errors = self.state.link.rx_errors.wrapping_add(1);
    }

    fn send<P: Packet>(&mut self, p: &P) {
        let mut buf = OutPacket::new();
        // A fresh buffer holds MAX_PACKET bytes, more than any packet struct.
        let _ = buf.resize_default(MAX_PACKET);
        match protocol::encode(p, &mut buf) {
            Ok(n) => buf.truncate(n),
            Err(_) => return,
        }
        if self.tx.push_back(buf).is_err() {
            self.state.link.tx_dropped = self.state.link.tx_dropped.wrapping_add(1);
        } else {
            self.state.link.tx_packets = self.state.link.tx_packets.wrapping_add(1);
        }
    }

    fn nack(&mut self, t: PacketType, reason: NackReason) {
        self.nack_code(t as u8, reason, Nack::NO_FIELD);
    }

    fn nack_code(&mut self, code: u8, reason: NackReason, field_offset: u16) {
        self.send(&Nack {
            packet_type: code,
            reason: reason as u8,
            field_offset,
        });
    }

    fn settings_nack(&mut self, t: PacketType, e: SettingsError) {
        self.nack_code(t as u8, e.nack_reason(), e.field_offset());
    }

    /// Carries out one checked packet whose frame carried `payload_len` payload bytes.
    fn handle(&mut self, packet: AnyPacket, payload_len: usize) {
        let t = packet.packet_type();
        match packet {
            AnyPacket::Ping(p) => self.pong(p),
            AnyPacket::HelloRequest(_) => self.send_hello(),
            AnyPacket::StraightMovement(m) => self.enqueue(t, straight_move(m)),
            AnyPacket::RotationMovement(m) => self.enqueue(t, rotation_move(m)),
            AnyPacket::ArcMovement(m) => self.enqueue(t, arc_move(m)),
            AnyPacket::ClearQueue(_) => self.clear_queue(),
            AnyPacket::Stop(_) => self.halt(MoveOutcome::Stopped),
            AnyPacket::WheelSpeeds(w) => self.drive_wheel_speeds(t, w),
            AnyPacket::MotorPower(m) => self.drive_motor_power(m),
            AnyPacket::LineFollow(f) => self.line_follow(f),
            AnyPacket::LineCalibration(c) => self.calibrate_line(t, c),
            AnyPacket::SetLed(l) => self.set_led(l),
            AnyPacket::IrMessage(m) => self.ir_message = m.message,
            AnyPacket::SettingsUpdate(u) => self.update_settings(t, u, payload_len),
            AnyPacket::SettingsRead(r) => self.read_settings(t, r),
            AnyPacket::SettingsSave(_) => self.save_settings(t),
            AnyPacket::SettingsRestoreDefaults(_) => self.restore_default_settings(),
            AnyPacket::ReflectorConfig(c) => self.configure_reflector(t, c),
            // Robot-to-host packets coming back are ignored, as a robot would.
            AnyPacket::State(_)
            | AnyPacket::ReducedState(_)
            | AnyPacket::Hello(_)
            | AnyPacket::Pong(_)
            | AnyPacket::SettingsData(_)
            | AnyPacket::Log(_)
            | AnyPacket::Nack(_)
            | AnyPacket::MoveFinished(_)
            | AnyPacket::QueueEmpty(_)
            | AnyPacket::Obstacle(_)
            | AnyPacket::RobotEncountered(_)
            | AnyPacket::LineEvent(_)
            | AnyPacket::WatchdogStop(_)
            | AnyPacket::LoopOverrun(_)
            | AnyPacket::SettingsSaved(_) => {}
        }
    }

    fn send_hello(&mut self) {
        let hello = Hello::new(&self.settings, FIRMWARE_VERSION);
        self.send(&hello);
    }

    fn pong(&mut self, p: packets::Ping) {
        let pong = packets::Pong {
            seq: p.seq,
            host_time_us: p.host_time_us,
            robot_time_us: self.now.as_micros(),
        };
        self.send(&pong);
    }

    // --- Moves and direct drive ---

    fn clear_queue(&mut self) {
        self.abort_moves(MoveOutcome::Cleared);
        if self.drive == Drive::Moves {
            self.drive = Drive::Idle;
        }
    }

    fn drive_wheel_speeds(&mut self, t: PacketType, w: packets::WheelSpeeds) {
        let (l, r) = (w.left_mps, w.right_mps);
        if !(l.is_finite() && r.is_finite()) {
            return self.nack(t, NackReason::BadParameter);
        }
        self.abort_moves(MoveOutcome::Cleared);
        let max = self.settings.locomotion.max_speed_mps;
        let drive = Drive::WheelSpeeds {
            left: l.clamp(-max, max),
            right: r.clamp(-max, max),
        };
        self.set_drive(drive);
    }

    fn drive_motor_power(&mut self, m: packets::MotorPower) {
        self.abort_moves(MoveOutcome::Cleared);
        self.set_drive(Drive::MotorPower {
            left: m.left_pwm,
            right: m.right_pwm,
        });
    }

    // --- Line sensor and following ---

    fn line_follow(&mut self, f: packets::LineFollow) {
        if f.enable == 0 {
            if matches!(self.drive, Drive::LineFollow { .. }) {
                self.set_drive(Drive::Idle);
            }
            return;
        }
        let s = f.speed_mps;
        let speed = if s.is_finite() && s > 0.0 {
            s.min(self.settings.locomotion.max_speed_mps)
        } else {
            self.settings.line_follow.speed_mps
        };
        self.abort_moves(MoveOutcome::Cleared);
        self.follower.reset();
        self.set_drive(Drive::LineFollow { speed_mps: speed });
    }

    fn calibrate_line(&mut self, t: PacketType, c: packets::LineCalibration) {
        match CalibrationAction::try_from(c.action) {
            Ok(action) => self
                .line_sensor
                .calibrate(action, &mut self.settings.line_sensor),
            Err(_) => self.nack(t, NackReason::BadParameter),
        }
    }

    // --- Outputs ---

    fn set_led(&mut self, l: packets::SetLed) {
        self.board.set_rgb(l.red, l.green, l.blue);
        self.state.led = [l.red, l.green, l.blue];
    }

    // --- Settings and the reflector ---

    fn update_settings(&mut self, t: PacketType, u: packets::SettingsUpdate, payload_len: usize) {
        let (offset, bytes) = (usize::from(u.offset), u.bytes());
        match u
            .check_carried(payload_len)
            .and_then(|()| self.settings.update(offset, bytes))
        {
            Ok(()) => self.settings_changed(),
            Err(e) => self.settings_nack(t, e),
        }
    }

    fn read_settings(&mut self, t: PacketType, r: packets::SettingsRead) {
        let (offset, len) = (usize::from(r.offset), usize::from(r.len));
        let data = if len <= SETTINGS_CHUNK {
            self.settings.read(offset, len).ok()
        } else {
            None
        };
        match data.and_then(|d| packets::SettingsData::new(r.offset, d)) {
            Some(d) => self.send(&d),
            None => self.nack(t, NackReason::BadSettingsRange),
        }
    }

    fn save_settings(&mut self, t: PacketType) {
        let image = self.settings;
        match self.board.store(image.as_bytes()) {
            Ok(()) => self.send(&packets::SettingsSaved {
                size: Settings::SIZE as u16,
            }),
            Err(_) => self.nack(t, NackReason::StorageFailed),
        }
    }

    fn restore_default_settings(&mut self) {
        // The identity belongs to this robot, not to the factory image.
        let restored = Settings {
            identity: self.settings.identity,
            ..Settings::default()
        };
        // The live identity was validated when written; should it not pass, the factory
        // identity is the one known-good choice.
        self.settings = match restored.validate() {
            Ok(()) => restored,
            Err(_) => Settings::default(),
        };
        self.settings_changed();
    }

    fn configure_reflector(&mut self, t: PacketType, c: packets::ReflectorConfig) {
        if ReflectorMode::try_from(c.mode).is_err() {
            return self.nack(t, NackReason::BadParameter);
        }
        self.settings.reflector.mode = c.mode;
        self.settings.reflector.period_ms = c.period_ms.max(1);
        self.reflector.restart();
    }

    fn settings_changed(&mut self) {
        self.reflector.restart();
    }

    fn enqueue(&mut self, t: PacketType, mv: Move) {
        if self.drive != Drive::Moves {
            // Moves take over from teleop and line following.
            self.set_drive(Drive::Moves);
        }
        match self.locomotion.enqueue(mv) {
            Ok(()) => {}
            Err(EnqueueError::QueueFull) => self.nack(t, NackReason::QueueFull),
            Err(EnqueueError::BadParameter) => self.nack(t, NackReason::BadParameter),
        }
    }

    fn set_drive(&mut self, drive: Drive) {
        if core::mem::discriminant(&drive) != core::mem::discriminant(&self.drive) {
            self.wheel_pid = [Pid::new(); 2];
        }
        self.drive = drive;
    }

    fn abort_moves(&mut self, outcome: MoveOutcome) {
        let mut events: Vec<LocomotionEvent, 12> = Vec::new();
        self.locomotion.abort(outcome, &mut |e| {
            let _ = events.push(e);
        });
        for e in events {
            self.locomotion_event(e);
        }
    }

    /// Everything stops: queue cleared, teleop and following off, motors off.
    fn halt(&mut self, outcome: MoveOutcome) {
        self.abort_moves(outcome);
        self.set_drive(Drive::Idle);
        self.apply_pwm(0.0, 0.0);
    }

    fn locomotion_event(&mut self, e: LocomotionEvent) {
        match e {
            LocomotionEvent::Finished { id, outcome } => self.send(&packets::MoveFinished {
                move_id: id,
                outcome: outcome as u8,
            }),
            LocomotionEvent::QueueEmpty => self.send(&packets::QueueEmpty {}),
        }
    }

    fn main_loop(&mut self, scheduled: Instant, now: Instant) {
        let period = Duration::from_micros(u64::from(self.settings.scheduler.main_period_us));
        let (next, overrun) = next_period(scheduled, now, period);
        self.scheduler.schedule(Channel::MainLoop, next);
        if let Some(late) = overrun {
            self.state.link.overruns = self.state.link.overruns.wrapping_add(1);
            self.send(&packets::LoopOverrun {
                late_us: late.as_micros().min(u64::from(u32::MAX)) as u32,
            });
        }
        let dt = self
            .last_main
            .map_or(period, |last| now - last)
            .as_secs_f32()
            .max(1e-4);
        self.last_main = Some(now);

        let g = self.settings.geometry;
        let tick = tick_m(g.wheel_diameter_m, g.ticks_per_rev);
        let timeout = Duration::from_micros(u64::from(self.settings.speed_meter.timeout_us));
        let wheels = WheelInputs {
            left_ticks: self.speed[0].ticks(),
            right_ticks: self.speed[1].ticks(),
            left_mps: self.speed[0].speed(now, tick, timeout),
            right_mps: self.speed[1].speed(now, tick, timeout),
        };
        let (targets, pwm) = self.control(now, wheels, dt);
        // A single-channel encoder cannot see direction: pulses count in the direction the wheel
        // is meant to turn (its target's sign, or the duty's without a target), and that changes
        // only from standstill. Moves wait for their wheels to read zero speed before reversing
        // one, and count from there. The speed loops (line following, wheel speeds) are stricter:
        // standstill is no edge for the meter's timeout (the first edge after a pause reads as
        // zero speed while the wheel still turns); and a target the meter cannot resolve leaves
        // the wheel resting. No mode brakes against the counted direction (below).
        let speed_loop = matches!(
            self.drive,
            Drive::LineFollow { .. } | Drive::WheelSpeeds { .. }
        );
        let slowest_seen = self.slowest_seen();
        let speeds = [wheels.left_mps, wheels.right_mps];
        let mut duty = [pwm.0, pwm.1];
        for (k, d) in duty.iter_mut().enumerate() {
            let target = [targets.0, targets.1][k];
            let target = if speed_loop && target.abs() < slowest_seen {
                0.0
            } else {
                target
            };
            let intent = if target != 0.0 { target } else { *d };
            if intent == 0.0 {
                continue;
            }
            let turning = if speed_loop {
                self.speed[k].moving(now, timeout)
            } else {
                speeds[k] != 0.0
            };
            let backwards = intent < 0.0;
            if backwards != self.speed[k].is_backwards() {
                if turning {
                    *d = 0.0;
                } else {
                    self.speed[k].set_backwards(backwards);
                }
            }
            let brakes = *d != 0.0 && (*d < 0.0) != self.speed[k].is_backwards();
            // A duty against the counted direction is never applied; the shorted motor and
            // friction slow the wheel. Braking carries a wheel through zero unseen (the meter
            // reads the last pulse interval, and lags most near standstill); its pulses then
            // count the wrong way, it reads faster than its target, and braking on drives it
            // backwards ever harder. Steering hard over a colour mark once counted a metre
            // forwards as a metre backwards; a move braking at its start reversed a robot 11 cm
            // while its model drove 11 cm ahead.
            if brakes {
                *d = 0.0;
            }
        }
        self.apply_pwm(duty[0], duty[1]);
        self.sample_sensors(now, wheels, targets);
        if let Some(mode) = self.reflector.due(now, &self.settings.reflector) {
            match mode {
                ReflectorMode::Full => {
                    let s = self.state;
                    self.send(&s);
                }
                ReflectorMode::Reduced => {
                    let r = self.state.reduced();
                    self.send(&r);
                }
                ReflectorMode::None => {}
            }
        }
    }

    /// Runs the active drive mode: returns wheel-speed targets and duties.
    fn control(&mut self, now: Instant, wheels: WheelInputs, dt: f32) -> ((f32, f32), (f32, f32)) {
        match self.drive {
            Drive::Idle => ((0.0, 0.0), (0.0, 0.0)),
            Drive::MotorPower { left, right } => ((0.0, 0.0), (f32::from(left), f32::from(right))),
            Drive::WheelSpeeds { left, right } => (
                (left, right),
                self.wheel_speed_control(wheels, (left, right), dt),
            ),
            Drive::LineFollow { speed_mps } => {
                let mark = Mark::try_from(self.state.line.mark).unwrap_or(Mark::None);
                let out = self.follower.update(
                    now,
                    &self.line,
                    mark,
                    speed_mps,
                    &self.settings.line_pid,
                    &self.settings.line_follow,
                    dt,
                );
                if out.gave_up {
                    self.set_drive(Drive::Idle);
                    crate::fw_log!(self, Warn, "line", "line lost, following stopped");
                    return ((0.0, 0.0), (0.0, 0.0));
                }
                let t = (out.left_mps, out.right_mps);
                (t, self.wheel_speed_control(wheels, t, dt))
            }
            Drive::Moves => {
                let mut events: Vec<LocomotionEvent, 4> = Vec::new();
                let cmd = self.locomotion.step(wheels, &self.settings, dt, &mut |e| {
                    let _ = events.push(e);
                });
                for e in events {
                    self.locomotion_event(e);
                }
                match cmd {
                    Some(DriveCommand {
                        left_pwm,
                        right_pwm,
                        left_target_mps,
                        right_target_mps,
                    }) => ((left_target_mps, right_target_mps), (left_pwm, right_pwm)),
                    None => {
                        self.set_drive(Drive::Idle);
                        ((0.0, 0.0), (0.0, 0.0))
                    }
                }
            }
        }
    }

    /// The slowest wheel speed the speed meter resolves: one pulse per timeout.
    fn slowest_seen(&self) -> f32 {
        let g = self.settings.geometry;
        let timeout = Duration::from_micros(u64::from(self.settings.speed_meter.timeout_us));
        tick_m(g.wheel_diameter_m, g.ticks_per_rev) / timeout.as_secs_f32().max(1e-3)
    }

    fn wheel_speed_control(
        &mut self,
        wheels: WheelInputs,
        target: (f32, f32),
        dt: f32,
    ) -> (f32, f32) {
        let ff = self.settings.locomotion.pwm_per_mps;
        let gains = self.settings.wheel_pid;
        let slowest_seen = self.slowest_seen();
        let measured = [wheels.left_mps, wheels.right_mps];
        let mut duty = [0.0; 2];
        for (k, t) in [target.0, target.1].into_iter().enumerate() {
            // A speed the meter cannot resolve cannot be held: the loop would only dither the
            // wheel back and forth, and its pulses would count the wrong way. The wheel rests.
            if t.abs() < slowest_seen {
                self.wheel_pid[k].reset();
            } else {
                duty[k] = ff * t + self.wheel_pid[k].update(&gains, t - measured[k], dt);
            }
        }
        (duty[0], duty[1])
    }

    /// Maps a duty request to the motor: dead-band compensation and limit.
    fn apply_pwm(&mut self, left: f32, right: f32) {
        let m = self.settings.motor;
        let max = f32::from(m.max_pwm.min(1000));
        let min = f32::from(m.min_pwm).min(max);
        let map = |p: f32| -> i16 {
            if !p.is_finite() || p.abs() < 0.5 {
                return 0;
            }
            let mag = (min + p.abs() * (max - min) / 1000.0).min(max);
            (mag.copysign(p)) as i16
        };
        let (l, r) = (map(left), map(right));
        self.board.set_pwm(l, r);
        self.state.wheels.left_pwm = l;
        self.state.wheels.right_pwm = r;
    }

    fn sample_sensors(&mut self, now: Instant, wheels: WheelInputs, targets: (f32, f32)) {
        let s = &mut self.state;
        s.uptime_ms = now.as_millis() as u32;
        s.encoders.left_ticks = wheels.left_ticks;
        s.encoders.right_ticks = wheels.right_ticks;
        s.wheels.left_mps = wheels.left_mps;
        s.wheels.right_mps = wheels.right_mps;
        s.wheels.left_target_mps = targets.0;
        s.wheels.right_target_mps = targets.1;
        let rgbc = self.board.read_colour();
        s.colour.red = rgbc[0];
        s.colour.green = rgbc[1];
        s.colour.blue = rgbc[2];
        s.colour.clear = rgbc[3];
        s.line.mark = classify_mark(rgbc, &self.settings.colour) as u8;
        let a = self.board.read_accel();
        s.accel.x_mg = a[0];
        s.accel.y_mg = a[1];
        s.accel.z_mg = a[2];
        s.power.battery_mv = self.board.battery_mv();
        s.power.current_ma = self.board.current_ma();
        s.power.temperature_dc = self.board.temperature_dc();
        s.locomotion.mode = self.drive.mode() as u8;
        s.locomotion.queue_len = self.locomotion.len() as u8;
        s.locomotion.active_move = self.locomotion.active_id().unwrap_or(0);
        s.locomotion.progress_m = self.locomotion.progress();
        s.proximity = self.proximity.state();
        let mut flags = 0;
        if self.line.lost {
            flags |= LINE_LOST;
        }
        if matches!(self.drive, Drive::LineFollow { .. }) {
            flags |= LINE_FOLLOWING;
        }
        if self.line_sensor.is_calibrating() {
            flags |= LINE_CALIBRATING;
        }
        s.line.flags = flags;
    }

    fn line_task(&mut self, scheduled: Instant, now: Instant) {
        let period = Duration::from_micros(u64::from(self.settings.scheduler.line_period_us));
        let (next, _) = next_period(scheduled, now, period);
        self.scheduler.schedule(Channel::LineSensor, next);
        let raw = self.line_sensor.sample(&mut self.board);
        let reading = self.line_sensor.process(&raw, &self.settings.line_sensor);
        if reading.lost != self.line.lost {
            self.send(&packets::LineEvent {
                lost: u8::from(reading.lost),
                position_um: self.line.position_um,
            });
        }
        self.line = reading;
        self.state.line.darkness = reading.darkness;
        self.state.line.position_um = reading.position_um;
    }

    fn ir_transmit_task(&mut self, scheduled: Instant, now: Instant) {
        let period = Duration::from_micros(u64::from(self.settings.scheduler.ir_slot_us));
        let (next, _) = next_period(scheduled, now, period);
        self.scheduler.schedule(Channel::IrTransmit, next);
        let (led, power, frame) = self.proximity.next_transmission(
            self.robot_id(),
            self.ir_message,
            &self.settings.proximity,
        );
        self.board.transmit(led, power, frame);
    }

    fn ir_report_task(&mut self, scheduled: Instant, now: Instant) {
        let (next, _) = next_period(scheduled, now, Duration::from_millis(20));
        self.scheduler.schedule(Channel::IrReport, next);
        while let Some(e) = self.proximity.poll_event(now, &self.settings.proximity) {
            match e {
                ProximityEvent::Obstacle(o) => self.send(&o),
                ProximityEvent::Robot(r) => self.send(&r),
            }
        }
    }
}

// Move packets in the units locomotion works in (radians, not the protocol's degrees).

fn straight_move(m: packets::StraightMovement) -> Move {
    Move {
        id: m.move_id,
        kind: MoveKind::Straight {
            distance_m: m.distance_m,
        },
        speed_mps: m.speed_mps,
    }
}

fn rotation_move(m: packets::RotationMovement) -> Move {
    Move {
        id: m.move_id,
        kind: MoveKind::Rotate {
            angle_rad: m.angle_deg.to_radians(),
        },
        speed_mps: m.speed_mps,
    }
}

fn arc_move(m: packets::ArcMovement) -> Move {
    Move {
        id: m.move_id,
        kind: MoveKind::Arc {
            radius_m: m.radius_m,
            angle_rad: m.angle_deg.to_radians(),
        },
        speed_mps: m.speed_mps,
    }
}

/// Lets a board that queues edges hand them over one by one (used by `tick`).
impl EncoderEdge {
    /// An edge of `wheel` at `at`.
    pub const fn new(wheel: Wheel, at: Instant) -> Self {
        Self { wheel, at }
    }
}
