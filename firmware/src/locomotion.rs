//! Locomotion (thesis 6.5, 11.4): a queue of straight / rotate / arc moves executed one after
//! another by a robot-speed PID chained with a wheel-balance controller.
//!
//! Each move is a target distance per wheel `(dl, dr)`; its direction `t = (dl, dr) / max(|dl|, |dr|)`
//! is the left:right trajectory ratio (1:1 straight, −1:1 rotate, anything else an arc). The speed
//! PID drives the outer wheel's speed along `t` to the profile `f(s)` (thesis fig. 11.6: ramp up,
//! cruise, ramp down); the balance PID steers the duty along the normal of `t` so the wheels'
//! travelled distances stay on that ratio. Moves chain from where the previous one *should* have
//! ended, so coasting past one target is taken back by the next move.

use core::ops::ControlFlow;

use heapless::Deque;
use protocol::packets::MoveOutcome;
use protocol::settings::Settings;

use crate::pid::Pid;

/// Capacity of the move queue.
pub const QUEUE_CAPACITY: usize = 8;

/// Geometry of a move.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MoveKind {
    /// Straight line, signed metres (negative = backwards).
    Straight {
        /// Distance.
        distance_m: f32,
    },
    /// Turn in place, signed radians (positive = counter-clockwise).
    Rotate {
        /// Angle.
        angle_rad: f32,
    },
    /// Circular arc of the robot centre, centre to the left for positive angles.
    Arc {
        /// Radius of the centre's path.
        radius_m: f32,
        /// Heading change.
        angle_rad: f32,
    },
}

/// A queued move.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Move {
    /// Host-chosen id reported when the move ends.
    pub id: u16,
    /// Geometry.
    pub kind: MoveKind,
    /// Cruise speed of the outer wheel, m/s.
    pub speed_mps: f32,
}

impl Move {
    /// Signed distance each wheel must travel, metres, for wheel gauge `gauge_m`.
    pub fn wheel_distances(&self, gauge_m: f32) -> (f32, f32) {
        let half = gauge_m * 0.5;
        match self.kind {
            MoveKind::Straight { distance_m } => (distance_m, distance_m),
            MoveKind::Rotate { angle_rad } => (-angle_rad * half, angle_rad * half),
            MoveKind::Arc {
                radius_m,
                angle_rad,
            } => {
                // Always forward: a negative angle is a right turn with the centre to the right,
                // so the left wheel is then the outer one.
                let along = angle_rad.abs() * radius_m;
                (along - angle_rad * half, along + angle_rad * half)
            }
        }
    }

    fn is_valid(&self) -> bool {
        let finite = |v: f32| v.is_finite();
        let geometry = match self.kind {
            MoveKind::Straight { distance_m } => finite(distance_m),
            MoveKind::Rotate { angle_rad } => finite(angle_rad),
            MoveKind::Arc {
                radius_m,
                angle_rad,
            } => finite(radius_m) && finite(angle_rad) && radius_m >= 0.0,
        };
        geometry && finite(self.speed_mps) && self.speed_mps > 0.0
    }
}

/// What the queue reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LocomotionEvent {
    /// A move ended.
    Finished {
        /// Its id.
        id: u16,
        /// How.
        outcome: MoveOutcome,
    },
    /// The last move ended and nothing is queued.
    QueueEmpty,
}

/// Why a move was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EnqueueError {
    /// The queue holds [`QUEUE_CAPACITY`] moves.
    QueueFull,
    /// A distance, angle or speed is not finite, or the speed is not positive.
    BadParameter,
}

/// Wheel measurements handed to each control step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WheelInputs {
    /// Left encoder total.
    pub left_ticks: i32,
    /// Right encoder total.
    pub right_ticks: i32,
    /// Left wheel speed, m/s.
    pub left_mps: f32,
    /// Right wheel speed, m/s.
    pub right_mps: f32,
}

/// Output of one control step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DriveCommand {
    /// Left duty, permille.
    pub left_pwm: f32,
    /// Right duty, permille.
    pub right_pwm: f32,
    /// Left wheel speed the profile asks for, m/s.
    pub left_target_mps: f32,
    /// Right wheel speed the profile asks for, m/s.
    pub right_target_mps: f32,
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Active {
    mv: Move,
    /// Encoder totals where this move starts (the previous move's ideal end).
    origin: (i32, i32),
    /// Target distance per wheel.
    target: (f32, f32),
    /// Fraction done, kept for the state packet.
    progress: f32,
    /// Speed the profile starts from: the speed the previous move flowed into this one at, else
    /// the minimum speed.
    entry_mps: f32,
}

impl Move {
    /// Whether `next` can follow this move without slowing to the minimum speed between them:
    /// both drive forward (straights and arcs whose wheels both turn ahead) or both backward.
    /// A rotation, a pivot or a change of direction still ramps down, so that single-channel
    /// encoders never have to count a wheel through a reversal at speed.
    fn flows_into(&self, next: &Move, gauge_m: f32) -> bool {
        let forward = |m: &Move| {
            let (l, r) = m.wheel_distances(gauge_m);
            match m.kind {
                MoveKind::Rotate { .. } => None,
                _ if l > 0.0 && r > 0.0 => Some(true),
                _ if l < 0.0 && r < 0.0 => Some(false),
                _ => None,
            }
        };
        matches!((forward(self), forward(next)), (Some(a), Some(b)) if a == b)
    }
}

/// The move queue and its controllers.
#[derive(Clone, Debug)]
pub struct Locomotion {
    queue: Deque<Move, QUEUE_CAPACITY>,
    active: Option<Active>,
    /// Where the next move starts when chained; `None` after the queue ran empty.
    chain_origin: Option<(i32, i32)>,
    /// Direction each wheel was last driven in (+1, −1, or 0 before any move).
    last_dir: (i8, i8),
    speed_pid: Pid,
    balance_pid: Pid,
    /// The speed the move just finished flowed into the next at, for the next's profile.
    carried_mps: Option<f32>,
}

impl Default for Locomotion {
    fn default() -> Self {
        Self::new()
    }
}

impl Locomotion {
    /// Empty queue.
    pub const fn new() -> Self {
        Self {
            queue: Deque::new(),
            active: None,
            chain_origin: None,
            last_dir: (0, 0),
            speed_pid: Pid::new(),
            balance_pid: Pid::new(),
            carried_mps: None,
        }
    }

    /// Adds a move at the end of the queue.
    pub fn enqueue(&mut self, mv: Move) -> Result<(), EnqueueError> {
        if !mv.is_valid() {
            return Err(EnqueueError::BadParameter);
        }
        let queued = self.queue.len() + usize::from(self.active.is_some());
        if queued >= QUEUE_CAPACITY {
            return Err(EnqueueError::QueueFull);
        }
        self.queue
            .push_back(mv)
            .map_err(|_| EnqueueError::QueueFull)
    }

    /// Moves waiting or running.
    pub fn len(&self) -> usize {
        self.queue.len() + usize::from(self.active.is_some())
    }

    /// Whether nothing is queued or running.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Id of the running move.
    pub fn active_id(&self) -> Option<u16> {
        self.active.map(|a| a.mv.id)
    }

    /// Fraction of the running move done, 0..1.
    pub fn progress(&self) -> f32 {
        self.active.map_or(0.0, |a| a.progress)
    }

    /// Drops every move, the running one included, reporting each with `outcome`.
    pub fn abort(&mut self, outcome: MoveOutcome, events: &mut impl FnMut(LocomotionEvent)) {
        let had_any = !self.is_empty();
        if let Some(a) = self.active.take() {
            events(LocomotionEvent::Finished {
                id: a.mv.id,
                outcome,
            });
        }
        while let Some(mv) = self.queue.pop_front() {
            events(LocomotionEvent::Finished { id: mv.id, outcome });
        }
        self.chain_origin = None;
        self.carried_mps = None;
        self.last_dir = (0, 0);
        self.speed_pid.reset();
        self.balance_pid.reset();
        if had_any {
            events(LocomotionEvent::QueueEmpty);
        }
    }

    /// Drops every move older than `keep_from` (in wrapping id order; 0 drops them all), the
    /// running one included, reporting each with `outcome`; later moves stay queued, so a clear
    /// sent again after a loss never drops a move queued after it.
    pub fn abort_older(
        &mut self,
        keep_from: u16,
        outcome: MoveOutcome,
        events: &mut impl FnMut(LocomotionEvent),
    ) {
        if keep_from == 0 {
            return self.abort(outcome, events);
        }
        let older = |id: u16| (id.wrapping_sub(keep_from) as i16) < 0;
        let had_any = !self.is_empty();
        let running = self.active.map(|a| a.mv.id);
        if let Some(id) = running.filter(|&id| older(id)) {
            self.active = None;
            events(LocomotionEvent::Finished { id, outcome });
            self.chain_origin = None;
            self.carried_mps = None;
            self.last_dir = (0, 0);
            self.speed_pid.reset();
            self.balance_pid.reset();
        }
        for _ in 0..self.queue.len() {
            let Some(mv) = self.queue.pop_front() else {
                break;
            };
            if older(mv.id) {
                events(LocomotionEvent::Finished { id: mv.id, outcome });
            } else {
                // Popped from a queue that had room for it.
                let _ = self.queue.push_back(mv);
            }
        }
        if had_any && self.is_empty() {
            events(LocomotionEvent::QueueEmpty);
        }
    }

    /// One control step of `dt` seconds: duties for the running move, or `None` when idle.
    pub fn step(
        &mut self,
        wheels: WheelInputs,
        settings: &Settings,
        dt: f32,
        events: &mut impl FnMut(LocomotionEvent),
    ) -> Option<DriveCommand> {
        let geometry = &settings.geometry;
        let tick_m = tick_m(geometry.wheel_diameter_m, geometry.ticks_per_rev);
        loop {
            if self.active.is_none() {
                if let ControlFlow::Break(command) = self.start_next(wheels, settings) {
                    return command;
                }
            }
            let a = self.active.as_mut()?;
            let (dl, dr) = a.target;
            let outer = dl.abs().max(dr.abs());
            let done_l = wheels.left_ticks.wrapping_sub(a.origin.0) as f32 * tick_m;
            let done_r = wheels.right_ticks.wrapping_sub(a.origin.1) as f32 * tick_m;
            // Progress is the travelled vector projected on the target vector.
            let norm2 = dl * dl + dr * dr;
            let fraction = if norm2 > 0.0 {
                (done_l * dl + done_r * dr) / norm2
            } else {
                1.0
            };
            a.progress = fraction.clamp(0.0, 1.0);
            let (tl, tr) = (dl / outer, dr / outer);
            let t2 = tl * tl + tr * tr;
            // Outer-wheel speed along the target direction.
            let v = (wheels.left_mps * tl + wheels.right_mps * tr) / t2;
            let coast = (v * settings.locomotion.coast_s).clamp(0.0, outer * 0.25);
            let loco = &settings.locomotion;
            let cruise = a.mv.speed_mps.min(loco.max_speed_mps);
            // Looked at every step: a move queued while this one runs may still be flowed into.
            let exit_mps = match self.queue.front() {
                Some(next) if a.mv.flows_into(next, geometry.wheel_gauge_m) => {
                    Some(cruise.min(next.speed_mps.min(loco.max_speed_mps)))
                }
                _ => None,
            };
            if fraction * outer + coast >= outer || outer < tick_m * 0.5 {
                let (id, origin) = (a.mv.id, a.origin);
                if let ControlFlow::Break(()) =
                    self.complete(id, origin, (dl, dr), tick_m, exit_mps, events)
                {
                    return None;
                }
                continue;
            }
            self.last_dir = (sign(tl), sign(tr));
            let target_v = profile_between(
                a.progress * outer,
                outer,
                cruise,
                (a.entry_mps, exit_mps.unwrap_or(loco.min_speed_mps)),
                loco,
            );
            let u = loco.pwm_per_mps * target_v
                + self.speed_pid.update(&settings.speed_pid, target_v - v, dt);
            // Signed deviation from the target ratio, metres, along the unit normal (−tr, tl).
            let inv = 1.0 / libm::sqrtf(t2);
            let (nl, nr) = (-tr * inv, tl * inv);
            let deviation = done_l * nl + done_r * nr;
            let b = -self
                .balance_pid
                .update(&settings.balance_pid, deviation, dt);
            return Some(DriveCommand {
                left_pwm: u * (tl + b * nl),
                right_pwm: u * (tr + b * nr),
                left_target_mps: target_v * tl,
                right_target_mps: target_v * tr,
            });
        }
    }

    /// Makes the first queued move the running one, from where the last one ideally ended;
    /// breaks with what [`step`](Self::step) returns instead: `None` with nothing queued, or a
    /// standstill while a wheel that must reverse still turns.
    fn start_next(
        &mut self,
        wheels: WheelInputs,
        settings: &Settings,
    ) -> ControlFlow<Option<DriveCommand>> {
        let geometry = &settings.geometry;
        let Some(&next) = self.queue.front() else {
            return ControlFlow::Break(None);
        };
        let (nl, nr) = next.wheel_distances(geometry.wheel_gauge_m);
        let reverses = |last: i8, d: f32| last != 0 && d != 0.0 && (d < 0.0) != (last < 0);
        let moving = wheels.left_mps != 0.0 || wheels.right_mps != 0.0;
        if moving && (reverses(self.last_dir.0, nl) || reverses(self.last_dir.1, nr)) {
            // A single-channel encoder cannot see direction: let a wheel that must reverse
            // stop first, so its coasting pulses still count in the old direction.
            return ControlFlow::Break(Some(DriveCommand::default()));
        }
        let Some(mv) = self.queue.pop_front() else {
            return ControlFlow::Break(None);
        };
        let origin = self
            .chain_origin
            .unwrap_or((wheels.left_ticks, wheels.right_ticks));
        let carried = self.carried_mps.take();
        self.active = Some(Active {
            mv,
            origin,
            target: mv.wheel_distances(geometry.wheel_gauge_m),
            progress: 0.0,
            entry_mps: carried.unwrap_or(settings.locomotion.min_speed_mps),
        });
        // A move the last one flowed into keeps the speed loop's state: resetting it at
        // cruise speed would dip the wheels at every joint.
        if carried.is_none() {
            self.speed_pid.reset();
        }
        self.balance_pid.reset();
        ControlFlow::Continue(())
    }

    /// Ends the running move `id`, which started at encoder totals `origin` and drives the wheels
    /// `(dl, dr)`: the next move starts from its ideal end at `exit_mps`. Breaks when the queue
    /// has run empty.
    fn complete(
        &mut self,
        id: u16,
        origin: (i32, i32),
        (dl, dr): (f32, f32),
        tick_m: f32,
        exit_mps: Option<f32>,
        events: &mut impl FnMut(LocomotionEvent),
    ) -> ControlFlow<()> {
        self.carried_mps = exit_mps;
        let ticks = |d: f32| libm::roundf(d / tick_m) as i32;
        self.chain_origin = Some((
            origin.0.wrapping_add(ticks(dl)),
            origin.1.wrapping_add(ticks(dr)),
        ));
        self.active = None;
        events(LocomotionEvent::Finished {
            id,
            outcome: MoveOutcome::Completed,
        });
        if self.queue.is_empty() {
            self.chain_origin = None;
            events(LocomotionEvent::QueueEmpty);
            return ControlFlow::Break(());
        }
        ControlFlow::Continue(())
    }
}

/// The direction a wheel turns for a trajectory ratio `t`: 1 forward, -1 backward, 0 standing.
fn sign(t: f32) -> i8 {
    if t > 0.0 {
        1
    } else if t < 0.0 {
        -1
    } else {
        0
    }
}

/// Metres per encoder pulse.
pub fn tick_m(wheel_diameter_m: f32, ticks_per_rev: u16) -> f32 {
    core::f32::consts::PI * wheel_diameter_m / f32::from(ticks_per_rev.max(1))
}

/// The speed profile f(s) of thesis fig. 11.6: three linear pieces over a move of `total` metres.
pub fn profile(
    s: f32,
    total: f32,
    cruise: f32,
    loco: &protocol::settings::LocomotionSettings,
) -> f32 {
    profile_between(
        s,
        total,
        cruise,
        (loco.min_speed_mps, loco.min_speed_mps),
        loco,
    )
}

/// The profile of a move entered at `ends.0` and left at `ends.1` (m/s): it ramps from the
/// entry speed and down to the exit speed, each clamped to `[min_speed_mps, cruise]`, so a move
/// flowing into the next keeps its speed across the joint.
pub fn profile_between(
    s: f32,
    total: f32,
    cruise: f32,
    ends: (f32, f32),
    loco: &protocol::settings::LocomotionSettings,
) -> f32 {
    let v_min = loco.min_speed_mps.min(cruise).max(0.0);
    let ramp = |from: f32, d: f32, len: f32| {
        let from = from.clamp(v_min, cruise);
        if len > 0.0 {
            from + (cruise - from) * (d / len).clamp(0.0, 1.0)
        } else {
            cruise
        }
    };
    let up = ramp(ends.0, s, loco.accel_distance_m);
    let down = ramp(ends.1, total - s, loco.decel_distance_m);
    up.min(down).min(cruise).max(v_min)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn straight(id: u16, d: f32) -> Move {
        Move {
            id,
            kind: MoveKind::Straight { distance_m: d },
            speed_mps: 0.2,
        }
    }

    #[test]
    fn wheel_distances_for_each_kind() {
        let g = 0.026;
        assert_eq!(straight(0, 0.1).wheel_distances(g), (0.1, 0.1));
        let r = Move {
            id: 0,
            kind: MoveKind::Rotate {
                angle_rad: core::f32::consts::FRAC_PI_2,
            },
            speed_mps: 0.1,
        };
        let (l, rr) = r.wheel_distances(g);
        assert!((rr - core::f32::consts::FRAC_PI_2 * 0.013).abs() < 1e-6 && l == -rr);
        let a = Move {
            id: 0,
            kind: MoveKind::Arc {
                radius_m: 0.1,
                angle_rad: 1.0,
            },
            speed_mps: 0.1,
        };
        let (l, r) = a.wheel_distances(g);
        assert!((l - 0.087).abs() < 1e-6 && (r - 0.113).abs() < 1e-6);
        let right = Move {
            kind: MoveKind::Arc {
                radius_m: 0.1,
                angle_rad: -1.0,
            },
            ..a
        };
        let (l, r) = right.wheel_distances(g);
        assert!(
            (l - 0.113).abs() < 1e-6 && (r - 0.087).abs() < 1e-6,
            "a right turn drives forward with the left wheel outside: {l} {r}"
        );
    }

    #[test]
    fn profile_ramps_cruises_and_ramps_down() {
        let loco = Settings::default().locomotion;
        let total = 0.2;
        let v = |s| profile(s, total, 0.2, &loco);
        assert!((v(0.0) - loco.min_speed_mps).abs() < 1e-6);
        assert!(v(0.01) > v(0.0) && v(0.01) < 0.2);
        assert_eq!(v(0.1), 0.2);
        assert!(v(0.19) < 0.2);
        assert!((v(total) - loco.min_speed_mps).abs() < 1e-6);
        // A move shorter than both ramps peaks below cruise (triangle profile).
        let short = profile(0.01, 0.02, 0.2, &loco);
        assert!(short < 0.2 && short > loco.min_speed_mps);
    }

    /// Drives `moves` on ideal wheels that turn at exactly the speeds the profile asks for: the
    /// outer wheel's target speed at each step, the ids in the order the moves finished, and how
    /// far each wheel went.
    fn drive_ideal(moves: &[Move]) -> (Vec<f32>, Vec<u16>, (f32, f32)) {
        let s = Settings::default();
        let tick = tick_m(s.geometry.wheel_diameter_m, s.geometry.ticks_per_rev);
        let mut l = Locomotion::new();
        for m in moves {
            l.enqueue(*m).unwrap();
        }
        let dt = 0.005;
        let (mut at, mut w) = ((0.0f32, 0.0f32), WheelInputs::default());
        let (mut speeds, mut finished) = (Vec::new(), Vec::new());
        for _ in 0..10_000 {
            let mut on_event = |e| {
                if let LocomotionEvent::Finished { id, .. } = e {
                    finished.push(id);
                }
            };
            let Some(c) = l.step(w, &s, dt, &mut on_event) else {
                break;
            };
            speeds.push(c.left_target_mps.abs().max(c.right_target_mps.abs()));
            (w.left_mps, w.right_mps) = (c.left_target_mps, c.right_target_mps);
            at.0 += w.left_mps * dt;
            at.1 += w.right_mps * dt;
            w.left_ticks = libm::roundf(at.0 / tick) as i32;
            w.right_ticks = libm::roundf(at.1 / tick) as i32;
        }
        (speeds, finished, at)
    }

    #[test]
    fn forward_moves_flow_into_each_other_at_speed_and_end_where_they_add_up_to() {
        let min = Settings::default().locomotion.min_speed_mps;
        let arc = Move {
            id: 2,
            kind: MoveKind::Arc {
                radius_m: 0.3,
                angle_rad: 0.2,
            },
            speed_mps: 0.2,
        };
        let (speeds, finished, at) = drive_ideal(&[straight(1, 0.1), arc, straight(3, 0.1)]);
        assert_eq!(finished, [1, 2, 3]);
        let first = speeds.iter().position(|&v| v >= 0.2).unwrap();
        let last = speeds.iter().rposition(|&v| v >= 0.2).unwrap();
        assert!(
            speeds[first..=last].iter().all(|&v| v >= 0.2 - 1e-6),
            "no slowing at the joints: {speeds:?}"
        );
        // The wheels went what the three moves add up to, less the last one's coast.
        let (al, ar) = arc.wheel_distances(Settings::default().geometry.wheel_gauge_m);
        assert!((at.0 - (0.2 + al)).abs() < 0.004, "{at:?}");
        assert!((at.1 - (0.2 + ar)).abs() < 0.004, "{at:?}");
        assert!(speeds.last().is_some_and(|&v| v < 2.0 * min));

        // A rotation between two straights is still entered and left at the minimum speed.
        let rotate = Move {
            id: 2,
            kind: MoveKind::Rotate { angle_rad: 1.0 },
            speed_mps: 0.2,
        };
        let (speeds, finished, _) = drive_ideal(&[straight(1, 0.1), rotate, straight(3, 0.1)]);
        assert_eq!(finished, [1, 2, 3]);
        let slow = speeds.iter().filter(|&&v| v <= min + 0.005).count();
        assert!(
            slow >= 3,
            "ramps down before and after the turn: {speeds:?}"
        );
        let back = straight(2, -0.1);
        let g = 0.026;
        assert!(straight(1, 0.1).flows_into(&arc, g));
        assert!(!straight(1, 0.1).flows_into(&back, g));
        assert!(back.flows_into(&straight(3, -0.05), g));
        assert!(!arc.flows_into(&rotate, g));
    }

    #[test]
    fn queue_is_bounded_and_checks_parameters() {
        let mut l = Locomotion::new();
        for i in 0..QUEUE_CAPACITY as u16 {
            l.enqueue(straight(i, 0.1)).unwrap();
        }
        assert_eq!(l.enqueue(straight(99, 0.1)), Err(EnqueueError::QueueFull));
        let mut l = Locomotion::new();
        assert_eq!(
            l.enqueue(straight(1, f32::NAN)),
            Err(EnqueueError::BadParameter)
        );
        let mut slow = straight(1, 0.1);
        slow.speed_mps = 0.0;
        assert_eq!(l.enqueue(slow), Err(EnqueueError::BadParameter));
    }

    #[test]
    fn abort_reports_every_move_then_queue_empty() {
        let mut l = Locomotion::new();
        l.enqueue(straight(1, 0.1)).unwrap();
        l.enqueue(straight(2, 0.1)).unwrap();
        let s = Settings::default();
        let mut ev = Vec::new();
        assert!(l
            .step(WheelInputs::default(), &s, 0.005, &mut |e| ev.push(e))
            .is_some());
        l.abort(MoveOutcome::Stopped, &mut |e| ev.push(e));
        assert_eq!(
            ev,
            vec![
                LocomotionEvent::Finished {
                    id: 1,
                    outcome: MoveOutcome::Stopped
                },
                LocomotionEvent::Finished {
                    id: 2,
                    outcome: MoveOutcome::Stopped
                },
                LocomotionEvent::QueueEmpty
            ]
        );
        assert!(l.is_empty());
    }

    #[test]
    fn duty_pushes_forward_and_balance_corrects_a_lagging_wheel() {
        let mut l = Locomotion::new();
        l.enqueue(straight(1, 0.1)).unwrap();
        let s = Settings::default();
        // Left wheel 10 ticks behind: the balance must give it more duty than the right.
        let w = WheelInputs {
            left_ticks: 0,
            right_ticks: 10,
            left_mps: 0.0,
            right_mps: 0.0,
        };
        l.step(WheelInputs::default(), &s, 0.005, &mut |_| {});
        let c = l.step(w, &s, 0.005, &mut |_| {}).unwrap();
        assert!(c.left_pwm > 0.0 && c.right_pwm > 0.0);
        assert!(c.left_pwm > c.right_pwm, "{c:?}");
    }
}
