//! What drives the motors (idle, moves, line following, teleop), switching between drive modes,
//! and aborting moves.

use heapless::Vec;
use protocol::packets::{self, DriveMode, MoveOutcome};

use super::Firmware;
use crate::hal::Board;
use crate::locomotion::LocomotionEvent;
use crate::pid::Pid;

/// What drives the motors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Drive {
    Idle,
    Moves,
    LineFollow { speed_mps: f32 },
    WheelSpeeds { left: f32, right: f32 },
    MotorPower { left: i16, right: i16 },
}

impl Drive {
    pub(super) fn mode(&self) -> DriveMode {
        match self {
            Drive::Idle => DriveMode::Idle,
            Drive::Moves => DriveMode::Moves,
            Drive::LineFollow { .. } => DriveMode::LineFollow,
            Drive::WheelSpeeds { .. } => DriveMode::WheelSpeeds,
            Drive::MotorPower { .. } => DriveMode::MotorPower,
        }
    }
}

impl<B: Board> Firmware<B> {
    pub(super) fn set_drive(&mut self, drive: Drive) {
        if core::mem::discriminant(&drive) != core::mem::discriminant(&self.drive) {
            self.wheel_pid = [Pid::new(); 2];
        }
        self.drive = drive;
    }

    pub(super) fn abort_moves(&mut self, outcome: MoveOutcome) {
        self.abort_moves_older(0, outcome);
    }

    /// Drops the moves older than `keep_from` (0: all of them).
    pub(super) fn abort_moves_older(&mut self, keep_from: u16, outcome: MoveOutcome) {
        let mut events: Vec<LocomotionEvent, 12> = Vec::new();
        self.locomotion.abort_older(keep_from, outcome, &mut |e| {
            let _ = events.push(e);
        });
        for e in events {
            self.locomotion_event(e);
        }
    }

    /// Everything stops: queue cleared, teleop and following off, motors off.
    pub(super) fn halt(&mut self, outcome: MoveOutcome) {
        self.halt_keeping(0, outcome);
    }

    /// Everything stops but the moves numbered `keep_from` or later (0: none), which start
    /// after the stop.
    pub(super) fn halt_keeping(&mut self, keep_from: u16, outcome: MoveOutcome) {
        self.abort_moves_older(keep_from, outcome);
        let next = if self.locomotion.is_empty() {
            Drive::Idle
        } else {
            Drive::Moves
        };
        self.set_drive(next);
        self.apply_pwm(0.0, 0.0);
    }

    pub(super) fn locomotion_event(&mut self, e: LocomotionEvent) {
        match e {
            LocomotionEvent::Finished { id, outcome } => self.send_event(packets::MoveFinished {
                at_ms: 0,
                seq: 0,
                move_id: id,
                outcome: outcome as u8,
            }),
            LocomotionEvent::QueueEmpty => {
                self.send_event(packets::QueueEmpty { at_ms: 0, seq: 0 })
            }
        }
    }
}
