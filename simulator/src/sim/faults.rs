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

    /// Puts fault `kind` (loss, latency, corruption, duplication or reordering) on robot `i`'s
    /// link, both ways, for the packets sent over the next `lasting` of simulated time.
    pub fn impair_link(
        &mut self,
        i: usize,
        kind: world::faults::FaultKind,
        lasting: std::time::Duration,
    ) {
        let until_ns = self
            .now_ns
            .saturating_add(u64::try_from(lasting.as_nanos()).unwrap_or(u64::MAX));
        self.robots[i]
            .link
            .impair(Some(crate::link::Impairment { kind, until_ns }));
    }

    /// Injects (`Some`) or repairs (`None`) a fault of robot `i`'s body; it lasts through
    /// reboots, as a broken part would.
    pub fn set_body_fault(&mut self, i: usize, fault: Option<BodyFault>) {
        self.robots[i].fault = fault;
    }

    /// Kicks robot `i`: moves its body by (`dx`, `dy`) metres and turns it by `dtheta` radians at
    /// once, without telling its firmware (a moving body keeps its speed, turned with it). Its wheels never turn for it, so its encoders
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
        // Put down as it was picked up, in no time: its velocity turns with it, and nothing on
        // the robot (accelerometer included) feels the move.
        let (sin, cos) = (dtheta as f32).sin_cos();
        let v = *body.linvel();
        let turned = vector![cos * v.x - sin * v.y, sin * v.x + cos * v.y];
        body.set_translation(vector![x as f32, y as f32], true);
        body.set_rotation(Rotation::new(theta as f32), true);
        body.set_linvel(turned, true);
        r.last_velocity = nalgebra::Vector2::new(f64::from(turned.x), f64::from(turned.y));
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

/// A shove under way: a hand that grips the body and moves it along a half-sine velocity
/// profile, so that it starts and ends at rest and covers exactly the shove's displacement.
/// The tyres drag on the floor meanwhile (turning the wheels a shove along the heading moves
/// them) and the accelerometer feels the hand's acceleration, as on a real robot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Shove {
    /// When the hand starts, simulated seconds.
    start_s: f64,
    /// How long it pushes, seconds.
    duration_s: f64,
    /// Displacement along x and y (metres) and turn (radians) it gives in all.
    by: [f64; 3],
}

impl Shove {
    /// The hand's velocity (linear, angular) at `t_s`, `None` outside the shove.
    pub(super) fn velocity(&self, t_s: f64) -> Option<([f64; 2], f64)> {
        let f = (t_s - self.start_s) / self.duration_s;
        if !(0.0..=1.0).contains(&f) {
            return None;
        }
        // ∫₀ᴰ (π / 2D)·sin(πt/D) dt = 1.
        let k = std::f64::consts::FRAC_PI_2 / self.duration_s * (std::f64::consts::PI * f).sin();
        Some(([self.by[0] * k, self.by[1] * k], self.by[2] * k))
    }

    /// Whether the shove is over at `t_s`.
    pub(super) fn over(&self, t_s: f64) -> bool {
        t_s >= self.start_s + self.duration_s
    }
}

/// Clearance a drawn kick keeps from every other body and wall at its instant, metres.
const KICK_CLEARANCE_M: f64 = 0.001;

/// Shoves last at least and at most this long: a bump, not a slow carry.
pub const SHOVE_DURATION: std::ops::RangeInclusive<std::time::Duration> =
    std::time::Duration::from_millis(20)..=std::time::Duration::from_millis(100);

impl Simulation {
    /// Kicks robot `i` by `by` (x, y metres, turn radians) as `how` says: a teleport
    /// ([`displace`](Self::displace)) or a [`shove`](Self::shove).
    ///
    /// # Errors
    /// As [`displace`](Self::displace) and [`shove`](Self::shove).
    pub fn kick(&mut self, i: usize, by: [f64; 3], how: world::cli::KickHow) -> Result<(), String> {
        // A kick that would put the body through a wall lands nowhere a robot can be: refused,
        // so a run never goes on with a robot outside the world it reports on.
        if let Some(r) = self.robots.get(i) {
            let at = *self.bodies[r.body].position();
            let to = nalgebra::Point2::new(
                f64::from(at.translation.x) + by[0],
                f64::from(at.translation.y) + by[1],
            );
            if !self.world.arena.contains(to, world::robot::RADIUS_M) {
                return Err(format!(
                    "it would put robot {} at ({:.3}, {:.3}) m, outside the {} × {} m arena",
                    r.id, to.x, to.y, self.world.arena.width_m, self.world.arena.height_m
                ));
            }
        }
        match how {
            world::cli::KickHow::Teleport => self.displace(i, by[0], by[1], by[2]).map(|_| ()),
            world::cli::KickHow::Shove(d) => self.shove(i, (by[0], by[1], by[2]), d),
        }
    }

    /// A kick of robot `i` drawn from `seed`: a shift of up to `max_shift_m` in a direction and
    /// a turn of up to `max_turn_rad` either way, each uniform, redrawn until
    /// [`kick_is_clear`](Self::kick_is_clear); `None` when 200 draws found no clear one.
    pub fn draw_kick(
        &self,
        i: usize,
        seed: u64,
        max_shift_m: f64,
        max_turn_rad: f64,
    ) -> Option<[f64; 3]> {
        use rand::Rng;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..200).find_map(|_| {
            let shift = rng.gen_range(0.0..=max_shift_m);
            let towards = rng.gen_range(0.0..std::f64::consts::TAU);
            let turn = rng.gen_range(-max_turn_rad..=max_turn_rad);
            let by = [shift * towards.cos(), shift * towards.sin(), turn];
            self.kick_is_clear(i, (by[0], by[1], by[2])).then_some(by)
        })
    }

    /// Shoves robot `i` by (`dx`, `dy`) metres and `dtheta` radians over `duration`, starting
    /// now: a hand moves the body, overpowering its motors, and lets go at rest. Unlike
    /// [`displace`](Self::displace), the wheels, encoders and accelerometer feel it, and a body
    /// in the way stops it (a contact).
    ///
    /// # Errors
    /// There is no robot `i`, the displacement is not finite, or the duration is outside
    /// [`SHOVE_DURATION`].
    pub fn shove(
        &mut self,
        i: usize,
        (dx, dy, dtheta): (f64, f64, f64),
        duration: std::time::Duration,
    ) -> Result<(), String> {
        let now_s = self.now_ns as f64 * 1e-9;
        let Some(r) = self.robots.get_mut(i) else {
            return Err(format!("cannot shove robot index {i}: no such robot"));
        };
        if !(dx.is_finite() && dy.is_finite() && dtheta.is_finite()) {
            return Err(format!("cannot shove robot {}: not finite", r.id));
        }
        if !SHOVE_DURATION.contains(&duration) {
            return Err(format!(
                "cannot shove robot {} over {duration:?}: a shove lasts 20 to 100 ms",
                r.id
            ));
        }
        r.shove = Some(Shove {
            start_s: now_s,
            duration_s: duration.as_secs_f64(),
            by: [dx, dy, dtheta],
        });
        Ok(())
    }

    /// Whether robot `i` moved by (`dx`, `dy`, `dtheta`) from where it stands now, along a
    /// straight line, keeps clear of every other robot, box and wall: a kick drawn at random
    /// must be one a hand could give, not a robot put inside another.
    pub fn kick_is_clear(&self, i: usize, (dx, dy, dtheta): (f64, f64, f64)) -> bool {
        let Some(r) = self.robots.get(i) else {
            return false;
        };
        let body = &self.bodies[r.body];
        let start = *body.position();
        let steps = 8;
        (1..=steps).all(|k| {
            let f = f64::from(k) / f64::from(steps);
            let pose = Isometry::new(
                vector![
                    start.translation.x + (dx * f) as f32,
                    start.translation.y + (dy * f) as f32
                ],
                start.rotation.angle() + (dtheta * f) as f32,
            );
            body.colliders().iter().all(|&mine| {
                let shape = self.colliders[mine].shape();
                let local = self.colliders[mine]
                    .position_wrt_parent()
                    .copied()
                    .unwrap_or_else(Isometry::identity);
                let at = pose * local;
                self.colliders
                    .iter()
                    .filter(|(_, c)| c.parent() != Some(r.body))
                    .all(|(_, c)| {
                        rapier2d::parry::query::distance(&at, shape, c.position(), c.shape())
                            .is_ok_and(|d| f64::from(d) > KICK_CLEARANCE_M)
                    })
            })
        })
    }
}
