//! Building a simulation from a world and the options of a run: the arena's walls, a body for
//! each box, a body and booted firmware for each robot, the links' model and rapier's parameters.

use std::sync::Arc;

use firmware::Firmware;
use nalgebra::Vector2;
use protocol::settings::Settings;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rapier2d::prelude::*;

use super::contacts::Owner;
use super::{Pose, SimObstacle, SimRobot, Simulation};
use crate::board::{FloorView, SimBoard};
use crate::drive::WheelState;
use crate::ir::Grid;
use crate::link::{LinkModel, Piconet, SimLink};
use crate::spec::RobotSpec;
use crate::world::{RobotStart, World};

const WALL_THICKNESS: f32 = 0.02;

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

/// The longest substep of rapier's contact solver, seconds.
const SOLVER_SUBSTEP_S: f64 = 1.25e-3;

impl Simulation {
    /// Builds the world and boots every robot's firmware.
    pub fn new(world: World, config: SimConfig) -> Self {
        let seed = config.seed.or(world.seed).unwrap_or(1);
        let spec = config.spec;
        let mut bodies = RigidBodySet::new();
        let mut colliders = ColliderSet::new();
        let mut owners = Vec::new();
        add_walls(&world, &mut colliders, &mut owners);
        let obstacles = add_obstacles(&world, &mut bodies, &mut colliders, &mut owners);
        let robots = add_robots(
            &world,
            &spec,
            config.settings,
            seed,
            &mut bodies,
            &mut colliders,
            &mut owners,
        );
        owners.sort_by_key(|&(c, _)| c.into_raw_parts());
        let per = world.link.robots_per_piconet.max(1) as usize;
        let link_model = LinkModel {
            latency_s: world.link.latency_ms * 1e-3,
            jitter_s: world.link.jitter_ms * 1e-3,
            loss: world.link.loss,
            loss_burst_s: world.link.loss_burst_ms * 1e-3,
            bandwidth_bps: world.link.bandwidth_kbps * 1e3,
            robots_per_piconet: per,
        };
        let n_robots = robots.len();
        let piconets = vec![Piconet::default(); robots.len().div_ceil(per).max(1)];
        let params = integration_params(config.dt, config.physics_every);
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
}

/// The arena's four walls, fixed colliders just outside its border.
fn add_walls(
    world: &World,
    colliders: &mut ColliderSet,
    owners: &mut Vec<(ColliderHandle, Owner)>,
) {
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
}

/// A dynamic body for each box of the world, where the world puts it.
fn add_obstacles(
    world: &World,
    bodies: &mut RigidBodySet,
    colliders: &mut ColliderSet,
    owners: &mut Vec<(ColliderHandle, Owner)>,
) -> Vec<SimObstacle> {
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
            bodies,
        );
        owners.push((c, Owner::Obstacle(i)));
        obstacles.push(SimObstacle {
            body,
            start: o.position,
            friction: o.friction,
            half: [o.width_m * 0.5, o.height_m * 0.5],
        });
    }
    obstacles
}

/// A body for each robot of the world and its firmware booted on a board that sees the track;
/// each robot's noise stream is `seed` mixed with its id.
fn add_robots(
    world: &World,
    spec: &RobotSpec,
    settings: Settings,
    seed: u64,
    bodies: &mut RigidBodySet,
    colliders: &mut ColliderSet,
    owners: &mut Vec<(ColliderHandle, Owner)>,
) -> Vec<SimRobot> {
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
            bodies,
        );
        owners.push((c, Owner::Robot(i)));
        let mut settings = settings;
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
        robots.push(boot_robot(start, board, body, spec, stream));
    }
    robots
}

/// Robot `start` at power-on: its firmware booted on `board`, its body at rest, its link closed.
fn boot_robot(
    start: &RobotStart,
    board: SimBoard,
    body: RigidBodyHandle,
    spec: &RobotSpec,
    stream: u64,
) -> SimRobot {
    SimRobot {
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
        shove: None,
    }
}

/// Rapier's parameters for a physics step of `physics_every` clock steps of `dt`.
fn integration_params(dt: std::time::Duration, physics_every: u32) -> IntegrationParameters {
    let mut params = IntegrationParameters {
        dt: dt.as_secs_f32() * physics_every.max(1) as f32,
        ..IntegrationParameters::default()
    };
    // Centimetre scale: allowed penetration and sleep thresholds shrink to suit 48 mm robots.
    params.length_unit = 0.01;
    // The contact solver's substeps stay at most SOLVER_SUBSTEP_S long whatever the physics
    // rate: four at 200 and 250 Hz as before, one at 1 kHz, where four would be 0.25 ms
    // substeps for bodies that move 0.1 mm per step.
    params.num_solver_iterations =
        (f64::from(params.dt) / SOLVER_SUBSTEP_S).ceil().max(1.0) as usize;
    params
}

/// The direction `deg` degrees from the x axis as `[cos, sin]`.
fn unit_vector(deg: f64) -> [f64; 2] {
    let (s, c) = deg.to_radians().sin_cos();
    [c, s]
}
