//! Line following: a PID on the line position sets the wheel-speed difference (thesis 11.2).

use crate::line_sensor::LineReading;
use crate::pid::Pid;
use crate::time::{Duration, Instant};
use protocol::packets::Mark;
use protocol::settings::{LineFollowSettings, PidSettings};

/// Share of the speed kept while the line is lost: slow enough to turn back onto it.
const LOST_SPEED_FACTOR: f32 = 0.5;
/// Slowest set-point: a wheel stops at most, it is never driven backwards. A single-channel
/// encoder counts a reversing wheel's last coasting pulses the wrong way, and hard steering over
/// a colour mark reversed the inner wheel several times a second: 14° of phantom heading in one
/// second. Pivoting on a stopped wheel still turns on a 13 mm radius, far tighter than any
/// curve of tape.
const MIN_WHEEL_MPS: f32 = 0.0;

/// Wheel-speed set-points for the wheel-speed PIDs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FollowOutput {
    /// Left wheel speed in m/s, positive = forward.
    pub left_mps: f32,
    /// Right wheel speed in m/s, positive = forward.
    pub right_mps: f32,
    /// The line has been lost for longer than the timeout; the speeds are zero.
    pub gave_up: bool,
}

/// Line follower state: the line-position PID and how long the line has been lost.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LineFollower {
    pid: Pid,
    lost_since: Option<Instant>,
}

impl LineFollower {
    /// A follower with no history.
    pub const fn new() -> Self {
        Self {
            pid: Pid::new(),
            lost_since: None,
        }
    }

    /// Forgets the PID history and the lost timer, e.g. when following (re)starts.
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Wheel-speed set-points: base speed scaled by the mark (`red_factor` / `blue_factor`), PID on
    /// the line position (error in metres) whose output `u` is the wheel-speed difference (thesis
    /// fig. 11.3): left = v + u/2, right = v − u/2, so a line to the right turns the robot right.
    ///
    /// While the line is lost the follower keeps steering toward the held position at half speed;
    /// once lost for longer than `lost_timeout_ms` it gives up with zero speeds.
    #[allow(clippy::too_many_arguments)]
    pub fn update(
        &mut self,
        now: Instant,
        reading: &LineReading,
        mark: Mark,
        base_speed_mps: f32,
        line_pid: &PidSettings,
        settings: &LineFollowSettings,
        dt: f32,
    ) -> FollowOutput {
        if reading.lost {
            let since = *self.lost_since.get_or_insert(now);
            let timeout = Duration::from_millis(u64::from(settings.lost_timeout_ms));
            if now.since(since) > timeout {
                // A fresh start when the line is found again: the history belongs to a line that
                // is gone.
                self.pid.reset();
                return FollowOutput {
                    left_mps: 0.0,
                    right_mps: 0.0,
                    gave_up: true,
                };
            }
        } else {
            self.lost_since = None;
        }

        let factor = match mark {
            Mark::Red => settings.red_factor,
            Mark::Blue => settings.blue_factor,
            Mark::None => 1.0,
        };
        // The sensor looks ahead of the wheels, so following only works forwards; a corrupt
        // setting stops the robot instead of driving it backwards or at infinite speed.
        let mut v = finite_or_zero(base_speed_mps * factor).max(0.0);
        if reading.lost {
            v *= LOST_SPEED_FACTOR;
        }

        let error_m = f32::from(reading.position_um) * 1e-6;
        let u = finite_or_zero(self.pid.update(line_pid, error_m, dt));
        let (lo, hi) = (MIN_WHEEL_MPS, v + libm::fabsf(u));
        FollowOutput {
            left_mps: (v + u / 2.0).clamp(lo, hi),
            right_mps: (v - u / 2.0).clamp(lo, hi),
            gave_up: false,
        }
    }
}

fn finite_or_zero(x: f32) -> f32 {
    if x.is_finite() {
        x
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::settings::Settings;

    const DT: f32 = 0.005;

    fn reading(position_um: i16, lost: bool) -> LineReading {
        LineReading {
            darkness: [0; 8],
            position_um,
            lost,
        }
    }

    fn step(f: &mut LineFollower, ms: u64, r: &LineReading, mark: Mark) -> FollowOutput {
        let s = Settings::default();
        let lf = s.line_follow;
        f.update(
            Instant::from_millis(ms),
            r,
            mark,
            lf.speed_mps,
            &s.line_pid,
            &lf,
            DT,
        )
    }

    #[test]
    fn line_follow_centred_line_drives_straight() {
        let mut f = LineFollower::new();
        let o = step(&mut f, 0, &reading(0, false), Mark::None);
        assert_eq!(o.left_mps, o.right_mps);
        assert!((o.left_mps - 0.2).abs() < 1e-6, "{o:?}");
        assert!(!o.gave_up);
    }

    #[test]
    fn line_follow_line_to_the_right_turns_right() {
        let mut f = LineFollower::new();
        let o = step(&mut f, 0, &reading(2000, false), Mark::None);
        assert!(o.left_mps > o.right_mps, "{o:?}");
        // The mean speed is kept: the PID only splits it between the wheels.
        assert!(
            ((o.left_mps + o.right_mps) / 2.0 - 0.2).abs() < 1e-6,
            "{o:?}"
        );
        let mut f = LineFollower::new();
        let o = step(&mut f, 0, &reading(-2000, false), Mark::None);
        assert!(o.left_mps < o.right_mps, "{o:?}");
    }

    #[test]
    fn line_follow_marks_scale_the_speed() {
        let mut f = LineFollower::new();
        let o = step(&mut f, 0, &reading(0, false), Mark::Red);
        assert!(
            (o.left_mps - 0.1).abs() < 1e-6 && o.left_mps == o.right_mps,
            "{o:?}"
        );
        let o = step(&mut f, 5, &reading(0, false), Mark::Blue);
        assert!(
            (o.left_mps - 0.3).abs() < 1e-6 && o.left_mps == o.right_mps,
            "{o:?}"
        );
    }

    #[test]
    fn line_follow_never_drives_a_wheel_backwards() {
        let mut f = LineFollower::new();
        // Far right: the PID saturates at ±0.4 m/s difference, more than twice the speed.
        let o = step(&mut f, 0, &reading(10_000, false), Mark::Red);
        assert_eq!(o.right_mps, 0.0, "{o:?}");
        assert!((o.left_mps - 0.3).abs() < 1e-6, "{o:?}");
    }

    #[test]
    fn line_follow_lost_steers_toward_the_held_edge_at_half_speed() {
        let mut f = LineFollower::new();
        let o = step(&mut f, 0, &reading(1000, true), Mark::None);
        assert!(!o.gave_up);
        assert!(o.left_mps > o.right_mps, "{o:?}");
        assert!(
            ((o.left_mps + o.right_mps) / 2.0 - 0.1).abs() < 1e-6,
            "{o:?}"
        );
    }

    #[test]
    fn line_follow_lost_beyond_timeout_gives_up() {
        let mut f = LineFollower::new();
        step(&mut f, 0, &reading(0, false), Mark::None);
        let mut ms = 5;
        while ms <= 400 + 5 {
            let o = step(&mut f, ms, &reading(10_500, true), Mark::None);
            assert!(!o.gave_up, "gave up after {} ms", ms - 5);
            ms += 5;
        }
        let o = step(&mut f, ms, &reading(10_500, true), Mark::None);
        assert!(o.gave_up);
        assert_eq!((o.left_mps, o.right_mps), (0.0, 0.0));
    }

    #[test]
    fn line_follow_short_losses_do_not_add_up() {
        let mut f = LineFollower::new();
        // Lost for 300 ms, found for one step, lost for 300 ms again: never continuously > 400.
        let mut ms = 0;
        for _ in 0..2 {
            for _ in 0..60 {
                let o = step(&mut f, ms, &reading(-10_500, true), Mark::None);
                assert!(!o.gave_up, "gave up at {ms} ms");
                assert!(o.right_mps > o.left_mps);
                ms += 5;
            }
            assert!(!step(&mut f, ms, &reading(-3000, false), Mark::None).gave_up);
            ms += 5;
        }
    }

    #[test]
    fn line_follow_reset_forgets_the_lost_timer() {
        let mut f = LineFollower::new();
        step(&mut f, 0, &reading(10_500, true), Mark::None);
        assert!(step(&mut f, 500, &reading(10_500, true), Mark::None).gave_up);
        f.reset();
        assert!(!step(&mut f, 600, &reading(10_500, true), Mark::None).gave_up);
    }

    #[test]
    fn line_follow_non_finite_inputs_stop_instead_of_running_away() {
        let s = Settings::default();
        let mut f = LineFollower::new();
        let r = reading(0, false);
        let o = f.update(
            Instant::ZERO,
            &r,
            Mark::None,
            f32::NAN,
            &s.line_pid,
            &s.line_follow,
            DT,
        );
        assert_eq!((o.left_mps, o.right_mps), (0.0, 0.0));
        let o = f.update(
            Instant::ZERO,
            &r,
            Mark::None,
            -0.2,
            &s.line_pid,
            &s.line_follow,
            DT,
        );
        assert_eq!((o.left_mps, o.right_mps), (0.0, 0.0));
    }

    /// Lateral offset (m, positive = robot left of the line) after following a straight line along
    /// the x axis from `y0` for `seconds`, with the sensor `sensor_ahead_m` in front of the axle.
    /// Returns the largest |offset| seen after `settle_s`.
    fn closed_loop(gains: &PidSettings, y0: f32, sensor_ahead_m: f32, settle_s: f32) -> f32 {
        let s = Settings::default();
        let gauge = 0.026;
        let pitch_um = f32::from(s.line_sensor.spot_pitch_um);
        let mut f = LineFollower::new();
        let (mut y, mut heading) = (y0, 0.0f32);
        let mut worst_after = 0.0f32;
        for k in 0..400u64 {
            let t = k as f32 * DT;
            // Where the sensor bar crosses the line, measured along the bar (to the robot's right).
            let sensor_y = y + sensor_ahead_m * libm::sinf(heading);
            let pos_um = sensor_y / libm::cosf(heading) * 1e6;
            let lost = pos_um.abs() > 3.5 * pitch_um;
            let held = pos_um.clamp(-3.5 * pitch_um, 3.5 * pitch_um);
            let r = reading(held.round() as i16, lost);
            let o = f.update(
                Instant::from_millis(k * 5),
                &r,
                Mark::None,
                s.line_follow.speed_mps,
                gains,
                &s.line_follow,
                DT,
            );
            assert!(!o.gave_up);
            let v = (o.left_mps + o.right_mps) / 2.0;
            // Heading is counter-clockwise; a faster left wheel turns clockwise, toward −y.
            heading += (o.right_mps - o.left_mps) / gauge * DT;
            y += v * libm::sinf(heading) * DT;
            if t >= settle_s {
                worst_after = worst_after.max(y.abs());
            }
        }
        worst_after
    }

    #[test]
    fn line_follow_closed_loop_converges_with_default_gains() {
        let gains = Settings::default().line_pid;
        for y0 in [0.004, -0.004] {
            // Sensor on the axle is the hardest case: no look-ahead damping from the geometry.
            for ahead in [0.0, 0.01, 0.02] {
                let worst = closed_loop(&gains, y0, ahead, 1.0);
                assert!(
                    worst < 0.0005,
                    "start {y0} m, sensor {ahead} m ahead: {worst} m after 1 s"
                );
            }
        }
    }

    #[test]
    fn line_follow_closed_loop_fails_without_steering() {
        // The convergence test must be able to fail: with no steering the offset stays.
        let gains = PidSettings {
            kp: 0.0,
            ki: 0.0,
            kd: 0.0,
            i_limit: 0.0,
            out_limit: 0.0,
        };
        assert!(closed_loop(&gains, 0.004, 0.0, 1.0) > 0.0035);
    }
}
