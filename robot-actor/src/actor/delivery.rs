//! Delivery over a lossy link (protocol 3). The robot numbers its events and keeps its last
//! 32: a number the host skipped, or one the state says was sent and never came, is asked for
//! again (`EventReplay`). The robot's state shows what it took: the newest move id
//! (`last_move_id`) and its drive mode. A move, stop, clear or drive command that a state sampled
//! a round trip later does not show is sent again; each is safe to repeat (moves by their id,
//! stops and clears by `keep_from`). Nothing here runs when nothing is lost: a lockstep run on
//! a lossless link sends exactly what it sent before.

use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

use protocol::packets::DriveMode;
use protocol::RobotState;
use tokio::time::Instant;

/// Round trips remembered for the wait before a command counts as lost.
const RTTS: usize = 16;
/// The wait before any round trip was measured.
const UNMEASURED_WAIT: Duration = Duration::from_millis(250);
/// Added to 1.5 of the longest recent round trip: a state period and scheduling.
const WAIT_MARGIN: Duration = Duration::from_millis(30);
/// Events the robot keeps for a replay (`firmware::EVENT_LOG`).
const ROBOT_EVENT_LOG: u16 = 32;

/// What a drive command asked for, as the state's drive mode shows it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Expect {
    /// Line following on.
    Following,
    /// Line following off.
    NotFollowing,
    /// Teleop wheel speeds.
    WheelSpeeds,
    /// Teleop duties.
    MotorPower,
}

/// A command sent and not yet seen in the robot's state.
#[derive(Clone, Debug)]
struct Pending<K> {
    what: K,
    frame: Vec<u8>,
    sent_at: Instant,
    /// The host's next move id when it was sent: a later move supersedes a drive command.
    next_move: u16,
}

/// The host's half of delivery over a lossy link.
#[derive(Debug, Default)]
pub(super) struct Delivery {
    /// Newest event number heard.
    newest: Option<u16>,
    /// Event numbers skipped and not heard yet, with when a replay was last asked for.
    missing: BTreeMap<u16, Option<Instant>>,
    /// The newest stop or clear, by `keep_from`, until a state shows it; with whether it was a
    /// stop whose drive part no later drive command has replaced.
    clear: Option<Pending<(u16, bool)>>,
    /// The newest drive command, until a state shows it.
    drive: Option<Pending<Expect>>,
    /// Recent round trips.
    rtts: VecDeque<Duration>,
    /// The longest of them, kept with them: every state packet reads it.
    longest: Option<Duration>,
    /// Counters for the link statistics.
    pub(super) counts: DeliveryCounts,
}

/// What delivery did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DeliveryCounts {
    /// Events that arrived only when asked for again.
    pub events_recovered: u64,
    /// Events never heard: gone from the robot's log before they were asked for.
    pub events_lost: u64,
    /// Replays asked for.
    pub replays_asked: u64,
    /// Commands sent again because the robot's state did not show them.
    pub commands_resent: u64,
}

/// What to send after a state.
#[derive(Debug, Default)]
pub(super) struct Resend {
    /// Ask for the events from this number on.
    pub(super) replay_from: Option<u16>,
    /// Frames to send again, in order.
    pub(super) frames: Vec<Vec<u8>>,
}

/// Whether `a` comes after `b` in a wrapping 16-bit numbering.
pub(super) fn after(a: u16, b: u16) -> bool {
    (a.wrapping_sub(b) as i16) > 0
}

impl Delivery {
    /// A new link: nothing heard, nothing pending.
    pub(super) fn reset(&mut self) {
        let counts = self.counts;
        let rtts = std::mem::take(&mut self.rtts);
        *self = Delivery {
            counts,
            rtts,
            longest: self.longest,
            ..Delivery::default()
        };
    }

    /// A measured round trip.
    pub(super) fn on_rtt(&mut self, rtt: Duration) {
        if self.rtts.len() == RTTS {
            self.rtts.pop_front();
        }
        self.rtts.push_back(rtt);
        self.longest = self.rtts.iter().max().copied();
    }

    /// The longest of the recent round trips.
    pub(super) fn longest_rtt(&self) -> Option<Duration> {
        self.longest
    }

    /// How long a command may go unseen in the robot's state before it counts as lost.
    pub(super) fn wait(&self) -> Duration {
        match self.longest {
            Some(longest) => longest.mul_f64(1.5) + WAIT_MARGIN,
            None => UNMEASURED_WAIT,
        }
    }

    /// Whether event `seq` is news (not a copy of one already heard); notes the numbers it skips.
    pub(super) fn admit(&mut self, seq: u16) -> bool {
        let Some(newest) = self.newest else {
            self.newest = Some(seq);
            return true;
        };
        if after(seq, newest) {
            self.skipped_before(newest, seq);
            self.newest = Some(seq);
            return true;
        }
        if self.missing.remove(&seq).is_some() {
            self.counts.events_recovered += 1;
            return true;
        }
        false
    }

    /// Notes every number after `newest` and before `seq` as missing.
    fn skipped_before(&mut self, newest: u16, seq: u16) {
        let mut s = newest.wrapping_add(1).max(1);
        while s != seq {
            self.missing.insert(s, None);
            s = s.wrapping_add(1).max(1);
        }
    }

    /// A stop (`stop`) or clear sent with `keep_from`, as `frame`.
    pub(super) fn sent_clear(&mut self, keep_from: u16, stop: bool, frame: Vec<u8>) {
        if stop {
            self.drive = None;
        }
        self.clear = Some(Pending {
            what: (keep_from, stop),
            frame,
            sent_at: Instant::now(),
            next_move: keep_from,
        });
    }

    /// A drive command sent as `frame` while the host's next move id was `next_move`.
    pub(super) fn sent_drive(&mut self, what: Expect, frame: Vec<u8>, next_move: u16) {
        if let Some(c) = &mut self.clear {
            // The stop's drive part is replaced; what it cleared still has to be seen.
            c.what.1 = false;
        }
        self.drive = Some(Pending {
            what,
            frame,
            sent_at: Instant::now(),
            next_move,
        });
    }

    /// The robot stopped by itself (reflex, watchdog): a drive command before it is over.
    pub(super) fn robot_stopped(&mut self) {
        self.drive = None;
    }

    /// What to send again after `state`, given the host's next move id.
    pub(super) fn on_state(&mut self, state: &RobotState, next_move: u16) -> Resend {
        let now = Instant::now();
        let wait = self.wait();
        let mut out = Resend::default();
        // Events the robot sent before this state came before it on an ordered link.
        let sent = state.link.events_sent;
        if sent != 0 {
            match self.newest {
                Some(newest) if after(sent, newest) => {
                    // `sent` itself came before this state and was lost too.
                    self.skipped_before(newest, sent);
                    self.missing.insert(sent, None);
                    self.newest = Some(sent);
                }
                None => self.newest = Some(sent),
                _ => {}
            }
            let gone: Vec<u16> = self
                .missing
                .keys()
                .copied()
                .filter(|&s| sent.wrapping_sub(s) >= ROBOT_EVENT_LOG)
                .collect();
            for s in gone {
                self.missing.remove(&s);
                self.counts.events_lost += 1;
            }
        }
        let due = |asked: &Option<Instant>| asked.is_none_or(|t| now - t >= wait);
        if self.missing.values().any(due) {
            let newest = self.newest.unwrap_or(0);
            // The oldest missing number: the farthest behind the newest, across a wrap.
            let from = self
                .missing
                .keys()
                .copied()
                .max_by_key(|&s| newest.wrapping_sub(s))
                .unwrap_or(newest);
            for asked in self.missing.values_mut() {
                *asked = Some(now);
            }
            self.counts.replays_asked += 1;
            out.replay_from = Some(from);
        }
        let taken = state.locomotion.last_move_id;
        if let Some(c) = &mut self.clear {
            let (keep_from, stop) = c.what;
            let mode = DriveMode::try_from(state.locomotion.mode).ok();
            let cleared = keep_from == 0 || !after(keep_from.wrapping_sub(1), taken);
            let running_old = state.locomotion.active_move != 0
                && keep_from != 0
                && after(keep_from, state.locomotion.active_move);
            let driving = stop
                && matches!(
                    mode,
                    Some(DriveMode::LineFollow | DriveMode::WheelSpeeds | DriveMode::MotorPower)
                );
            if cleared && !running_old && !driving {
                self.clear = None;
            } else if now - c.sent_at >= wait {
                c.sent_at = now;
                out.frames.push(c.frame.clone());
                self.counts.commands_resent += 1;
            }
        }
        if let Some(d) = &mut self.drive {
            let mode = DriveMode::try_from(state.locomotion.mode).ok();
            let shown = match d.what {
                Expect::Following => mode == Some(DriveMode::LineFollow),
                Expect::NotFollowing => mode != Some(DriveMode::LineFollow),
                Expect::WheelSpeeds => mode == Some(DriveMode::WheelSpeeds),
                Expect::MotorPower => mode == Some(DriveMode::MotorPower),
            };
            if shown || d.next_move != next_move {
                // Seen, or a later move replaced it (sending it again would clear that move).
                self.drive = None;
            } else if now - d.sent_at >= wait {
                d.sent_at = now;
                out.frames.push(d.frame.clone());
                self.counts.commands_resent += 1;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_skipped_event_is_missing_until_it_comes_again_and_a_copy_is_not_news() {
        let mut d = Delivery::default();
        assert!(d.admit(1));
        assert!(d.admit(2));
        assert!(d.admit(5));
        assert_eq!(d.missing.keys().copied().collect::<Vec<_>>(), [3, 4]);
        assert!(d.admit(3));
        assert!(!d.admit(3), "a copy of an event already heard");
        assert!(!d.admit(2));
        assert_eq!(d.counts.events_recovered, 1);
        // Numbers wrap past 0, which is never used.
        let mut d = Delivery::default();
        assert!(d.admit(u16::MAX));
        assert!(d.admit(2));
        assert_eq!(d.missing.keys().copied().collect::<Vec<_>>(), [1]);
    }

    #[test]
    fn a_state_newer_than_every_event_heard_asks_for_the_rest() {
        let mut d = Delivery::default();
        assert!(d.admit(7));
        let mut s = RobotState::default();
        s.link.events_sent = 9;
        let r = d.on_state(&s, 1);
        assert_eq!(r.replay_from, Some(8));
        // Asked once per wait, not once per state.
        assert_eq!(d.on_state(&s, 1).replay_from, None);
        // Beyond the robot's log an event is lost for good.
        s.link.events_sent = 9 + ROBOT_EVENT_LOG;
        d.on_state(&s, 1);
        assert_eq!(d.counts.events_lost, 2);
    }
}
