#![doc = include_str!("../README.md")]
#![cfg_attr(not(test), no_std)]
#![warn(missing_docs)]

pub mod bump;
pub mod firmware;
pub mod hal;
pub mod line_follow;
pub mod line_sensor;
pub mod locomotion;
pub mod log;
#[cfg(any(test, feature = "mock"))]
pub mod mock;
pub mod pid;
pub mod proximity;
pub mod reflector;
pub mod scheduler;
pub mod speed;
pub mod time;
pub mod watchdog;

pub use firmware::{Firmware, FIRMWARE_VERSION};
pub use hal::Board;
pub use protocol;
pub use time::{Duration, Instant};
