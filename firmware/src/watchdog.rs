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
        w.feed(Instant::from_millis(100));
        assert_eq!(w.check(Instant::from_millis(600), t), None);
        assert_eq!(
            w.check(Instant::from_micros(600_001), t),
            Some(Duration::from_micros(500_001))
        );
        assert_eq!(w.check(Instant::from_millis(700), t), None, "once");
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
