//! Wheel speed by fixed Δs (thesis 11.5): the time between encoder edges, not edges per time.
//!
//! The encoder disc's black stripes are narrower than the white ones, so odd and even periods
//! differ (thesis fig. 11.7); the mean of the last two periods spans exactly two stripes and
//! cancels that. With no edge for `timeout` the speed reads zero. A single-channel encoder cannot
//! tell direction, so edges count in the direction the motor was last driven.

use crate::time::{Duration, Instant};

/// Speed and pulse count of one wheel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SpeedMeter {
    last_edge: Option<Instant>,
    periods: [Option<Duration>; 2],
    ticks: i32,
    backwards: bool,
}

impl SpeedMeter {
    /// No edges seen.
    pub const fn new() -> Self {
        Self {
            last_edge: None,
            periods: [None; 2],
            ticks: 0,
            backwards: false,
        }
    }

    /// Sets the direction edges count in, from the sign of the applied motor duty.
    pub fn set_backwards(&mut self, backwards: bool) {
        self.backwards = backwards;
    }

    /// An encoder edge captured at `at`; periods longer than `timeout` start a new measurement.
    pub fn on_edge(&mut self, at: Instant, timeout: Duration) {
        self.ticks = self.ticks.wrapping_add(if self.backwards { -1 } else { 1 });
        if let Some(last) = self.last_edge {
            let period = at - last;
            if period > timeout || period == Duration::ZERO {
                self.periods = [None; 2];
            } else {
                self.periods = [Some(period), self.periods[0]];
            }
        }
        self.last_edge = Some(at);
    }

    /// Whether an edge came within `timeout` of `now`. A wheel whose speed reads zero may still be
    /// turning: the first edge after a pause starts a new period measurement.
    pub fn moving(&self, now: Instant, timeout: Duration) -> bool {
        self.last_edge.is_some_and(|last| now - last <= timeout)
    }

    /// Whether pulses currently count backwards.
    pub fn is_backwards(&self) -> bool {
        self.backwards
    }

    /// Pulses since boot, signed by direction (wraps).
    pub fn ticks(&self) -> i32 {
        self.ticks
    }

    /// Speed in m/s at `now` for `tick_m` metres per pulse: zero after `timeout` without an edge.
    pub fn speed(&self, now: Instant, tick_m: f32, timeout: Duration) -> f32 {
        let Some(last) = self.last_edge else {
            return 0.0;
        };
        if now - last > timeout {
            return 0.0;
        }
        let mean_ns = match self.periods {
            [Some(a), Some(b)] => (a.as_nanos() + b.as_nanos()) as f32 * 0.5,
            [Some(a), None] => a.as_nanos() as f32,
            _ => return 0.0,
        };
        let v = tick_m / (mean_ns * 1e-9);
        if self.backwards {
            -v
        } else {
            v
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TICK_M: f32 = core::f32::consts::PI * 0.009 / 40.0;
    const TIMEOUT: Duration = Duration::from_millis(60);

    /// Edges of a wheel turning at `v` m/s whose black stripes cover `black` of each pulse pitch.
    fn edges(v: f32, black: f32, n: usize) -> impl Iterator<Item = Instant> {
        let pitch_s = TICK_M / v;
        let mut t = 0.0f64;
        (0..n).map(move |i| {
            let frac = if i % 2 == 0 { black } else { 1.0 - black };
            t += (2.0 * pitch_s * frac) as f64;
            Instant::from_nanos((t * 1e9).round() as u64)
        })
    }

    #[test]
    fn delta_s_speed_within_one_percent_at_40_mm_per_s() {
        let mut m = SpeedMeter::new();
        let mut last = Instant::ZERO;
        let mut worst = 0.0f32;
        for (i, at) in edges(0.040, 0.38, 60).enumerate() {
            m.on_edge(at, TIMEOUT);
            last = at;
            if i >= 2 {
                let v = m.speed(at, TICK_M, TIMEOUT);
                worst = worst.max((v - 0.040).abs() / 0.040);
            }
        }
        assert!(worst < 0.01, "worst relative error {worst}");
        // A single period alone would be 19% off: the stripes really are unequal in this test.
        let mut single = SpeedMeter::new();
        let mut e = edges(0.040, 0.38, 2);
        single.on_edge(e.next().unwrap(), TIMEOUT);
        let t = e.next().unwrap();
        single.on_edge(t, TIMEOUT);
        assert!((single.speed(t, TICK_M, TIMEOUT) - 0.040).abs() / 0.040 > 0.15);
        assert_eq!(m.ticks(), 60);
        assert!(m.speed(last + Duration::from_millis(59), TICK_M, TIMEOUT) > 0.0);
    }

    #[test]
    fn reads_zero_after_the_timeout() {
        let mut m = SpeedMeter::new();
        for at in edges(0.1, 0.5, 5) {
            m.on_edge(at, TIMEOUT);
        }
        let last = edges(0.1, 0.5, 5).last().unwrap();
        assert!(m.speed(last + TIMEOUT, TICK_M, TIMEOUT) > 0.09);
        assert_eq!(
            m.speed(last + TIMEOUT + Duration::from_nanos(1), TICK_M, TIMEOUT),
            0.0
        );
    }

    #[test]
    fn a_stale_period_after_a_stop_is_not_used() {
        let mut m = SpeedMeter::new();
        m.on_edge(Instant::ZERO, TIMEOUT);
        let restart = Instant::from_millis(500);
        m.on_edge(restart, TIMEOUT);
        assert_eq!(
            m.speed(restart, TICK_M, TIMEOUT),
            0.0,
            "500 ms period is not a speed"
        );
    }

    #[test]
    fn backwards_edges_count_down_and_read_negative() {
        let mut m = SpeedMeter::new();
        m.set_backwards(true);
        for at in edges(0.1, 0.5, 4) {
            m.on_edge(at, TIMEOUT);
        }
        let last = edges(0.1, 0.5, 4).last().unwrap();
        assert_eq!(m.ticks(), -4);
        assert!(m.speed(last, TICK_M, TIMEOUT) < -0.09);
    }
}
