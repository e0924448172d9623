//! Foxglove message parts.

use serde_json::{json, Value};

/// Foxglove time from nanoseconds.
pub fn fox_time(ns: u64) -> Value {
    json!({"sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000})
}

/// A Foxglove pose in the plane.
pub fn fox_pose(x: f64, y: f64, theta: f64) -> Value {
    json!({"position": {"x": x, "y": y, "z": 0.0},
        "orientation": {"x": 0.0, "y": 0.0, "z": (theta / 2.0).sin(), "w": (theta / 2.0).cos()}})
}
