//! The main loop: wheel speeds in, the active drive mode's targets and duties, the encoders'
//! direction guarded, and the duty mapped onto the motors.

use heapless::Vec;
use protocol::packets::{self, Mark};

use super::drive::Drive;
use super::Firmware;
use crate::hal::Board;
use crate::locomotion::{tick_m, DriveCommand, LocomotionEvent, WheelInputs};
use crate::scheduler::{next_period, Channel};
use crate::time::{Duration, Instant};

/// The sum of the wheels' targets (m/s) or duties beyond which the robot drives forwards or
/// backwards, for the reflex: a turn on the spot sums to zero.
const REFLEX_DRIVE: f32 = 1e-3;

impl<B: Board> Firmware<B> {
    pub(super) fn main_loop(&mut self, scheduled: Instant, now: Instant) {
        let period = Duration::from_micros(u64::from(self.settings.scheduler.main_period_us));
        let (next, overrun) = next_period(scheduled, now, period);
        self.scheduler.schedule(Channel::MainLoop, next);
        if let Some(late) = overrun {
            self.state.link.overruns = self.state.link.overruns.wrapping_add(1);
            self.send_event(packets::LoopOverrun {
                at_ms: 0,
                seq: 0,
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
        let (targets, pwm) = if self.reflex(now, targets, pwm) {
            ((0.0, 0.0), (0.0, 0.0))
        } else {
            (targets, pwm)
        };
        let duty = self.guard_direction(now, wheels, targets, pwm, timeout);
        self.apply_pwm(duty[0], duty[1]);
        self.sample_sensors(now, wheels, targets);
        self.detect_bump(now, wheels, dt, tick);
        self.reflect_state(now);
    }

    /// The proximity reflex: a drive towards a surface close enough to return the robot's own
    /// light at `reflex.power_level` or weaker stops, whatever the host believes, and is
    /// reported. Turning on the spot is no drive towards anything and goes on. Returns whether it
    /// stopped the robot.
    fn reflex(&mut self, now: Instant, targets: (f32, f32), pwm: (f32, f32)) -> bool {
        let level = self.settings.reflex.power_level;
        if level == 0 || self.drive == Drive::Idle {
            return false;
        }
        let ahead = match self.drive {
            Drive::MotorPower { .. } => pwm.0 + pwm.1,
            _ => targets.0 + targets.1,
        };
        // What the receivers see now, not the reports' memory of the last second: a robot that
        // has just turned away from the box would otherwise stop at the box it no longer faces.
        let (side, power) = if ahead > REFLEX_DRIVE {
            (
                packets::Side::Front,
                self.proximity.reflection(packets::Side::Front),
            )
        } else if ahead < -REFLEX_DRIVE {
            (
                packets::Side::Rear,
                self.proximity.reflection(packets::Side::Rear),
            )
        } else {
            return false;
        };
        if power == 0 || power > level {
            return false;
        }
        self.halt(packets::MoveOutcome::Blocked);
        self.send_event_at(packets::Reflex {
            at_ms: self.clock_ms(now),
            seq: 0,
            side: side as u8,
            power_level: power,
        });
        crate::fw_log!(self, Info, "reflex", "stopped short of something close");
        true
    }

    /// Reports a bump once the detector has seen one (see [`crate::bump`]).
    fn detect_bump(&mut self, now: Instant, wheels: WheelInputs, dt: f32, tick: f32) {
        let sample = crate::bump::Sample {
            now,
            dt,
            accel_mg: [self.state.accel.x_mg, self.state.accel.y_mg],
            wheels_mps: (wheels.left_mps, wheels.right_mps),
            gauge_m: self.settings.geometry.wheel_gauge_m,
            ticks: (wheels.left_ticks, wheels.right_ticks),
            tick_m: tick,
            idle: self.drive == Drive::Idle
                && self.locomotion.is_empty()
                && self.state.wheels.left_pwm == 0
                && self.state.wheels.right_pwm == 0,
        };
        if let Some(b) = self.bump.update(&sample, &self.settings.bump) {
            self.send_event_at(packets::Bump {
                at_ms: self.clock_ms(b.at),
                seq: 0,
                peak_mg: b.peak_mg.clamp(0.0, f32::from(u16::MAX)) as u16,
                moved_mm: (b.moved_m * 1e3).clamp(0.0, f32::from(u16::MAX)) as u16,
                along_mm: (b.moved[0] * 1e3).clamp(-32767.0, 32767.0) as i16,
                left_mm: (b.moved[1] * 1e3).clamp(-32767.0, 32767.0) as i16,
                cause: b.cause as u8,
            });
        }
    }

    /// The duties `pwm` with every duty the encoders could not count the right way taken off:
    /// a wheel that must reverse stops first, and no wheel brakes against its counted direction.
    fn guard_direction(
        &mut self,
        now: Instant,
        wheels: WheelInputs,
        targets: (f32, f32),
        pwm: (f32, f32),
        timeout: Duration,
    ) -> [f32; 2] {
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
        duty
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
    pub(super) fn apply_pwm(&mut self, left: f32, right: f32) {
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
}
