//! The PocketFleet coordinator: runs one supervised multi-robot experiment.
//!
//! # Layout
//! - `supervisor`: the supervisor actor, world model, behaviour supervision.
//! - `safety`: the predictive check every intent passes.
//! - `experiment`: wiring robots, supervisor and behaviour for one run.
//! - `report`: the experiment report, as text or JSON.
#![warn(missing_docs)]

pub mod experiment;
pub mod report;
pub mod safety;
pub mod supervisor;

pub use experiment::{load_world, run, LinkFault, Plan, Transport};
pub use report::Report;
