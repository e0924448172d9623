//! The command-line values and logging set-up the simulator's binary shares with the
//! coordinator's; they live in `world::cli`, which needs no physics.

pub use world::cli::*;
