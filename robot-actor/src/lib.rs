#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

pub mod actor;
pub mod discover;
pub mod link;
pub mod odometry;
pub mod robot;
pub mod settings;
pub mod shard;

pub use actor::{
    DeliveryCounts, Incompatibility, MoveCommand, RobotActor, RobotConfig, RobotError, RobotEvent,
    RobotEventKind, StateBatch, StateUpdated, WriteSettings,
};
pub use odometry::{Odometry, Pose};
pub use robot::{CallError, Robot};
pub use shard::Shards;
