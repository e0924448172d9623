//! The simulation: robots running the unmodified firmware on [`SimBoard`](crate::board::SimBoard)s,
//! their bodies in rapier2d, boxes with floor friction, walls, IR light, links, a simulated clock
//! and ground truth.
//!
//! One [`Simulation::step`] of `dt` (1 ms by default):
//! 1. each robot's motors integrate from the duty its firmware set, the tyres push its body within
//!    their grip, and the wheels' encoder stripes produce timestamped edges;
//! 2. rapier resolves contacts and integrates; box floor friction is applied to the result;
//! 3. the clock advances, sensors are read off the new world (floor under the line sensor, colour,
//!    acceleration, battery), due link packets are delivered, and every firmware `tick`s;
//! 4. IR frames the firmware transmitted travel to receivers; outgoing packets enter the links.
//!
//! Everything is a function of the world file and the seed: same seed, bit-identical run.

mod build;
mod contacts;
mod drivetrain;
mod faults;
mod host;
mod robot;
mod sensors;
mod serve;
mod step;

use nalgebra::Point2;
use rapier2d::prelude::*;

use crate::ir::{Grid, Obb};
use crate::link::{LinkModel, Piconet};
use crate::spec::RobotSpec;
use crate::world::World;
use contacts::Owner;

pub use build::SimConfig;
pub use contacts::{Contact, ContactKind};
pub use faults::{BodyFault, SHOVE_DURATION};
pub use host::{HostSilence, SILENCE_NS, WHEEL_STOPPED_MPS};
pub use robot::SimRobot;

const GRAVITY: f64 = 9.81;
/// Robot count from which per-robot work runs on every core; each robot touches only its own
/// state in those phases, so the result does not depend on the thread count.
const PARALLEL_FROM: usize = 256;

/// True pose of a robot or box: the host's pose type, so ground truth and estimates compare
/// directly.
pub use world::Pose;

struct SimObstacle {
    body: RigidBodyHandle,
    start: Point2<f64>,
    friction: f64,
    half: [f64; 2],
}

/// The whole simulated world.
pub struct Simulation {
    world: World,
    spec: RobotSpec,
    link_model: LinkModel,
    dt_ns: u64,
    now_ns: u64,
    physics_every: u64,
    /// Start and end of the physics step under way, nanoseconds.
    physics_span: (u64, u64),
    robots: Vec<SimRobot>,
    obstacles: Vec<SimObstacle>,
    piconets: Vec<Piconet>,
    bodies: RigidBodySet,
    colliders: ColliderSet,
    owners: Vec<(ColliderHandle, Owner)>,
    pipeline: PhysicsPipeline,
    params: IntegrationParameters,
    islands: IslandManager,
    broad_phase: DefaultBroadPhase,
    narrow_phase: NarrowPhase,
    impulse_joints: ImpulseJointSet,
    multibody_joints: MultibodyJointSet,
    ccd: CCDSolver,
    grid: Grid,
    robot_boxes: Vec<Obb>,
    obstacle_boxes: Vec<Obb>,
    active_contacts: Vec<ContactKind>,
    contacts: Vec<Contact>,
    /// Per robot, what its last serving left to pass on: [`OUTGOING`] and [`BEAMS`] bits.
    served: Vec<u8>,
    /// The IR LEDs' directions from the heading and the half-angle of their cone, as unit
    /// vectors `[cos, sin]`, so tracing a beam takes no trigonometry.
    ir_leds: [[f64; 2]; 6],
    ir_cone_half: [f64; 2],
    /// Per robot, the earliest time a packet could be due at the host (`u64::MAX`: none queued);
    /// never later than the truth, so the host's polls skip a robot's cold state when nothing
    /// can be due.
    host_due_ns: Vec<u64>,
}

/// [`Simulation::served`] bit: the firmware has packets to send.
const OUTGOING: u8 = 1;
/// [`Simulation::served`] bit: the firmware lit IR LEDs.
const BEAMS: u8 = 2;

impl Simulation {
    /// The world this simulation was built from.
    pub fn world(&self) -> &World {
        &self.world
    }

    /// The robot model.
    pub fn spec(&self) -> &RobotSpec {
        &self.spec
    }

    /// Simulated time since start.
    pub fn now(&self) -> std::time::Duration {
        std::time::Duration::from_nanos(self.now_ns)
    }

    /// The step length.
    pub fn dt(&self) -> std::time::Duration {
        std::time::Duration::from_nanos(self.dt_ns)
    }

    /// Every robot, in world-file order.
    pub fn robots(&self) -> &[SimRobot] {
        &self.robots
    }

    /// Index of the robot with `id`.
    pub fn robot_index(&self, id: u16) -> Option<usize> {
        self.robots.iter().position(|r| r.id == id)
    }

    /// True pose of each box.
    pub fn obstacle_poses(&self) -> Vec<Pose> {
        self.obstacles
            .iter()
            .map(|o| {
                let b = &self.bodies[o.body];
                Pose {
                    x: f64::from(b.translation().x),
                    y: f64::from(b.translation().y),
                    theta: f64::from(b.rotation().angle()),
                }
            })
            .collect()
    }

    /// How far each box moved from where it started, metres.
    pub fn obstacle_displacements(&self) -> Vec<f64> {
        self.obstacles
            .iter()
            .zip(self.obstacle_poses())
            .map(|(o, p)| (p.x - o.start.x).hypot(p.y - o.start.y))
            .collect()
    }
}
