//! The world a simulation runs in: walled arena, tape track, movable obstacles, robot start poses,
//! radio link and light, read from TOML world files ([`file`](mod@file)) or built-in presets ([`presets`]).
//! Also what every host crate must agree on about the robot: its geometry ([`robot`]), [`Pose`]
//! and [`wrap_angle`].
//!
//! Coordinates are metres on the floor, x to the right and y up (seen from above), headings in
//! radians counter-clockwise from +x.

#![warn(missing_docs)]

pub mod cli;
pub mod faults;
pub mod file;
#[cfg(feature = "graph")]
pub mod graph;
pub mod pose;
pub mod presets;
pub mod robot;
pub mod track;

use std::collections::HashSet;
use std::fmt;

use nalgebra::{Point2, Rotation2, Vector2};

use robot::{RADIUS_M as ROBOT_RADIUS_M, WIDTH_M as ROBOT_WIDTH_M};

pub use file::{load, parse, WorldError, WorldFile};
#[cfg(feature = "graph")]
pub use graph::{GraphEdge, GraphNode, NodeKind, Route, TrackGraph};
pub use pose::{wrap_angle, Pose};
pub use presets::{grid, preset, preset_names};
pub use track::{
    Edge, EdgeEnd, EdgeSpec, Mark, Node, QueryCost, Surface, Track, TrackError, TrackPoint,
};

/// The walled floor: walls stand along the border of the rectangle 0 ≤ x ≤ `width_m`,
/// 0 ≤ y ≤ `height_m`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Arena {
    /// Extent along x in metres.
    pub width_m: f64,
    /// Extent along y in metres.
    pub height_m: f64,
}

impl Arena {
    /// Whether `p` is inside the walls with at least `margin_m` to spare.
    pub fn contains(&self, p: Point2<f64>, margin_m: f64) -> bool {
        p.x >= margin_m
            && p.y >= margin_m
            && p.x <= self.width_m - margin_m
            && p.y <= self.height_m - margin_m
    }
}

/// A rectangular box lying on the floor that robots can push.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Obstacle {
    /// Centre in metres.
    pub position: Point2<f64>,
    /// Extent along the box's own x axis (along x at heading 0), in metres.
    pub width_m: f64,
    /// Extent along the box's own y axis, in metres.
    pub height_m: f64,
    /// Rotation of the box, radians counter-clockwise.
    pub heading_rad: f64,
    /// Mass in kilograms.
    pub mass_kg: f64,
    /// Coulomb friction coefficient against the floor.
    pub friction: f64,
}

impl Obstacle {
    /// The four corners in world coordinates.
    pub fn corners(&self) -> [Point2<f64>; 4] {
        let rot = Rotation2::new(self.heading_rad);
        let (hx, hy) = (self.width_m / 2.0, self.height_m / 2.0);
        [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
            .map(|(x, y)| self.position + rot * Vector2::new(x, y))
    }

    /// Whether `p` lies within `margin_m` of the box (inside it, or near its sides).
    pub fn contains(&self, p: Point2<f64>, margin_m: f64) -> bool {
        let local = Rotation2::new(-self.heading_rad) * (p - self.position);
        local.x.abs() <= self.width_m / 2.0 + margin_m
            && local.y.abs() <= self.height_m / 2.0 + margin_m
    }

    /// Force the floor's Coulomb friction resists sliding with, μ·m·g, in newtons.
    pub fn floor_friction_n(&self) -> f64 {
        self.friction * self.mass_kg * GRAVITY_MPS2
    }
}

/// Standard gravity, m/s².
pub const GRAVITY_MPS2: f64 = 9.81;

/// The widest and longest arena a world may have, metres: the largest generated lattice
/// (400 × 400 nodes, 80.2 m) fits, and the simulator's spatial index over it stays within tens
/// of megabytes (a 1,000 m arena took 911 MB before it was refused).
pub const MAX_ARENA_M: f64 = 100.0;

/// The most robots a world may hold: twice the largest fleet the project runs (1,000 robots
/// on a 64 × 32 lattice); 20,001 robots took 792 MB and gave no result in a minute.
pub const MAX_ROBOTS: usize = 2000;

/// Where a robot starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotStart {
    /// Robot id, as in the firmware's identity settings.
    pub id: u16,
    /// Centre of the body in metres.
    pub position: Point2<f64>,
    /// Heading in radians counter-clockwise from +x.
    pub heading_rad: f64,
}

/// Radio link model between the host and the robots.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RadioModel {
    /// One-way latency in milliseconds.
    pub latency_ms: f64,
    /// Jitter added to each packet's latency, milliseconds: drawn uniformly in `0..jitter_ms`.
    pub jitter_ms: f64,
    /// Probability (0..=1) that a packet is lost, over the long run.
    pub loss: f64,
    /// Mean length of a fade, milliseconds: 0 draws each packet's loss on its own; above 0 the
    /// link fades for this long on average (a Gilbert–Elliott channel in time whose bad state
    /// loses every packet), a `loss` share of the time.
    pub loss_burst_ms: f64,
    /// Usable bandwidth of one piconet in kilobits per second.
    pub bandwidth_kbps: f64,
    /// Robots one radio (piconet master) serves; more robots need more radios.
    pub robots_per_piconet: u32,
}

impl Default for RadioModel {
    /// The `l2cap` profile.
    fn default() -> Self {
        LINK_PROFILES[1].2
    }
}

/// The named link profiles: name, what it stands for, and the model.
pub const LINK_PROFILES: [(&str, &str, RadioModel); 4] = [
    (
        "ideal",
        "no latency, no jitter, no loss, no air time to share",
        RadioModel {
            latency_ms: 0.0,
            jitter_ms: 0.0,
            loss: 0.0,
            loss_burst_ms: 0.0,
            bandwidth_kbps: 1.0e6,
            robots_per_piconet: 7,
        },
    ),
    (
        "l2cap",
        "the default: 10-12 ms, no loss after retransmission, 700 kbit/s per piconet of 7",
        RadioModel {
            latency_ms: 10.0,
            jitter_ms: 2.0,
            loss: 0.0,
            loss_burst_ms: 0.0,
            bandwidth_kbps: 700.0,
            robots_per_piconet: 7,
        },
    ),
    (
        "bluetooth",
        "30 ms ± 15 ms, 700 kbit/s per piconet of 7, 1 % loss in fades of 20 ms on average",
        RadioModel {
            latency_ms: 15.0,
            jitter_ms: 30.0,
            loss: 0.01,
            loss_burst_ms: 20.0,
            bandwidth_kbps: 700.0,
            robots_per_piconet: 7,
        },
    ),
    (
        "poor",
        "80 ms ± 40 ms, 700 kbit/s per piconet of 7, 5 % loss in fades of 50 ms on average",
        RadioModel {
            latency_ms: 40.0,
            jitter_ms: 80.0,
            loss: 0.05,
            loss_burst_ms: 50.0,
            bandwidth_kbps: 700.0,
            robots_per_piconet: 7,
        },
    ),
];

impl RadioModel {
    /// The named profile, if there is one by that name.
    pub fn profile(name: &str) -> Option<RadioModel> {
        LINK_PROFILES
            .iter()
            .find(|(n, _, _)| *n == name)
            .map(|&(_, _, m)| m)
    }

    /// The profiles' names, comma-separated, for messages.
    pub fn profile_names() -> String {
        LINK_PROFILES.map(|(n, _, _)| n).join(", ")
    }

    /// Checks every value's range; the first problem found, in key order.
    pub fn validate(&self) -> Result<(), Problem> {
        let l = self;
        require(
            non_negative(l.latency_ms),
            Place::Link("latency_ms"),
            l.latency_ms,
            "0 ms or more",
        )?;
        require(
            non_negative(l.jitter_ms),
            Place::Link("jitter_ms"),
            l.jitter_ms,
            "0 ms or more",
        )?;
        require(
            (0.0..=1.0).contains(&l.loss),
            Place::Link("loss"),
            l.loss,
            "a probability in 0..=1",
        )?;
        require(
            non_negative(l.loss_burst_ms),
            Place::Link("loss_burst_ms"),
            l.loss_burst_ms,
            "a mean fade of 0 ms or more",
        )?;
        require(
            positive(l.bandwidth_kbps),
            Place::Link("bandwidth_kbps"),
            l.bandwidth_kbps,
            "a positive rate in kbit/s",
        )?;
        require(
            l.robots_per_piconet >= 1,
            Place::Link("robots_per_piconet"),
            f64::from(l.robots_per_piconet),
            "at least 1",
        )
    }
}

/// Ambient light seen by the IR sensors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// Ambient IR level, 0 (dark) ..= 1 (as bright as a lit white floor).
    pub ambient: f64,
    /// Standard deviation of sensor noise, as a fraction of full scale.
    pub noise: f64,
}

impl Default for Light {
    fn default() -> Self {
        Light {
            ambient: 0.2,
            noise: 0.01,
        }
    }
}

/// A validated world, ready for the simulator.
#[derive(Clone, Debug)]
pub struct World {
    /// Short name.
    pub name: String,
    /// What the world is for.
    pub description: String,
    /// Where it came from (file name or `preset:NAME`), for messages.
    pub origin: String,
    /// The walled floor.
    pub arena: Arena,
    /// The tape.
    pub track: Track,
    /// Movable boxes.
    pub obstacles: Vec<Obstacle>,
    /// Robot start poses.
    pub robots: Vec<RobotStart>,
    /// Radio link model.
    pub link: RadioModel,
    /// Ambient light and sensor noise.
    pub light: Light,
    /// Seed for every random choice of a run; `None` lets the simulator pick one.
    pub seed: Option<u64>,
    /// Faults the experiment injects (a world file's `[[faults]]`).
    pub faults: Vec<faults::FaultSpec>,
}

/// Which value of a world a [`Problem`] is about: a section, the index of an entry in its list
/// (0-based, in file order) and a key, so a world file can point at the line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Place {
    /// A key of `[arena]`.
    Arena(&'static str),
    /// A key of `[[track.nodes]]` number `.0`.
    Node(usize, &'static str),
    /// A key of `[[track.edges]]` number `.0`.
    Edge(usize, &'static str),
    /// A key of `[[obstacles]]` number `.0`.
    Obstacle(usize, &'static str),
    /// A key of `[[robots]]` number `.0`.
    Robot(usize, &'static str),
    /// A key of `[link]`.
    Link(&'static str),
    /// A key of `[light]`.
    Light(&'static str),
    /// A key of `[[faults]]` number `.0`.
    Fault(usize, &'static str),
}

impl fmt::Display for Place {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Place::Arena(k) => write!(f, "arena.{k}"),
            Place::Node(i, k) => write!(f, "track.nodes[{i}].{k}"),
            Place::Edge(i, k) => write!(f, "track.edges[{i}].{k}"),
            Place::Obstacle(i, k) => write!(f, "obstacles[{i}].{k}"),
            Place::Robot(i, k) => write!(f, "robots[{i}].{k}"),
            Place::Link(k) => write!(f, "link.{k}"),
            Place::Light(k) => write!(f, "light.{k}"),
            Place::Fault(i, k) => write!(f, "faults[{i}].{k}"),
        }
    }
}

/// Why a world's content (as opposed to its TOML syntax) was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Problem {
    /// The track itself is inconsistent.
    #[error(transparent)]
    Track(#[from] TrackError),
    /// A number outside its allowed range.
    #[error("{place} = {value}: expected {expected}")]
    OutOfRange {
        /// The value's place.
        place: Place,
        /// The refused value.
        value: f64,
        /// What was expected instead.
        expected: &'static str,
    },
    /// A node lies outside the walls.
    #[error("node \"{id}\" at ({x}, {y}) lies outside the arena")]
    NodeOutside {
        /// Index of the node.
        node: usize,
        /// Its id.
        id: String,
        /// Its x in metres.
        x: f64,
        /// Its y in metres.
        y: f64,
    },
    /// An edge (an arc, typically) runs outside the walls.
    #[error("edge {edge} runs outside the arena")]
    EdgeOutside {
        /// Index of the edge.
        edge: usize,
    },
    /// Part of an obstacle lies outside the walls.
    #[error("obstacle {obstacle} does not fit inside the arena")]
    ObstacleOutside {
        /// Index of the obstacle.
        obstacle: usize,
    },
    /// A robot's body would stick through a wall.
    #[error(
        "robot {id} at ({x}, {y}) does not fit inside the arena: its centre must keep \
         {ROBOT_RADIUS_M:.3} m from the walls"
    )]
    RobotOutside {
        /// Index of the robot.
        robot: usize,
        /// Its id.
        id: u16,
        /// Its x in metres.
        x: f64,
        /// Its y in metres.
        y: f64,
    },
    /// Two robots share an id.
    #[error("robot id {id} is used twice")]
    DuplicateRobot {
        /// Index of the later robot.
        robot: usize,
        /// The repeated id.
        id: u16,
    },
    /// Two robots start on top of each other.
    #[error("robots {id} and {other_id} overlap: their centres are closer than {ROBOT_WIDTH_M} m")]
    RobotsOverlap {
        /// Index of the later robot.
        robot: usize,
        /// Its id.
        id: u16,
        /// The other robot's id.
        other_id: u16,
    },
    /// `[link] profile` names no profile.
    #[error("link profile {name:?} is not one of {known}")]
    UnknownLinkProfile {
        /// The name given.
        name: String,
        /// The known names.
        known: String,
    },
    /// A declared fault is not one the simulator can inject.
    #[error("fault {fault}: {why}")]
    BadFault {
        /// Index of the fault.
        fault: usize,
        /// The key at fault.
        key: &'static str,
        /// What is wrong.
        why: String,
    },
    /// More robots than the simulator is built to hold.
    #[error("{count} robots: at most {MAX_ROBOTS} are allowed")]
    TooManyRobots {
        /// How many the world lists.
        count: usize,
    },
    /// A robot starts inside an obstacle.
    #[error("robot {id} starts on top of obstacle {obstacle}")]
    RobotOnObstacle {
        /// Index of the robot.
        robot: usize,
        /// Its id.
        id: u16,
        /// Index of the obstacle.
        obstacle: usize,
    },
}

impl Problem {
    /// The value the problem is about.
    pub fn place(&self) -> Place {
        match self {
            Problem::Track(e) => match e {
                TrackError::DuplicateNode { node, .. } => Place::Node(*node, "id"),
                TrackError::NonFiniteNode { node, .. } => Place::Node(*node, "x"),
                TrackError::UnknownNode { edge, end, .. } => match end {
                    EdgeEnd::From => Place::Edge(*edge, "from"),
                    EdgeEnd::To => Place::Edge(*edge, "to"),
                },
                TrackError::ZeroLength { edge, .. } => Place::Edge(*edge, "to"),
                TrackError::BadTurn { edge, .. } => Place::Edge(*edge, "turn_deg"),
                TrackError::BadWidth { edge, .. } => Place::Edge(*edge, "width_m"),
            },
            Problem::OutOfRange { place, .. } => *place,
            Problem::NodeOutside { node, .. } => Place::Node(*node, "x"),
            Problem::EdgeOutside { edge } => Place::Edge(*edge, "turn_deg"),
            Problem::ObstacleOutside { obstacle } => Place::Obstacle(*obstacle, "x"),
            Problem::RobotOutside { robot, .. } => Place::Robot(*robot, "x"),
            Problem::DuplicateRobot { robot, .. } => Place::Robot(*robot, "id"),
            Problem::RobotsOverlap { robot, .. } => Place::Robot(*robot, "x"),
            Problem::RobotOnObstacle { robot, .. } => Place::Robot(*robot, "x"),
            Problem::UnknownLinkProfile { .. } => Place::Link("profile"),
            Problem::TooManyRobots { .. } => Place::Robot(MAX_ROBOTS, "id"),
            Problem::BadFault { fault, key, .. } => Place::Fault(*fault, key),
        }
    }
}

fn require(ok: bool, place: Place, value: f64, expected: &'static str) -> Result<(), Problem> {
    if ok {
        Ok(())
    } else {
        Err(Problem::OutOfRange {
            place,
            value,
            expected,
        })
    }
}

/// Whether `v` is a finite number above zero.
fn positive(v: f64) -> bool {
    v.is_finite() && v > 0.0
}

/// Whether `v` is a finite number, zero or above.
fn non_negative(v: f64) -> bool {
    v.is_finite() && v >= 0.0
}

impl World {
    /// Checks everything [`Track::new`] cannot: sizes and ranges, that the tape, obstacles and
    /// robots fit inside the arena, unique robot ids, and that nothing starts on top of anything
    /// else. Returns the first problem found, in file order.
    pub fn validate(&self) -> Result<(), Problem> {
        self.validate_arena()?;
        self.validate_track()?;
        self.validate_obstacles()?;
        self.validate_robots()?;
        self.check_robot_overlap()?;
        self.validate_link_and_light()?;
        self.validate_faults()
    }

    /// Every declared fault is of a robot the world has.
    fn validate_faults(&self) -> Result<(), Problem> {
        for (i, f) in self.faults.iter().enumerate() {
            if !self.robots.iter().any(|r| r.id == f.robot) {
                return Err(Problem::BadFault {
                    fault: i,
                    key: "robot",
                    why: format!("the world has no robot {}", f.robot),
                });
            }
        }
        Ok(())
    }

    /// The arena's size.
    fn validate_arena(&self) -> Result<(), Problem> {
        let a = self.arena;
        require(
            positive(a.width_m) && a.width_m <= MAX_ARENA_M,
            Place::Arena("width_m"),
            a.width_m,
            "a positive width in metres, at most 100",
        )?;
        require(
            positive(a.height_m) && a.height_m <= MAX_ARENA_M,
            Place::Arena("height_m"),
            a.height_m,
            "a positive height in metres, at most 100",
        )?;
        Ok(())
    }

    /// The tape inside the arena: every node, and every arc along its length.
    fn validate_track(&self) -> Result<(), Problem> {
        let a = self.arena;
        for (i, n) in self.track.nodes().iter().enumerate() {
            if !a.contains(n.position, 0.0) {
                return Err(Problem::NodeOutside {
                    node: i,
                    id: n.id.clone(),
                    x: n.position.x,
                    y: n.position.y,
                });
            }
        }
        for (i, e) in self.track.edges().iter().enumerate() {
            if e.is_arc()
                && !self
                    .track
                    .polyline(i, 0.01)
                    .iter()
                    .all(|&p| a.contains(p, 0.0))
            {
                return Err(Problem::EdgeOutside { edge: i });
            }
        }
        Ok(())
    }

    /// Each obstacle's numbers, and its corners inside the arena.
    fn validate_obstacles(&self) -> Result<(), Problem> {
        let a = self.arena;
        for (i, o) in self.obstacles.iter().enumerate() {
            for (key, v) in [
                ("x", o.position.x),
                ("y", o.position.y),
                ("heading_deg", o.heading_rad.to_degrees()),
            ] {
                require(v.is_finite(), Place::Obstacle(i, key), v, "a finite number")?;
            }
            require(
                positive(o.width_m),
                Place::Obstacle(i, "width_m"),
                o.width_m,
                "a positive width in metres",
            )?;
            require(
                positive(o.height_m),
                Place::Obstacle(i, "height_m"),
                o.height_m,
                "a positive height in metres",
            )?;
            require(
                positive(o.mass_kg),
                Place::Obstacle(i, "mass_kg"),
                o.mass_kg,
                "a positive mass in kilograms",
            )?;
            require(
                non_negative(o.friction),
                Place::Obstacle(i, "friction"),
                o.friction,
                "a friction coefficient of 0 or more",
            )?;
            if !o.corners().iter().all(|&c| a.contains(c, 0.0)) {
                return Err(Problem::ObstacleOutside { obstacle: i });
            }
        }
        Ok(())
    }

    /// Each robot: a finite pose, a unique id, inside the arena, not on an obstacle.
    fn validate_robots(&self) -> Result<(), Problem> {
        if self.robots.len() > MAX_ROBOTS {
            return Err(Problem::TooManyRobots {
                count: self.robots.len(),
            });
        }
        let a = self.arena;
        let mut ids = HashSet::with_capacity(self.robots.len());
        for (i, r) in self.robots.iter().enumerate() {
            for (key, v) in [
                ("x", r.position.x),
                ("y", r.position.y),
                ("heading_deg", r.heading_rad.to_degrees()),
            ] {
                require(v.is_finite(), Place::Robot(i, key), v, "a finite number")?;
            }
            if !ids.insert(r.id) {
                return Err(Problem::DuplicateRobot { robot: i, id: r.id });
            }
            if !a.contains(r.position, ROBOT_RADIUS_M) {
                return Err(Problem::RobotOutside {
                    robot: i,
                    id: r.id,
                    x: r.position.x,
                    y: r.position.y,
                });
            }
            if let Some(obstacle) = self
                .obstacles
                .iter()
                .position(|o| o.contains(r.position, ROBOT_WIDTH_M / 2.0))
            {
                return Err(Problem::RobotOnObstacle {
                    robot: i,
                    id: r.id,
                    obstacle,
                });
            }
        }
        Ok(())
    }

    /// The link's and the light's ranges.
    fn validate_link_and_light(&self) -> Result<(), Problem> {
        self.link.validate()?;
        let g = self.light;
        require(
            (0.0..=1.0).contains(&g.ambient),
            Place::Light("ambient"),
            g.ambient,
            "a level in 0..=1",
        )?;
        require(
            non_negative(g.noise),
            Place::Light("noise"),
            g.noise,
            "0 or more",
        )?;
        Ok(())
    }

    /// Robots closer than a body width certainly overlap, whatever their headings. Sweeps along x
    /// so that tens of thousands of robots stay cheap.
    fn check_robot_overlap(&self) -> Result<(), Problem> {
        let mut order: Vec<usize> = (0..self.robots.len()).collect();
        order.sort_by(|&i, &j| {
            self.robots[i]
                .position
                .x
                .total_cmp(&self.robots[j].position.x)
        });
        for (k, &i) in order.iter().enumerate() {
            let ri = &self.robots[i];
            for &j in &order[k + 1..] {
                let rj = &self.robots[j];
                if rj.position.x - ri.position.x >= ROBOT_WIDTH_M {
                    break;
                }
                if (rj.position - ri.position).norm() < ROBOT_WIDTH_M {
                    // Report the one later in the file: that is where the user added the clash.
                    let (later, earlier) = if i > j { (ri, rj) } else { (rj, ri) };
                    return Err(Problem::RobotsOverlap {
                        robot: i.max(j),
                        id: later.id,
                        other_id: earlier.id,
                    });
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obstacle_corners_and_containment_follow_heading() {
        let o = Obstacle {
            position: Point2::new(1.0, 1.0),
            width_m: 0.2,
            height_m: 0.1,
            heading_rad: std::f64::consts::FRAC_PI_2,
            mass_kg: 0.1,
            friction: 0.5,
        };
        // Turned by 90°, the box is 0.1 wide along x and 0.2 along y.
        assert!(o.contains(Point2::new(1.0, 1.09), 0.0));
        assert!(!o.contains(Point2::new(1.09, 1.0), 0.0));
        let max_y = o.corners().iter().map(|c| c.y).fold(f64::MIN, f64::max);
        assert!((max_y - 1.1).abs() < 1e-12);
    }
}
