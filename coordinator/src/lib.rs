//! The PocketFleet coordinator: runs one supervised multi-robot experiment.
//!
//! # Layout
//! - `supervisor`: the supervisor actor and behaviour supervision.
//! - `world_model`: the live world model in a `DashMap`.
//! - `safety`: the predictive check every intent passes.
//! - `experiment`: wiring robots, supervisor and behaviour for one run.
//! - `report`: the experiment report, as text or JSON.
//! - `record`, `replay`: MCAP recording of a run and its replay.
//! - `observer`, `instruments`: the actor that feeds the recorder, the panel and plots.
//! - `panel`: the live web control panel.
//! - `plot`: the trajectory plot of a run.
//! - `sweep`: batches of runs over seeds and settings, with their statistics.
#![warn(missing_docs)]

pub mod behaviour_actor;
pub mod experiment;
#[doc = include_str!("../../docs/writing-behaviours.md")]
pub mod guide {}
pub mod instruments;
pub mod observer;
pub mod panel;
pub mod plot;
pub mod record;
pub mod recover;
pub mod replay;
pub mod report;
pub mod supervisor;
pub mod sweep;

pub use experiment::{load_world, run, run_with, Kick, LinkFault, Plan, SettingWrite, Transport};
pub use instruments::Run;
pub use observer::Instruments;
pub use report::{GroundTruth, ObstacleReport, Report, RobotReport};
pub use simulator::BodyFault;
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
