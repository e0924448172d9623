//! The scheduler's other channels: sampling the line sensor, transmitting IR frames, reporting
//! what the IR receivers saw.

use protocol::packets::{self};

use super::Firmware;
use crate::hal::Board;
use crate::proximity::ProximityEvent;
use crate::scheduler::{next_period, Channel};
use crate::time::{Duration, Instant};

impl<B: Board> Firmware<B> {
    pub(super) fn line_task(&mut self, scheduled: Instant, now: Instant) {
        let period = Duration::from_micros(u64::from(self.settings.scheduler.line_period_us));
        let (next, _) = next_period(scheduled, now, period);
        self.scheduler.schedule(Channel::LineSensor, next);
        let raw = self.line_sensor.sample(&mut self.board);
        let reading = self.line_sensor.process(&raw, &self.settings.line_sensor);
        if reading.lost != self.line.lost {
            self.send_event(packets::LineEvent {
                at_ms: 0,
                seq: 0,
                lost: u8::from(reading.lost),
                position_um: self.line.position_um,
            });
        }
        self.line = reading;
        self.state.line.darkness = reading.darkness;
        self.state.line.position_um = reading.position_um;
    }

    pub(super) fn ir_transmit_task(&mut self, scheduled: Instant, now: Instant) {
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

    pub(super) fn ir_report_task(&mut self, scheduled: Instant, now: Instant) {
        let (next, _) = next_period(scheduled, now, Duration::from_millis(20));
        self.scheduler.schedule(Channel::IrReport, next);
        while let Some(e) = self.proximity.poll_event(now, &self.settings.proximity) {
            match e {
                ProximityEvent::Obstacle(o) => self.send_event(o),
                ProximityEvent::Robot(r) => self.send_event(r),
            }
        }
    }
}
