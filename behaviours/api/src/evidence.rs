//! Evidence that the robots did the work a verdict claims, from their own encoders.
//!
//! Events and poses alone can be had without moving: a robot whose wheels are jammed, or whose
//! encoders never tick, still answers, and a firmware with a broken wheel geometry reports its
//! moves finished at once. [`Odometer`] keeps, per robot, what its encoders measured: the path
//! its odometry pose travelled and the angle it turned (both from encoder pulses alone, never
//! from the track-corrected estimate), and watches for a stall: wheels the firmware is driving at
//! a set-point while neither encoder counts a pulse.

use std::collections::BTreeMap;
use std::time::Duration;

use world::Pose;

use crate::snapshot::{RobotView, WorldSnapshot};

/// A wheel set-point at least this fast (m/s) counts as driving: below about 0.012 m/s the
/// firmware's speed meter cannot resolve the wheel and lets it rest, and the slowest move or
/// creep any built-in commands is 0.03 m/s.
pub const DRIVING_MPS: f32 = 0.02;
/// Driven this long without an encoder pulse is a stall: at the slowest driving set-point a
/// 9 mm wheel turns about 85 pulses in this time, and a wheel pressed against an obstacle slips
/// and still counts.
pub const STALL_AFTER: Duration = Duration::from_secs(3);
/// Pulses within the stall window that are still taken as no motion (one stripe edge can be
/// crossed by vibration alone).
const STALL_PULSES: u32 = 2;
/// The share of a claimed distance or turn the encoders must have measured: odometry reads a
/// few per cent short where wheels slip, never 10 %.
pub const EVIDENCE_SHARE: f64 = 0.9;

/// A robot driven without its encoders counting.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stall {
    /// Robot id.
    pub robot: u16,
    /// The largest wheel set-point seen during the stall, m/s.
    pub set_point_mps: f32,
    /// How long it was driven without a pulse, by the robot's clock.
    pub driven_for: Duration,
}

impl std::fmt::Display for Stall {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "robot {}: wheels driven at a set-point of {:.2} m/s for {:.1} s without an encoder \
             pulse (it cannot move, or cannot measure that it does)",
            self.robot,
            self.set_point_mps,
            self.driven_for.as_secs_f64()
        )
    }
}

/// Where a stall window began: the robot's clock, its encoder totals, the fastest set-point.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Window {
    since_ms: u32,
    ticks: (i32, i32),
    set_point_mps: f32,
}

#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Reading {
    last_pose: Option<Pose>,
    last_uptime_ms: Option<u32>,
    distance_m: f64,
    turned_rad: f64,
    window: Option<Window>,
    stall: Option<Stall>,
}

/// Per-robot distance and turning as the encoders measured them, and stalls.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Odometer {
    robots: BTreeMap<u16, Reading>,
}

impl Odometer {
    /// Nothing measured yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes a snapshot: adds each robot's odometry travel since the previous one and updates
    /// its stall watch.
    pub fn observe(&mut self, world: &WorldSnapshot) {
        for view in &world.robots {
            let r = self.robots.entry(view.id).or_default();
            if let Some(p) = r.last_pose {
                // Sampled every 100 ms, a chord of the driven arc is within a fraction of a
                // per cent of it.
                r.distance_m += (view.odometry.x - p.x).hypot(view.odometry.y - p.y);
                r.turned_rad += (view.odometry.theta - p.theta).abs();
            }
            r.last_pose = Some(view.odometry);
            watch(r, view);
        }
    }

    /// Metres robot `id`'s odometry pose travelled (zero for a robot never seen).
    pub fn distance_m(&self, id: u16) -> f64 {
        self.robots.get(&id).map_or(0.0, |r| r.distance_m)
    }

    /// Radians robot `id`'s odometry heading turned, either way.
    pub fn turned_rad(&self, id: u16) -> f64 {
        self.robots.get(&id).map_or(0.0, |r| r.turned_rad)
    }

    /// The least turning any of `ids` measured, degrees (infinite for no robot).
    pub fn least_turn_deg(&self, ids: impl IntoIterator<Item = u16>) -> f64 {
        ids.into_iter()
            .map(|id| self.turned_rad(id).to_degrees())
            .fold(f64::INFINITY, f64::min)
    }

    /// The first robot found stalled, if any.
    pub fn stall(&self) -> Option<Stall> {
        self.robots.values().find_map(|r| r.stall)
    }

    /// The robot among `ids` whose encoders measured least against what `claimed` says it
    /// drove, as (id, measured metres, claimed metres), when that is below [`EVIDENCE_SHARE`].
    pub fn short_of(
        &self,
        ids: impl IntoIterator<Item = u16>,
        claimed: impl Fn(u16) -> f64,
    ) -> Option<(u16, f64, f64)> {
        ids.into_iter()
            .map(|id| (id, self.distance_m(id), claimed(id)))
            .filter(|(_, measured, claim)| *measured < EVIDENCE_SHARE * claim)
            .min_by(|a, b| (a.1 / a.2.max(1e-9)).total_cmp(&(b.1 / b.2.max(1e-9))))
    }

    /// The least distance any of `ids` measured, metres (zero for none).
    pub fn least_m(&self, ids: impl IntoIterator<Item = u16>) -> f64 {
        let least = ids
            .into_iter()
            .map(|id| self.distance_m(id))
            .fold(f64::INFINITY, f64::min);
        if least.is_finite() {
            least
        } else {
            0.0
        }
    }
}

/// One sample of the stall watch. Only fresh states count (the robot's clock moved), so a state
/// frozen by a cut link is not taken for wheels that do not turn.
fn watch(r: &mut Reading, view: &RobotView) {
    let s = &view.state;
    let uptime = s.uptime_ms;
    if !view.connected {
        r.window = None;
        return;
    }
    if r.last_uptime_ms.replace(uptime) == Some(uptime) {
        return;
    }
    let w = s.wheels;
    let set_point = w.left_target_mps.abs().max(w.right_target_mps.abs());
    let ticks = (s.encoders.left_ticks, s.encoders.right_ticks);
    if set_point.is_nan() || set_point < DRIVING_MPS {
        r.window = None;
        return;
    }
    let Some(win) = r.window.as_mut() else {
        r.window = Some(Window {
            since_ms: uptime,
            ticks,
            set_point_mps: set_point,
        });
        return;
    };
    let moved = |a: i32, b: i32| a.wrapping_sub(b).unsigned_abs() > STALL_PULSES;
    // A clock that went back is a rebooted robot: its window starts again.
    let rebooted = uptime < win.since_ms;
    if rebooted || moved(ticks.0, win.ticks.0) || moved(ticks.1, win.ticks.1) {
        *win = Window {
            since_ms: uptime,
            ticks,
            set_point_mps: set_point,
        };
        return;
    }
    win.set_point_mps = win.set_point_mps.max(set_point);
    let driven_for = Duration::from_millis(u64::from(uptime.wrapping_sub(win.since_ms)));
    if driven_for >= STALL_AFTER && r.stall.is_none() {
        r.stall = Some(Stall {
            robot: view.id,
            set_point_mps: win.set_point_mps,
            driven_for,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(id: u16, x: f64, theta: f64, uptime_ms: u32, ticks: i32, target: f32) -> RobotView {
        let mut state = protocol::RobotState {
            uptime_ms,
            ..Default::default()
        };
        state.encoders.left_ticks = ticks;
        state.encoders.right_ticks = ticks;
        state.wheels.left_target_mps = target;
        state.wheels.right_target_mps = target;
        RobotView {
            id,
            connected: true,
            pose: Pose::default(),
            odometry: Pose { x, y: 0.0, theta },
            state,
            pending_moves: 0,
            on_track: None,
            ..Default::default()
        }
    }

    fn snap(robots: Vec<RobotView>) -> WorldSnapshot {
        WorldSnapshot {
            time: Duration::ZERO,
            robots: robots.into_iter().map(std::sync::Arc::new).collect(),
            encounters: Vec::new(),
            arena: (1.0, 1.0),
        }
    }

    #[test]
    fn travel_adds_up_path_and_turning_from_odometry() {
        let mut o = Odometer::new();
        o.observe(&snap(vec![view(1, 0.0, 0.0, 0, 0, 0.1)]));
        o.observe(&snap(vec![view(1, 0.1, 0.0, 100, 140, 0.1)]));
        o.observe(&snap(vec![view(1, 0.1, -1.0, 200, 200, 0.1)]));
        o.observe(&snap(vec![view(1, 0.05, -1.0, 300, 270, 0.1)]));
        assert!((o.distance_m(1) - 0.15).abs() < 1e-12);
        assert!((o.turned_rad(1) - 1.0).abs() < 1e-12);
        assert_eq!(o.stall(), None);
        assert_eq!(o.distance_m(9), 0.0);
        assert_eq!(o.short_of([1], |_| 0.16), None);
        assert_eq!(o.short_of([1], |_| 0.2).map(|s| s.0), Some(1));
    }

    #[test]
    fn driven_wheels_without_pulses_are_a_stall_after_three_seconds() {
        let mut o = Odometer::new();
        for k in 0..=29u32 {
            o.observe(&snap(vec![view(2, 0.0, 0.0, 1000 + 100 * k, 7, 0.1)]));
        }
        assert_eq!(o.stall(), None, "2.9 s is not yet a stall");
        o.observe(&snap(vec![view(2, 0.0, 0.0, 4000, 8, 0.1)]));
        let s = o.stall().expect("stalled");
        assert_eq!(s.robot, 2);
        assert!(s.to_string().contains("robot 2"), "{s}");
    }

    #[test]
    fn resting_turning_or_unheard_robots_are_not_stalled() {
        let mut o = Odometer::new();
        // At rest: set-point zero.
        for k in 0..100u32 {
            o.observe(&snap(vec![view(1, 0.0, 0.0, 100 * k, 0, 0.0)]));
        }
        // Turning: pulses keep coming.
        for k in 0..100u32 {
            o.observe(&snap(vec![view(2, 0.0, 0.0, 100 * k, 10 * k as i32, 0.1)]));
        }
        // A frozen state (link cut): the robot's clock does not move.
        for _ in 0..100 {
            o.observe(&snap(vec![view(3, 0.0, 0.0, 500, 0, 0.1)]));
        }
        assert_eq!(o.stall(), None);
    }
}
