#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

// The `params!` macro names this crate by its path, inside it as well as in an author's crate.
extern crate self as behaviour_api;

pub mod behaviour;
pub mod event;
pub mod evidence;
pub mod intent;
pub mod moves;
pub mod params;
pub mod registration;
pub mod runner;
pub mod snapshot;
pub mod team;
pub mod testing;
pub mod track_loop;
pub mod verdict;

pub use behaviour::Behaviour;
pub use event::{Event, FrontSighting, Obstacle, Sighting};
pub use evidence::{Odometer, Stall};
pub use intent::Intent;
pub use params::{NoParams, ParamError, ParamInfo, Params};
pub use protocol::packets::{MoveOutcome, Side};
pub use protocol::MoveCommand;
pub use registration::{BehaviourConfig, Constructor, Entry, Register};
pub use runner::{Reply, Runner};
pub use snapshot::{
    Encounter, Localisation, LocalisationEvent, PoseUncertainty, RobotView, Robots, TrackPosition,
    WorldSnapshot,
};
pub use team::{HeldPolicy, Team};
pub use track_loop::TrackLoop;
pub use verdict::Verdict;
pub use world::Pose;

/// The serde the [`params!`] macro derives with, so an author's crate needs no serde of its own.
pub use serde;
