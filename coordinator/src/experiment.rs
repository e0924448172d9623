//! One supervised experiment: robots from the simulator or from addresses, robot actors, the
//! supervisor and the behaviour, run until the behaviour's verdict, the time limit or Ctrl-C, then a
//! report with ground truth where there is one.

use std::sync::Arc;
use std::time::Duration;

use actix::Actor;
use anyhow::{anyhow, bail, Context as _, Result};
use behaviours::{BehaviourConfig, Entry, Registry};
use protocol::packets::Hello;
use robot_actor::actor::SetOdometryOrigin;
use robot_actor::discover::StaticList;
use robot_actor::link::sim::SimDiscoverer;
use robot_actor::link::{Discovered, Discoverer};
use robot_actor::{Pose, Robot, RobotConfig, Shards};
use simulator::runtime::{self, Pace};
use simulator::world::{file, presets, Track, World};
use simulator::{BodyFault, SimConfig, Simulation};
use tokio::sync::oneshot;

use crate::instruments::{Hooks, Run};
use crate::observer::{Instruments, Observer};
use crate::report::{GroundTruth, ObstacleReport, Report, RobotReport};
use crate::supervisor::{Abort, Outcome, Supervisor};
use world_model::safety::Safety;
use world_model::WorldModel;

/// Where the robots come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Transport {
    /// Simulated robots in this process (the default).
    Sim,
    /// Robots at the given addresses (`tcp://…`, `serial://…`, `bt://…`).
    Addresses(Vec<String>),
    /// The robots of an MCAP recording, played back (see `coordinator replay`).
    Replay(std::path::PathBuf),
    /// Robots behind `pocketfleet-gateway`s on zenoh (feature `zenoh`).
    #[cfg(feature = "zenoh")]
    Zenoh {
        /// The fleet's name.
        fleet: String,
        /// How many robots to wait for before the experiment starts.
        robots: usize,
        /// Endpoints and configuration.
        options: robot_actor::link::zenoh::ZenohOptions,
    },
}

/// What to run.
#[derive(Clone, Debug)]
pub struct Plan {
    /// Behaviour name.
    pub behaviour: String,
    /// World preset name or file; `None` takes the behaviour's preferred world.
    pub world: Option<String>,
    /// How many simulated robots (the world's first N); `None` takes them all.
    pub robots: Option<usize>,
    /// Robot source.
    pub transport: Transport,
    /// Seed.
    pub seed: u64,
    /// Pace the simulation to the wall clock.
    pub realtime: bool,
    /// Time limit (simulated when simulating).
    pub duration: Duration,
    /// Behaviour parameters.
    pub params: std::collections::BTreeMap<String, String>,
    /// Link cuts to inject into simulated robots.
    pub faults: Vec<LinkFault>,
    /// Body faults of simulated robots, by robot id, present from the start (a robot that
    /// cannot move, or cannot measure that it does, to prove that verdicts need the work done).
    pub body_faults: Vec<(u16, BodyFault)>,
    /// Kicks of simulated robots: bodies moved without their odometry knowing.
    pub kicks: Vec<Kick>,
    /// Settings written to every robot before the experiment starts.
    pub settings: Vec<SettingWrite>,
    /// Clock steps (1 ms) per physics step of simulated robots: 1 is physics at 1 kHz.
    pub physics_every: u32,
}

/// One robot setting the coordinator writes to every robot before the experiment starts,
/// confirmed by read-back; each robot actor writes it again after a reconnect or reboot.
/// Parsed from `PATH=VALUE`, e.g. `watchdog.timeout_ms=400` (`docs/protocol.md` lists the paths).
#[derive(Clone, Debug, PartialEq)]
pub struct SettingWrite {
    /// The field's dotted path.
    pub path: String,
    /// Its byte offset in the settings.
    pub offset: usize,
    /// The value's bytes, little-endian as on the wire.
    pub bytes: Vec<u8>,
}

impl std::str::FromStr for SettingWrite {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        use protocol::layout::Layout;
        let (path, value) = s
            .split_once('=')
            .ok_or_else(|| format!("{s:?}: expected PATH=VALUE, e.g. watchdog.timeout_ms=400"))?;
        let (path, value) = (path.trim(), value.trim());
        let (offset, ty) = protocol::Settings::LAYOUT
            .field_type(path)
            .ok_or_else(|| format!("{path:?} is not a robot setting (see docs/protocol.md)"))?;
        let bad = |e: &dyn std::fmt::Display| format!("{path} is a {}: {value:?}: {e}", ty.name);
        macro_rules! number {
            ($t:ty) => {
                value
                    .parse::<$t>()
                    .map_err(|e| bad(&e))?
                    .to_le_bytes()
                    .to_vec()
            };
        }
        let bytes = match ty.name {
            "u8" => number!(u8),
            "u16" => number!(u16),
            "u32" => number!(u32),
            "i8" => number!(i8),
            "i16" => number!(i16),
            "i32" => number!(i32),
            "f32" => number!(f32),
            "f64" => number!(f64),
            other if ty.fields.is_empty() && ty.array.is_none() => {
                return Err(format!("{path} is a {other}, which --setting cannot write"))
            }
            _ => {
                return Err(format!(
                    "{path} is a group of settings: name one of its fields"
                ))
            }
        };
        Ok(SettingWrite {
            path: path.to_string(),
            offset,
            bytes,
        })
    }
}

impl Plan {
    /// The default time limit, the CLI's `--duration` default.
    pub const DEFAULT_DURATION: Duration = Duration::from_secs(600);

    /// The simulated robots' physics rate, Hz.
    pub fn physics_hz(&self) -> u32 {
        1000 / self.physics_every.max(1)
    }

    /// `behaviour` on simulated robots: its own world with all its robots, seed 1, as fast as
    /// possible, [`Plan::DEFAULT_DURATION`], no parameters, faults or kicks.
    pub fn sim(behaviour: impl Into<String>) -> Plan {
        Plan {
            behaviour: behaviour.into(),
            world: None,
            robots: None,
            transport: Transport::Sim,
            seed: 1,
            realtime: false,
            duration: Self::DEFAULT_DURATION,
            params: std::collections::BTreeMap::new(),
            faults: Vec::new(),
            body_faults: Vec::new(),
            kicks: Vec::new(),
            settings: Vec::new(),
            physics_every: 1,
        }
    }

    /// Runs in this world preset or file instead of the behaviour's own.
    pub fn world(mut self, world: impl Into<String>) -> Plan {
        self.world = Some(world.into());
        self
    }

    /// Runs with the world's first `n` robots.
    pub fn robots(mut self, n: usize) -> Plan {
        self.robots = Some(n);
        self
    }

    /// Seeds the simulation's noise and the behaviour's choices.
    pub fn seed(mut self, seed: u64) -> Plan {
        self.seed = seed;
        self
    }

    /// Sets the time limit.
    pub fn duration(mut self, limit: Duration) -> Plan {
        self.duration = limit;
        self
    }

    /// Sets one behaviour parameter, replacing an earlier value for `key`.
    pub fn param(mut self, key: impl Into<String>, value: impl Into<String>) -> Plan {
        self.params.insert(key.into(), value.into());
        self
    }

    /// Sets several behaviour parameters.
    pub fn params<K: Into<String>, V: Into<String>>(
        mut self,
        params: impl IntoIterator<Item = (K, V)>,
    ) -> Plan {
        self.params
            .extend(params.into_iter().map(|(k, v)| (k.into(), v.into())));
        self
    }

    /// Adds a link cut of a simulated robot.
    pub fn fault(mut self, fault: LinkFault) -> Plan {
        self.faults.push(fault);
        self
    }

    /// Breaks simulated robot `robot` (by id) from the start.
    pub fn body_fault(mut self, robot: u16, fault: BodyFault) -> Plan {
        self.body_faults.push((robot, fault));
        self
    }

    /// Adds a kick of a simulated robot.
    pub fn kick(mut self, kick: Kick) -> Plan {
        self.kicks.push(kick);
        self
    }

    /// Takes the robots from `transport` instead of the simulator.
    pub fn transport(mut self, transport: Transport) -> Plan {
        self.transport = transport;
        self
    }

    /// Paces the simulation to the wall clock (or not).
    pub fn realtime(mut self, realtime: bool) -> Plan {
        self.realtime = realtime;
        self
    }

    /// Whether this plan runs on a paused clock (see [`crate::actor_system`]): everything but
    /// robots at addresses, unless paced to the wall clock.
    pub fn paused_clock(&self) -> bool {
        !self.realtime && matches!(self.transport, Transport::Sim | Transport::Replay(_))
    }
}

/// A kick: simulated robot `robot` (by id) is moved by (`dx_m`, `dy_m`) and turned by
/// `dtheta_rad` at `at`, at once and without its firmware noticing, as if picked up and put down.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Kick {
    /// Robot id.
    pub robot: u16,
    /// When, after the robots are connected.
    pub at: Duration,
    /// Displacement along x, metres.
    pub dx_m: f64,
    /// Displacement along y, metres.
    pub dy_m: f64,
    /// Turn, radians counter-clockwise.
    pub dtheta_rad: f64,
    /// Further displacement to the robot's left (negative: right) at the moment of the kick,
    /// metres: a sideways shove whatever way the robot faces then.
    pub sideways_m: f64,
}

impl From<simulator::cli::KickArg> for Kick {
    /// The kick `--kick ID:SECONDS:DX,DY[,DEG]` gives (no sideways shove).
    fn from(k: simulator::cli::KickArg) -> Self {
        Self {
            robot: k.robot,
            at: k.at,
            dx_m: k.dx_m,
            dy_m: k.dy_m,
            dtheta_rad: k.dtheta_rad,
            sideways_m: 0.0,
        }
    }
}

/// A simulated link cut: robot `robot` (world order) loses its link at `at` for `duration`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LinkFault {
    /// Index of the robot in the world's robot list.
    pub robot: usize,
    /// When, after the robots are connected.
    pub at: Duration,
    /// For how long.
    pub duration: Duration,
}

/// Loads a preset by name or a world file by path.
pub fn load_world(name: &str) -> Result<World> {
    if let Some(w) = presets::preset(name) {
        return Ok(w);
    }
    if let Some(spec) = name.strip_prefix("grid:") {
        // `grid:COLSxROWS:ROBOTS`, a generated warehouse lattice.
        let parsed = spec.split_once(':').and_then(|(size, robots)| {
            let (c, r) = size.split_once('x')?;
            Some((c.parse().ok()?, r.parse().ok()?, robots.parse().ok()?))
        });
        let Some((cols, rows, robots)) = parsed else {
            bail!("world {name:?}: expected grid:COLSxROWS:ROBOTS, e.g. grid:12x8:50");
        };
        return presets::grid_exact(cols, rows, robots).map_err(|e| anyhow!("world {name:?}: {e}"));
    }
    if let Some(robots) = name.strip_prefix("serpentine:") {
        // `serpentine:ROBOTS`, one generated loop for line following at scale.
        return match robots.parse::<usize>() {
            Ok(n) if (1..=usize::from(u16::MAX)).contains(&n) => Ok(presets::serpentine(n)),
            _ => bail!(
                "world {name:?}: expected serpentine:ROBOTS with 1 to {} robots, e.g. \
                 serpentine:500",
                u16::MAX
            ),
        };
    }
    if name.ends_with(".toml") || std::path::Path::new(name).exists() {
        return file::load(name).map_err(|e| anyhow!("{e}"));
    }
    bail!(
        "unknown world {name:?}: not a preset ({}) nor a .toml file",
        presets::preset_names().join(", ")
    )
}

/// Runs one experiment to its end and reports it.
pub async fn run(plan: Plan, registry: &Registry) -> Result<Report> {
    Ok(run_with(plan, registry, Instruments::default())
        .await?
        .report)
}

/// Runs one experiment with a recorder, a control panel or trails, and reports it.
pub async fn run_with(plan: Plan, registry: &Registry, instruments: Instruments) -> Result<Run> {
    let setup = resolve(&plan, registry)?;
    let world = &setup.world;
    let wall = std::time::Instant::now();
    let mut hooks = Hooks::new(&plan, &setup.world_name, world.robots.len(), instruments)?;
    let (discovered, origins, sim) = find_robots(&plan, world, &mut hooks).await?;
    let discovered = hooks.tap(discovered, world);
    let observer = hooks.observer(world, sim.clone());
    // A robot that cannot answer within the whole time limit will not be waited for longer.
    let deadline = HELLO_DEADLINE.min(plan.duration);
    // On a paused clock everything stays on this thread: simulated time advances only when every
    // task waits, which other threads' tasks cannot take part in. Otherwise the robots are
    // spread over shards beside this arbiter (stopped when this returns, after the robots are
    // closed).
    let shards = (!plan.paused_clock()).then(Shards::beside_system);
    let robots = connect_all(
        &discovered,
        origins.as_deref(),
        world,
        (&observer, hooks.watches_states()),
        deadline,
        shards.as_ref(),
    )
    .await?;
    write_settings(&robots, &plan.settings).await?;
    let (supervisor, model, done) = start_supervisor(&plan, &setup, &robots);
    hooks.serve_panel(&supervisor, &robots, world).await?;
    // From here to the verdict the model is checked against the ground truth.
    let sampler = ModelSampler::start(sim.as_ref(), &model);
    if let Some(h) = &sim {
        inject_faults(h, &plan.faults, &setup.kicks);
    }
    let started = tokio::time::Instant::now();
    let progress = progress_bar(plan.duration, started);
    let outcome = await_verdict(&supervisor, done, plan.duration).await?;
    let model_errors = sampler.finish().await?;
    // A replay runs to the recording's end whatever its behaviour decides, so every recorded
    // snapshot can be checked.
    hooks.replay_to_end().await;
    let experiment_time = tokio::time::Instant::now() - started;
    if let Some((bar, task)) = progress {
        task.abort();
        bar.finish_and_clear();
    }
    let ending = Ending {
        outcome,
        truth: ground_truth(sim.as_ref()).await,
        model_errors,
        experiment_time,
    };
    let per_robot = robot_reports(&ending, &robots, world, &model).await?;
    hooks.linger(&ending.outcome.verdict).await;
    for (_, robot) in &robots {
        robot.close();
    }
    if let Some(h) = &sim {
        h.stop();
    }
    let report = build_report(&plan, world, ending, per_robot, wall.elapsed());
    hooks.finish(report, &observer).await
}

/// A plan checked against its behaviour and world, before anything starts.
struct Setup {
    /// The name the world was loaded by.
    world_name: String,
    /// The world, cut down to the plan's robots.
    world: World,
    track: Arc<Track>,
    entry: Entry,
    /// Each kick with the index of its robot in the world.
    kicks: Vec<(usize, Kick)>,
}

/// Finds the behaviour and loads its world, and checks the parameters, faults and kicks: a bad
/// plan is refused before any robot is touched.
fn resolve(plan: &Plan, registry: &Registry) -> Result<Setup> {
    let entry = registry.get(&plan.behaviour).ok_or_else(|| {
        anyhow!(
            "unknown behaviour {:?}; known: {}",
            plan.behaviour,
            registry.names().join(", ")
        )
    })?;
    let world_name = plan
        .world
        .clone()
        .unwrap_or_else(|| entry.world.to_string());
    let mut world = load_world(&world_name)?;
    if world.robots.is_empty() {
        bail!("world {world_name:?} places no robots: give it at least one [[robots]] entry");
    }
    if let Some(n) = plan.robots {
        if n == 0 || n > world.robots.len() {
            bail!(
                "--robots {n}: world {:?} has room for 1 to {} robots",
                world.name,
                world.robots.len()
            );
        }
        world.robots.truncate(n);
    }
    let track = Arc::new(world.track.clone());
    // The parameters are parsed into the behaviour's typed declaration and checked against the
    // world here; nothing is built.
    entry
        .check(&BehaviourConfig {
            robots: world.robots.iter().map(|r| r.id).collect(),
            seed: plan.seed,
            params: plan.params.clone(),
            track: Arc::clone(&track),
        })
        .map_err(|e| anyhow!("behaviour {}: {e}", plan.behaviour))?;
    if !plan.body_faults.is_empty() && plan.transport != Transport::Sim {
        bail!("body faults can only be injected into simulated robots (transport sim)");
    }
    if !plan.kicks.is_empty() && plan.transport != Transport::Sim {
        bail!("only simulated robots can be kicked (transport sim)");
    }
    let mut kicks = Vec::new();
    for k in &plan.kicks {
        let Some(index) = world.robots.iter().position(|r| r.id == k.robot) else {
            bail!("kick of robot {}: no such robot in the world", k.robot);
        };
        if !(k.dx_m.is_finite() && k.dy_m.is_finite() && k.dtheta_rad.is_finite()) {
            bail!("kick of robot {}: the displacement must be finite", k.robot);
        }
        kicks.push((index, *k));
    }
    Ok(Setup {
        world_name,
        world,
        track,
        entry: *entry,
        kicks,
    })
}

/// The robots of the plan's transport, their starting poses when the world places them, and the
/// simulation when there is one.
async fn find_robots(
    plan: &Plan,
    world: &World,
    hooks: &mut Hooks,
) -> Result<(
    Vec<Discovered>,
    Option<Vec<Pose>>,
    Option<runtime::SimHandle>,
)> {
    Ok(match &plan.transport {
        Transport::Sim => {
            let origins = start_poses(world);
            let (handle, found) = start_simulation(plan, world).await?;
            (found, Some(origins), Some(handle))
        }
        Transport::Addresses(addrs) => {
            let found = StaticList {
                addresses: addrs.clone(),
            }
            .discover()
            .await?;
            (found, None, None)
        }
        Transport::Replay(_) => {
            let (found, simulated) = hooks.replay_connectors()?;
            (found, simulated.then(|| start_poses(world)), None)
        }
        #[cfg(feature = "zenoh")]
        Transport::Zenoh {
            fleet,
            robots,
            options,
        } => {
            use robot_actor::link::zenoh::{open_session, Keys, ZenohDiscoverer};
            let keys = Keys::new(fleet)?;
            let session = open_session(options).await?;
            let found = ZenohDiscoverer::new(session, keys, *robots, HELLO_DEADLINE)
                .discover()
                .await?;
            if found.len() < *robots {
                bail!(
                    "fleet {fleet}: {} of the {robots} robots asked for have a gateway after {} s",
                    found.len(),
                    HELLO_DEADLINE.as_secs()
                );
            }
            (found, None, None)
        }
    })
}

/// Where the world places each robot.
fn start_poses(world: &World) -> Vec<Pose> {
    world
        .robots
        .iter()
        .map(|r| Pose {
            x: r.position.x,
            y: r.position.y,
            theta: r.heading_rad,
        })
        .collect()
}

/// Starts the world's simulation with the plan's seed, pace and body faults, and finds its robots.
async fn start_simulation(
    plan: &Plan,
    world: &World,
) -> Result<(runtime::SimHandle, Vec<Discovered>)> {
    if plan.physics_every >= 4 && !world.obstacles.is_empty() {
        tracing::warn!(
            physics_hz = plan.physics_hz(),
            "physics below 500 Hz: moves, turns and line following keep their accuracy, but \
             contacts are resolved every {} ms, and two robots push the heavy box about a fifth \
             less far in the same time than at 1 kHz (250 Hz: 17 %, 200 Hz: 22 %)",
            plan.physics_every
        );
    }
    let mut sim = Simulation::new(
        world.clone(),
        SimConfig {
            seed: Some(plan.seed),
            physics_every: plan.physics_every,
            ..SimConfig::default()
        },
    );
    for &(id, fault) in &plan.body_faults {
        let i = sim
            .robot_index(id)
            .ok_or_else(|| anyhow!("body fault for robot {id}: no such robot in the world"))?;
        sim.set_body_fault(i, Some(fault));
    }
    let pace = if plan.realtime {
        Pace::WallClock
    } else {
        Pace::TokioClock
    };
    let (handle, ends, _task) = runtime::spawn(sim, pace);
    let found = SimDiscoverer::new(ends).discover().await?;
    Ok((handle, found))
}

/// Starts the supervisor over the connected robots, running the plan's behaviour; the receiver
/// gets its outcome.
fn start_supervisor(
    plan: &Plan,
    setup: &Setup,
    robots: &[(u16, Robot)],
) -> (
    actix::Addr<Supervisor>,
    WorldModel,
    oneshot::Receiver<Outcome>,
) {
    let config = BehaviourConfig {
        robots: robots.iter().map(|(id, _)| *id).collect(),
        seed: plan.seed,
        params: plan.params.clone(),
        track: Arc::clone(&setup.track),
    };
    let (done_tx, done_rx) = oneshot::channel();
    let supervisor = Supervisor::new(
        robots.to_vec(),
        Arc::clone(&setup.track),
        (setup.world.arena.width_m, setup.world.arena.height_m),
        setup.entry,
        config,
        Duration::from_millis(100),
        Safety::default(),
        done_tx,
    );
    let model = supervisor.model();
    (supervisor.start(), model, done_rx)
}

/// Schedules the plan's link cuts and kicks on the simulation's clock.
fn inject_faults(h: &runtime::SimHandle, faults: &[LinkFault], kicks: &[(usize, Kick)]) {
    for fault in faults.iter().copied() {
        let h = h.clone();
        tokio::spawn(async move {
            tokio::time::sleep(fault.at).await;
            h.set_link_up(fault.robot, false);
            tokio::time::sleep(fault.duration).await;
            h.set_link_up(fault.robot, true);
        });
    }
    for &(index, kick) in kicks {
        let h = h.clone();
        tokio::spawn(async move {
            tokio::time::sleep(kick.at).await;
            let (mut dx, mut dy) = (kick.dx_m, kick.dy_m);
            if kick.sideways_m != 0.0 {
                let heading = h
                    .poses()
                    .await
                    .and_then(|p| p.robots.get(index).map(|(_, p)| p.theta))
                    .unwrap_or(0.0);
                dx -= kick.sideways_m * heading.sin();
                dy += kick.sideways_m * heading.cos();
            }
            match h.displace(index, dx, dy, kick.dtheta_rad).await {
                Ok(p) => tracing::info!(
                    robot = kick.robot,
                    x = p.x,
                    y = p.y,
                    theta = p.theta,
                    "kicked"
                ),
                Err(e) => tracing::warn!(robot = kick.robot, "kick not applied: {e}"),
            }
        });
    }
}

/// Waits for the supervisor's outcome; at the time limit or on Ctrl-C it is told to abort, and
/// still sends its outcome once every robot is stopped.
async fn await_verdict(
    supervisor: &actix::Addr<Supervisor>,
    mut done: oneshot::Receiver<Outcome>,
    limit: Duration,
) -> Result<Outcome> {
    let aborted = tokio::select! {
        o = &mut done => Some(o),
        _ = tokio::time::sleep(limit) => {
            supervisor.do_send(Abort(format!("did not finish within {limit:?}")));
            None
        }
        _ = tokio::signal::ctrl_c() => {
            supervisor.do_send(Abort("interrupted (Ctrl-C)".into()));
            None
        }
    };
    match aborted {
        Some(o) => o,
        None => done.await,
    }
    .context("supervisor stopped without a verdict")
}

/// The simulation's ground truth once stop commands have had time to reach the robots.
async fn ground_truth(sim: Option<&runtime::SimHandle>) -> Option<runtime::Truth> {
    tokio::time::sleep(Duration::from_millis(300)).await;
    match sim {
        Some(h) => h.truth().await,
        None => None,
    }
}

/// What a run left to report once its robots stopped.
struct Ending {
    outcome: Outcome,
    truth: Option<runtime::Truth>,
    model_errors: ModelErrors,
    experiment_time: Duration,
}

/// Each robot's final state, estimate and ground truth.
async fn robot_reports(
    ending: &Ending,
    robots: &[(u16, Robot)],
    world: &World,
    model: &WorldModel,
) -> Result<Vec<RobotReport>> {
    let truth = ending.truth.as_ref();
    let mut per_robot = Vec::new();
    for (i, (id, robot)) in robots.iter().enumerate() {
        let snap = robot.snapshot().await?;
        let truth_pose =
            truth.and_then(|t| t.robots.iter().find(|(r, _)| r == id).map(|(_, p)| *p));
        let estimate = model.robots().get(id).map_or(snap.pose, |v| v.pose);
        let off_tape_m = truth_pose.and_then(|p| {
            let sensor = nalgebra::Point2::new(
                p.x + SENSOR_AHEAD_M * p.theta.cos(),
                p.y + SENSOR_AHEAD_M * p.theta.sin(),
            );
            world.track.nearest(sensor).map(|n| n.distance_m)
        });
        let worst = ending.model_errors.worst.get(id);
        per_robot.push(RobotReport {
            id: *id,
            worst_model_error_m: worst.map(|w| w.0),
            worst_model_heading_error_rad: worst.map(|w| w.1),
            localisation: ending
                .outcome
                .localisation
                .iter()
                .find(|(r, _)| r == id)
                .map(|(_, l)| *l)
                .unwrap_or_default(),
            odometry: snap.pose,
            estimate,
            off_tape_m,
            truth: truth_pose.map(|p| Pose {
                x: p.x,
                y: p.y,
                theta: p.theta,
            }),
            distance_m: truth.and_then(|t| t.distances_m.get(i).copied()),
            link: snap.link,
            wheels_mps: (
                f64::from(snap.state.wheels.left_mps),
                f64::from(snap.state.wheels.right_mps),
            ),
        });
    }
    Ok(per_robot)
}

/// The experiment's report.
fn build_report(
    plan: &Plan,
    world: &World,
    ending: Ending,
    robots: Vec<RobotReport>,
    wall_time: Duration,
) -> Report {
    let Ending {
        outcome,
        truth,
        model_errors,
        experiment_time,
    } = ending;
    Report {
        behaviour: plan.behaviour.clone(),
        world: world.name.clone(),
        seed: plan.seed,
        verdict: outcome.verdict,
        robots,
        obstacles: truth
            .as_ref()
            .map(|t| obstacle_reports(world, t))
            .unwrap_or_default(),
        ground_truth: truth.as_ref().map(|t| GroundTruth {
            robot_contacts: t.robot_collisions,
            wall_contacts: t.wall_contacts,
            collision_log: t.collision_log.clone(),
            model_samples: model_errors.samples,
            physics_hz: plan.physics_hz(),
        }),
        held_intents: outcome
            .held
            .iter()
            .map(|(t, i, why)| format!("{t:?}: {i:?}: {why}"))
            .collect(),
        links: outcome.links,
        encounters: outcome.encounters.len(),
        restarts: outcome.restarts,
        experiment_time,
        wall_time,
        peak_memory_bytes: crate::report::peak_memory_bytes(),
    }
}

/// How often, on the experiment's clock, the world model is checked against the ground truth.
const MODEL_SAMPLE_PERIOD: Duration = Duration::from_millis(100);

/// The world model's worst error against the ground truth over a run.
#[derive(Clone, Debug, Default)]
struct ModelErrors {
    /// Per robot id: the worst position error (metres) and the worst heading error (radians).
    worst: std::collections::BTreeMap<u16, (f64, f64)>,
    /// How many times the model was checked.
    samples: usize,
}

/// The model error sampler of a simulated run, from the supervisor's start to the verdict.
struct ModelSampler {
    stop: oneshot::Sender<()>,
    task: Option<tokio::task::JoinHandle<ModelErrors>>,
}

impl ModelSampler {
    /// Starts sampling when there is a simulation to take the truth from.
    fn start(sim: Option<&runtime::SimHandle>, model: &WorldModel) -> Self {
        let (stop, stopped) = oneshot::channel();
        let task = sim
            .cloned()
            .map(|h| tokio::spawn(sample_model_errors(h, model.robots(), stopped)));
        Self { stop, task }
    }

    /// Stops sampling and gives the worst errors seen.
    async fn finish(self) -> Result<ModelErrors> {
        let _ = self.stop.send(());
        match self.task {
            Some(task) => task.await.context("the model error sampler failed"),
            None => Ok(ModelErrors::default()),
        }
    }
}

/// Compares every robot's model pose with its true pose each [`MODEL_SAMPLE_PERIOD`] until `stop`
/// fires or the simulation ends. A robot counts from its first report on: before it the model has
/// no pose of its own for it.
async fn sample_model_errors(
    h: runtime::SimHandle,
    views: Arc<dashmap::DashMap<u16, Arc<behaviours::RobotView>>>,
    mut stop: oneshot::Receiver<()>,
) -> ModelErrors {
    let mut errors = ModelErrors::default();
    let mut tick = tokio::time::interval(MODEL_SAMPLE_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    // Model against ground truth once a second in the log, for studying the estimator.
    let log = tracing::enabled!(target: "coordinator::truth", tracing::Level::DEBUG);
    let log_every = (Duration::from_secs(1).as_millis() / MODEL_SAMPLE_PERIOD.as_millis()) as usize;
    loop {
        tokio::select! {
            biased;
            _ = &mut stop => break,
            _ = tick.tick() => {}
        }
        let Some(truth) = h.poses().await else { break };
        errors.samples += 1;
        for (id, p) in &truth.robots {
            let Some(v) = views.get(id) else { continue };
            if !v.connected && !errors.worst.contains_key(id) {
                continue;
            }
            let position = (p.x - v.pose.x).hypot(p.y - v.pose.y);
            let heading = wrap_rad(p.theta - v.pose.theta).abs();
            let worst = errors.worst.entry(*id).or_insert((0.0, 0.0));
            worst.0 = worst.0.max(position);
            worst.1 = worst.1.max(heading);
            if log && errors.samples % log_every == 0 {
                tracing::debug!(
                    target: "coordinator::truth",
                    robot = id,
                    t = truth.now.as_secs_f64(),
                    truth = ?(p.x, p.y, p.theta),
                    model = ?(v.pose.x, v.pose.y, v.pose.theta),
                    odometry = ?(v.odometry.x, v.odometry.y, v.odometry.theta),
                    line_um = { v.state.line.position_um },
                );
            }
        }
    }
    errors
}

use world::wrap_angle as wrap_rad;

/// The longest wait for a robot's hello (shortened to the experiment's time limit).
pub const HELLO_DEADLINE: Duration = Duration::from_secs(10);

use world::robot::LINE_SENSOR_AHEAD_M as SENSOR_AHEAD_M;

fn obstacle_reports(world: &World, truth: &runtime::Truth) -> Vec<ObstacleReport> {
    world
        .obstacles
        .iter()
        .zip(&truth.obstacles)
        .zip(&truth.obstacle_displacements_m)
        .map(|((spec, pose), moved)| {
            // The footprint's perimeter, sampled every 2 mm, against the tape's edges.
            let (s, c) = pose.theta.sin_cos();
            let (hw, hh) = (spec.width_m / 2.0, spec.height_m / 2.0);
            let steps = ((spec.width_m + spec.height_m) / 0.002).ceil().max(4.0) as usize;
            let mut clear = f64::INFINITY;
            for k in 0..=steps {
                let t = k as f64 / steps as f64;
                for (lx, ly) in [
                    (-hw + 2.0 * hw * t, -hh),
                    (-hw + 2.0 * hw * t, hh),
                    (-hw, -hh + 2.0 * hh * t),
                    (hw, -hh + 2.0 * hh * t),
                ] {
                    let q =
                        nalgebra::Point2::new(pose.x + c * lx - s * ly, pose.y + s * lx + c * ly);
                    if let Some(n) = world.track.nearest(q) {
                        let half_tape = world.track.edges()[n.edge].width_m / 2.0;
                        clear = clear.min((n.distance_m - half_tape).max(0.0));
                    }
                    if world.track.floor_at(q).ir_reflectance < 0.9 {
                        clear = 0.0;
                    }
                }
            }
            ObstacleReport {
                pose: [pose.x, pose.y, pose.theta],
                moved_m: *moved,
                clear_of_tape_m: clear,
            }
        })
        .collect()
}

/// Starts a robot actor per discovered robot and waits for every hello at once, at most
/// `deadline` each. Refused robots, silent ones and two robots claiming one id end the experiment
/// before it starts, with every robot closed; the first such problem in discovery order is the one
/// reported. The observer hears every robot's events, and its states only when `observe_states`.
async fn connect_all(
    found: &[Discovered],
    origins: Option<&[Pose]>,
    world: &World,
    (observer, observe_states): (&actix::Addr<Observer>, bool),
    deadline: Duration,
    shards: Option<&Shards>,
) -> Result<Vec<(u16, Robot)>> {
    let mut started: Vec<Robot> = Vec::with_capacity(found.len());
    for (i, d) in found.iter().enumerate() {
        let config = RobotConfig {
            origin: origins.and_then(|o| o.get(i).copied()).unwrap_or_default(),
            ..RobotConfig::default()
        };
        let robot = match shards {
            Some(shards) => shards.start(Arc::clone(&d.connector), config),
            None => Robot::start(Arc::clone(&d.connector), config),
        };
        // Before any packet: replay checks the observer's view after each robot's k-th update.
        if observe_states {
            robot.subscribe(observer.clone().recipient());
        }
        robot.subscribe_events(observer.clone().recipient());
        started.push(robot);
    }
    let hellos = futures::future::join_all(
        started
            .iter()
            .zip(found)
            .map(|(r, d)| greet(r, d, deadline)),
    )
    .await;
    let mut robots: Vec<(u16, Robot, String)> = Vec::with_capacity(found.len());
    let mut failure = None;
    for ((robot, d), greeted) in started.into_iter().zip(found).zip(hellos) {
        let peer = d.connector.peer();
        let greeted = greeted.and_then(|hello| {
            match robots.iter().find(|(id, _, _)| *id == hello.robot_id) {
                Some((id, _, first)) => Err(anyhow!(
                    "robots at {first} and {peer} both say they are robot {id}: every robot \
                     needs its own id"
                )),
                None => Ok(hello),
            }
        });
        let hello = match greeted {
            Ok(hello) if failure.is_none() => hello,
            Ok(_) => {
                robot.close();
                continue;
            }
            Err(e) => {
                robot.close();
                failure.get_or_insert(e);
                continue;
            }
        };
        if origins.is_none() {
            // Robots reached by address start where the world file places their id.
            if let Some(start) = world.robots.iter().find(|r| r.id == hello.robot_id) {
                robot.addr().do_send(SetOdometryOrigin(Pose {
                    x: start.position.x,
                    y: start.position.y,
                    theta: start.heading_rad,
                }));
            }
        }
        tracing::info!(robot = { hello.robot_id }, %peer, "connected");
        robots.push((hello.robot_id, robot, peer));
    }
    if let Some(e) = failure {
        for (_, r, _) in &robots {
            r.close();
        }
        return Err(e);
    }
    Ok(robots.into_iter().map(|(id, r, _)| (id, r)).collect())
}

/// Writes each of `settings` to every robot, confirmed by read-back: a refusal (a value out of
/// the robot's range) ends the experiment before it starts, naming the setting and the robot.
async fn write_settings(robots: &[(u16, Robot)], settings: &[SettingWrite]) -> Result<()> {
    for (id, robot) in robots {
        for w in settings {
            let msg = robot_actor::WriteSettings {
                offset: w.offset,
                bytes: w.bytes.clone(),
            };
            robot
                .addr()
                .send(msg)
                .await
                .map_err(|e| anyhow!("--setting {}: robot {id}: {e}", w.path))?
                .map_err(|e| anyhow!("--setting {}: robot {id} refused it: {e}", w.path))?;
        }
    }
    Ok(())
}

/// Waits for one robot's hello; a timeout says why the link never came up, if it did not.
async fn greet(robot: &Robot, d: &Discovered, deadline: Duration) -> Result<Hello> {
    match tokio::time::timeout(deadline, robot.connected()).await {
        Ok(hello) => hello.with_context(|| d.name.clone()),
        Err(_) => {
            let snapshot = robot.snapshot().await?;
            match snapshot.link_error {
                Some(why) => bail!("{}: {why}; no link within {deadline:?}", d.name),
                None => bail!("{} did not say hello within {deadline:?}", d.name),
            }
        }
    }
}

/// A progress bar over the time limit, on a terminal only; it moves with the experiment's clock.
fn progress_bar(
    limit: Duration,
    started: tokio::time::Instant,
) -> Option<(indicatif::ProgressBar, tokio::task::JoinHandle<()>)> {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return None;
    }
    let bar = indicatif::ProgressBar::new(limit.as_millis() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} ms")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message("experiment time");
    let b = bar.clone();
    let task = tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_millis(100));
        loop {
            tick.tick().await;
            b.set_position((tokio::time::Instant::now() - started).as_millis() as u64);
        }
    });
    Some((bar, task))
}
