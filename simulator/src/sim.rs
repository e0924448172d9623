//! The simulation: robots running the unmodified firmware on [`SimBoard`]s, their bodies in rapier2d,
//! boxes with floor friction, walls, IR light, links, a simulated clock and ground truth.
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

use std::sync::Arc;

use firmware::hal::{EncoderEdge, IrFrame, Wheel};
use firmware::{Firmware, Instant};
use nalgebra::{Point2, Vector2};
use protocol::settings::Settings;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rapier2d::prelude::*;
use rayon::prelude::*;

use crate::board::{FloorView, SimBoard};
use crate::drive::{inverse_mass_along, MotorStep, WheelState};
use crate::ir::{self, Beam, Grid, Obb, Scene};
use crate::link::{LinkModel, LinkStats, Piconet, SimLink};
use crate::spec::RobotSpec;
use crate::world::World;

const GRAVITY: f64 = 9.81;
const WALL_THICKNESS: f32 = 0.02;
/// Robot count from which per-robot work runs on every core; each robot touches only its own
/// state in those phases, so the result does not depend on the thread count.
const PARALLEL_FROM: usize = 256;

/// Options of a simulation run.
#[derive(Clone, Debug)]
pub struct SimConfig {
    /// Seed of every noise and jitter stream (the world's own seed when `None`).
    pub seed: Option<u64>,
    /// The clock's step: link packets, encoder edges and firmware deadlines are served on it.
    pub dt: std::time::Duration,
    /// Clock steps per physics step (motors, tyres, rapier, body sensors); 1 runs physics on
    /// every step. Between physics steps the line and colour sensors look at the floor where
    /// the body is at that instant, interpolated along the step.
    pub physics_every: u32,
    /// The robot model.
    pub spec: RobotSpec,
    /// Settings image every robot boots with (its id is set per robot).
    pub settings: Settings,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            seed: None,
            dt: std::time::Duration::from_millis(1),
            physics_every: 1,
            spec: RobotSpec::default(),
            settings: Settings::default(),
        }
    }
}

/// True pose of a robot or box: the host's pose type, so ground truth and estimates compare
/// directly.
pub use world::Pose;

/// Which pair of things touched.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ContactKind {
    /// Two robots (indices).
    RobotRobot(usize, usize),
    /// A robot and the arena wall.
    RobotWall(usize),
    /// A robot and a box (robot index, box index).
    RobotObstacle(usize, usize),
}

/// A contact that began at a time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    /// What touched.
    pub kind: ContactKind,
    /// When it began, seconds of simulated time.
    pub at_s: f64,
}

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

/// One simulated PocketBot2.
pub struct SimRobot {
    id: u16,
    firmware: Firmware<SimBoard>,
    body: RigidBodyHandle,
    wheels: [WheelState; 2],
    charge_ah: f64,
    temperature_c: f64,
    current_a: f64,
    last_velocity: Vector2<f64>,
    link: SimLink,
    connected: bool,
    distance_m: f64,
    pose: Pose,
    fault: Option<BodyFault>,
    last_host_packet_ns: Option<u64>,
    still_since_ns: Option<u64>,
    silences: Vec<HostSilence>,
    settings_updates: u32,
    /// Line sensor centre and heading's (sin, cos) at the start and the end of the physics step
    /// under way, for the floor to be looked at in between.
    sensor_path: [([f64; 2], (f64, f64)); 2],
    /// Frames the robot's IR LEDs sent this step and where each arrived, traced while it was
    /// served and delivered once every robot has been.
    lit: Vec<(IrFrame, Option<ir::Arrivals>)>,
}

/// The longest substep of rapier's contact solver, seconds.
const SOLVER_SUBSTEP_S: f64 = 1.25e-3;

/// How long the host must be silent before the simulator logs a [`HostSilence`]: well over the
/// host's ping period, under the firmware's default watchdog (500 ms).
pub const SILENCE_NS: u64 = 250_000_000;
/// A wheel whose rim moves slower than this counts as stopped, m/s.
pub const WHEEL_STOPPED_MPS: f64 = 0.001;

/// A time the host sent a robot nothing for at least [`SILENCE_NS`], and what the robot's body
/// did meanwhile (its wheels' true speeds, not what its encoders say).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HostSilence {
    /// When the last host packet before the silence reached the robot, simulated seconds.
    pub last_packet_s: f64,
    /// When the next one reached it, if one did.
    pub resumed_s: Option<f64>,
    /// When both wheels were first below [`WHEEL_STOPPED_MPS`] within the silence, if they were.
    pub wheels_stopped_s: Option<f64>,
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
    /// Keeps the log of host silences at `now_ns`; `packet` when a host packet arrived.
    fn watch_host(&mut self, now_ns: u64, packet: bool, radius_m: f64) {
        let still = self
            .wheels
            .iter()
            .all(|w| (w.omega * radius_m).abs() < WHEEL_STOPPED_MPS);
        self.still_since_ns = if still {
            self.still_since_ns.or(Some(now_ns))
        } else {
            None
        };
        let seconds = |ns: u64| ns as f64 * 1e-9;
        if packet {
            if let Some(s) = self.silences.last_mut().filter(|s| s.resumed_s.is_none()) {
                s.resumed_s = Some(seconds(now_ns));
            }
            self.last_host_packet_ns = Some(now_ns);
            return;
        }
        let Some(last) = self.last_host_packet_ns else {
            return;
        };
        match self.silences.last_mut().filter(|s| s.resumed_s.is_none()) {
            Some(s) if s.wheels_stopped_s.is_none() => {
                s.wheels_stopped_s = self.still_since_ns.map(seconds);
            }
            Some(_) => {}
            None if now_ns - last >= SILENCE_NS => self.silences.push(HostSilence {
                last_packet_s: seconds(last),
                resumed_s: None,
                // Wheels that stood before the silence began stopped, for it, when it began.
                wheels_stopped_s: self.still_since_ns.map(|t| seconds(t.max(last))),
            }),
            None => {}
        }
    }
    /// Puts the line sensor where the body is at `now_ns` within the physics step from `start`
    /// to `end`, along a straight line between its ends: a step is a few millimetres at most.
    fn place_floor_sensor(&mut self, now_ns: u64, start: u64, end: u64) {
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

struct SimObstacle {
    body: RigidBodyHandle,
    start: Point2<f64>,
    friction: f64,
    half: [f64; 2],
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Owner {
    Robot(usize),
    Obstacle(usize),
    Wall,
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
    /// Builds the world and boots every robot's firmware.
    pub fn new(world: World, config: SimConfig) -> Self {
        let seed = config.seed.or(world.seed).unwrap_or(1);
        let spec = config.spec;
        let mut bodies = RigidBodySet::new();
        let mut colliders = ColliderSet::new();
        let mut owners = Vec::new();
        let (w, h) = (world.arena.width_m as f32, world.arena.height_m as f32);
        for (cx, cy, hx, hy) in [
            (
                w * 0.5,
                -WALL_THICKNESS,
                w * 0.5 + 2.0 * WALL_THICKNESS,
                WALL_THICKNESS,
            ),
            (
                w * 0.5,
                h + WALL_THICKNESS,
                w * 0.5 + 2.0 * WALL_THICKNESS,
                WALL_THICKNESS,
            ),
            (
                -WALL_THICKNESS,
                h * 0.5,
                WALL_THICKNESS,
                h * 0.5 + 2.0 * WALL_THICKNESS,
            ),
            (
                w + WALL_THICKNESS,
                h * 0.5,
                WALL_THICKNESS,
                h * 0.5 + 2.0 * WALL_THICKNESS,
            ),
        ] {
            let c = colliders.insert(
                ColliderBuilder::cuboid(hx, hy)
                    .translation(vector![cx, cy])
                    .friction(0.3)
                    .build(),
            );
            owners.push((c, Owner::Wall));
        }
        let mut obstacles = Vec::new();
        for (i, o) in world.obstacles.iter().enumerate() {
            let body = bodies.insert(
                RigidBodyBuilder::dynamic()
                    .translation(vector![o.position.x as f32, o.position.y as f32])
                    .rotation(o.heading_rad as f32)
                    .can_sleep(false)
                    .build(),
            );
            let c = colliders.insert_with_parent(
                ColliderBuilder::cuboid(o.width_m as f32 * 0.5, o.height_m as f32 * 0.5)
                    .mass(o.mass_kg as f32)
                    .friction(0.4)
                    .restitution(0.0)
                    .build(),
                body,
                &mut bodies,
            );
            owners.push((c, Owner::Obstacle(i)));
            obstacles.push(SimObstacle {
                body,
                start: o.position,
                friction: o.friction,
                half: [o.width_m * 0.5, o.height_m * 0.5],
            });
        }
        let track = Arc::new(world.track.clone());
        let colour_scale = 1000.0 * (0.8 + 0.4 * world.light.ambient as f32);
        let mut robots = Vec::new();
        for (i, start) in world.robots.iter().enumerate() {
            let body = bodies.insert(
                RigidBodyBuilder::dynamic()
                    .translation(vector![start.position.x as f32, start.position.y as f32])
                    .rotation(start.heading_rad as f32)
                    .can_sleep(false)
                    .build(),
            );
            let c = colliders.insert_with_parent(
                ColliderBuilder::cuboid(spec.length_m as f32 * 0.5, spec.width_m as f32 * 0.5)
                    .mass(spec.mass_kg as f32)
                    .friction(0.3)
                    .restitution(0.0)
                    .build(),
                body,
                &mut bodies,
            );
            owners.push((c, Owner::Robot(i)));
            let mut settings = config.settings;
            settings.identity.robot_id = start.id;
            let stream = seed ^ (u64::from(start.id) << 32);
            let mut board = SimBoard::new(
                Some(settings.as_bytes().to_vec()),
                ChaCha8Rng::seed_from_u64(stream),
            );
            board.ambient = world.light.ambient as f32;
            board.noise = world.light.noise as f32;
            board.line_gain = spec.line_gain as f32;
            board.ambient_gain = spec.ambient_gain as f32;
            board.floor = Some(FloorView::new(
                Arc::clone(&track),
                [start.position.x, start.position.y],
                start.heading_rad.sin_cos(),
                spec.spot_pitch_m,
                colour_scale,
            ));
            robots.push(SimRobot {
                id: start.id,
                firmware: Firmware::new(board),
                body,
                wheels: [WheelState::default(); 2],
                charge_ah: spec.battery.capacity_ah * spec.battery.initial_charge,
                temperature_c: 25.0,
                current_a: spec.battery.idle_a,
                last_velocity: Vector2::zeros(),
                link: SimLink::new(ChaCha8Rng::seed_from_u64(stream ^ 0x5EED)),
                connected: false,
                distance_m: 0.0,
                pose: Pose {
                    x: start.position.x,
                    y: start.position.y,
                    theta: start.heading_rad,
                },
                fault: None,
                last_host_packet_ns: None,
                still_since_ns: None,
                silences: Vec::new(),
                settings_updates: 0,
                sensor_path: [(
                    [start.position.x, start.position.y],
                    start.heading_rad.sin_cos(),
                ); 2],
                lit: Vec::new(),
            });
        }
        owners.sort_by_key(|&(c, _)| c.into_raw_parts());
        let per = world.link.robots_per_piconet.max(1) as usize;
        let link_model = LinkModel {
            latency_s: world.link.latency_ms * 1e-3,
            jitter_s: world.link.jitter_ms * 1e-3,
            loss: world.link.loss,
            bandwidth_bps: world.link.bandwidth_kbps * 1e3,
            robots_per_piconet: per,
        };
        let n_robots = robots.len();
        let piconets = vec![Piconet::default(); robots.len().div_ceil(per).max(1)];
        let mut params = IntegrationParameters {
            dt: config.dt.as_secs_f32() * config.physics_every.max(1) as f32,
            ..IntegrationParameters::default()
        };
        // Centimetre scale: allowed penetration and sleep thresholds shrink to suit 48 mm robots.
        params.length_unit = 0.01;
        // The contact solver's substeps stay at most SOLVER_SUBSTEP_S long whatever the physics
        // rate: four at 200 and 250 Hz as before, one at 1 kHz, where four would be 0.25 ms
        // substeps for bodies that move 0.1 mm per step.
        params.num_solver_iterations =
            (f64::from(params.dt) / SOLVER_SUBSTEP_S).ceil().max(1.0) as usize;
        let ir_leds = spec.ir_led_angle_deg.map(unit_vector);
        let ir_cone_half = unit_vector(spec.ir_cone_half_deg);
        let mut sim = Self {
            obstacle_boxes: Vec::with_capacity(obstacles.len()),
            robot_boxes: Vec::with_capacity(robots.len()),
            world,
            spec,
            link_model,
            dt_ns: config.dt.as_nanos() as u64,
            now_ns: 0,
            physics_every: u64::from(config.physics_every.max(1)),
            physics_span: (0, 0),
            robots,
            obstacles,
            piconets,
            bodies,
            colliders,
            owners,
            pipeline: PhysicsPipeline::new(),
            params,
            islands: IslandManager::new(),
            broad_phase: DefaultBroadPhase::new(),
            narrow_phase: NarrowPhase::new(),
            impulse_joints: ImpulseJointSet::new(),
            multibody_joints: MultibodyJointSet::new(),
            ccd: CCDSolver::new(),
            grid: Grid::default(),
            active_contacts: Vec::new(),
            contacts: Vec::new(),
            served: vec![0; n_robots],
            host_due_ns: vec![u64::MAX; n_robots],
            ir_leds,
            ir_cone_half,
        };
        sim.read_sensors();
        sim
    }

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

    /// Every contact that began so far.
    pub fn contacts(&self) -> &[Contact] {
        &self.contacts
    }

    /// Robot–robot contacts that began so far.
    pub fn robot_collisions(&self) -> usize {
        self.contacts
            .iter()
            .filter(|c| matches!(c.kind, ContactKind::RobotRobot(..)))
            .count()
    }

    /// The host end of robot `i`'s link opens: the robot sends its hello.
    pub fn connect(&mut self, i: usize) {
        let now = Instant::from_nanos(self.now_ns);
        let r = &mut self.robots[i];
        r.connected = true;
        r.firmware.on_link_connected(now);
        self.flush_outgoing(i);
    }

    /// The host end of robot `i`'s link closes; the robot's packets go nowhere, and what either
    /// side had queued is discarded so the next host starts afresh.
    pub fn disconnect(&mut self, i: usize) {
        let r = &mut self.robots[i];
        r.connected = false;
        r.link.host_closed();
    }

    /// Counts packets a host-side buffer of robot `i`'s link discarded when its host left.
    pub fn count_discarded_on_close(&mut self, i: usize, packets: u64) {
        self.robots[i].link.count_discarded_on_close(packets);
    }

    /// Accounts for a host-side buffer of robot `i`'s link: the packets it dropped for being full
    /// towards the robot (`to_robot`) and towards the host, as (packets, bytes), and the most bytes
    /// it held at once.
    pub fn note_host_buffer(
        &mut self,
        i: usize,
        to_robot: (u64, u64),
        to_host: (u64, u64),
        peak_bytes: usize,
    ) {
        let link = &mut self.robots[i].link;
        link.count_overflow_to_robot(to_robot.0, to_robot.1);
        link.count_overflow_to_host(to_host.0, to_host.1);
        link.note_host_buffer_peak(peak_bytes);
    }

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

    /// The host sends one packet to robot `i`.
    pub fn host_send(&mut self, i: usize, packet: Vec<u8>) {
        let per = self.link_model.robots_per_piconet;
        let r = &mut self.robots[i];
        r.link.send_to_robot(
            self.now_ns,
            packet,
            &self.link_model,
            &mut self.piconets[i / per],
        );
    }

    /// The next packet from robot `i` that has arrived at the host.
    pub fn host_recv(&mut self, i: usize) -> Option<Vec<u8>> {
        if *self.host_due_ns.get(i)? > self.now_ns {
            return None;
        }
        let link = &mut self.robots[i].link;
        let p = link.recv_at_host(self.now_ns);
        self.host_due_ns[i] = link.next_at_host().unwrap_or(u64::MAX);
        p
    }

    /// Runs `steps` steps.
    pub fn run_steps(&mut self, steps: u64) {
        for _ in 0..steps {
            self.step();
        }
    }

    /// Runs for at least `d` of simulated time.
    pub fn run_for(&mut self, d: std::time::Duration) {
        let end = self.now_ns + d.as_nanos() as u64;
        while self.now_ns < end {
            self.step();
        }
    }

    /// Length of one physics step, nanoseconds.
    fn physics_dt_ns(&self) -> u64 {
        self.dt_ns * self.physics_every
    }

    /// Advances the world by one step of the clock.
    pub fn step(&mut self) {
        if self.robots.len() >= PARALLEL_FROM && rayon::current_thread_index().is_none() {
            // One hand-over to the pool per step instead of one per parallel pass: the caller
            // sleeps once, and the passes split between workers that are already awake.
            rayon::scope(|_| self.step_in_pool());
        } else {
            self.step_in_pool();
        }
    }

    fn step_in_pool(&mut self) {
        // Physics starts on the step after the firmware's boot tick and every `physics_every`
        // steps from there, so a duty the main loop sets on its period moves the body at once.
        let k = self.physics_every;
        if (self.now_ns / self.dt_ns) % k == 1 % k {
            self.physics_step();
        }
        self.now_ns += self.dt_ns;
        self.serve_firmware();
    }

    /// Motors, tyres, rapier and box friction over one physics step from now, then the body
    /// sensors at its end.
    fn physics_step(&mut self) {
        let dt = self.physics_dt_ns() as f64 * 1e-9;
        let t0 = self.now_ns;
        self.physics_span = (t0, t0 + self.physics_dt_ns());
        let spec = &self.spec;
        let bodies = &self.bodies;
        let clock_dt = self.dt_ns as f64 * 1e-9;
        let substeps = self.physics_every as u32;
        let drive =
            |r: &mut SimRobot| drive_robot(spec, r, &bodies[r.body], t0, clock_dt, substeps);
        let drives: Vec<Drive> = if self.robots.len() >= PARALLEL_FROM {
            self.robots.par_iter_mut().map(drive).collect()
        } else {
            self.robots.iter_mut().map(drive).collect()
        };
        for (r, d) in self.robots.iter().zip(&drives) {
            let (v, w) = d.set;
            let body = &mut self.bodies[r.body];
            body.set_linvel(vector![v[0] as f32, v[1] as f32], true);
            body.set_angvel(w as f32, true);
        }
        let obstacle_start: Vec<(Vector<Real>, Real)> = self
            .obstacles
            .iter()
            .map(|o| {
                let b = &self.bodies[o.body];
                (*b.translation(), b.rotation().angle())
            })
            .collect();
        self.pipeline.step(
            &vector![0.0, 0.0],
            &self.params,
            &mut self.islands,
            &mut self.broad_phase,
            &mut self.narrow_phase,
            &mut self.bodies,
            &mut self.colliders,
            &mut self.impulse_joints,
            &mut self.multibody_joints,
            &mut self.ccd,
            &(),
            &(),
        );
        if substeps > 1 {
            // Rapier moved each body with the sub-steps' mean velocity; it goes on from their
            // last, with whatever rapier's contacts changed.
            for (r, d) in self.robots.iter().zip(&drives) {
                let body = &mut self.bodies[r.body];
                let (set, end) = (d.set, d.end);
                let v = body.linvel();
                let w = body.angvel();
                body.set_linvel(
                    vector![
                        (end.0[0] + (f64::from(v.x) - set.0[0])) as f32,
                        (end.0[1] + (f64::from(v.y) - set.0[1])) as f32
                    ],
                    true,
                );
                body.set_angvel((end.1 + (f64::from(w) - set.1)) as f32, true);
            }
        }
        self.floor_friction(&obstacle_start, dt);
        self.record_contacts(t0 + self.dt_ns);
        self.read_sensors();
    }

    /// Serves every firmware at the clock's new time: link packets, encoder edges that have
    /// happened, and a tick where one of its deadlines is due; then IR and outgoing packets.
    fn serve_firmware(&mut self) {
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
            let mut heard = false;
            while let Some(p) = r.link.recv_at_robot(now_ns) {
                if p.get(1) == Some(&(protocol::PacketType::SettingsUpdate as u8)) {
                    r.settings_updates += 1;
                }
                r.firmware.on_link_packet(now, &p);
                heard = true;
            }
            r.watch_host(now_ns, heard, radius_m);
            // Edges reach the firmware as its capture interrupt would: once they have happened.
            // Most steps have none waiting.
            if !r.firmware.board().edges.is_empty() {
                let mut edges = std::mem::take(&mut r.firmware.board_mut().edges);
                edges.retain(|e| {
                    let happened = e.at <= edges_until;
                    if happened {
                        r.firmware.on_encoder_edge(e.wheel, e.at);
                    }
                    !happened
                });
                r.firmware.board_mut().edges = edges;
            }
            if r.firmware.next_deadline().is_some_and(|d| d <= now) {
                if interpolate {
                    r.place_floor_sensor(now_ns, span_start, span_end);
                }
                r.firmware.tick(now);
            }
            // Beams only read the scene, which moves only on physics steps: traced here, on
            // whichever core serves the sender, and delivered below in the robots' order.
            let board = r.firmware.board_mut();
            if !board.ir_out.is_empty() {
                let lit = &mut r.lit;
                lit.extend(
                    board
                        .ir_out
                        .drain(..)
                        .map(|(led, power, frame)| (frame, trace(i, led, power))),
                );
            }
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

    fn flush_outgoing(&mut self, i: usize) {
        let per = self.link_model.robots_per_piconet;
        let r = &mut self.robots[i];
        while let Some(p) = r.firmware.pop_packet() {
            if r.connected {
                r.link.send_to_host(
                    self.now_ns,
                    p.to_vec(),
                    &self.link_model,
                    &mut self.piconets[i / per],
                );
            }
        }
        if let Some(at) = r.link.next_at_host() {
            self.host_due_ns[i] = self.host_due_ns[i].min(at);
        }
    }

    /// Coulomb floor friction of boxes: removes up to μ·g·dt of speed and redoes the position
    /// update with what is left, so a push weaker than static friction moves nothing.
    fn floor_friction(&mut self, start: &[(Vector<Real>, Real)], dt: f64) {
        for (o, &(p0, a0)) in self.obstacles.iter().zip(start) {
            let b = &mut self.bodies[o.body];
            let v = [f64::from(b.linvel().x), f64::from(b.linvel().y)];
            let speed = v[0].hypot(v[1]);
            let dv = o.friction * GRAVITY * dt;
            let keep = if speed > dv {
                (speed - dv) / speed
            } else {
                0.0
            };
            let v1 = [v[0] * keep, v[1] * keep];
            // Dry friction over the footprint: torque ≈ μ·m·g·r̄ with r̄ about a third of the diagonal.
            let mass = f64::from(b.mass());
            let inertia = f64::from(b.mass_properties().effective_angular_inertia());
            let r_mean = o.half[0].hypot(o.half[1]) * 2.0 / 3.0;
            let dw = if inertia > 0.0 {
                o.friction * mass * GRAVITY * r_mean * dt / inertia
            } else {
                0.0
            };
            let w = f64::from(b.angvel());
            let w1 = if w.abs() > dw {
                w - dw * w.signum()
            } else {
                0.0
            };
            b.set_linvel(vector![v1[0] as f32, v1[1] as f32], true);
            b.set_angvel(w1 as f32, true);
            b.set_translation(
                vector![p0.x + (v1[0] * dt) as f32, p0.y + (v1[1] * dt) as f32],
                true,
            );
            b.set_rotation(Rotation::new(a0 + (w1 * dt) as f32), true);
        }
    }

    fn owner(&self, c: ColliderHandle) -> Option<Owner> {
        self.owners
            .binary_search_by_key(&c.into_raw_parts(), |&(h, _)| h.into_raw_parts())
            .ok()
            .map(|k| self.owners[k].1)
    }

    fn record_contacts(&mut self, now_ns: u64) {
        let mut now_active = Vec::new();
        for pair in self.narrow_phase.contact_pairs() {
            if !pair.has_any_active_contact {
                continue;
            }
            let (Some(a), Some(b)) = (self.owner(pair.collider1), self.owner(pair.collider2))
            else {
                continue;
            };
            let kind = match (a, b) {
                (Owner::Robot(x), Owner::Robot(y)) => ContactKind::RobotRobot(x.min(y), x.max(y)),
                (Owner::Robot(x), Owner::Wall) | (Owner::Wall, Owner::Robot(x)) => {
                    ContactKind::RobotWall(x)
                }
                (Owner::Robot(x), Owner::Obstacle(o)) | (Owner::Obstacle(o), Owner::Robot(x)) => {
                    ContactKind::RobotObstacle(x, o)
                }
                _ => continue,
            };
            now_active.push(kind);
        }
        now_active.sort();
        now_active.dedup();
        let at_s = now_ns as f64 * 1e-9;
        for k in &now_active {
            if self.active_contacts.binary_search(k).is_err() {
                self.contacts.push(Contact { kind: *k, at_s });
            }
        }
        self.active_contacts = now_active;
    }

    /// Reads every robot's sensors off the world at the current time.
    fn read_sensors(&mut self) {
        let dt = self.physics_dt_ns() as f64 * 1e-9;
        let spec = &self.spec;
        let battery = &spec.battery;
        let bodies = &self.bodies;
        let sense = |r: &mut SimRobot| -> Obb {
            let b = &bodies[r.body];
            let x = f64::from(b.translation().x);
            let y = f64::from(b.translation().y);
            let theta_wrapped = f64::from(b.rotation().angle());
            let dtheta =
                world::wrap_angle(theta_wrapped - r.pose.theta.rem_euclid(std::f64::consts::TAU));
            let (dx, dy) = (x - r.pose.x, y - r.pose.y);
            r.distance_m += (dx * dx + dy * dy).sqrt();
            r.pose = Pose {
                x,
                y,
                theta: r.pose.theta + dtheta,
            };
            let (s, c) = theta_wrapped.sin_cos();
            let vel = Vector2::new(f64::from(b.linvel().x), f64::from(b.linvel().y));
            let acc = (vel - r.last_velocity) / dt;
            r.last_velocity = vel;
            let sensor = [
                x + c * spec.line_sensor_ahead_m,
                y + s * spec.line_sensor_ahead_m,
            ];
            r.sensor_path = [r.sensor_path[1], (sensor, (s, c))];
            let board = r.firmware.board_mut();
            board.place_floor_sensor(sensor, (s, c));
            let to_mg = |a: f64| (a / GRAVITY * 1000.0).clamp(-32000.0, 32000.0) as i16;
            board.accel = [
                to_mg(acc.x * c + acc.y * s),
                to_mg(-acc.x * s + acc.y * c),
                1000,
            ];
            let soc = (r.charge_ah / battery.capacity_ah).clamp(0.0, 1.0);
            let open = battery.empty_v + (battery.full_v - battery.empty_v) * soc;
            let volts = (open - r.current_a * battery.internal_ohm).max(0.0);
            board.battery_mv = (volts * 1000.0) as u16;
            board.current_ma = (r.current_a * 1000.0).min(32000.0) as i16;
            // Self-heating towards 25 °C + 40 °C/A with a one-minute time constant.
            r.temperature_c += (25.0 + 40.0 * r.current_a - r.temperature_c) * dt / 60.0;
            board.temperature_dc = (r.temperature_c * 10.0) as i16;
            Obb::new(
                [x, y],
                [spec.length_m * 0.5, spec.width_m * 0.5],
                theta_wrapped,
            )
        };
        if self.robots.len() >= PARALLEL_FROM {
            self.robots
                .par_iter_mut()
                .map(sense)
                .collect_into_vec(&mut self.robot_boxes);
        } else {
            self.robot_boxes.clear();
            self.robot_boxes.extend(self.robots.iter_mut().map(sense));
        }
        self.obstacle_boxes.clear();
        for o in &self.obstacles {
            let b = &self.bodies[o.body];
            self.obstacle_boxes.push(Obb::new(
                [f64::from(b.translation().x), f64::from(b.translation().y)],
                o.half,
                f64::from(b.rotation().angle()),
            ));
        }
        let arena = &self.world.arena;
        let cell = self.spec.ir_range_m.iter().cloned().fold(0.05, f64::max) + 0.01;
        self.grid.rebuild(
            arena.width_m,
            arena.height_m,
            cell,
            self.robot_boxes.iter().map(|b| b.center),
        );
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

/// The direction `deg` degrees from the x axis as `[cos, sin]`.
fn unit_vector(deg: f64) -> [f64; 2] {
    let (s, c) = deg.to_radians().sin_cos();
    [c, s]
}

/// What the drive train did to one robot's body over a physics step.
#[derive(Clone, Copy, Debug)]
struct Drive {
    /// Linear and angular velocity rapier moves the body with over the step: the sub-steps'
    /// displacement divided by the step's length.
    set: ([f64; 2], f64),
    /// Velocity the sub-steps ended with, for the body once rapier has stepped.
    end: ([f64; 2], f64),
}

/// Motors, tyres and encoders of one robot over a physics step of `substeps` clock steps of
/// `dt` each, starting at `t0`.
///
/// The drive train is integrated on the clock step whatever the physics rate: between contacts a
/// robot's body moves only as its tyres push it, so the sub-steps carry its heading and position
/// forward themselves and hand rapier the step's displacement as a velocity. A coarser physics
/// step then coarsens only the contacts, not the coupling of motor, wheel and body.
fn drive_robot(
    spec: &RobotSpec,
    r: &mut SimRobot,
    body: &RigidBody,
    t0: u64,
    dt: f64,
    substeps: u32,
) -> Drive {
    let pwm = r.firmware.board().pwm;
    let step = dt * f64::from(substeps);
    let v_body = [f64::from(body.linvel().x), f64::from(body.linvel().y)];
    let w_body = f64::from(body.angvel());
    let still = |w: &WheelState| w.omega == 0.0 && w.current_a == 0.0;
    if pwm == (0, 0) && r.wheels.iter().all(still) && v_body == [0.0; 2] && w_body == 0.0 {
        // At rest with the motors off nothing turns, pushes or draws current: the step would
        // compute zeros. Only the battery's idle drain goes on.
        drain_battery(spec, r, pwm, step);
        return Drive {
            set: (v_body, w_body),
            end: (v_body, w_body),
        };
    }
    let volts = f64::from(r.firmware.board().battery_mv) / 1000.0;
    let mass = f64::from(body.mass());
    let inertia = f64::from(body.mass_properties().effective_angular_inertia());
    let (mut s, mut c) = f64::from(body.rotation().angle()).sin_cos();
    // The wheels' effective masses depend on where they sit on the body, not on its heading.
    let arms = [1.0f64, -1.0].map(|side| {
        let half = side * spec.wheel_gauge_m * 0.5;
        [
            c * spec.axle_offset_m - s * half,
            s * spec.axle_offset_m + c * half,
        ]
    });
    let radius = spec.wheel_radius_m();
    let wheel_k = radius * radius / spec.motor.inertia;
    let fixed = DriveStep {
        spec,
        radius,
        inv_mass: 1.0 / mass,
        inv_inertia: 1.0 / inertia,
        k: arms.map(|arm| {
            let k_long = inverse_mass_along(mass, inertia, arm, [c, s]);
            let k_lat = inverse_mass_along(mass, inertia, arm, [-s, c]);
            InverseMass {
                long: 1.0 / k_long,
                lat: 1.0 / k_lat,
                shared: 1.0 / (k_long + wheel_k),
            }
        }),
        tyre_spin: radius / spec.motor.inertia,
        grip: spec.tyre_friction * mass * GRAVITY * 0.5 * dt,
        motor: [pwm.0, pwm.1]
            .map(|duty| MotorStep::new(&spec.motor, f64::from(duty) / 1000.0, volts, dt)),
        volts,
        pwm,
        jammed: r.fault == Some(BodyFault::JammedWheels),
        counting: r.fault != Some(BodyFault::DeadEncoders),
        dt,
    };
    let mut v = v_body;
    let mut omega = w_body;
    let (mut moved, mut turned) = ([0.0f64; 2], 0.0f64);
    for k in 0..substeps {
        if k > 0 {
            // Turned by the last sub-step's δ = ω·dt, at most a few degrees: the series is exact
            // to 1e-9 there.
            let d = omega * dt;
            let d2 = d * d;
            let (sd, cd) = (d * (1.0 - d2 / 6.0), 1.0 - d2 * 0.5 * (1.0 - d2 / 12.0));
            (s, c) = (s * cd + c * sd, c * cd - s * sd);
        }
        let t = t0 as f64 * 1e-9 + f64::from(k) * dt;
        (v, omega) = fixed.substep(r, (s, c), (v, omega), t);
        // As rapier integrates: the new velocity over the whole sub-step.
        moved[0] += v[0] * dt;
        moved[1] += v[1] * dt;
        turned += omega * dt;
    }
    drain_battery(spec, r, pwm, step);
    let set = if substeps == 1 {
        (v, omega)
    } else {
        ([moved[0] / step, moved[1] / step], turned / step)
    };
    Drive {
        set,
        end: (v, omega),
    }
}

/// Reciprocals of the inverse effective masses at one wheel's contact patch.
struct InverseMass {
    /// Along the heading, of the body alone.
    long: f64,
    /// Across the heading.
    lat: f64,
    /// Along the heading, of the body and the wheel's rim sharing the impulse.
    shared: f64,
}

/// What stays fixed over a physics step's clock steps of one robot's drive train, with the
/// divisions done once: the sub-steps are chains of dependent operations.
struct DriveStep<'a> {
    spec: &'a RobotSpec,
    radius: f64,
    inv_mass: f64,
    inv_inertia: f64,
    k: [InverseMass; 2],
    /// Wheel speed lost per unit of tyre impulse, radius / wheel inertia.
    tyre_spin: f64,
    /// Largest impulse one tyre transmits in a clock step, μ·m·g/2·dt.
    grip: f64,
    motor: [MotorStep; 2],
    volts: f64,
    pwm: (i16, i16),
    jammed: bool,
    counting: bool,
    dt: f64,
}

impl DriveStep<'_> {
    /// One clock step of motors, tyres and encoders from the body's velocity `(v, omega)` with
    /// its heading's `(sin, cos)`, starting at `t0_s`; returns the body's new velocity.
    fn substep(
        &self,
        r: &mut SimRobot,
        (s, c): (f64, f64),
        (mut v, mut omega): ([f64; 2], f64),
        t0_s: f64,
    ) -> ([f64; 2], f64) {
        let spec = self.spec;
        let dt = self.dt;
        let radius = self.radius;
        let omega_start = [r.wheels[0].omega, r.wheels[1].omega];
        for ((w, duty), motor) in r
            .wheels
            .iter_mut()
            .zip([self.pwm.0, self.pwm.1])
            .zip(&self.motor)
        {
            if self.jammed {
                w.jam(&spec.motor, f64::from(duty) / 1000.0, self.volts);
            } else {
                w.drive_with(&spec.motor, motor);
            }
        }
        let fwd = [c, s];
        let left = [-s, c];
        let grip = self.grip;
        for (k, side) in [(0usize, 1.0f64), (1, -1.0)] {
            let half = side * spec.wheel_gauge_m * 0.5;
            let arm = [
                fwd[0] * spec.axle_offset_m + left[0] * half,
                fwd[1] * spec.axle_offset_m + left[1] * half,
            ];
            let vp = [v[0] - omega * arm[1], v[1] + omega * arm[0]];
            let ground_long = vp[0] * fwd[0] + vp[1] * fwd[1];
            let ground_lat = vp[0] * left[0] + vp[1] * left[1];
            let inv_k = &self.k[k];
            let wheel = &mut r.wheels[k];
            // A blocked wheel is part of the chassis: the tyre brakes the body alone. A turning
            // one is gripped so that the contact point moves with the rim, the impulse shared
            // between the body and the wheel.
            let mut j_long = if self.jammed {
                -ground_long * inv_k.long
            } else {
                (wheel.rim_speed(radius) - ground_long) * inv_k.shared
            };
            let mut j_lat = -ground_lat * inv_k.lat;
            // The tyre transmits at most μ·N: a wheel asked for more slips. Squares compared
            // first, since the tyre holds in nearly every step and needs no root then.
            let total2 = j_long * j_long + j_lat * j_lat;
            if total2 > grip * grip {
                [j_long, j_lat] = slipping([j_long, j_lat], total2, grip);
            }
            if !self.jammed {
                wheel.omega -= j_long * self.tyre_spin;
            }
            let j = [
                fwd[0] * j_long + left[0] * j_lat,
                fwd[1] * j_long + left[1] * j_lat,
            ];
            v[0] += j[0] * self.inv_mass;
            v[1] += j[1] * self.inv_mass;
            omega += (arm[0] * j[1] - arm[1] * j[0]) * self.inv_inertia;
        }
        let counting = self.counting;
        let board = r.firmware.board_mut();
        for (k, wheel_id) in [(0usize, Wheel::Left), (1, Wheel::Right)] {
            let capture = spec.capture_hz;
            let edges = &mut board.edges;
            r.wheels[k].advance(spec, omega_start[k], dt, |frac| {
                if !counting {
                    return;
                }
                let t = t0_s + frac * dt;
                let ticks = (t * capture).round();
                let at = Instant::from_nanos((ticks / capture * 1e9).round() as u64);
                edges.push_back(EncoderEdge {
                    wheel: wheel_id,
                    at,
                });
            });
        }
        (v, omega)
    }
}

/// A tyre's impulse `j` (squared length `total2`) cut to the largest it can transmit, `grip`.
///
/// Out of line, so that the compiler branches around the root and the division rather than
/// computing them in every sub-step as a select: they would then stand on the sub-step's chain of
/// dependent operations.
#[cold]
#[inline(never)]
fn slipping(j: [f64; 2], total2: f64, grip: f64) -> [f64; 2] {
    let scale = grip / total2.sqrt();
    [j[0] * scale, j[1] * scale]
}

/// The current the robot draws over the step (idle plus each motor's share of its duty), and
/// the charge it takes from the battery.
fn drain_battery(spec: &RobotSpec, r: &mut SimRobot, pwm: (i16, i16), dt: f64) {
    let motor_a: f64 = r
        .wheels
        .iter()
        .zip([pwm.0, pwm.1])
        .map(|(w, d)| (w.current_a * f64::from(d) / 1000.0).abs())
        .sum();
    r.current_a = spec.battery.idle_a + motor_a;
    r.charge_ah = (r.charge_ah - r.current_a * dt / 3600.0).max(0.0);
}
