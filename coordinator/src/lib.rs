//! The PocketFleet coordinator: runs one supervised multi-robot experiment.
//!
//! # Layout
//! - `plan`: what an experiment is asked to be ([`Plan`]) and how a world is found by name.
//! - `experiment`: wiring robots, supervisor and behaviour for one run.
//! - `supervisor`: the supervisor actor: the world model fed, every intent checked, the behaviour
//!   supervised.
//! - `behaviour_actor`: the actix shell a behaviour runs in.
//! - `report`: the experiment report, as text or JSON.
//! - `instruments`: everything around a run, behind [`Instruments`] and [`Run`]: MCAP recording,
//!   replay and recover, the live web panel, trajectory plots, and sweeps of many runs.
//!
//! The estimation layer (world model, relocalisation, safety check) is the `world-model` crate.
#![warn(missing_docs)]

pub mod behaviour_actor;
pub mod experiment;
#[doc = include_str!("../../docs/writing-behaviours.md")]
pub mod guide {}
pub mod instruments;
pub mod plan;
pub mod report;
pub mod supervisor;
pub mod twin;

pub use experiment::{run, run_with};
pub use instruments::{Instruments, Run};
pub use plan::{
    load_world, FaultKind, FaultSpec, Kick, KickHow, Plan, RandomFault, RandomKick, SettingWrite,
    Transport,
};
pub use report::{GroundTruth, KickRecord, ObstacleReport, Report, RobotReport};
pub use twin::BodyFault;
/// The estimation layer the supervisor keeps (its own crate, re-exported for the benches).
pub use world_model;

/// An actix system on a current-thread tokio runtime, with its clock paused when `paused`: under a
/// paused clock simulated time advances whenever every task waits, so a simulated experiment runs
/// in lockstep, deterministically and as fast as the machine allows.
pub fn actor_system(paused: bool) -> actix::SystemRunner {
    actix::System::with_tokio_rt(move || {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .start_paused(paused)
            .build()
            .expect("a current-thread tokio runtime builds")
    })
}

/// Runs one experiment to its end on an actor system of its own (paused when
/// [`Plan::paused_clock`]), blocking the calling thread, which must not run an actor system
/// already, and reports it.
pub fn run_blocking(plan: Plan, registry: &behaviours::Registry) -> anyhow::Result<Report> {
    Ok(run_blocking_with(plan, registry, Instruments::default())?.report)
}

/// [`run_blocking`] with a recorder, a control panel or trails.
pub fn run_blocking_with(
    plan: Plan,
    registry: &behaviours::Registry,
    instruments: Instruments,
) -> anyhow::Result<Run> {
    actor_system(plan.paused_clock()).block_on(run_with(plan, registry, instruments))
}
