//! The supervisor's estimation layer, kept apart from the physics: the live world model (each
//! robot's pose, odometry corrected against the tape its line sensor sees, with a covariance; lost
//! and found), the relocalisation of a lost robot, and the safety check every intent passes.
//! It reads robots' state reports and the world's description (`world`), never the simulator, so
//! the same code estimates real robots and digital twins.
//!
//! # Layout
//! - [`model`]: [`WorldModel`], its estimates and their updates.
//! - [`relocalise`]: [`Relocaliser`](relocalise::Relocaliser), the search a lost robot drives.
//! - [`safety`]: [`Safety`](safety::Safety), swept footprints checked against every robot.

#![warn(missing_docs)]

pub mod model;
pub mod relocalise;
pub mod safety;

pub use model::{Felt, LocalisationStats, Transition, WorldModel, LOST_SIGMA_M, RELOCATE_M};
