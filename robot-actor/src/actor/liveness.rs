//! Liveness of the link: opening it, pinging (which also feeds the robot's watchdog) and
//! measuring round trips, declaring it lost after a silence, failing what waited on it, and
//! reconnecting with exponential backoff.

use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use actix::prelude::*;
use futures::StreamExt;
use protocol::packets;
use tokio::sync::mpsc;
use tokio::time::Instant;
use tokio_stream::wrappers::UnboundedReceiverStream;
use tracing::{info, warn};

use super::{RobotActor, RobotError, RobotEventKind};
use crate::link::{LinkCounters, LinkError};

/// Link statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinkStats {
    /// Packets received and accepted.
    pub packets_in: u64,
    /// Packets sent.
    pub packets_out: u64,
    /// Frames dropped for bad checksum, length or type.
    pub checksum_errors: u64,
    /// Frames dropped by the framing layer.
    pub dropped_frames: u64,
    /// Latest round-trip time.
    pub rtt: Option<Duration>,
    /// Mean round-trip time.
    pub rtt_mean: Option<Duration>,
    /// Time since the last packet from the robot.
    pub silent_for: Option<Duration>,
    /// Links lost so far.
    pub losses: u64,
    /// What delivery over a lossy link did: events asked for again, commands sent again.
    pub delivery: super::DeliveryCounts,
    /// Successful reconnects.
    pub reconnects: u64,
    /// Round trips measured by pings: median and 99th percentile.
    pub rtt_p50: Option<Duration>,
    /// See `rtt_p50`.
    pub rtt_p99: Option<Duration>,
    /// Events whose lateness was measured (their robot time placed on the host clock).
    pub events_timed: u64,
    /// How long after it happened on the robot an event arrived: median and 99th percentile.
    pub event_late_p50: Option<Duration>,
    /// See `event_late_p50`.
    pub event_late_p99: Option<Duration>,
}

/// Percentiles of a link's durations, in microseconds; allocated with the first sample, so the
/// thousands of links a scale run opens without pings cost nothing.
#[derive(Default)]
struct Percentiles(Option<hdrhistogram::Histogram<u32>>);

impl Percentiles {
    fn record(&mut self, d: Duration) {
        let h = self.0.get_or_insert_with(|| {
            // Two significant figures (1 %), up to a minute: about 9 KiB per histogram.
            hdrhistogram::Histogram::new_with_bounds(1, 60_000_000, 2)
                .expect("constant histogram bounds are valid")
        });
        h.saturating_record(d.as_micros().clamp(1, 60_000_000) as u64);
    }

    fn quantile(&self, q: f64) -> Option<Duration> {
        let h = self.0.as_ref().filter(|h| !h.is_empty())?;
        Some(Duration::from_micros(h.value_at_quantile(q)))
    }

    fn len(&self) -> u64 {
        self.0.as_ref().map_or(0, |h| h.len())
    }
}

/// The robot's clock placed on the host's: the pong with the shortest round trip so far says
/// its robot time was read half that round trip after its ping left (the usual NTP estimate,
/// off by at most half the round trip's asymmetry).
#[derive(Clone, Copy)]
struct ClockAnchor {
    rtt: Duration,
    host: Instant,
    robot_us: u64,
}

/// The current link, if any, and what the actor has measured of every link so far.
pub(super) struct Liveness {
    /// Bumped whenever a link opens or is dropped, so events still queued from an older link
    /// are recognised and ignored.
    pub(super) generation: u64,
    /// Packets to the robot; `None` while no link is open.
    pub(super) tx: Option<mpsc::Sender<Vec<u8>>>,
    /// The open link's I/O counters.
    pub(super) counters: Option<Arc<LinkCounters>>,
    /// When the open link came up.
    pub(super) connected_at: Option<Instant>,
    /// When the robot was last heard from.
    pub(super) last_seen: Option<Instant>,
    /// Why the latest connect attempt failed, until a link opens.
    pub(super) link_error: Option<String>,
    /// Delay before the next reconnect attempt.
    backoff: Duration,
    /// Counters and round-trip times over every link.
    pub(super) stats: LinkStats,
    /// The latest round trip, for delivery's wait.
    pub(super) last_rtt: Option<Duration>,
    /// Pings waiting for their pong, by sequence number, with when each was sent.
    pings: HashMap<u32, Instant>,
    next_ping: u32,
    rtt_sum: Duration,
    rtt_count: u32,
    rtts: Percentiles,
    lateness: Percentiles,
    anchor: Option<ClockAnchor>,
}

impl Liveness {
    /// No link yet; the first reconnect waits `min_backoff`.
    pub(super) fn new(min_backoff: Duration) -> Self {
        Self {
            generation: 0,
            tx: None,
            counters: None,
            connected_at: None,
            last_seen: None,
            link_error: None,
            backoff: min_backoff,
            stats: LinkStats::default(),
            last_rtt: None,
            pings: HashMap::new(),
            next_ping: 0,
            rtt_sum: Duration::ZERO,
            rtt_count: 0,
            rtts: Percentiles::default(),
            lateness: Percentiles::default(),
            anchor: None,
        }
    }

    /// Takes the pong to ping `seq`, whose robot clock read `robot_us`, into the round-trip
    /// times and the clock anchor.
    pub(super) fn on_pong(&mut self, seq: u32, robot_us: u64) {
        if let Some(sent) = self.pings.remove(&seq) {
            let rtt = Instant::now() - sent;
            self.rtts.record(rtt);
            // A robot that rebooted restarted its clock: an anchor from before is meaningless.
            let stale = self.anchor.is_some_and(|a| robot_us < a.robot_us);
            if stale || self.anchor.is_none_or(|a| rtt <= a.rtt) {
                self.anchor = Some(ClockAnchor {
                    rtt,
                    host: sent + rtt / 2,
                    robot_us,
                });
            }
            self.stats.rtt = Some(rtt);
            self.last_rtt = Some(rtt);
            self.rtt_sum += rtt;
            self.rtt_count += 1;
            self.stats.rtt_mean = Some(self.rtt_sum / self.rtt_count);
        }
    }

    /// Takes an event that happened at `robot_ms` of the robot's clock and arrived `at` into the
    /// lateness figures, once the clock is anchored.
    pub(super) fn on_event_time(&mut self, robot_ms: u32, at: Instant) {
        let Some(a) = self.anchor else {
            return;
        };
        let robot_us = u64::from(robot_ms) * 1000;
        let happened = if robot_us >= a.robot_us {
            a.host + Duration::from_micros(robot_us - a.robot_us)
        } else {
            a.host
                .checked_sub(Duration::from_micros(a.robot_us - robot_us))
                .unwrap_or(a.host)
        };
        self.lateness.record(at.saturating_duration_since(happened));
    }

    /// The statistics as of now, with the open link's framing errors counted in.
    pub(super) fn stats_now(&self) -> LinkStats {
        let mut link = self.stats;
        link.rtt_p50 = self.rtts.quantile(0.5);
        link.rtt_p99 = self.rtts.quantile(0.99);
        link.events_timed = self.lateness.len();
        link.event_late_p50 = self.lateness.quantile(0.5);
        link.event_late_p99 = self.lateness.quantile(0.99);
        if let Some(c) = &self.counters {
            link.dropped_frames += c.framing_errors.load(Ordering::Relaxed);
        }
        link.silent_for = self.last_seen.map(|t| Instant::now() - t);
        link
    }
}

impl RobotActor {
    pub(super) fn connect(&mut self, ctx: &mut Context<Self>) {
        let fut = self.connector.connect();
        ctx.spawn(fut.into_actor(self).map(|res, act, ctx| match res {
            Ok(link) => {
                act.link.generation += 1;
                let generation = act.link.generation;
                info!(peer = %link.peer, "link up");
                act.link.tx = Some(link.tx);
                act.greeting.greeted = false;
                act.link.counters = Some(link.counters);
                act.link.connected_at = Some(Instant::now());
                act.link.last_seen = Some(Instant::now());
                act.link.backoff = act.config.min_backoff;
                act.link.link_error = None;
                ctx.add_stream(UnboundedReceiverStream::new(link.rx).map(move |e| (generation, e)));
                let _ = act.send(&packets::HelloRequest {});
            }
            Err(e) => {
                warn!(error = %e, "connect failed");
                act.link.link_error = Some(describe_connect_error(&e));
                act.schedule_reconnect(ctx);
            }
        }));
    }

    fn schedule_reconnect(&mut self, ctx: &mut Context<Self>) {
        let delay = self.link.backoff;
        self.link.backoff = (self.link.backoff * 2).min(self.config.max_backoff);
        ctx.run_later(delay, |act, ctx| act.connect(ctx));
    }

    pub(super) fn link_lost(&mut self, ctx: &mut Context<Self>, why: &str) {
        if self.link.tx.is_none() {
            return;
        }
        warn!(robot = self.robot_id(), why, "link lost");
        self.link.generation += 1;
        self.link.tx = None;
        self.greeting.greeted = false;
        if let Some(c) = self.link.counters.take() {
            self.link.stats.dropped_frames += c.framing_errors.load(Ordering::Relaxed);
        }
        self.link.stats.losses += 1;
        let robot = self.robot_id();
        let now = Instant::now();
        self.moves.link_lost(robot, now);
        let lost = || RobotError::LinkLost {
            robot,
            after: Duration::ZERO,
        };
        self.mirror.link_lost(lost);
        self.link.pings.clear();
        self.emit(RobotEventKind::LinkLost);
        self.schedule_reconnect(ctx);
    }

    pub(super) fn ping(&mut self, ctx: &mut Context<Self>) {
        let Some(seen) = self.link.last_seen else {
            return;
        };
        if self.link.tx.is_some() && Instant::now() - seen > self.config.link_timeout {
            self.link_lost(ctx, "silent past the link timeout");
            return;
        }
        if self.link.tx.is_some() && !self.greeting.greeted {
            // The first request may have been lost with a link that came back by itself.
            let _ = self.send(&packets::HelloRequest {});
        }
        self.link.next_ping = self.link.next_ping.wrapping_add(1);
        let seq = self.link.next_ping;
        let now = Instant::now();
        if self
            .send(&packets::Ping {
                seq,
                host_time_us: 0,
            })
            .is_ok()
        {
            self.link.pings.insert(seq, now);
            // Forget pings whose pong never came, so the table stays small.
            self.link
                .pings
                .retain(|_, sent| now - *sent < Duration::from_secs(10));
        }
    }
}

/// A failed connect attempt in a few words; a refusal says so plainly, as it is the usual mistake
/// (a wrong port, or a robot server not started yet).
fn describe_connect_error(e: &LinkError) -> String {
    match e {
        LinkError::Connect { source, .. }
            if source.kind() == std::io::ErrorKind::ConnectionRefused =>
        {
            "connection refused (nothing listens there)".to_owned()
        }
        other => other.to_string(),
    }
}
