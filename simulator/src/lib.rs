#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

pub mod board;
pub mod cli;
pub mod drive;
pub mod ir;
pub mod link;
pub mod runtime;
pub mod serve;
pub mod sim;
pub mod spec;
/// The physics-free world (tracks, graph, world files, presets), from the `world` crate.
pub use ::world;

pub use sim::{BodyFault, HostSilence, SimConfig, Simulation};
pub use spec::RobotSpec;
pub use world::World;
