//! Simulated robot links: each carries exactly the protocol packets a real link would, delayed by a
//! latency with jitter, thinned by loss, and serialised through the air time of a piconet whose
//! bandwidth its robots share (defaults modelled on Bluetooth L2CAP: ~10 ms, no loss after
//! retransmission, ~700 kbit/s for up to 7 robots).
//!
//! Packets in one direction stay in order, as on L2CAP. A cut link drops everything in both
//! directions until it is restored.

use std::collections::VecDeque;

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Timing of a link, in nanoseconds of simulated time where not said otherwise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkModel {
    /// One-way latency, seconds.
    pub latency_s: f64,
    /// Uniform jitter added to the latency, seconds (0..jitter).
    pub jitter_s: f64,
    /// Probability that a packet is lost.
    pub loss: f64,
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
}

/// One robot's link: two ordered queues of packets with delivery times.
#[derive(Clone, Debug)]
pub struct Link {
    to_robot: VecDeque<(u64, Vec<u8>)>,
    to_host: VecDeque<(u64, Vec<u8>)>,
    up: bool,
    stats: LinkStats,
    rng: ChaCha8Rng,
}

impl Link {
    /// An up link with its own random stream.
    pub fn new(rng: ChaCha8Rng) -> Self {
        Self {
            to_robot: VecDeque::new(),
            to_host: VecDeque::new(),
            up: true,
            stats: LinkStats::default(),
            rng,
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

    /// Counters.
    pub fn stats(&self) -> LinkStats {
        self.stats
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
        if let Some(at) = self.schedule(now_ns, packet.len(), model, air, true) {
            self.to_robot.push_back((at, packet));
        }
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
        if let Some(at) = self.schedule(now_ns, packet.len(), model, air, false) {
            self.to_host.push_back((at, packet));
        }
    }

    /// The next packet due at the robot by `now_ns`.
    pub fn recv_at_robot(&mut self, now_ns: u64) -> Option<Vec<u8>> {
        pop_due(&mut self.to_robot, now_ns)
    }

    /// The next packet due at the host by `now_ns`.
    pub fn recv_at_host(&mut self, now_ns: u64) -> Option<Vec<u8>> {
        pop_due(&mut self.to_host, now_ns)
    }

    fn schedule(
        &mut self,
        now_ns: u64,
        bytes: usize,
        model: &LinkModel,
        air: &mut Piconet,
        to_robot: bool,
    ) -> Option<u64> {
        if !self.up {
            self.stats.dropped_while_cut += 1;
            return None;
        }
        if model.loss > 0.0 && self.rng.gen::<f64>() < model.loss {
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
        let mut at = start + air_ns + ((model.latency_s + jitter).max(0.0) * 1e9) as u64;
        let queue = if to_robot {
            &self.to_robot
        } else {
            &self.to_host
        };
        if let Some(&(last, _)) = queue.back() {
            at = at.max(last);
        }
        Some(at)
    }
}

fn pop_due(q: &mut VecDeque<(u64, Vec<u8>)>, now_ns: u64) -> Option<Vec<u8>> {
    if q.front().is_some_and(|&(at, _)| at <= now_ns) {
        q.pop_front().map(|(_, p)| p)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn link() -> Link {
        Link::new(ChaCha8Rng::seed_from_u64(7))
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
        let mut links: Vec<Link> = (0..7).map(|_| link()).collect();
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
}
