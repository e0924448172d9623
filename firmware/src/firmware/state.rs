//! The robot state: the main loop's sensor readings written into it, and the reflector sending it.

use protocol::packets::ReflectorMode;
use protocol::state::{LINE_CALIBRATING, LINE_FOLLOWING, LINE_LOST};

use super::drive::Drive;
use super::Firmware;
use crate::hal::Board;
use crate::line_sensor::classify_mark;
use crate::locomotion::WheelInputs;
use crate::time::Instant;

impl<B: Board> Firmware<B> {
    pub(super) fn sample_sensors(
        &mut self,
        now: Instant,
        wheels: WheelInputs,
        targets: (f32, f32),
    ) {
        let uptime_ms = self.clock_ms(now);
        let s = &mut self.state;
        s.uptime_ms = uptime_ms;
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
        s.locomotion.last_move_id = self.last_move_id;
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

    /// Sends the full or reduced state when the reflector is due.
    pub(super) fn reflect_state(&mut self, now: Instant) {
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
}
