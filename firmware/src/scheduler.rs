//! The four-channel scheduler (thesis 11.1): one pending event per channel, no priority queue.
//!
//! Channel 0 times the main loop, channel 1 the line sensor, channels 2 and 3 the proximity unit.
//! A periodic channel that is served more than one period late counts as an overrun, which the
//! firmware reports as a warning event.

use crate::time::{Duration, Instant};

/// Number of channels, as on the thesis's four compare channels.
pub const CHANNELS: usize = 4;

/// What each channel times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    /// Control loop, sensors, state reflector.
    MainLoop = 0,
    /// Line sensor sampling.
    LineSensor = 1,
    /// IR transmit slots.
    IrTransmit = 2,
    /// IR sighting reports.
    IrReport = 3,
}

impl Channel {
    const ALL: [Channel; CHANNELS] = [
        Channel::MainLoop,
        Channel::LineSensor,
        Channel::IrTransmit,
        Channel::IrReport,
    ];
}

/// One pending event time per channel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Scheduler {
    due: [Option<Instant>; CHANNELS],
}

impl Scheduler {
    /// No events pending.
    pub const fn new() -> Self {
        Self {
            due: [None; CHANNELS],
        }
    }

    /// Sets the channel's event, replacing any pending one.
    pub fn schedule(&mut self, channel: Channel, at: Instant) {
        self.due[channel as usize] = Some(at);
    }

    /// Removes the channel's event.
    pub fn cancel(&mut self, channel: Channel) {
        self.due[channel as usize] = None;
    }

    /// When the channel's event is due.
    pub fn pending(&self, channel: Channel) -> Option<Instant> {
        self.due[channel as usize]
    }

    /// The earliest pending event time, for a board that sleeps until then.
    pub fn next_due(&self) -> Option<Instant> {
        self.due.iter().flatten().min().copied()
    }

    /// Takes the earliest event due at `now`: its channel and the time it was scheduled for.
    pub fn pop_due(&mut self, now: Instant) -> Option<(Channel, Instant)> {
        let (i, at) = self
            .due
            .iter()
            .enumerate()
            .filter_map(|(i, d)| d.filter(|&at| at <= now).map(|at| (i, at)))
            .min_by_key(|&(_, at)| at)?;
        self.due[i] = None;
        Some((Channel::ALL[i], at))
    }
}

/// Next time of a periodic event served at `now` that was due at `scheduled`.
///
/// On time, the next event keeps the period grid (no drift); more than one period late, it is an
/// overrun: the lateness is returned and the grid restarts from `now`.
pub fn next_period(
    scheduled: Instant,
    now: Instant,
    period: Duration,
) -> (Instant, Option<Duration>) {
    let period = period.max(Duration::from_micros(100));
    let late = now - scheduled;
    if late > period {
        (now + period, Some(late))
    } else {
        (scheduled + period, None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_event_per_channel_earliest_first() {
        let mut s = Scheduler::new();
        s.schedule(Channel::IrReport, Instant::from_micros(30));
        s.schedule(Channel::MainLoop, Instant::from_micros(50));
        s.schedule(Channel::MainLoop, Instant::from_micros(20));
        assert_eq!(s.next_due(), Some(Instant::from_micros(20)));
        assert_eq!(s.pop_due(Instant::from_micros(10)), None);
        let now = Instant::from_micros(40);
        assert_eq!(
            s.pop_due(now),
            Some((Channel::MainLoop, Instant::from_micros(20)))
        );
        assert_eq!(
            s.pop_due(now),
            Some((Channel::IrReport, Instant::from_micros(30)))
        );
        assert_eq!(s.pop_due(now), None);
        assert_eq!(s.next_due(), None);
    }

    #[test]
    fn cancel_removes_the_event() {
        let mut s = Scheduler::new();
        s.schedule(Channel::LineSensor, Instant::from_micros(1));
        s.cancel(Channel::LineSensor);
        assert_eq!(s.pop_due(Instant::from_millis(1)), None);
    }

    #[test]
    fn on_time_keeps_the_grid_and_late_is_an_overrun() {
        let p = Duration::from_millis(5);
        let t = Instant::from_millis(10);
        assert_eq!(
            next_period(t, t + Duration::from_millis(4), p),
            (Instant::from_millis(15), None)
        );
        let late = t + Duration::from_millis(12);
        assert_eq!(
            next_period(t, late, p),
            (late + p, Some(Duration::from_millis(12)))
        );
    }
}
