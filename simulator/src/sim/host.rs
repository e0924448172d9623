//! The host's end of each robot's link: opening and closing it, packets both ways, the host-side
//! buffers' accounting, and the log of the host's silences towards each robot.

use firmware::Instant;

use super::{SimRobot, Simulation};

/// How long the host must be silent before the simulator logs a [`HostSilence`]: well over the
/// host's ping period, under the firmware's default watchdog (500 ms).
pub const SILENCE_NS: u64 = 250_000_000;
/// A wheel whose rim moves slower than this counts as stopped, m/s.
pub const WHEEL_STOPPED_MPS: f64 = 0.001;

/// A time the host sent a robot nothing for at least [`SILENCE_NS`], and what the robot's body
/// did meanwhile (its wheels' true speeds, not what its encoders say).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HostSilence {
    /// When the last host packet before the silence reached the robot, simulated seconds.
    pub last_packet_s: f64,
    /// When the next one reached it, if one did.
    pub resumed_s: Option<f64>,
    /// When both wheels were first below [`WHEEL_STOPPED_MPS`] within the silence, if they were.
    pub wheels_stopped_s: Option<f64>,
}

impl SimRobot {
    /// Keeps the log of host silences at `now_ns`; `packet` when a host packet arrived.
    pub(super) fn watch_host(&mut self, now_ns: u64, packet: bool, radius_m: f64) {
        let still = self
            .wheels
            .iter()
            .all(|w| (w.omega * radius_m).abs() < WHEEL_STOPPED_MPS);
        self.still_since_ns = if still {
            self.still_since_ns.or(Some(now_ns))
        } else {
            None
        };
        let seconds = |ns: u64| ns as f64 * 1e-9;
        if packet {
            if let Some(s) = self.silences.last_mut().filter(|s| s.resumed_s.is_none()) {
                s.resumed_s = Some(seconds(now_ns));
            }
            self.last_host_packet_ns = Some(now_ns);
            return;
        }
        let Some(last) = self.last_host_packet_ns else {
            return;
        };
        match self.silences.last_mut().filter(|s| s.resumed_s.is_none()) {
            Some(s) if s.wheels_stopped_s.is_none() => {
                s.wheels_stopped_s = self.still_since_ns.map(seconds);
            }
            Some(_) => {}
            None if now_ns - last >= SILENCE_NS => self.silences.push(HostSilence {
                last_packet_s: seconds(last),
                resumed_s: None,
                // Wheels that stood before the silence began stopped, for it, when it began.
                wheels_stopped_s: self.still_since_ns.map(|t| seconds(t.max(last))),
            }),
            None => {}
        }
    }
}

impl Simulation {
    /// The host end of robot `i`'s link opens: the robot sends its hello.
    pub fn connect(&mut self, i: usize) {
        let now = Instant::from_nanos(self.now_ns);
        let r = &mut self.robots[i];
        r.connected = true;
        r.firmware.on_link_connected(now);
        self.flush_outgoing(i);
    }

    /// The host end of robot `i`'s link closes; the robot's packets go nowhere, and what either
    /// side had queued is discarded so the next host starts afresh.
    pub fn disconnect(&mut self, i: usize) {
        let r = &mut self.robots[i];
        r.connected = false;
        r.link.host_closed();
    }

    /// Counts packets a host-side buffer of robot `i`'s link discarded when its host left.
    pub fn count_discarded_on_close(&mut self, i: usize, packets: u64) {
        self.robots[i].link.count_discarded_on_close(packets);
    }

    /// Accounts for a host-side buffer of robot `i`'s link: the packets it dropped for being full
    /// towards the robot (`to_robot`) and towards the host, as (packets, bytes), and the most bytes
    /// it held at once.
    pub fn note_host_buffer(
        &mut self,
        i: usize,
        to_robot: (u64, u64),
        to_host: (u64, u64),
        peak_bytes: usize,
    ) {
        let link = &mut self.robots[i].link;
        link.count_overflow_to_robot(to_robot.0, to_robot.1);
        link.count_overflow_to_host(to_host.0, to_host.1);
        link.note_host_buffer_peak(peak_bytes);
    }

    /// The host sends one packet to robot `i`.
    pub fn host_send(&mut self, i: usize, packet: Vec<u8>) {
        let per = self.link_model.robots_per_piconet;
        let r = &mut self.robots[i];
        r.link.send_to_robot(
            self.now_ns,
            packet,
            &self.link_model,
            &mut self.piconets[i / per],
        );
    }

    /// The next packet from robot `i` that has arrived at the host.
    pub fn host_recv(&mut self, i: usize) -> Option<Vec<u8>> {
        if *self.host_due_ns.get(i)? > self.now_ns {
            return None;
        }
        let link = &mut self.robots[i].link;
        let p = link.recv_at_host(self.now_ns);
        self.host_due_ns[i] = link.next_at_host().unwrap_or(u64::MAX);
        p
    }

    /// Passes the packets robot `i`'s firmware has to send to its link, while the host end is open.
    pub(super) fn flush_outgoing(&mut self, i: usize) {
        let per = self.link_model.robots_per_piconet;
        let r = &mut self.robots[i];
        while let Some(p) = r.firmware.pop_packet() {
            if r.connected {
                r.link.send_to_host(
                    self.now_ns,
                    p.to_vec(),
                    &self.link_model,
                    &mut self.piconets[i / per],
                );
            }
        }
        if let Some(at) = r.link.next_at_host() {
            self.host_due_ns[i] = self.host_due_ns[i].min(at);
        }
    }
}
