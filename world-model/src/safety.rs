//! The supervisor's predictive safety check: an intent that would drive a robot into another robot
//! or out of the arena is held back. Robots are their oriented 48 × 32 mm footprints grown by a
//! tunable margin; a move is swept from where the robot's queued moves will leave it, in steps of
//! at most 5 mm and 5°, against every other robot where it stands and where its own queued moves
//! will leave it. Each footprint also grows by its robot's position uncertainty, so a robot the
//! world model is unsure of gets a wider berth: the mover's by 1σ ([`Safety::berth`]), a lost
//! mover's path also by a turn of 3σ of its heading about its start; every other
//! robot's by 1σ when the model tracks it, and when it is lost or just bumped by its whole
//! uncertainty region ([`LOST_SIGMAS`] σ, and what a turn of as many σ of its heading sweeps), an
//! exclusion zone the others keep clear of ([`Safety::reach`]).

use behaviour_api::{Intent, Localisation, MoveCommand, Pose, RobotView, WorldSnapshot};

/// Tunables of the check.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Safety {
    /// Footprint length along the heading, metres.
    pub length_m: f64,
    /// Footprint width, metres.
    pub width_m: f64,
    /// Clearance each robot keeps around its footprint, metres (the safety radius): two robots
    /// may come no closer than twice this.
    pub margin_m: f64,
    /// How far ahead a wheel-speed command is extrapolated, seconds.
    pub horizon_s: f64,
}

impl Default for Safety {
    fn default() -> Self {
        Self {
            length_m: world::robot::LENGTH_M,
            width_m: world::robot::WIDTH_M,
            margin_m: 0.0015,
            horizon_s: 0.5,
        }
    }
}

/// Each footprint grows by this many standard deviations of its robot's position uncertainty.
pub const UNCERTAINTY_SIGMAS: f64 = 1.0;

/// A lost robot's footprint grows by this many standard deviations of its position and of its
/// heading: the region it may be anywhere in, not a 1σ ring.
pub const LOST_SIGMAS: f64 = 3.0;

/// A lost mover's straight drive is widened only to its sides up to this heading uncertainty
/// (1σ); beyond it, in every direction (see `Safety::drift`).
pub const SIDE_ONLY_RAD: f64 = 60.0 * std::f64::consts::PI / 180.0;

/// How much farther than its berth a lost mover may be from one of its path's poses: to each
/// side of the path, and in every direction, metres.
#[derive(Clone, Copy, Debug, Default)]
struct Growth {
    side: f64,
    all: f64,
}

/// Wheels slower than this, m/s, leave a robot where it stands.
pub const AT_REST_MPS: f64 = 0.005;

/// Robots already within each other's widened footprints may close in by at most this along a
/// path (two pushers backing off side by side are not quite parallel).
const ALONGSIDE_M: f64 = 0.002;

/// A path whose heading changes by more than this turns the robot.
const TURN_EPS_RAD: f64 = 1e-3;

/// Largest step between checked poses along a path.
const STEP_M: f64 = 0.005;
const STEP_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;

/// The broad phase: only a robot with a pose within reach of the path's bounding box can fail
/// the exact test, which with a thousand robots would otherwise dominate.
struct Broad {
    lo: (f64, f64),
    hi: (f64, f64),
    /// The checked robot's reach from its path, metres.
    mine_reach: f64,
    length_m: f64,
    width_m: f64,
}

impl Broad {
    fn new(safety: &Safety, path: &[Pose], my_margin: f64) -> Self {
        let (mut lo, mut hi) = (
            (f64::INFINITY, f64::INFINITY),
            (f64::NEG_INFINITY, f64::NEG_INFINITY),
        );
        for p in path {
            lo = (lo.0.min(p.x), lo.1.min(p.y));
            hi = (hi.0.max(p.x), hi.1.max(p.y));
        }
        let mut broad = Self {
            lo,
            hi,
            mine_reach: 0.0,
            length_m: safety.length_m,
            width_m: safety.width_m,
        };
        broad.mine_reach = broad.half_diag(my_margin.max(safety.margin_m));
        broad
    }

    fn half_diag(&self, margin: f64) -> f64 {
        (self.length_m / 2.0 + margin).hypot(self.width_m / 2.0 + margin)
    }

    /// Whether a robot at `q` with footprint margin `their_margin` may reach the path.
    fn near(&self, q: Pose, their_margin: f64) -> bool {
        let dx = (self.lo.0 - q.x).max(q.x - self.hi.0).max(0.0);
        let dy = (self.lo.1 - q.y).max(q.y - self.hi.1).max(0.0);
        // NaN poses and margins compare false and so count as near: the exact test decides.
        let gap = dx.hypot(dy);
        let reach = self.mine_reach + self.half_diag(their_margin) + 1e-3;
        gap <= reach || gap.is_nan() || reach.is_nan()
    }
}

impl Safety {
    /// Whether the model has lost `v`, or is less sure of it than tape could find it.
    fn lost(&self, v: &RobotView) -> bool {
        v.localisation == Localisation::Lost
            || v.uncertainty.position_m > crate::model::LOST_SIGMA_M
    }

    /// How far a moving robot's own footprint is grown: the margin and 1σ of its position,
    /// tracked or lost; a lost one's also by what a turn of 1σ of its heading sweeps, since it
    /// may really face that far off the way the model has it.
    pub fn berth(&self, v: &RobotView) -> f64 {
        let turned = if self.lost(v) {
            self.turned(v, UNCERTAINTY_SIGMAS)
        } else {
            0.0
        };
        self.margin_m + UNCERTAINTY_SIGMAS * v.uncertainty.position_m + turned
    }

    /// How far robot `v`'s footprint is grown beyond its plain size: the margin, and its
    /// uncertainty. For a tracked robot, [`UNCERTAINTY_SIGMAS`] σ of its position. For a lost
    /// one (or one more uncertain than the model's lost limit, where no tape could find it),
    /// its exclusion zone: [`LOST_SIGMAS`] σ of its position, and the farthest any point of
    /// its footprint moves under a turn of [`LOST_SIGMAS`] σ of its heading (at most what puts
    /// the footprint's circumscribed circle inside the grown rectangle, which covers any
    /// heading). A footprint displaced by less than the growth, or turned by less than that
    /// turn, stays inside the grown one.
    pub fn reach(&self, v: &RobotView) -> f64 {
        if !self.lost(v) {
            return self.margin_m + UNCERTAINTY_SIGMAS * v.uncertainty.position_m;
        }
        self.margin_m + LOST_SIGMAS * v.uncertainty.position_m + self.turned(v, LOST_SIGMAS)
    }

    /// The farthest any point of `v`'s footprint moves under a turn of `sigmas` σ of its
    /// heading, at most what covers any heading.
    fn turned(&self, v: &RobotView, sigmas: f64) -> f64 {
        let half_diag = (self.length_m / 2.0).hypot(self.width_m / 2.0);
        let any_heading = half_diag - self.width_m.min(self.length_m) / 2.0;
        let turn = (sigmas * v.uncertainty.heading_rad).min(std::f64::consts::PI);
        (2.0 * half_diag * (turn / 2.0).sin()).min(any_heading)
    }

    /// How much farther than its berth a mover may really be from each of `path`'s poses: none
    /// for a tracked robot. A lost one may face up to δ = `sigmas` σ of its heading off, which
    /// turns its whole path about its start: a straight drive's pose `s` metres along may
    /// really lie `s·tan δ` to either side (within the wedge the widened footprints sweep), for
    /// δ up to [`SIDE_ONLY_RAD`]; a wider δ, or an arc, moves the pose up to `2·c·sin(δ/2)`
    /// in any direction, `c` its distance from the start. A turn on the spot stays where it is.
    fn drift(&self, v: &RobotView, path: &[Pose], sigmas: f64) -> Vec<Growth> {
        let none = Growth::default();
        let Some(start) = path.first().copied() else {
            return Vec::new();
        };
        if !self.lost(v) {
            return vec![none; path.len()];
        }
        let delta = (sigmas * v.uncertainty.heading_rad).min(std::f64::consts::PI);
        let straight = path.iter().all(|p| p.theta == start.theta);
        path.iter()
            .map(|p| {
                let c = (p.x - start.x).hypot(p.y - start.y);
                if straight && delta <= SIDE_ONLY_RAD {
                    Growth {
                        side: c * delta.tan(),
                        all: 0.0,
                    }
                } else {
                    Growth {
                        side: 0.0,
                        all: 2.0 * c * (delta / 2.0).sin(),
                    }
                }
            })
            .collect()
    }

    /// Where `v`, driving on its wheels with no queued move, will be when a command sent now
    /// reaches it, `late` after the pose its latest state gave (the state's age plus the link's
    /// round trip: it came up one way and the command goes down the other). `None` for a robot
    /// at rest, whose pose stands. At most the check's horizon ahead: a robot silent for longer
    /// is stopped by its own watchdog.
    pub fn landing(&self, v: &RobotView, late: std::time::Duration) -> Option<Pose> {
        let w = v.state.wheels;
        let (left, right) = (f64::from(w.left_mps), f64::from(w.right_mps));
        if left.abs().max(right.abs()) < AT_REST_MPS {
            return None;
        }
        let dt = late.as_secs_f64().min(self.horizon_s);
        Some(ahead(v.pose, (left, right), dt))
    }

    /// `Ok` when the intent is safe in `world`, else why not. `from` is where the robot's queued
    /// moves will leave it (its pose when it has none); `others_planned` where other robots'
    /// queued moves will leave them.
    pub fn check_planned(
        &self,
        intent: &Intent,
        world: &WorldSnapshot,
        from: Option<Pose>,
        others_planned: &[(u16, Pose)],
    ) -> Result<(), Refusal> {
        let Some(me) = world.robot(intent.robot()) else {
            return Err(format!("robot {} is not in the experiment", intent.robot()).into());
        };
        let start = from.unwrap_or(me.pose);
        let Some(path) = self.path(intent, start) else {
            return Ok(());
        };
        // An uncertain pose gets a wider berth: each footprint grows by its own uncertainty. The
        // mover is taken within 1σ even when lost: its whole region is what the others keep
        // clear of, and a lost robot searching for the tape beside another (a queue, pushers
        // side by side) could otherwise never move (record 0031).
        let my_margin = self.berth(me);
        let drift = self.drift(me, &path, LOST_SIGMAS);
        let wall_drift = self.drift(me, &path, UNCERTAINTY_SIGMAS);
        // Against other robots a lost mover's path is widened by 3σ of its heading: a bump's
        // turn is what no sensor feels (a search leg approved on 1σ ran a robot facing 32° off
        // into its neighbour, 165025 `token_ring`), while its shift is felt within millimetres.
        // Against the walls the mover is taken at 1σ of its position, widened to its sides by
        // its path's wedge of 1σ of heading, but not grown for a turn or ahead: that held
        // searches towards a wall that found their robots before (a follower knocked off a
        // bend, `traffic_control` robots by the arena's edge). Without the wedge, a search leg
        // driven 19° off the model's heading (1σ: 15°) met the wall.
        let wall_margin = self.margin_m + UNCERTAINTY_SIGMAS * me.uncertainty.position_m;
        self.within_arena(me, (&path, &wall_drift), wall_margin, world.arena)?;
        let widest_drift = drift.iter().map(|g| g.side + g.all).fold(0.0, f64::max);
        let broad = Broad::new(self, &path, my_margin + widest_drift);
        let widest_margin = world
            .robots
            .iter()
            .map(|o| self.reach(o))
            .fold(self.margin_m, f64::max);
        let mut near_planned: Vec<(u16, Pose)> = others_planned
            .iter()
            .filter(|(_, p)| broad.near(*p, widest_margin))
            .copied()
            .collect();
        near_planned.sort_by_key(|(id, _)| *id);
        for other in world.robots.iter().filter(|o| o.id != me.id) {
            let their_margin = self.reach(other);
            let planned_near = near_planned
                .binary_search_by_key(&other.id, |(id, _)| *id)
                .is_ok();
            if !planned_near && !broad.near(other.pose, their_margin) {
                continue;
            }
            let mut theirs = vec![other.pose];
            theirs.extend(
                others_planned
                    .iter()
                    .filter(|(id, _)| *id == other.id)
                    .map(|(_, p)| *p),
            );
            for q in theirs {
                self.clear_of(me, other, q, (&path, &drift), my_margin, their_margin)
                    .map_err(|reason| Refusal {
                        reason,
                        robot: Some(other.id),
                    })?;
            }
        }
        Ok(())
    }

    /// The poses a moving intent sweeps from `start`, `None` for an intent that does not move
    /// the robot.
    fn path(&self, intent: &Intent, start: Pose) -> Option<Vec<Pose>> {
        Some(match *intent {
            Intent::Move { command, .. } => sweep(start, command),
            Intent::WheelSpeeds { left, right, .. } => {
                let (l, r) = (f64::from(left), f64::from(right));
                let v = (l + r) / 2.0;
                // Gauge of the wheels; the turn rate only shapes the extrapolated arc.
                let w = (r - l) / 0.04;
                let (d, a) = (v * self.horizon_s, w * self.horizon_s);
                let n = ((d.abs() / STEP_M).max(a.abs() / STEP_RAD)).ceil().max(1.0) as usize;
                (0..=n)
                    .map(|k| {
                        let t = k as f64 / n as f64;
                        arc_pose(start, d * t, a * t)
                    })
                    .collect()
            }
            _ => return None,
        })
    }

    /// Every footprint along `path` inside the arena.
    fn within_arena(
        &self,
        me: &RobotView,
        (path, drift): (&[Pose], &[Growth]),
        my_margin: f64,
        (w, h): (f64, f64),
    ) -> Result<(), String> {
        for (p, g) in path.iter().zip(drift) {
            let grown = Footprint::new(
                *p,
                self.length_m,
                self.width_m + 2.0 * g.side,
                my_margin + g.all,
            );
            for c in grown.corners() {
                if c.0 < 0.0 || c.1 < 0.0 || c.0 > w || c.1 > h {
                    return Err(format!(
                        "robot {} would leave the arena at ({:.3}, {:.3})",
                        me.id, p.x, p.y
                    ));
                }
            }
        }
        Ok(())
    }

    /// `me` along `path` keeps clear of `other` standing at `q`. Robots already inside each
    /// other's widened footprints (pushing side by side, or a bad estimate) may still move apart
    /// or alongside: such a path is refused only where it closes in on the other by more than
    /// `ALONGSIDE_M`, or deepens an overlap of the footprints with the plain margin.
    fn clear_of(
        &self,
        me: &RobotView,
        other: &RobotView,
        q: Pose,
        (path, drift): (&[Pose], &[Growth]),
        my_margin: f64,
        their_margin: f64,
    ) -> Result<(), String> {
        // A lost mover's footprint widens to each side as it goes (see [`Safety::drift`]).
        let grown = |p: Pose, g: Growth, margin: f64| {
            Footprint::new(
                p,
                self.length_m,
                self.width_m + 2.0 * g.side,
                margin + g.all,
            )
        };
        let fq = Footprint::new(q, self.length_m, self.width_m, their_margin);
        let overlapping_now = grown(path[0], Growth::default(), my_margin).overlaps(&fq);
        // Parting from a lost robot is judged against its whole region: where in it the robot
        // stands is unknown, and a corner of it may stand in the way out.
        let their_depth_margin = if self.lost(other) {
            their_margin
        } else {
            self.margin_m
        };
        let fq_plain = Footprint::new(q, self.length_m, self.width_m, their_depth_margin);
        let my_depth_margin = if self.lost(me) {
            my_margin
        } else {
            self.margin_m
        };
        let start_depth = grown(path[0], Growth::default(), my_depth_margin).depth(&fq_plain);
        // A lost mover may not close in at all, nor turn there: where it really stands beside
        // the other robot is unknown, and any corner a turn swings out may be the near one. A
        // turn bringing the model's footprint more nearly parallel to the other's lessens the
        // overlap the model sees, while the robot, really facing up to 20° the other way, swings
        // a corner into its neighbour (165062 `cooperative_push`): so no turn at all.
        let lost_me = self.lost(me);
        let tolerance = if lost_me { 0.0 } else { ALONGSIDE_M };
        let Some((p, _)) = path.iter().zip(drift).skip(1).find(|(p, d)| {
            if !overlapping_now {
                return grown(**p, **d, my_margin).overlaps(&fq);
            }
            if lost_me && wrap_abs(p.theta - path[0].theta) > TURN_EPS_RAD {
                return true;
            }
            let depth = grown(**p, **d, my_depth_margin).depth(&fq_plain);
            depth > start_depth + tolerance || (depth > 0.0 && depth > start_depth)
        }) else {
            return Ok(());
        };
        let widened = my_margin + their_margin - 2.0 * self.margin_m;
        Err(if widened >= 0.0005 {
            format!(
                "robot {} would touch robot {} at ({:.3}, {:.3}) (their footprints widened by \
                 {:.1} and {:.1} mm for the uncertainty of their poses)",
                me.id,
                other.id,
                p.x,
                p.y,
                (my_margin - self.margin_m) * 1e3,
                (their_margin - self.margin_m) * 1e3
            )
        } else {
            format!(
                "robot {} would touch robot {} at ({:.3}, {:.3})",
                me.id, other.id, p.x, p.y
            )
        })
    }

    /// `Ok` when the intent is safe from the robots' current poses.
    pub fn check(&self, intent: &Intent, world: &WorldSnapshot) -> Result<(), Refusal> {
        self.check_planned(intent, world, None, &[])
    }
}

/// Why the safety check held an intent, and the robot it would have touched, if that is why.
#[derive(Clone, Debug, PartialEq)]
pub struct Refusal {
    /// What would have gone wrong, in words.
    pub reason: String,
    /// The robot it would have touched.
    pub robot: Option<u16>,
}

impl From<String> for Refusal {
    fn from(reason: String) -> Self {
        Self {
            reason,
            robot: None,
        }
    }
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.reason)
    }
}

/// The size of an angle, wrapped to at most π.
fn wrap_abs(a: f64) -> f64 {
    let a = a.rem_euclid(std::f64::consts::TAU);
    a.min(std::f64::consts::TAU - a)
}

/// Where `command` ends when it starts at `p`.
pub fn end_pose(p: Pose, command: MoveCommand) -> Pose {
    sweep(p, command).last().copied().unwrap_or(p)
}

/// Poses along `command` from `p`, both ends included.
fn sweep(p: Pose, command: MoveCommand) -> Vec<Pose> {
    let (d, a) = match command {
        MoveCommand::Straight { distance_m, .. } => (f64::from(distance_m), 0.0),
        MoveCommand::Rotate { angle_deg, .. } => (0.0, f64::from(angle_deg).to_radians()),
        MoveCommand::Arc {
            radius_m,
            angle_deg,
            ..
        } => {
            let a = f64::from(angle_deg).to_radians();
            (f64::from(radius_m).abs() * a.abs(), a)
        }
    };
    let n = ((d.abs() / STEP_M).max(a.abs() / STEP_RAD)).ceil().max(1.0) as usize;
    (0..=n)
        .map(|k| {
            let t = k as f64 / n as f64;
            arc_pose(p, d * t, a * t)
        })
        .collect()
}

/// Where a robot at `p` driving its wheels at `(left, right)` m/s will be `dt` seconds later.
pub fn ahead(p: Pose, (left, right): (f64, f64), dt: f64) -> Pose {
    let v = (left + right) / 2.0;
    let w = (right - left) / world::robot::WHEEL_GAUGE_M;
    arc_pose(p, v * dt, w * dt)
}

/// The pose after driving `d` metres while turning by `a` radians at a constant rate.
fn arc_pose(p: Pose, d: f64, a: f64) -> Pose {
    // The chord of a circular arc leaves along the mean heading; its length is d·sinc(a/2).
    let chord = if a.abs() < 1e-9 {
        d
    } else {
        d * (a / 2.0).sin() / (a / 2.0)
    };
    let mid = p.theta + a / 2.0;
    Pose {
        x: p.x + chord * mid.cos(),
        y: p.y + chord * mid.sin(),
        theta: p.theta + a,
    }
}

/// An oriented rectangle.
#[derive(Clone, Copy, Debug)]
struct Footprint {
    centre: (f64, f64),
    axes: [(f64, f64); 2],
    half: [f64; 2],
}

impl Footprint {
    fn new(p: Pose, length: f64, width: f64, margin: f64) -> Self {
        let (s, c) = p.theta.sin_cos();
        Self {
            centre: (p.x, p.y),
            axes: [(c, s), (-s, c)],
            half: [length / 2.0 + margin, width / 2.0 + margin],
        }
    }

    fn corners(&self) -> [(f64, f64); 4] {
        let [a, b] = self.axes;
        let [ha, hb] = self.half;
        let at = |u: f64, v: f64| {
            (
                self.centre.0 + a.0 * u + b.0 * v,
                self.centre.1 + a.1 * u + b.1 * v,
            )
        };
        [at(ha, hb), at(-ha, hb), at(-ha, -hb), at(ha, -hb)]
    }

    /// The least distance one rectangle must move along any of the four separating axes to
    /// part from the other (negative when they are apart, by the widest gap). On an axis where
    /// one projection holds the other, that is the way out to the nearer end, so a footprint
    /// inside a larger region goes deeper as it moves towards the region's middle.
    fn depth(&self, other: &Footprint) -> f64 {
        let mut least = f64::INFINITY;
        for axis in self.axes.iter().chain(other.axes.iter()) {
            let (lo1, hi1) = self.project(*axis);
            let (lo2, hi2) = other.project(*axis);
            least = least.min((hi1 - lo2).min(hi2 - lo1));
        }
        least
    }

    fn overlaps(&self, other: &Footprint) -> bool {
        self.depth(other) > 0.0
    }

    fn project(&self, axis: (f64, f64)) -> (f64, f64) {
        let c = self.centre.0 * axis.0 + self.centre.1 * axis.1;
        let r: f64 = self
            .axes
            .iter()
            .zip(self.half)
            .map(|(a, h)| h * (a.0 * axis.0 + a.1 * axis.1).abs())
            .sum();
        (c - r, c + r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use behaviour_api::RobotView;
    use std::f64::consts::FRAC_PI_2;

    fn world(robots: &[(u16, f64, f64, f64)]) -> WorldSnapshot {
        WorldSnapshot {
            time: Default::default(),
            robots: robots
                .iter()
                .map(|&(id, x, y, theta)| {
                    std::sync::Arc::new(RobotView {
                        id,
                        connected: true,
                        pose: Pose { x, y, theta },
                        odometry: Default::default(),
                        state: Default::default(),
                        pending_moves: 0,
                        on_track: None,
                        ..Default::default()
                    })
                })
                .collect(),
            encounters: Vec::new(),
            arena: (1.0, 1.0),
        }
    }

    fn straight(robot: u16, d: f32) -> Intent {
        Intent::Move {
            robot,
            command: MoveCommand::Straight {
                distance_m: d,
                speed_mps: 0.2,
            },
            tag: 0,
        }
    }

    /// `tracked` with its first robot lost, `position_m` and `heading_deg` uncertain (1σ).
    fn first_lost(tracked: &WorldSnapshot, position_m: f64, heading_deg: f64) -> WorldSnapshot {
        let lost = RobotView {
            localisation: Localisation::Lost,
            uncertainty: behaviour_api::PoseUncertainty {
                position_m,
                heading_rad: heading_deg.to_radians(),
            },
            ..(*tracked.robots[0]).clone()
        };
        WorldSnapshot {
            robots: std::iter::once(lost)
                .chain(tracked.robots[1..].iter().map(|r| (**r).clone()))
                .map(std::sync::Arc::new)
                .collect(),
            ..tracked.clone()
        }
    }

    /// Two pushers side by side, 16 mm between their bodies, both facing the box; robot 1 lost
    /// with 20 mm and 20° of 1σ. It may not turn beside its neighbour nor drive along it, where
    /// its true heading may take it into it; the neighbour may back away from it.
    #[test]
    fn a_lost_pusher_may_not_move_beside_its_neighbour_which_may_back_away() {
        let s = Safety::default();
        let tracked = world(&[(1, 0.5, 0.3, FRAC_PI_2), (2, 0.548, 0.3, FRAC_PI_2)]);
        let w = first_lost(&tracked, 0.02, 20.0);
        let turn = Intent::Move {
            robot: 1,
            command: MoveCommand::Rotate {
                angle_deg: -2.0,
                speed_mps: 0.05,
            },
            tag: 0,
        };
        for (what, intent) in [("a 2° turn", turn), ("a drive along", straight(1, 0.1))] {
            assert!(s.check(&intent, &tracked).is_ok(), "tracked: {what}");
            assert!(s.check(&intent, &w).is_err(), "lost: {what}");
        }
        assert!(s.check(&straight(2, -0.05), &w).is_ok());
        // Modelled 14° askew, a turn square to its neighbour lessens the overlap the model
        // sees; really facing the other way, it swings its corner into the neighbour.
        let askew = w.robots[0].pose.theta - 14f64.to_radians();
        let mut one = (*w.robots[0]).clone();
        one.pose.theta = askew;
        let skewed = WorldSnapshot {
            robots: [one, (*w.robots[1]).clone()]
                .into_iter()
                .map(std::sync::Arc::new)
                .collect(),
            ..w.clone()
        };
        let square = Intent::Move {
            robot: 1,
            command: MoveCommand::Rotate {
                angle_deg: 14.0,
                speed_mps: 0.03,
            },
            tag: 0,
        };
        assert!(s.check(&square, &skewed).is_err());
    }

    /// A tracked pusher 49 mm beside a lost one (27 mm and 20° of 1σ) stands wholly inside the
    /// lost robot's region. Driving on along its heading, 1° towards the lost robot, takes it
    /// deeper into that region and is held; backing out of it is approved.
    #[test]
    fn a_robot_inside_a_lost_robots_region_may_only_leave_it() {
        let s = Safety::default();
        let tracked = world(&[
            (1, 0.5, 0.5, FRAC_PI_2),
            (2, 0.451, 0.5, FRAC_PI_2 - 0.0175),
        ]);
        let w = first_lost(&tracked, 0.027, 20.0);
        for d in [0.01, 0.04] {
            assert!(s.check(&straight(2, d), &w).is_err(), "on by {d} m");
            assert!(s.check(&straight(2, -d), &w).is_ok(), "back by {d} m");
        }
    }

    #[test]
    fn holds_back_a_move_into_another_robot_or_a_wall() {
        let s = Safety::default();
        let w = world(&[(1, 0.3, 0.5, 0.0), (2, 0.45, 0.5, 0.0), (3, 0.3, 0.2, 0.0)]);
        assert!(
            s.check(&straight(1, 0.1), &w).is_err(),
            "robot 2 is in the way"
        );
        assert!(
            s.check(&straight(1, -0.1), &w).is_ok(),
            "backing away is fine"
        );
        assert!(s.check(&straight(3, 0.5), &w).is_ok());
        assert!(s.check(&straight(3, 0.8), &w).is_err(), "out of the arena");
        let spin = Intent::Move {
            robot: 1,
            command: MoveCommand::Rotate {
                angle_deg: 90.0,
                speed_mps: 0.1,
            },
            tag: 0,
        };
        assert!(s.check(&spin, &w).is_ok());
        assert!(s
            .check(
                &Intent::WheelSpeeds {
                    robot: 1,
                    left: 0.3,
                    right: 0.3
                },
                &w
            )
            .is_err());
    }

    #[test]
    fn two_robots_side_by_side_may_push_together_but_not_turn_into_each_other() {
        let s = Safety::default();
        // Facing north, 36 mm apart centre to centre: 4 mm between their 32 mm wide bodies.
        let w = world(&[(1, 0.482, 0.1, FRAC_PI_2), (2, 0.518, 0.1, FRAC_PI_2)]);
        assert!(s.check(&straight(1, 0.1), &w).is_ok());
        assert!(s.check(&straight(2, 0.1), &w).is_ok());
        let turn = Intent::Move {
            robot: 1,
            command: MoveCommand::Rotate {
                angle_deg: 90.0,
                speed_mps: 0.1,
            },
            tag: 0,
        };
        assert!(
            s.check(&turn, &w).is_err(),
            "its 48 mm length swings into robot 2"
        );
    }

    #[test]
    fn a_move_is_checked_from_where_the_queue_leaves_the_robot() {
        let s = Safety::default();
        let w = world(&[(1, 0.3, 0.5, 0.0), (2, 0.3, 0.62, 0.0)]);
        let north = straight(1, 0.1);
        assert!(s.check(&north, &w).is_ok(), "east is clear");
        let turned = end_pose(
            w.robots[0].pose,
            MoveCommand::Rotate {
                angle_deg: 90.0,
                speed_mps: 0.1,
            },
        );
        assert!((turned.theta - FRAC_PI_2).abs() < 1e-9);
        assert!(
            s.check_planned(&north, &w, Some(turned), &[]).is_err(),
            "after the queued quarter turn it heads into robot 2"
        );
        // Robot 2 is about to leave: where its queue ends counts too.
        let w = world(&[(1, 0.3, 0.5, 0.0), (2, 0.6, 0.8, 0.0)]);
        let planned = [(
            2,
            Pose {
                x: 0.42,
                y: 0.5,
                theta: 0.0,
            },
        )];
        assert!(s
            .check_planned(&straight(1, 0.1), &w, None, &planned)
            .is_err());
    }

    #[test]
    fn a_driving_robot_is_judged_where_the_command_will_reach_it() {
        let s = Safety::default();
        // Robot 1 follows the tape east at 50 mm/s, robot 2 stands ahead: a 100 mm drive on
        // ends 9 mm short of it from the pose robot 1's last state gave, and 16 mm into it from
        // where the link's latency will have carried robot 1 (25 mm on, the horizon's worth).
        let mut w = world(&[(1, 0.30, 0.5, 0.0), (2, 0.46, 0.5, 0.0)]);
        {
            let me = std::sync::Arc::make_mut(&mut w.robots.make_mut()[0]);
            me.state.wheels.left_mps = 0.05;
            me.state.wheels.right_mps = 0.05;
        }
        let late = std::time::Duration::from_millis(800);
        let landing = s.landing(&w.robots[0], late).expect("it drives");
        assert!(
            (landing.x - (0.30 + 0.05 * s.horizon_s)).abs() < 1e-9,
            "{landing:?}"
        );
        assert!(landing.y == 0.5 && landing.theta == 0.0);
        let on = straight(1, 0.1);
        assert!(s.check_planned(&on, &w, None, &[]).is_ok());
        assert!(
            s.check_planned(&on, &w, Some(landing), &[]).is_err(),
            "from where it will be, the drive ends in robot 2"
        );
        // Standing, a robot is where its state says, however old.
        assert_eq!(s.landing(&w.robots[1], late), None);
    }

    #[test]
    fn an_arc_is_swept_along_its_curve() {
        let p = Pose {
            x: 0.0,
            y: 0.0,
            theta: 0.0,
        };
        let quarter = MoveCommand::Arc {
            radius_m: 0.1,
            angle_deg: 90.0,
            speed_mps: 0.1,
        };
        let e = end_pose(p, quarter);
        assert!(
            (e.x - 0.1).abs() < 1e-6 && (e.y - 0.1).abs() < 1e-6,
            "{e:?}"
        );
        let right = MoveCommand::Arc {
            radius_m: 0.1,
            angle_deg: -90.0,
            speed_mps: 0.1,
        };
        let e = end_pose(p, right);
        assert!(
            (e.x - 0.1).abs() < 1e-6 && (e.y + 0.1).abs() < 1e-6,
            "{e:?}"
        );
    }

    mod exclusion {
        use super::*;
        use proptest::prelude::*;
        use std::f64::consts::PI;

        /// A view at a pose with an uncertainty, tracked or lost.
        fn robot(id: u16, pose: Pose, sigma: (f64, f64), lost: bool) -> RobotView {
            RobotView {
                id,
                connected: true,
                pose,
                uncertainty: behaviour_api::PoseUncertainty {
                    position_m: sigma.0,
                    heading_rad: sigma.1,
                },
                localisation: if lost {
                    Localisation::Lost
                } else {
                    Localisation::Tracking
                },
                ..Default::default()
            }
        }

        /// Where a robot may really be: within its position's reach (σ for a tracked robot,
        /// `LOST_SIGMAS` σ for a lost one) in direction `u`, turned by `t` of its heading's
        /// (none for a tracked one, `LOST_SIGMAS` σ for a lost one).
        fn possible(v: &RobotView, at: Pose, u: (f64, f64), t: f64) -> Pose {
            let lost = v.localisation == Localisation::Lost;
            let k = if lost {
                LOST_SIGMAS
            } else {
                UNCERTAINTY_SIGMAS
            };
            let r = k * v.uncertainty.position_m * u.0;
            let turn = if lost {
                t * (LOST_SIGMAS * v.uncertainty.heading_rad).min(PI)
            } else {
                0.0
            };
            Pose {
                x: at.x + r * u.1.cos(),
                y: at.y + r * u.1.sin(),
                theta: at.theta + turn,
            }
        }

        fn intent(kind: u8, amount: f64) -> Intent {
            let command = match kind {
                0 => MoveCommand::Straight {
                    distance_m: amount as f32,
                    speed_mps: 0.1,
                },
                1 => MoveCommand::Rotate {
                    angle_deg: (amount * 1200.0) as f32,
                    speed_mps: 0.05,
                },
                _ => MoveCommand::Arc {
                    radius_m: 0.1,
                    angle_deg: (amount * 600.0) as f32,
                    speed_mps: 0.1,
                },
            };
            Intent::Move {
                robot: 1,
                command,
                tag: 0,
            }
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(4000))]

            /// The rule the supervisor keeps: a move the check approves, from robots clear of
            /// each other's grown footprints, sweeps footprints (at the check's own steps) that
            /// touch none of the other robot's possible poses: the mover anywhere within 1σ of
            /// where the check sweeps it (a lost mover's whole path also turned about its start
            /// by up to 3σ of its heading), the other within its region (a tracked one within
            /// 1σ, a lost one within 3σ and turned by up to 3σ of its heading).
            #[test]
            fn an_approved_move_never_reaches_where_the_other_robot_may_be(
                a in (0.3..0.7f64, 0.3..0.7f64, -PI..PI),
                b in (0.03..0.16f64, -PI..PI, -PI..PI),
                sigmas in (0.0..0.02f64, 0.0..0.5f64, 0.0..0.02f64, 0.0..0.5f64),
                lost in (any::<bool>(), any::<bool>()),
                kind in 0..3u8,
                amount in -0.15..0.15f64,
                where_a in (0.0..=1.0f64, -PI..PI, -1.0..=1.0f64),
                where_b in (0.0..=1.0f64, -PI..PI, -1.0..=1.0f64),
            ) {
                let s = Safety::default();
                let pa = Pose { x: a.0, y: a.1, theta: a.2 };
                let pb = Pose { x: a.0 + b.0 * b.1.cos(), y: a.1 + b.0 * b.1.sin(), theta: b.2 };
                let me = robot(1, pa, (sigmas.0, sigmas.1), lost.0);
                let other = robot(2, pb, (sigmas.2, sigmas.3), lost.1);
                let mine_grown = Footprint::new(pa, s.length_m, s.width_m, s.berth(&me));
                let theirs_grown = Footprint::new(pb, s.length_m, s.width_m, s.reach(&other));
                if mine_grown.overlaps(&theirs_grown) {
                    // Already inside each other's regions: the check then only lets them part.
                    return Ok(());
                }
                let world = WorldSnapshot {
                    time: Default::default(),
                    robots: [me.clone(), other.clone()].into_iter().map(std::sync::Arc::new).collect(),
                    encounters: Vec::new(),
                    arena: (1.0, 1.0),
                };
                let intent = intent(kind, amount);
                if s.check(&intent, &world).is_err() {
                    return Ok(());
                }
                let really_b = possible(&other, pb, (where_b.0, where_b.1), where_b.2);
                let theirs = Footprint::new(really_b, s.length_m, s.width_m, 0.0);
                // A lost mover may really face up to 3σ of its heading off: its whole path turns
                // by that about its start.
                let phi = if lost.0 {
                    where_a.2 * (LOST_SIGMAS * sigmas.1).min(PI)
                } else {
                    0.0
                };
                let (sp, cp) = phi.sin_cos();
                for p in s.path(&intent, pa).expect("a move moves") {
                    let (dx, dy) = (p.x - pa.x, p.y - pa.y);
                    let p = Pose {
                        x: pa.x + dx * cp - dy * sp,
                        y: pa.y + dx * sp + dy * cp,
                        theta: p.theta + phi,
                    };
                    // The mover within 1σ of where the check sweeps it, lost or not.
                    let tracked = RobotView { localisation: Localisation::Tracking, ..me.clone() };
                    let really_a = possible(&tracked, p, (where_a.0, where_a.1), where_a.2);
                    let mine = Footprint::new(really_a, s.length_m, s.width_m, 0.0);
                    prop_assert!(
                        !mine.overlaps(&theirs),
                        "approved {intent:?}: at {really_a:?} it touches robot 2 at {really_b:?}"
                    );
                }
            }
        }
    }
}
