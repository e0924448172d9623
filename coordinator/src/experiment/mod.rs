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
#[cfg(feature = "sim")]
use robot_actor::link::sim::SimDiscoverer;
use robot_actor::link::{Discovered, Discoverer};
use robot_actor::{Pose, Robot, RobotConfig, Shards};
#[cfg(feature = "sim")]
use simulator::runtime::{self, Pace};
#[cfg(feature = "sim")]
use simulator::{SimConfig, Simulation};
use tokio::sync::oneshot;
use world::{Track, World};

use crate::instruments::observer::{Instruments, Observer};
use crate::instruments::{Hooks, Run};
use crate::plan::{load_world, FaultSpec, Kick, Plan, SettingWrite, Transport};
use crate::report::{FaultRecord, GroundTruth, KickRecord, ObstacleReport, Report, RobotReport};
use crate::supervisor::{Abort, Outcome, Supervisor};
use crate::twin::{SimHandle, Truth};
use world_model::safety::Safety;
use world_model::WorldModel;

pub mod resume;
mod robots;
mod truth;

use robots::*;
use truth::*;

/// Runs one experiment to its end and reports it.
pub async fn run(plan: Plan, registry: &Registry) -> Result<Report> {
    Ok(run_with(plan, registry, Instruments::default())
        .await?
        .report)
}

/// Runs one experiment with a recorder, a control panel or trails, and reports it.
pub async fn run_with(plan: Plan, registry: &Registry, instruments: Instruments) -> Result<Run> {
    let setup = resolve(&plan, registry)?;
    let _load = HostLoad::start(plan.host_load);
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
    let resumed = match &plan.resume {
        Some(r) => Some(r.adopt(&robots).await?),
        None => None,
    };
    let (supervisor, model, done) = start_supervisor(&plan, &setup, &robots, resumed.as_ref());
    hooks.serve_panel(&supervisor, &robots, world).await?;
    // From here to the verdict the model is checked against the ground truth.
    let sampler = ModelSampler::start(sim.as_ref(), &model);
    let landed = sim
        .as_ref()
        .map(|h| inject_faults(h, &setup.faults, &setup.kicks, &hooks.event_log()));
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
    let landed = landed
        .map(|k| k.lock().unwrap_or_else(|e| e.into_inner()).clone())
        .unwrap_or_default();
    let mut report = build_report(&plan, world, ending, per_robot, wall.elapsed(), landed);
    report.conditions.resumed = resumed;
    hooks.finish(report, &observer).await
}

/// Threads that keep a core busy each, standing for the other programs on a loaded host, until
/// dropped.
pub struct HostLoad {
    stop: Arc<std::sync::atomic::AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl HostLoad {
    /// Starts `n` busy threads.
    pub fn start(n: usize) -> HostLoad {
        use std::sync::atomic::{AtomicBool, Ordering};
        let stop = Arc::new(AtomicBool::new(false));
        let threads = (0..n)
            .map(|_| {
                let stop = Arc::clone(&stop);
                std::thread::spawn(move || {
                    let mut x = 1u64;
                    while !stop.load(Ordering::Relaxed) {
                        // A few microseconds of arithmetic between looks at the flag.
                        for _ in 0..1000 {
                            x = std::hint::black_box(x.wrapping_mul(6364136223846793005) + 1);
                        }
                    }
                })
            })
            .collect();
        HostLoad { stop, threads }
    }
}

impl Drop for HostLoad {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
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
    /// Each fault (the world's, the plan's and those drawn) with the index of its robot.
    faults: Vec<(usize, FaultSpec)>,
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
    if let Some(link) = &plan.link {
        if plan.transport != Transport::Sim {
            bail!(
                "--link-profile {}: only simulated links follow a profile (transport sim)",
                link.name
            );
        }
        world.link = link.model;
    }
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
    let kicked = !(plan.kicks.is_empty() && plan.random_kicks.is_empty());
    if kicked && plan.transport != Transport::Sim {
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
    let ids: Vec<u16> = world.robots.iter().map(|r| r.id).collect();
    for (n, r) in plan.random_kicks.iter().enumerate() {
        // A second random kick in one run draws from its own stream.
        let seed = plan.seed.wrapping_add((n as u64) << 32);
        if let Some(k) = Kick::random(*r, seed, &ids) {
            kicks.push((
                world
                    .robots
                    .iter()
                    .position(|w| w.id == k.robot)
                    .unwrap_or(0),
                k,
            ));
        }
    }
    let faults = resolve_faults(plan, &world)?;
    Ok(Setup {
        world_name,
        world,
        track,
        entry: *entry,
        kicks,
        faults,
    })
}

/// The faults a run injects: its world's, its plan's, and those drawn for its seed, each with
/// the index of its robot in the world (cut down to the plan's robots).
fn resolve_faults(plan: &Plan, world: &World) -> Result<Vec<(usize, FaultSpec)>> {
    let ids: Vec<u16> = world.robots.iter().map(|r| r.id).collect();
    let mut specs: Vec<FaultSpec> = world.faults.iter().chain(&plan.faults).copied().collect();
    for (n, r) in plan.random_faults.iter().enumerate() {
        // A second random fault in one run draws from its own stream.
        let seed = plan.seed.wrapping_add((n as u64) << 32);
        specs.extend(crate::plan::random_fault(*r, seed, &ids));
    }
    if !specs.is_empty() && plan.transport != Transport::Sim {
        bail!("faults can only be injected into simulated robots (transport sim)");
    }
    specs
        .into_iter()
        .map(|f| match ids.iter().position(|&id| id == f.robot) {
            Some(index) => Ok((index, f)),
            None => bail!("{}: no such robot in the experiment", f.describe()),
        })
        .collect()
}

/// Starts the supervisor over the connected robots, running the plan's behaviour; the receiver
/// gets its outcome.
fn start_supervisor(
    plan: &Plan,
    setup: &Setup,
    robots: &[(u16, Robot)],
    resumed: Option<&resume::Resumed>,
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
    // Before the supervisor takes its first state: adopted robots start as uncertain as the
    // killed run left them, widened for the gap.
    for a in resumed.map_or(&[][..], |r| &r.robots) {
        model.resume(a.id, a.sigma_mm / 1e3, a.sigma_deg.to_radians());
    }
    (supervisor.start(), model, done_rx)
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

/// How often, on the experiment's clock, the world model is checked against the ground truth.
const MODEL_SAMPLE_PERIOD: Duration = Duration::from_millis(100);

/// The longest wait for a robot's hello (shortened to the experiment's time limit).
pub const HELLO_DEADLINE: Duration = Duration::from_secs(10);
