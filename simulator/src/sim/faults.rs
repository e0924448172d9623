//! Faults injected from outside: a broken part of a robot's body, a cut link, a kick, a reboot.

use firmware::{Firmware, Instant};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rapier2d::prelude::*;

use super::{Pose, Simulation};
use crate::board::SimBoard;
use crate::drive::WheelState;

/// A physical fault of one robot's body, injected to test what the host can tell from what the
/// robot reports. The firmware runs on and still answers; only the body misbehaves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BodyFault {
    /// Both wheels are blocked against the chassis: the motors draw stall current and turn
    /// nothing, the encoders never tick, and the tyres hold the body where it stands.
    JammedWheels,
    /// Both encoders are dead: the wheels turn and the robot moves, but the firmware counts no
    /// pulse (and so keeps raising the duty of a wheel it believes stands still).
    DeadEncoders,
}

impl BodyFault {
    /// Every fault with its name as [`BodyFault::from_str`](std::str::FromStr) takes it.
    pub const NAMES: [(&'static str, BodyFault); 2] = [
        ("jammed-wheels", BodyFault::JammedWheels),
        ("dead-encoders", BodyFault::DeadEncoders),
    ];
}

impl std::str::FromStr for BodyFault {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::NAMES
            .iter()
            .find(|(name, _)| *name == s)
            .map(|(_, f)| *f)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::NAMES.iter().map(|(n, _)| *n).collect();
                format!("unknown body fault {s:?}: expected {}", names.join(" or "))
            })
    }
}

impl Simulation {
    /// Cuts (`false`) or restores (`true`) robot `i`'s link, as a fault.
    pub fn set_link_up(&mut self, i: usize, up: bool) {
        self.robots[i].link.set_up(up);
    }

    /// Injects (`Some`) or repairs (`None`) a fault of robot `i`'s body; it lasts through
    /// reboots, as a broken part would.
    pub fn set_body_fault(&mut self, i: usize, fault: Option<BodyFault>) {
        self.robots[i].fault = fault;
    }

    /// Kicks robot `i`: moves its body by (`dx`, `dy`) metres and turns it by `dtheta` radians at
    /// once, at rest, without telling its firmware. Its wheels never turn for it, so its encoders
    /// and the odometry built on them do not see the move: only the ground truth and what the
    /// sensors see from the new place do. Returns the new true pose.
    ///
    /// # Errors
    /// There is no robot `i`, or the displacement is not finite.
    pub fn displace(&mut self, i: usize, dx: f64, dy: f64, dtheta: f64) -> Result<Pose, String> {
        let Some(r) = self.robots.get_mut(i) else {
            return Err(match self.robots.len() {
                0 => format!("cannot displace robot index {i}: the world has no robots"),
                n => format!(
                    "cannot displace robot index {i}: the world's robots are indexed 0 to {}",
                    n - 1
                ),
            });
        };
        if !(dx.is_finite() && dy.is_finite() && dtheta.is_finite()) {
            return Err(format!(
                "cannot displace robot {} by ({dx}, {dy}) m and {dtheta} rad: not finite",
                r.id
            ));
        }
        let body = &mut self.bodies[r.body];
        let x = f64::from(body.translation().x) + dx;
        let y = f64::from(body.translation().y) + dy;
        let theta = f64::from(body.rotation().angle()) + dtheta;
        body.set_translation(vector![x as f32, y as f32], true);
        body.set_rotation(Rotation::new(theta as f32), true);
        body.set_linvel(vector![0.0, 0.0], true);
        body.set_angvel(0.0, true);
        // The true pose follows at once (the kick is not distance driven); its heading stays
        // unwrapped, counting the turn the kick gave.
        r.pose = Pose {
            x: f64::from(body.translation().x),
            y: f64::from(body.translation().y),
            theta: r.pose.theta + dtheta,
        };
        Ok(r.pose)
    }

    /// Reboots robot `i`'s firmware: RAM state is lost, the stored settings image is loaded again,
    /// and if its link is open it says hello again.
    pub fn reboot(&mut self, i: usize) {
        let now = Instant::from_nanos(self.now_ns);
        let r = &mut self.robots[i];
        let placeholder = Firmware::new(SimBoard::new(None, ChaCha8Rng::seed_from_u64(0)));
        let mut board = std::mem::replace(&mut r.firmware, placeholder).into_board();
        board.edges.clear();
        board.ir_out.clear();
        r.lit.clear();
        board.pwm = (0, 0);
        r.firmware = Firmware::new(board);
        r.wheels = [WheelState::default(); 2];
        if r.connected {
            r.firmware.on_link_connected(now);
        }
        self.flush_outgoing(i);
    }
}
