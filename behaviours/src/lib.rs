#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

pub mod cooperative_push;
pub mod line_follow;
mod registry;
pub mod square_walk;
pub mod token_ring;
pub mod traffic_control;

pub use registry::Registry;

// The contract, re-exported: code that runs the built-ins names one crate.
pub use behaviour_api::*;
pub use world::graph::TrackGraph;
