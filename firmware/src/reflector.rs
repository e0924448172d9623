//! State reflector (thesis 6.4, 9.7): sends the full or reduced state at a configurable period.

use protocol::packets::ReflectorMode;
use protocol::settings::ReflectorSettings;

use crate::time::{Duration, Instant};

/// Decides when the next state packet is due.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Reflector {
    next: Option<Instant>,
}

impl Reflector {
    /// Sends its first packet at the first check.
    pub const fn new() -> Self {
        Self { next: None }
    }

    /// Makes the next check send at once, e.g. after a reconfiguration.
    pub fn restart(&mut self) {
        self.next = None;
    }

    /// The mode to send now, if a packet is due; unknown mode codes send nothing.
    pub fn due(&mut self, now: Instant, settings: &ReflectorSettings) -> Option<ReflectorMode> {
        let mode = ReflectorMode::try_from(settings.mode).ok()?;
        if mode == ReflectorMode::None {
            return None;
        }
        let period = Duration::from_millis(u64::from(settings.period_ms.max(1)));
        match self.next {
            Some(next) if now < next => None,
            Some(next) => {
                // Stay on the period grid unless a whole period was missed.
                let after = next + period;
                self.next = Some(if after <= now { now + period } else { after });
                Some(mode)
            }
            None => {
                self.next = Some(now + period);
                Some(mode)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sends_at_the_period_in_the_configured_mode() {
        let mut r = Reflector::new();
        let s = ReflectorSettings {
            mode: ReflectorMode::Reduced as u8,
            period_ms: 10,
        };
        let sent: Vec<u64> = (0..=50)
            .map(Instant::from_millis)
            .filter(|&t| r.due(t, &s).is_some())
            .map(|t| t.as_millis())
            .collect();
        assert_eq!(sent, vec![0, 10, 20, 30, 40, 50]);
        assert_eq!(
            r.due(Instant::from_millis(60), &s),
            Some(ReflectorMode::Reduced)
        );
    }

    #[test]
    fn none_and_unknown_modes_send_nothing() {
        let mut r = Reflector::new();
        let none = ReflectorSettings {
            mode: 0,
            period_ms: 1,
        };
        let bad = ReflectorSettings {
            mode: 9,
            period_ms: 1,
        };
        assert_eq!(r.due(Instant::ZERO, &none), None);
        assert_eq!(r.due(Instant::ZERO, &bad), None);
    }
}
