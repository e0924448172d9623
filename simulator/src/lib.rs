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
pub mod world;

pub use sim::{BodyFault, SimConfig, Simulation};
pub use spec::RobotSpec;
pub use world::World;
