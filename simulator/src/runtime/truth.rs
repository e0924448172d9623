//! Ground truth for tests and reports: every robot's true pose, distance, contacts, wheel speeds
//! and what it heard from its host.

use std::time::Duration;

use crate::sim::{Pose, Simulation};

/// Ground truth at one instant, for tests and reports.
#[derive(Clone, Debug, PartialEq)]
pub struct Truth {
    /// Simulated time.
    pub now: Duration,
    /// Robot ids and true poses.
    pub robots: Vec<(u16, Pose)>,
    /// True distance each robot drove, metres.
    pub distances_m: Vec<f64>,
    /// Box poses.
    pub obstacles: Vec<Pose>,
    /// How far each box moved from its start, metres.
    pub obstacle_displacements_m: Vec<f64>,
    /// Robot–robot contacts so far.
    pub robot_collisions: usize,
    /// Each robot–robot contact: when it began (simulated seconds) and the two robot ids.
    pub collision_log: Vec<(f64, u16, u16)>,
    /// Robot–wall contacts so far.
    pub wall_contacts: usize,
    /// Each robot–wall contact: when it began (simulated seconds) and the robot's id.
    pub wall_contact_log: Vec<(f64, u16)>,
    /// Each robot's true wheel rim speeds (left, right), m/s.
    pub wheel_speeds_mps: Vec<[f64; 2]>,
    /// When each robot last heard its host, simulated seconds.
    pub last_host_packet_s: Vec<Option<f64>>,
    /// Each robot's host silences so far.
    pub host_silences: Vec<Vec<crate::sim::HostSilence>>,
    /// Settings update packets each robot received from its host.
    pub settings_updates: Vec<u32>,
    /// Each robot's firmware watchdog timeout now, milliseconds (0: off).
    pub watchdog_ms: Vec<u16>,
}

/// The robots' true poses at one instant: the part of [`Truth`] cheap enough to ask for many times
/// a second.
#[derive(Clone, Debug, PartialEq)]
pub struct Poses {
    /// Simulated time.
    pub now: Duration,
    /// Robot ids and true poses, in world order.
    pub robots: Vec<(u16, Pose)>,
}

impl Truth {
    /// The longest any robot's wheels kept turning while its host was silent (a cut link, a
    /// lost burst, a host that stopped), seconds: from the last packet it heard to its wheels
    /// stopping, or to the next packet or now if they never did. A robot already standing when
    /// the silence began counts nothing.
    pub fn longest_unattended_s(&self) -> f64 {
        let now = self.now.as_secs_f64();
        self.host_silences
            .iter()
            .flatten()
            .map(|s| {
                let end = s.wheels_stopped_s.or(s.resumed_s).unwrap_or(now);
                (end - s.last_packet_s).max(0.0)
            })
            .fold(0.0, f64::max)
    }
}

/// Ground truth of a simulation.
pub fn truth(sim: &Simulation) -> Truth {
    use crate::sim::ContactKind;
    Truth {
        now: sim.now(),
        robots: sim.robots().iter().map(|r| (r.id(), r.pose())).collect(),
        distances_m: sim.robots().iter().map(|r| r.distance_m()).collect(),
        obstacles: sim.obstacle_poses(),
        obstacle_displacements_m: sim.obstacle_displacements(),
        robot_collisions: sim.robot_collisions(),
        collision_log: sim
            .contacts()
            .iter()
            .filter_map(|c| match c.kind {
                ContactKind::RobotRobot(a, b) => {
                    Some((c.at_s, sim.robots()[a].id(), sim.robots()[b].id()))
                }
                _ => None,
            })
            .collect(),
        wall_contacts: sim
            .contacts()
            .iter()
            .filter(|c| matches!(c.kind, ContactKind::RobotWall(_)))
            .count(),
        wall_contact_log: sim
            .contacts()
            .iter()
            .filter_map(|c| match c.kind {
                ContactKind::RobotWall(a) => Some((c.at_s, sim.robots()[a].id())),
                _ => None,
            })
            .collect(),
        wheel_speeds_mps: sim
            .robots()
            .iter()
            .map(|r| r.wheel_speeds_mps(sim.spec()))
            .collect(),
        last_host_packet_s: sim
            .robots()
            .iter()
            .map(|r| r.last_host_packet_s())
            .collect(),
        host_silences: sim
            .robots()
            .iter()
            .map(|r| r.host_silences().to_vec())
            .collect(),
        settings_updates: sim.robots().iter().map(|r| r.settings_updates()).collect(),
        watchdog_ms: sim
            .robots()
            .iter()
            .map(|r| r.firmware().settings().watchdog.timeout_ms)
            .collect(),
    }
}
