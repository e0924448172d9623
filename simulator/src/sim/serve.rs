//! Serving every firmware at each clock step: link packets, encoder edges, due ticks, and the IR
//! frames and packets the firmwares send.

use firmware::Instant;
use rayon::prelude::*;

use super::{SimRobot, Simulation, BEAMS, OUTGOING, PARALLEL_FROM};
use crate::ir::{self, Beam, Scene};

impl Simulation {
    /// Serves every firmware at the clock's new time: link packets, encoder edges that have
    /// happened, and a tick where one of its deadlines is due; then IR and outgoing packets.
    pub(super) fn serve_firmware(&mut self) {
        let now = Instant::from_nanos(self.now_ns);
        let now_ns = self.now_ns;
        let radius_m = self.spec.wheel_radius_m();
        let (span_start, span_end) = self.physics_span;
        // The step's last tick takes every edge it made, as capture rounding can date one a
        // fraction of a microsecond after the step's end.
        let edges_until = if now_ns >= span_end {
            Instant::from_nanos(u64::MAX)
        } else {
            now
        };
        let interpolate = self.physics_every > 1;
        let scene = Scene {
            robots: &self.robot_boxes,
            obstacles: &self.obstacle_boxes,
            arena: [self.world.arena.width_m, self.world.arena.height_m],
            grid: &self.grid,
        };
        let spec = &self.spec;
        let (leds, cone_half) = (&self.ir_leds, self.ir_cone_half);
        let trace = |i: usize, led: u8, power: u8| {
            let &led = leds.get(usize::from(led))?;
            let level = usize::from(power.clamp(1, 4)) - 1;
            Some(ir::propagate(
                &scene,
                &Beam {
                    robot: i,
                    led,
                    range: spec.ir_range_m[level],
                    cone_half,
                },
            ))
        };
        let tick = |(i, r): (usize, &mut SimRobot)| -> u8 {
            r.hear_host(now, now_ns, radius_m);
            // Edges reach the firmware as its capture interrupt would: once they have happened.
            // Most steps have none waiting.
            r.pass_edges(edges_until);
            if r.firmware.next_deadline().is_some_and(|d| d <= now) {
                if interpolate {
                    r.place_floor_sensor(now_ns, span_start, span_end);
                }
                r.firmware.tick(now);
            }
            // Beams only read the scene, which moves only on physics steps: traced here, on
            // whichever core serves the sender, and delivered below in the robots' order.
            r.trace_beams(|led, power| trace(i, led, power));
            // Read while the robot's state is in this core's cache, so the serial passes below
            // visit only robots with something to pass on.
            (u8::from(r.firmware.has_outgoing()) * OUTGOING) | (u8::from(!r.lit.is_empty()) * BEAMS)
        };
        let mut served = std::mem::take(&mut self.served);
        if self.robots.len() >= PARALLEL_FROM {
            self.robots
                .par_iter_mut()
                .enumerate()
                .map(tick)
                .collect_into_vec(&mut served);
        } else {
            served.clear();
            served.extend(self.robots.iter_mut().enumerate().map(tick));
        }
        self.deliver_ir(now, &mut served);
        for (i, &bits) in served.iter().enumerate() {
            if bits & OUTGOING != 0 {
                self.flush_outgoing(i);
            }
        }
        self.served = served;
    }

    /// Delivers the frames of the beams the robots `served` marks sent, in the robots' order and
    /// each robot's LEDs' order, so the thread count cannot change the run; marks the receivers
    /// as having packets to send (a sighting may report at once).
    fn deliver_ir(&mut self, now: Instant, served: &mut [u8]) {
        for i in 0..self.robots.len() {
            if served[i] & BEAMS == 0 {
                continue;
            }
            let mut lit = std::mem::take(&mut self.robots[i].lit);
            for (frame, arrived) in lit.drain(..) {
                let Some(arrived) = arrived else { continue };
                for (j, side) in arrived.robots {
                    self.robots[j].firmware.on_ir_frame(now, side, frame);
                    served[j] |= OUTGOING;
                }
                if let Some(side) = arrived.reflection {
                    self.robots[i].firmware.on_ir_frame(now, side, frame);
                    served[i] |= OUTGOING;
                }
            }
            self.robots[i].lit = lit;
        }
    }
}

impl SimRobot {
    /// Hands the firmware every link packet that has reached the robot by `now`, counting the
    /// settings updates, and keeps the log of the host's silences.
    fn hear_host(&mut self, now: Instant, now_ns: u64, radius_m: f64) {
        let mut heard = false;
        while let Some(p) = self.link.recv_at_robot(now_ns) {
            if p.get(1) == Some(&(protocol::PacketType::SettingsUpdate as u8)) {
                self.settings_updates += 1;
            }
            self.firmware.on_link_packet(now, &p);
            heard = true;
        }
        self.watch_host(now_ns, heard, radius_m);
    }

    /// Hands the firmware the encoder edges that have happened by `edges_until`.
    fn pass_edges(&mut self, edges_until: Instant) {
        if !self.firmware.board().edges.is_empty() {
            let mut edges = std::mem::take(&mut self.firmware.board_mut().edges);
            edges.retain(|e| {
                let happened = e.at <= edges_until;
                if happened {
                    self.firmware.on_encoder_edge(e.wheel, e.at);
                }
                !happened
            });
            self.firmware.board_mut().edges = edges;
        }
    }

    /// Takes the frames the IR LEDs sent, each with where `trace` finds it arrives.
    fn trace_beams(&mut self, trace: impl Fn(u8, u8) -> Option<ir::Arrivals>) {
        let board = self.firmware.board_mut();
        if !board.ir_out.is_empty() {
            let lit = &mut self.lit;
            lit.extend(
                board
                    .ir_out
                    .drain(..)
                    .map(|(led, power, frame)| (frame, trace(led, power))),
            );
        }
    }
}
