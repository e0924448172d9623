//! Bump detection: the robot tells its host when something other than its own wheels moved it.
//!
//! Two signs are read each main loop. A *jolt*: the accelerometer reads an acceleration that the
//! wheel speeds do not explain (along the heading, the change of the mean wheel speed; across it,
//! the centripetal acceleration of the turn they drive), by more than a threshold. The jolt is
//! integrated twice while it lasts, which says how far it moved the robot. And *wheels turning
//! while idle*: a robot standing with its motors off and its wheels stopped whose encoders count
//! pulses was turned or pushed along (a turn about its centre moves no accelerometer at the
//! centre, but drags both wheels).
//!
//! A robot's own starts, stops and pushes jolt the accelerometer by up to a few g, because the
//! wheel speeds measured by pulse intervals lag the body; but the jolt integrated twice moves it
//! only a millimetre or two. A jolt is therefore reported only when it moved the robot at least
//! `min_moved_mm` (6 mm by default; measured in the simulator: starts and stops 0–2 mm, a pusher
//! meeting its box 5 mm, a 15 mm shove 16 mm, a 30 mm one 30 mm).

use crate::time::{Duration, Instant};
use protocol::packets::BumpCause;
use protocol::settings::BumpSettings;

/// m/s² per milli-g.
const MPS2_PER_MG: f32 = 9.806_65e-3;
/// A jolt ends after this many main loops running below half its threshold.
const QUIET_LOOPS: u8 = 3;
/// A jolt longer than this is reported at once, ended or not: the host must hear of it while
/// it goes on.
const LONGEST_JOLT: Duration = Duration::from_millis(300);
/// The most a robot's own tyres accelerate it, m/s² (twice the grip of rubber on the floor).
const MOST_OWN_MPS2: f32 = 20.0;
/// A robot counts as standing once its motors were off for this long: wheels coasting after a
/// stop still count pulses.
const SETTLED: Duration = Duration::from_millis(300);

/// A bump, as the [`Bump`](protocol::packets::Bump) event reports it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bump {
    /// When it began.
    pub at: Instant,
    /// The largest unexplained acceleration, milli-g.
    pub peak_mg: f32,
    /// How far it moved the robot, metres (for wheels turned while idle, their travel, of
    /// unknown direction).
    pub moved_m: f32,
    /// The move along the heading and to the left, metres (robot frame at its start); zero
    /// for wheels turned while idle.
    pub moved: [f32; 2],
    /// What gave it away.
    pub cause: BumpCause,
}

/// A jolt under way: its start, peak, and the velocity and displacement the unexplained
/// acceleration gave so far.
#[derive(Clone, Copy, Debug)]
struct Jolt {
    start: Instant,
    peak_mg: f32,
    velocity: [f32; 2],
    moved: [f32; 2],
    /// Seconds integrated.
    lasted: f32,
    quiet: u8,
}

/// What one main loop hands the detector.
#[derive(Clone, Copy, Debug)]
pub struct Sample {
    /// Now.
    pub now: Instant,
    /// Since the previous sample, seconds.
    pub dt: f32,
    /// Accelerometer, milli-g, robot frame (x forward, y left).
    pub accel_mg: [i16; 2],
    /// Measured wheel speeds (left, right), m/s.
    pub wheels_mps: (f32, f32),
    /// Distance between the wheels, metres.
    pub gauge_m: f32,
    /// Encoder pulses counted so far (left, right).
    pub ticks: (i32, i32),
    /// Distance per pulse, metres.
    pub tick_m: f32,
    /// The motors are off and nothing asks them to turn.
    pub idle: bool,
}

/// The detector's memory between main loops.
#[derive(Clone, Copy, Debug, Default)]
pub struct BumpDetector {
    last_speed: Option<f32>,
    /// The previous loop's unexplained acceleration, m/s²: a jolt is integrated from the loop
    /// before it crossed the threshold.
    last_unexplained: [f32; 2],
    jolt: Option<Jolt>,
    /// Since when the robot stood idle, and its pulse counts when it settled.
    standing: Option<(Instant, (i32, i32))>,
}

impl BumpDetector {
    /// A detector that has seen nothing.
    pub const fn new() -> Self {
        Self {
            last_speed: None,
            last_unexplained: [0.0; 2],
            jolt: None,
            standing: None,
        }
    }

    /// Takes one main loop's sample; returns a bump once one is over (or has lasted long).
    pub fn update(&mut self, s: &Sample, settings: &BumpSettings) -> Option<Bump> {
        let min_moved = f32::from(settings.min_moved_mm) * 1e-3;
        let jolt = self
            .jolt_update(s, settings.threshold_mg)
            .filter(|b| b.moved_m >= min_moved);
        let idle = self.idle_update(s, settings.idle_ticks);
        jolt.or(idle)
    }

    fn jolt_update(&mut self, s: &Sample, threshold_mg: u16) -> Option<Bump> {
        let (l, r) = s.wheels_mps;
        let speed = (l + r) / 2.0;
        let turn = if s.gauge_m > 0.0 {
            (r - l) / s.gauge_m
        } else {
            0.0
        };
        let last_speed = self.last_speed.replace(speed)?;
        // No tyre pushes a body harder than its grip: a faster change of the measured speed is
        // the speed meter's (two pulses close together), not the robot's.
        let along = ((speed - last_speed) / s.dt.max(1e-4)).clamp(-MOST_OWN_MPS2, MOST_OWN_MPS2);
        if threshold_mg == 0 {
            self.jolt = None;
            return None;
        }
        let unexplained = [
            f32::from(s.accel_mg[0]) * MPS2_PER_MG - along,
            f32::from(s.accel_mg[1]) * MPS2_PER_MG - speed * turn,
        ];
        let before = core::mem::replace(&mut self.last_unexplained, unexplained);
        let mg = libm::hypotf(unexplained[0], unexplained[1]) / MPS2_PER_MG;
        let threshold = f32::from(threshold_mg);
        let felt_mg = libm::hypotf(f32::from(s.accel_mg[0]), f32::from(s.accel_mg[1]));
        let jolt = match self.jolt.as_mut() {
            // A jolt starts in the accelerometer, not in the wheel speeds alone.
            None if mg > threshold && felt_mg > threshold / 2.0 => {
                let velocity = [before[0] * s.dt, before[1] * s.dt];
                self.jolt.insert(Jolt {
                    start: s.now,
                    peak_mg: 0.0,
                    velocity,
                    moved: [velocity[0] * s.dt, velocity[1] * s.dt],
                    lasted: s.dt,
                    quiet: 0,
                })
            }
            None => return None,
            Some(j) => j,
        };
        jolt.peak_mg = jolt.peak_mg.max(mg);
        for ((v, m), a) in jolt
            .velocity
            .iter_mut()
            .zip(jolt.moved.iter_mut())
            .zip(unexplained)
        {
            *v += a * s.dt;
            *m += *v * s.dt;
        }
        jolt.lasted += s.dt;
        jolt.quiet = if mg < threshold / 2.0 {
            jolt.quiet + 1
        } else {
            0
        };
        let over = jolt.quiet >= QUIET_LOOPS || s.now - jolt.start >= LONGEST_JOLT;
        if !over {
            return None;
        }
        let j = *jolt;
        self.jolt = None;
        // The robot was at rest relative to its wheels before the jolt and is after it: the
        // velocity left at its end is integration drift, taken off as a linear ramp.
        let moved = [0, 1].map(|k| j.moved[k] - j.velocity[k] * j.lasted / 2.0);
        Some(Bump {
            at: j.start,
            peak_mg: j.peak_mg,
            moved_m: libm::hypotf(moved[0], moved[1]),
            moved,
            cause: BumpCause::Jolt,
        })
    }

    fn idle_update(&mut self, s: &Sample, idle_ticks: u8) -> Option<Bump> {
        // Only whether the motors are off counts here, not the wheel speeds: a push turns the
        // wheels, and their speed reading must not restart the count it is caught by.
        if !s.idle || idle_ticks == 0 {
            self.standing = None;
            return None;
        }
        let (since, at) = *self.standing.get_or_insert((s.now, s.ticks));
        if s.now - since < SETTLED {
            // Still settling: pulses of the coasting wheels are the robot's own.
            self.standing = Some((since, s.ticks));
            return None;
        }
        let pulses = (s.ticks.0 - at.0).unsigned_abs() + (s.ticks.1 - at.1).unsigned_abs();
        if pulses < u32::from(idle_ticks) {
            return None;
        }
        // Counted from here again once the wheels settle: one report per push.
        self.standing = Some((s.now, s.ticks));
        Some(Bump {
            at: s.now,
            peak_mg: 0.0,
            moved_m: pulses as f32 * s.tick_m / 2.0,
            moved: [0.0; 2],
            cause: BumpCause::WheelsWhileIdle,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t_ms: u64, accel_mg: [i16; 2], wheels: f32, ticks: (i32, i32), idle: bool) -> Sample {
        Sample {
            now: Instant::from_millis(t_ms),
            dt: 0.005,
            accel_mg,
            wheels_mps: (wheels, wheels),
            gauge_m: 0.026,
            ticks,
            tick_m: 0.0007,
            idle,
        }
    }

    fn settings() -> BumpSettings {
        BumpSettings {
            threshold_mg: 250,
            min_moved_mm: 6,
            idle_ticks: 3,
        }
    }

    #[test]
    fn a_sideways_shove_is_a_jolt_of_about_its_size() {
        let mut d = BumpDetector::new();
        // 15 mm across over 50 ms on a half-sine velocity profile, sampled every 5 ms.
        let (shift, dur) = (0.015f32, 0.05f32);
        let mut bumps = Vec::new();
        for k in 0..40u64 {
            let t = k as f32 * 0.005 - 0.02;
            let a = if (0.0..dur).contains(&t) {
                shift * core::f32::consts::PI.powi(2) / (2.0 * dur * dur)
                    * (core::f32::consts::PI * t / dur).cos()
            } else {
                0.0
            };
            let mg = (a / MPS2_PER_MG) as i16;
            bumps.extend(d.update(&sample(k * 5, [0, mg], 0.0, (0, 0), false), &settings()));
        }
        assert_eq!(bumps.len(), 1, "{bumps:?}");
        let b = bumps[0];
        assert_eq!(b.cause, BumpCause::Jolt);
        assert!(b.peak_mg > 2500.0, "{b:?}");
        assert!((b.moved_m - shift).abs() < 0.005, "{b:?}");
    }

    #[test]
    fn a_glitch_of_the_wheel_speeds_alone_is_no_bump() {
        let mut d = BumpDetector::new();
        for k in 0..40u64 {
            // Two pulses close together read as 2 m/s for one loop.
            let v = if k == 10 { 2.0 } else { 0.1 };
            assert_eq!(
                d.update(&sample(k * 5, [0, 0], v, (0, 0), false), &settings()),
                None
            );
        }
    }

    #[test]
    fn driving_its_own_wheels_explain_is_no_bump() {
        let mut d = BumpDetector::new();
        // Speeding up at 3 m/s² (306 mg) as the wheels say.
        for k in 0..20u64 {
            let v = k as f32 * 0.015;
            assert_eq!(
                d.update(&sample(k * 5, [306, 0], v, (0, 0), false), &settings()),
                None
            );
        }
    }

    #[test]
    fn wheels_turning_while_it_stands_are_one_bump_per_push() {
        let mut d = BumpDetector::new();
        let mut got = Vec::new();
        for k in 0..200u64 {
            // Standing from 0; at 0.5 s something turns it: the wheels count pulses.
            let ticks = if k < 100 { (0, 0) } else { (-3, 3) };
            got.extend(d.update(&sample(k * 5, [0, 0], 0.0, ticks, true), &settings()));
        }
        assert_eq!(got.len(), 1, "{got:?}");
        assert_eq!(got[0].cause, BumpCause::WheelsWhileIdle);
        // Pulses right after it came to rest are its own coasting.
        let mut d = BumpDetector::new();
        for k in 0..40u64 {
            let ticks = ((k.min(30) / 5) as i32, 0);
            assert_eq!(
                d.update(&sample(k * 5, [0, 0], 0.0, ticks, true), &settings()),
                None
            );
        }
    }
}
