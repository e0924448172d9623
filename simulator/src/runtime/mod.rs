//! The simulation as an async service: a task steps the world, paced either by a tokio clock
//! (faster than real time under a paused test clock, or as fast as the machine goes) or by the wall
//! clock, and each robot's link appears as an async packet channel ([`LinkEnd`]).
//!
//! Under tokio's paused clock (`start_paused(true)`) the stepping task sleeps one `dt` per step, so
//! simulated time advances only when every other task is idle: lockstep, deterministic, and as
//! fast as the host side can keep up.
//!
//! Packets a host sends wait in a buffer of [`LINK_BUFFER_BYTES`](crate::link::LINK_BUFFER_BYTES)
//! until the next step hands them to the link, which holds as much again: a host sending faster
//! than the link carries loses packets (counted in the robot's
//! [`LinkStats`](crate::link::LinkStats) and logged at most once a second), and neither memory nor
//! the delay of later packets grows with the flood.

mod buffer;
mod handle;
mod link_end;
mod stepping;
mod truth;

use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{mpsc, oneshot};

use crate::sim::{Pose, Simulation};
use buffer::HostBuffer;

pub use buffer::Sink;
pub use handle::SimHandle;
pub use link_end::{LinkEnd, LinkSender};
pub use truth::{truth, Poses, Truth};

/// How the stepping task keeps time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pace {
    /// One tokio `sleep(dt)` per step: real time on a real clock, instant under a paused clock.
    TokioClock,
    /// Steps as fast as possible, yielding to other tasks between steps.
    Unpaced,
    /// Steps in batches and sleeps until the wall clock catches up.
    WallClock,
    /// As [`Pace::WallClock`], with simulated time running at this fraction of the wall
    /// clock's pace (0.5: one simulated second every two seconds).
    Scaled(f64),
}

/// A request from a link end or the handle, carried out by the stepping task between two steps.
enum Command {
    Connect(usize),
    Disconnect(usize, Option<oneshot::Sender<()>>),
    SetLinkUp(usize, bool),
    Truth(oneshot::Sender<Truth>),
    Poses(oneshot::Sender<Poses>),
    Displace(usize, [f64; 3], oneshot::Sender<Result<Pose, String>>),
    DisplaceAt(Duration, usize, [f64; 3], world::cli::KickHow),
    Inspect(Box<dyn FnOnce(&mut Simulation) + Send>),
    /// A job for a simulated time, run between the steps that reach it.
    At(Duration, Box<dyn FnOnce(&mut Simulation) + Send>),
    Stop,
}

/// Starts stepping `sim` on the current tokio runtime; returns its control handle and one link end
/// per robot (not yet connected).
pub fn spawn(
    sim: Simulation,
    pace: Pace,
) -> (SimHandle, Vec<LinkEnd>, tokio::task::JoinHandle<Simulation>) {
    let (cmd_tx, cmd_rx) = mpsc::unbounded_channel();
    let mut ends = Vec::new();
    let mut to_robot_rx = Vec::new();
    let mut from_robot_tx = Vec::new();
    let waiting: Arc<[AtomicBool]> = sim
        .robots()
        .iter()
        .map(|_| AtomicBool::new(false))
        .collect();
    for (i, r) in sim.robots().iter().enumerate() {
        let buffer = Arc::new(HostBuffer::new(Arc::clone(&waiting), i));
        let (from_tx, from_rx) = mpsc::unbounded_channel();
        ends.push(LinkEnd {
            robot_id: r.id(),
            index: i,
            to_robot: Arc::clone(&buffer),
            from_robot: from_rx,
            commands: cmd_tx.clone(),
        });
        to_robot_rx.push(buffer);
        from_robot_tx.push(from_tx);
    }
    let task = tokio::spawn(stepping::step_loop(
        sim,
        pace,
        cmd_rx,
        to_robot_rx,
        from_robot_tx,
        waiting,
    ));
    (SimHandle { commands: cmd_tx }, ends, task)
}
