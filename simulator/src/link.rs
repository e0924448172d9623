//! Simulated robot links: each carries exactly the protocol packets a real link would, delayed by a
//! latency with jitter, thinned by loss, and serialised through the air time of a piconet whose
//! bandwidth its robots share (defaults modelled on Bluetooth L2CAP: ~10 ms, no loss after
//! retransmission, ~700 kbit/s for up to 7 robots).
//!
//! Loss is drawn per packet on its own, or, when the model gives fades a length, from a
//! Gilbert–Elliott channel in time: the link alternates between good spells that lose nothing and
//! fades that lose everything sent during them, both exponentially long, one channel per link
//! shared by both directions (a fade hits one radio both ways). A fade is a spell of time, not a
//! run of packets, so a link that sends little is not silenced for longer.
//!
//! Packets in one direction stay in order, as on L2CAP. A cut link drops everything in both
//! directions until it is restored.
//!
//! Each direction holds at most [`LINK_BUFFER_BYTES`] bytes waiting for air time or in flight, like the small RX ring of a real robot's UART: a
//! sender faster than the air drops what does not fit, counted in [`LinkStats`], instead of queueing
//! without bound and pushing every later packet (and the piconet's air time) minutes away.

use std::collections::VecDeque;

/// Default bytes one direction of a link holds before it drops: a few KiB, as a PocketBot2's UART
/// RX ring; at ~700 kbit/s it is ~50 ms of air time, so a full buffer delays a packet that little.
pub const LINK_BUFFER_BYTES: usize = 4096;

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Timing of a link, in nanoseconds of simulated time where not said otherwise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkModel {
    /// One-way latency, seconds.
    pub latency_s: f64,
    /// Uniform jitter added to the latency, seconds (0..jitter).
    pub jitter_s: f64,
    /// Probability that a packet is lost, over the long run.
    pub loss: f64,
    /// Mean length of a fade, seconds: 0 draws each packet's loss on its own; above 0 the link
    /// fades for this long on average, a `loss` share of the time.
    pub loss_burst_s: f64,
    /// Air bandwidth of one piconet, bits per second.
    pub bandwidth_bps: f64,
    /// Robots sharing one piconet's air time.
    pub robots_per_piconet: usize,
}

impl Default for LinkModel {
    fn default() -> Self {
        Self {
            latency_s: 0.010,
            jitter_s: 0.002,
            loss: 0.0,
            loss_burst_s: 0.0,
            bandwidth_bps: 700_000.0,
            robots_per_piconet: 7,
        }
    }
}

/// Shared air time of one piconet.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Piconet {
    busy_until_ns: u64,
}

/// Counters of one link.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Packets the host sent.
    pub to_robot: u64,
    /// Packets the robot sent.
    pub to_host: u64,
    /// Packets lost by the loss model.
    pub lost: u64,
    /// Packets dropped because the link was cut.
    pub dropped_while_cut: u64,
    /// Host-to-robot packets dropped because the robot's buffer was full.
    pub overflow_to_robot: u64,
    /// Bytes of those packets.
    pub overflow_to_robot_bytes: u64,
    /// Robot-to-host packets dropped because the host's buffer was full.
    pub overflow_to_host: u64,
    /// Bytes of those packets.
    pub overflow_to_host_bytes: u64,
    /// Packets still queued when the host end closed, discarded with it.
    pub discarded_on_close: u64,
    /// Packets a fault lost (beside the loss model's).
    pub fault_lost: u64,
    /// Packets a fault corrupted (one byte replaced).
    pub corrupted: u64,
    /// Packets a fault delivered twice.
    pub duplicated: u64,
    /// Packets a fault let overtake the one before.
    pub reordered: u64,
    /// Packets a fault delayed.
    pub delayed: u64,
    /// Most bytes ever waiting towards the robot at once (never above the buffer).
    pub peak_to_robot_bytes: u64,
    /// Most bytes ever waiting towards the host at once (never above the buffer).
    pub peak_to_host_bytes: u64,
    /// Most bytes ever waiting in the host-side buffer before entering the link, where the link
    /// is driven through `runtime` (never above [`LINK_BUFFER_BYTES`]).
    pub peak_host_buffer_bytes: u64,
}

impl LinkStats {
    /// Packets dropped for a full buffer, both directions.
    pub fn overflowed(&self) -> u64 {
        self.overflow_to_robot + self.overflow_to_host
    }
}

/// An ordered queue of packets bounded in bytes: what does not fit is refused, never buffered.
#[derive(Clone, Debug, Default)]
pub struct PacketQueue {
    items: VecDeque<(u64, Vec<u8>)>,
    bytes: usize,
    capacity: usize,
    peak_bytes: usize,
}

impl PacketQueue {
    /// An empty queue holding at most `capacity` bytes.
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity,
            ..Self::default()
        }
    }

    /// Appends `packet` tagged `at` if it fits; gives it back otherwise.
    pub fn push(&mut self, at: u64, packet: Vec<u8>) -> Result<(), Vec<u8>> {
        if !self.fits(packet.len()) {
            return Err(packet);
        }
        self.bytes += packet.len();
        self.peak_bytes = self.peak_bytes.max(self.bytes);
        self.items.push_back((at, packet));
        Ok(())
    }

    /// Whether `len` more bytes fit.
    pub fn fits(&self, len: usize) -> bool {
        self.bytes + len <= self.capacity
    }

    /// The oldest packet and its tag.
    pub fn pop(&mut self) -> Option<(u64, Vec<u8>)> {
        let item = self.items.pop_front()?;
        self.bytes -= item.1.len();
        Some(item)
    }

    /// The oldest packet if its tag is at most `now`.
    pub fn pop_due(&mut self, now: u64) -> Option<Vec<u8>> {
        if self.items.front().is_some_and(|&(at, _)| at <= now) {
            self.pop().map(|(_, p)| p)
        } else {
            None
        }
    }

    /// Swaps the payloads of the two newest packets (their tags stay, so the queue stays in
    /// delivery order): the newest overtakes the one before. Whether there were two.
    pub fn swap_last_two(&mut self) -> bool {
        let n = self.items.len();
        if n < 2 {
            return false;
        }
        let last = std::mem::take(&mut self.items[n - 1].1);
        let before = std::mem::replace(&mut self.items[n - 2].1, last);
        self.items[n - 1].1 = before;
        true
    }

    /// Tag of the oldest packet.
    pub fn first_tag(&self) -> Option<u64> {
        self.items.front().map(|&(at, _)| at)
    }

    /// Tag of the newest packet.
    pub fn last_tag(&self) -> Option<u64> {
        self.items.back().map(|&(at, _)| at)
    }

    /// Empties the queue; returns how many packets it held.
    pub fn clear(&mut self) -> usize {
        let n = self.items.len();
        self.items.clear();
        self.bytes = 0;
        n
    }

    /// Packets queued.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// Whether nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Bytes queued.
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// Most bytes ever queued at once.
    pub fn peak_bytes(&self) -> usize {
        self.peak_bytes
    }

    /// The byte bound.
    pub fn capacity(&self) -> usize {
        self.capacity
    }
}

/// A fault on a link until a time: what it does to each packet sent meanwhile, either way.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Impairment {
    /// What it does (a link-level kind; a cut is [`SimLink::set_up`], a reboot is the robot's).
    pub kind: world::faults::FaultKind,
    /// Packets sent from this simulated time on, ns, are left alone.
    pub until_ns: u64,
}

/// One robot's link: two ordered queues of packets with delivery times.
#[derive(Clone, Debug)]
pub struct SimLink {
    to_robot: PacketQueue,
    to_host: PacketQueue,
    up: bool,
    impairment: Option<Impairment>,
    stats: LinkStats,
    rng: ChaCha8Rng,
    /// The Gilbert–Elliott channel is in a fade.
    fading: bool,
    /// When the channel's current spell (fade or good) ends, ns; 0 before the first packet.
    spell_ends_ns: u64,
}

impl SimLink {
    /// An up link with its own random stream, buffering [`LINK_BUFFER_BYTES`] per direction.
    pub fn new(rng: ChaCha8Rng) -> Self {
        Self::with_buffer(rng, LINK_BUFFER_BYTES)
    }

    /// An up link whose directions each hold at most `buffer_bytes`.
    pub fn with_buffer(rng: ChaCha8Rng, buffer_bytes: usize) -> Self {
        Self {
            to_robot: PacketQueue::new(buffer_bytes),
            to_host: PacketQueue::new(buffer_bytes),
            up: true,
            impairment: None,
            stats: LinkStats::default(),
            rng,
            fading: false,
            spell_ends_ns: 0,
        }
    }

    /// Whether packets get through.
    pub fn is_up(&self) -> bool {
        self.up
    }

    /// Cuts or restores the link; cutting drops everything in flight.
    pub fn set_up(&mut self, up: bool) {
        if !up {
            self.stats.dropped_while_cut += (self.to_robot.len() + self.to_host.len()) as u64;
            self.to_robot.clear();
            self.to_host.clear();
        }
        self.up = up;
    }

    /// Puts a fault on the link (`None` lifts it); it ends by itself at its `until_ns`.
    pub fn impair(&mut self, impairment: Option<Impairment>) {
        self.impairment = impairment;
    }

    /// Counters.
    pub fn stats(&self) -> LinkStats {
        LinkStats {
            peak_to_robot_bytes: self.to_robot.peak_bytes() as u64,
            peak_to_host_bytes: self.to_host.peak_bytes() as u64,
            ..self.stats
        }
    }

    /// Bytes waiting towards the robot and towards the host.
    pub fn queued_bytes(&self) -> (usize, usize) {
        (self.to_robot.bytes(), self.to_host.bytes())
    }

    /// The host end closed: whatever it sent that is still on the way, and whatever the robot sent
    /// it, is discarded, so a host connecting next starts from an empty link.
    pub fn host_closed(&mut self) {
        let n = self.to_robot.clear() + self.to_host.clear();
        self.stats.discarded_on_close += n as u64;
    }

    /// Counts host packets discarded on close before they had even entered the link.
    pub fn count_discarded_on_close(&mut self, packets: u64) {
        self.stats.discarded_on_close += packets;
    }

    /// Counts host packets dropped before reaching the link (a host-side buffer was full).
    pub fn count_overflow_to_robot(&mut self, packets: u64, bytes: u64) {
        self.stats.overflow_to_robot += packets;
        self.stats.overflow_to_robot_bytes += bytes;
    }

    /// Counts robot packets the host side dropped (its client did not read fast enough).
    pub fn count_overflow_to_host(&mut self, packets: u64, bytes: u64) {
        self.stats.overflow_to_host += packets;
        self.stats.overflow_to_host_bytes += bytes;
    }

    /// Records that the host-side buffer held `bytes` at its fullest.
    pub fn note_host_buffer_peak(&mut self, bytes: usize) {
        let bytes = bytes as u64;
        self.stats.peak_host_buffer_bytes = self.stats.peak_host_buffer_bytes.max(bytes);
    }

    /// The host sends a packet at `now_ns`.
    pub fn send_to_robot(
        &mut self,
        now_ns: u64,
        packet: Vec<u8>,
        model: &LinkModel,
        air: &mut Piconet,
    ) {
        self.stats.to_robot += 1;
        self.send(now_ns, packet, model, air, true);
    }

    /// The robot sends a packet at `now_ns`.
    pub fn send_to_host(
        &mut self,
        now_ns: u64,
        packet: Vec<u8>,
        model: &LinkModel,
        air: &mut Piconet,
    ) {
        self.stats.to_host += 1;
        self.send(now_ns, packet, model, air, false);
    }

    /// Puts a packet on its way, through the fault on the link if one is on.
    fn send(
        &mut self,
        now_ns: u64,
        mut packet: Vec<u8>,
        model: &LinkModel,
        air: &mut Piconet,
        to_robot: bool,
    ) {
        use world::faults::FaultKind;
        let fault = self
            .impairment
            .filter(|f| now_ns < f.until_ns && self.up)
            .map(|f| f.kind);
        let hit = |rng: &mut ChaCha8Rng, share: f64| rng.gen::<f64>() < share;
        let mut extra_s = 0.0;
        match fault {
            Some(FaultKind::Loss(share)) if hit(&mut self.rng, share) => {
                self.stats.fault_lost += 1;
                return;
            }
            Some(FaultKind::Corrupt(share)) if !packet.is_empty() && hit(&mut self.rng, share) => {
                // One byte replaced by a different one: what a single burst of noise does.
                let at = self.rng.gen_range(0..packet.len());
                packet[at] ^= self.rng.gen_range(1..=u8::MAX);
                self.stats.corrupted += 1;
            }
            Some(FaultKind::Latency(s)) => {
                extra_s = s;
                self.stats.delayed += 1;
            }
            _ => {}
        }
        let len = packet.len();
        let Some(at) = self.schedule(now_ns, len, model, air, to_robot, extra_s) else {
            return;
        };
        let twice = matches!(fault, Some(FaultKind::Duplicate(share)) if hit(&mut self.rng, share));
        let overtakes =
            matches!(fault, Some(FaultKind::Reorder(share)) if hit(&mut self.rng, share));
        let queue = if to_robot {
            &mut self.to_robot
        } else {
            &mut self.to_host
        };
        let copy = twice.then(|| packet.clone());
        // `schedule` checked that it fits.
        let _ = queue.push(at, packet);
        if let Some(copy) = copy {
            if queue.push(at, copy).is_ok() {
                self.stats.duplicated += 1;
            }
        }
        if overtakes && queue.swap_last_two() {
            self.stats.reordered += 1;
        }
    }

    /// The next packet due at the robot by `now_ns`.
    pub fn recv_at_robot(&mut self, now_ns: u64) -> Option<Vec<u8>> {
        self.to_robot.pop_due(now_ns)
    }

    /// The next packet due at the host by `now_ns`.
    pub fn recv_at_host(&mut self, now_ns: u64) -> Option<Vec<u8>> {
        self.to_host.pop_due(now_ns)
    }

    /// When the oldest packet on its way to the host arrives there, if one is on its way.
    pub fn next_at_host(&self) -> Option<u64> {
        self.to_host.first_tag()
    }

    /// Whether a packet sent at `now_ns` is lost: a draw on its own, or whether the channel is
    /// in a fade then (fades last `loss_burst_s` on average and fill a `loss` share of the time).
    fn lose(&mut self, now_ns: u64, model: &LinkModel) -> bool {
        if model.loss_burst_s <= 0.0 || model.loss >= 1.0 {
            return self.rng.gen::<f64>() < model.loss;
        }
        let fade_s = model.loss_burst_s;
        let good_s = fade_s * (1.0 - model.loss) / model.loss;
        if self.spell_ends_ns == 0 {
            // The first packet finds the channel in its long-run state.
            self.fading = self.rng.gen::<f64>() < model.loss;
            self.spell_ends_ns = now_ns + self.spell_ns(if self.fading { fade_s } else { good_s });
        }
        while now_ns >= self.spell_ends_ns {
            self.fading = !self.fading;
            let mean = if self.fading { fade_s } else { good_s };
            self.spell_ends_ns += self.spell_ns(mean).max(1);
        }
        self.fading
    }

    /// An exponentially distributed spell of mean `mean_s`, ns.
    fn spell_ns(&mut self, mean_s: f64) -> u64 {
        let u: f64 = self.rng.gen::<f64>();
        (-(1.0 - u).ln() * mean_s * 1e9).min(1e15) as u64
    }

    fn schedule(
        &mut self,
        now_ns: u64,
        bytes: usize,
        model: &LinkModel,
        air: &mut Piconet,
        to_robot: bool,
        extra_s: f64,
    ) -> Option<u64> {
        if !self.up {
            self.stats.dropped_while_cut += 1;
            return None;
        }
        // A full buffer refuses the packet before it takes any air time, as a full UART ring
        // loses the bytes without delaying those behind it.
        let queue = if to_robot {
            &self.to_robot
        } else {
            &self.to_host
        };
        if !queue.fits(bytes) {
            if to_robot {
                self.count_overflow_to_robot(1, bytes as u64);
            } else {
                self.count_overflow_to_host(1, bytes as u64);
            }
            return None;
        }
        if model.loss > 0.0 && self.lose(now_ns, model) {
            self.stats.lost += 1;
            return None;
        }
        // Air time: L2CAP + baseband overhead of ~10 bytes per packet on top of the payload.
        let air_ns = if model.bandwidth_bps > 0.0 {
            ((bytes + 10) as f64 * 8.0 / model.bandwidth_bps * 1e9) as u64
        } else {
            0
        };
        let start = air.busy_until_ns.max(now_ns);
        air.busy_until_ns = start + air_ns;
        let jitter = if model.jitter_s > 0.0 {
            self.rng.gen::<f64>() * model.jitter_s
        } else {
            0.0
        };
        let mut at = start + air_ns + ((model.latency_s + jitter + extra_s).max(0.0) * 1e9) as u64;
        let queue = if to_robot {
            &self.to_robot
        } else {
            &self.to_host
        };
        if let Some(last) = queue.last_tag() {
            at = at.max(last);
        }
        Some(at)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn link() -> SimLink {
        SimLink::new(ChaCha8Rng::seed_from_u64(7))
    }

    #[test]
    fn a_fault_on_the_link_does_what_it_says_to_packets_sent_while_it_lasts_and_then_stops() {
        use world::faults::FaultKind;
        let model = LinkModel::default();
        let ms = 1_000_000u64;
        // Twenty packets, one a millisecond, numbered by their byte; the fault covers the first
        // ten; everything is read at 5 s.
        let run = |kind: FaultKind| {
            let (mut l, mut air) = (link(), Piconet::default());
            l.impair(Some(Impairment {
                kind,
                until_ns: 10 * ms,
            }));
            for k in 0..20u8 {
                l.send_to_robot(u64::from(k) * ms, vec![k, 0xAA], &model, &mut air);
            }
            let at_1s: Vec<Vec<u8>> = std::iter::from_fn(|| l.recv_at_robot(1_000 * ms)).collect();
            let later: Vec<Vec<u8>> = std::iter::from_fn(|| l.recv_at_robot(5_000 * ms)).collect();
            (l.stats(), at_1s, later)
        };
        let (stats, got, _) = run(FaultKind::Loss(1.0));
        assert_eq!(stats.fault_lost, 10);
        assert_eq!(
            got.iter().map(|p| p[0]).collect::<Vec<_>>(),
            (10..20).collect::<Vec<_>>()
        );
        let (stats, got, later) = run(FaultKind::Latency(1.5));
        assert_eq!(stats.delayed, 10);
        // Order kept: the undelayed packets wait behind the delayed ones.
        assert!(got.is_empty(), "{got:?}");
        assert_eq!(
            later.iter().map(|p| p[0]).collect::<Vec<_>>(),
            (0..20).collect::<Vec<_>>()
        );
        let (stats, got, _) = run(FaultKind::Corrupt(1.0));
        assert_eq!(stats.corrupted, 10);
        let changed = got
            .iter()
            .enumerate()
            .filter(|(k, p)| **p != vec![*k as u8, 0xAA]);
        assert_eq!(changed.count(), 10);
        let (stats, got, _) = run(FaultKind::Duplicate(1.0));
        assert_eq!((stats.duplicated, got.len()), (10, 30));
        let (stats, got, _) = run(FaultKind::Reorder(1.0));
        assert_eq!(stats.reordered, 9);
        let order: Vec<u8> = got.iter().map(|p| p[0]).collect();
        assert_ne!(order[..10], (0..10).collect::<Vec<_>>()[..]);
        assert_eq!(order[10..], (10..20).collect::<Vec<_>>()[..]);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..20).collect::<Vec<_>>());
    }

    #[test]
    fn fades_keep_their_long_run_share_and_last_their_mean_whatever_the_packet_rate() {
        let model = LinkModel {
            loss: 0.05,
            loss_burst_s: 0.040,
            ..LinkModel::default()
        };
        // One packet a millisecond, then one every 50 ms: a fade is time, not packets.
        for every_ms in [1u64, 50] {
            let mut l = link();
            let (mut lost, mut sent, mut runs, mut previous) = (0u32, 0u32, 0u32, false);
            for k in 0..(2_000_000 / every_ms) {
                let now = l.lose(k * every_ms * 1_000_000, &model);
                sent += 1;
                lost += u32::from(now);
                runs += u32::from(now && !previous);
                previous = now;
            }
            let rate = f64::from(lost) / f64::from(sent);
            let mean_run_ms = f64::from(lost) / f64::from(runs) * every_ms as f64;
            assert!(
                (rate - 0.05).abs() < 0.01,
                "every {every_ms} ms: loss {rate}"
            );
            if every_ms == 1 {
                assert!(
                    (mean_run_ms - 40.0).abs() < 5.0,
                    "fades of {mean_run_ms:.1} ms"
                );
            } else {
                // A fade outlasts the next 50 ms with probability e^(-50/40): runs of about
                // 1.4 packets, where a chain counted in packets would silence this link for 4.
                let packets = f64::from(lost) / f64::from(runs);
                assert!(packets < 1.6, "runs of {packets:.2} packets");
            }
        }
    }

    #[test]
    fn latency_jitter_and_order() {
        let model = LinkModel::default();
        let mut air = Piconet::default();
        let mut l = link();
        for i in 0..20u8 {
            l.send_to_robot(0, vec![i; 20], &model, &mut air);
        }
        assert_eq!(
            l.recv_at_robot(9_000_000),
            None,
            "nothing before the latency"
        );
        let mut got = Vec::new();
        while let Some(p) = l.recv_at_robot(20_000_000) {
            got.push(p[0]);
        }
        assert_eq!(got, (0..20).collect::<Vec<_>>(), "in order");
    }

    #[test]
    fn a_shared_piconet_serialises_air_time() {
        let model = LinkModel {
            jitter_s: 0.0,
            ..LinkModel::default()
        };
        let mut air = Piconet::default();
        // Buffers big enough for the burst: this is about air time, not overflow.
        let mut links: Vec<SimLink> = (0..7)
            .map(|_| SimLink::with_buffer(ChaCha8Rng::seed_from_u64(7), 1 << 20))
            .collect();
        // 7 robots each send 100 full-state packets at once: 7·100·(110 + 10 overhead)·8 bits at
        // 700 kbit/s take 0.96 s of air time.
        for l in links.iter_mut() {
            for _ in 0..100 {
                l.send_to_host(0, vec![0; 110], &model, &mut air);
            }
        }
        let busy_s = air.busy_until_ns as f64 * 1e-9;
        assert!((busy_s - 0.96).abs() < 0.01, "{busy_s}");
        let delivered_by_half: usize = links
            .iter_mut()
            .map(|l| std::iter::from_fn(|| l.recv_at_host(500_000_000)).count())
            .sum();
        // By 0.5 s (10 ms of it latency) about 0.49 / 0.96 of them have arrived.
        assert!(
            (330..390).contains(&delivered_by_half),
            "{delivered_by_half}"
        );
    }

    #[test]
    fn loss_and_cut() {
        let model = LinkModel {
            loss: 0.5,
            ..LinkModel::default()
        };
        let mut air = Piconet::default();
        let mut l = link();
        for _ in 0..1000 {
            l.send_to_host(0, vec![1], &model, &mut air);
        }
        let lost = l.stats().lost;
        assert!((400..600).contains(&lost), "{lost}");
        l.set_up(false);
        l.send_to_robot(0, vec![1], &model, &mut air);
        assert_eq!(l.recv_at_host(u64::MAX), None);
        assert!(l.stats().dropped_while_cut > 0);
    }

    #[test]
    fn a_flood_is_dropped_past_the_buffer_without_taking_air_time() {
        let model = LinkModel {
            jitter_s: 0.0,
            ..LinkModel::default()
        };
        let mut air = Piconet::default();
        let mut l = link();
        // 1 MB of 100-byte packets at once: only the first 4 KiB fit.
        for _ in 0..10_000 {
            l.send_to_robot(0, vec![0; 100], &model, &mut air);
        }
        let s = l.stats();
        let fit = (LINK_BUFFER_BYTES / 100) as u64;
        assert_eq!(s.overflow_to_robot, 10_000 - fit);
        assert_eq!(s.overflow_to_robot_bytes, (10_000 - fit) * 100);
        assert_eq!(s.peak_to_robot_bytes, fit * 100);
        // Only what fits took air time: 40 · 110 bytes at 700 kbit/s ≈ 50 ms.
        let busy_s = air.busy_until_ns as f64 * 1e-9;
        assert!(busy_s < 0.06, "{busy_s}");
        // Once delivered there is room again, and a new packet arrives a latency later.
        let delivered = std::iter::from_fn(|| l.recv_at_robot(100_000_000)).count();
        assert_eq!(delivered as u64, fit);
        l.send_to_robot(100_000_000, vec![9; 10], &model, &mut air);
        assert_eq!(l.recv_at_robot(111_000_000), Some(vec![9; 10]));
    }

    #[test]
    fn closing_the_host_end_discards_what_is_queued() {
        let model = LinkModel::default();
        let mut air = Piconet::default();
        let mut l = link();
        for _ in 0..5 {
            l.send_to_robot(0, vec![1; 10], &model, &mut air);
            l.send_to_host(0, vec![2; 10], &model, &mut air);
        }
        l.host_closed();
        assert_eq!(l.queued_bytes(), (0, 0));
        assert_eq!(l.stats().discarded_on_close, 10);
        assert_eq!(l.recv_at_robot(u64::MAX), None);
        assert_eq!(l.recv_at_host(u64::MAX), None);
    }
}
