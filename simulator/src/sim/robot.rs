//! One simulated robot: its firmware on a [`SimBoard`], body, wheels, battery, link and ground
//! truth.

use firmware::hal::IrFrame;
use firmware::Firmware;
use nalgebra::Vector2;
use rapier2d::prelude::RigidBodyHandle;

use super::{BodyFault, HostSilence, Pose};
use crate::board::SimBoard;
use crate::drive::WheelState;
use crate::ir;
use crate::link::{LinkStats, SimLink};
use crate::spec::RobotSpec;

/// One simulated PocketBot2.
pub struct SimRobot {
    pub(super) id: u16,
    pub(super) firmware: Firmware<SimBoard>,
    pub(super) body: RigidBodyHandle,
    pub(super) wheels: [WheelState; 2],
    pub(super) charge_ah: f64,
    pub(super) temperature_c: f64,
    pub(super) current_a: f64,
    pub(super) last_velocity: Vector2<f64>,
    pub(super) link: SimLink,
    pub(super) connected: bool,
    pub(super) distance_m: f64,
    pub(super) pose: Pose,
    pub(super) fault: Option<BodyFault>,
    pub(super) last_host_packet_ns: Option<u64>,
    pub(super) still_since_ns: Option<u64>,
    pub(super) silences: Vec<HostSilence>,
    pub(super) settings_updates: u32,
    /// Line sensor centre and heading's (sin, cos) at the start and the end of the physics step
    /// under way, for the floor to be looked at in between.
    pub(super) sensor_path: [([f64; 2], (f64, f64)); 2],
    /// Frames the robot's IR LEDs sent this step and where each arrived, traced while it was
    /// served and delivered once every robot has been.
    pub(super) lit: Vec<(IrFrame, Option<ir::Arrivals>)>,
    /// A hand moving the body, while it does.
    pub(super) shove: Option<super::faults::Shove>,
}

impl SimRobot {
    /// The robot id.
    pub fn id(&self) -> u16 {
        self.id
    }
    /// The firmware, for inspection.
    pub fn firmware(&self) -> &Firmware<SimBoard> {
        &self.firmware
    }
    /// True pose.
    pub fn pose(&self) -> Pose {
        self.pose
    }
    /// True distance driven, metres.
    pub fn distance_m(&self) -> f64 {
        self.distance_m
    }
    /// Link counters.
    pub fn link_stats(&self) -> LinkStats {
        self.link.stats()
    }
    /// Bytes waiting on the link towards the robot and towards the host.
    pub fn link_queued_bytes(&self) -> (usize, usize) {
        self.link.queued_bytes()
    }
    /// The body fault injected, if any.
    pub fn body_fault(&self) -> Option<BodyFault> {
        self.fault
    }
    /// Whether the link is up.
    pub fn link_up(&self) -> bool {
        self.link.is_up()
    }
    /// When the last host packet reached the robot, simulated seconds.
    pub fn last_host_packet_s(&self) -> Option<f64> {
        self.last_host_packet_ns.map(|ns| ns as f64 * 1e-9)
    }
    /// Settings update packets the host sent this robot so far (accepted or not).
    pub fn settings_updates(&self) -> u32 {
        self.settings_updates
    }
    /// Every silence of the host towards this robot so far (see [`HostSilence`]).
    pub fn host_silences(&self) -> &[HostSilence] {
        &self.silences
    }
    /// True rim speed of each wheel (left, right), m/s.
    pub fn wheel_speeds_mps(&self, spec: &RobotSpec) -> [f64; 2] {
        let r = spec.wheel_radius_m();
        [self.wheels[0].omega * r, self.wheels[1].omega * r]
    }
    /// Puts the line sensor where the body is at `now_ns` within the physics step from `start`
    /// to `end`, along a straight line between its ends: a step is a few millimetres at most.
    pub(super) fn place_floor_sensor(&mut self, now_ns: u64, start: u64, end: u64) {
        let f = (now_ns.saturating_sub(start) as f64 / end.saturating_sub(start).max(1) as f64)
            .min(1.0);
        let [(p0, (s0, c0)), (p1, (s1, c1))] = self.sensor_path;
        let lerp = |a: f64, b: f64| a + (b - a) * f;
        let sensor = [lerp(p0[0], p1[0]), lerp(p0[1], p1[1])];
        let sin_cos = (lerp(s0, s1), lerp(c0, c1));
        let board = self.firmware.board_mut();
        board.place_floor_sensor(sensor, sin_cos);
    }

    /// Battery terminal voltage, volts.
    pub fn battery_v(&self) -> f64 {
        f64::from(self.firmware.board().battery_mv) / 1000.0
    }
}
