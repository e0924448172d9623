//! Link watchdog (thesis 2.3.2): a robot whose host falls silent stops by itself.
//!
//! Armed by the first host packet, so a robot that was never connected does not report; fires once
//! per silence and re-arms on the next packet.

use crate::time::{Duration, Instant};

/// Silence detector for the host link.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Watchdog {
    last_host: Option<Instant>,
    fired: bool,
}

impl Watchdog {
    /// Not armed.
    pub const fn new() -> Self {
        Self {
            last_host: None,
            fired: false,
        }
    }

    /// A packet from the host arrived.
    pub fn feed(&mut self, now: Instant) {
        self.last_host = Some(now);
        self.fired = false;
    }

    /// The first instant at which [`check`](Self::check) fires, if it is armed and has not
    /// fired for this silence yet; `None` also for a zero timeout.
    pub fn deadline(&self, timeout: Duration) -> Option<Instant> {
        let last = self.last_host?;
        if timeout == Duration::ZERO || self.fired {
            return None;
        }
        Some(last + timeout + Duration::from_nanos(1))
    }

    /// `Some(silence)` exactly once when the host has been silent for longer than `timeout`;
    /// a zero timeout disables the watchdog.
    pub fn check(&mut self, now: Instant, timeout: Duration) -> Option<Duration> {
        let last = self.last_host?;
        let silent = now - last;
        if timeout == Duration::ZERO || self.fired || silent <= timeout {
            return None;
        }
        self.fired = true;
        Some(silent)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fires_once_after_the_timeout_and_rearms() {
        let mut w = Watchdog::new();
        let t = Duration::from_millis(500);
        assert_eq!(w.check(Instant::from_millis(10_000), t), None, "not armed");
        assert_eq!(w.deadline(t), None, "not armed");
        w.feed(Instant::from_millis(100));
        let due = w.deadline(t).expect("armed");
        let mut probe = w;
        let just_before = Instant::from_nanos(due.as_nanos() - 1);
        assert_eq!(probe.check(just_before, t), None, "not before its deadline");
        assert!(probe.check(due, t).is_some(), "fires at its deadline");
        assert_eq!(w.check(Instant::from_millis(600), t), None);
        assert_eq!(
            w.check(Instant::from_micros(600_001), t),
            Some(Duration::from_micros(500_001))
        );
        assert_eq!(w.check(Instant::from_millis(700), t), None, "once");
        assert_eq!(w.deadline(t), None, "nothing left to fire");
        w.feed(Instant::from_millis(800));
        assert!(w.check(Instant::from_millis(1301), t).is_some());
    }

    #[test]
    fn zero_timeout_disables() {
        let mut w = Watchdog::new();
        w.feed(Instant::ZERO);
        assert_eq!(w.check(Instant::from_millis(100_000), Duration::ZERO), None);
    }
}
