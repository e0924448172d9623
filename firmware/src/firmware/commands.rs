//! The host's commands: each checked packet dispatched to what carries it out (moves and direct
//! drive, line following and calibration, the LED, settings and the reflector).

use protocol::packets::{
    self, AnyPacket, CalibrationAction, Hello, MoveOutcome, NackReason, PacketType, ReflectorMode,
    SETTINGS_CHUNK,
};
use protocol::settings::Settings;

use super::drive::Drive;
use super::{Firmware, FIRMWARE_VERSION};
use crate::hal::Board;
use crate::locomotion::{EnqueueError, Move, MoveKind};

impl<B: Board> Firmware<B> {
    /// Carries out one checked packet whose frame carried `payload_len` payload bytes.
    pub(super) fn handle(&mut self, packet: AnyPacket, payload_len: usize) {
        let t = packet.packet_type();
        match packet {
            AnyPacket::Ping(p) => self.pong(p),
            AnyPacket::HelloRequest(_) => self.send_hello(),
            AnyPacket::EventReplay(r) => self.replay_events(r.from_seq),
            AnyPacket::StraightMovement(m) => self.enqueue(t, straight_move(m)),
            AnyPacket::RotationMovement(m) => self.enqueue(t, rotation_move(m)),
            AnyPacket::ArcMovement(m) => self.enqueue(t, arc_move(m)),
            AnyPacket::ClearQueue(c) => {
                self.skip_moves_before(c.keep_from);
                self.clear_queue(c.keep_from);
            }
            AnyPacket::Stop(s) => {
                self.skip_moves_before(s.keep_from);
                self.halt_keeping(s.keep_from, MoveOutcome::Stopped);
            }
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
            | AnyPacket::SettingsSaved(_)
            | AnyPacket::Bump(_)
            | AnyPacket::Reflex(_) => {}
        }
    }

    /// Introduces the robot; a host greeted afresh numbers its moves from 1 again.
    pub(super) fn send_hello(&mut self) {
        self.last_move_id = 0;
        let hello = Hello::new(&self.settings, FIRMWARE_VERSION);
        self.send(&hello);
    }

    fn pong(&mut self, p: packets::Ping) {
        let pong = packets::Pong {
            seq: p.seq,
            host_time_us: p.host_time_us,
            robot_time_us: self.now.since(self.boot).as_micros(),
        };
        self.send(&pong);
    }

    // --- Moves and direct drive ---

    /// Moves numbered before `keep_from` that never arrived are void: each is reported cleared,
    /// so the host stops waiting for it, and `keep_from` is the next move taken.
    fn skip_moves_before(&mut self, keep_from: u16) {
        if keep_from == 0 {
            return;
        }
        // At most a queue's worth of moves can be outstanding; a longer gap is a stale request.
        let gap = keep_from.wrapping_sub(next_move_id(self.last_move_id));
        if gap == 0 || gap > 32 {
            return;
        }
        let mut id = next_move_id(self.last_move_id);
        while id != keep_from {
            self.send_event(packets::MoveFinished {
                at_ms: 0,
                seq: 0,
                move_id: id,
                outcome: MoveOutcome::Cleared as u8,
            });
            self.last_move_id = id;
            id = next_move_id(id);
        }
    }

    fn clear_queue(&mut self, keep_from: u16) {
        self.abort_moves_older(keep_from, MoveOutcome::Cleared);
        if self.drive == Drive::Moves && self.locomotion.is_empty() {
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
        // Moves run in the order the host numbered them, from 1 after each hello: a copy sent
        // again (an id already taken) is ignored, and so is a move after a gap (one before it
        // was lost on the way: the host sends the gap again, then this one).
        if mv.id != next_move_id(self.last_move_id) {
            return;
        }
        self.last_move_id = mv.id;
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
}

/// The id after `id` in the host's numbering, which wraps and never uses 0.
fn next_move_id(id: u16) -> u16 {
    id.wrapping_add(1).max(1)
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
