//! Shards: robot actors spread over arbiters (threads) of their own. Decoding, checksums and
//! odometry are per frame and independent between robots, so a fleet of thousands of links
//! needs more than the one thread the supervisor's arbiter runs on.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use actix::Arbiter;

use crate::link::Connector;
use crate::{Robot, RobotConfig};

/// Arbiters that robot actors are started on round-robin; stopped when dropped.
pub struct Shards {
    arbiters: Vec<Arbiter>,
    next: AtomicUsize,
}

impl Shards {
    /// `n` arbiters (at least one), each on a thread of its own.
    pub fn new(n: usize) -> Self {
        Self {
            arbiters: (0..n.max(1)).map(|_| Arbiter::new()).collect(),
            next: AtomicUsize::new(0),
        }
    }

    /// One arbiter per core the process may use but one, which is left to the system arbiter
    /// (the supervisor and the world model); at least one.
    pub fn beside_system() -> Self {
        Self::new(std::thread::available_parallelism().map_or(1, |n| n.get()) - 1)
    }

    /// How many arbiters there are.
    pub fn len(&self) -> usize {
        self.arbiters.len()
    }

    /// Never: there is always at least one arbiter (for clippy's `len_without_is_empty`).
    pub fn is_empty(&self) -> bool {
        self.arbiters.is_empty()
    }

    /// Starts a robot on the next arbiter, its states batched per arbiter (see
    /// [`RobotConfig::batch_states`]).
    pub fn start(&self, connector: Arc<dyn Connector>, config: RobotConfig) -> Robot {
        let i = self.next.fetch_add(1, Ordering::Relaxed) % self.arbiters.len();
        let config = RobotConfig {
            batch_states: true,
            ..config
        };
        Robot::start_in(&self.arbiters[i].handle(), connector, config)
    }
}

impl Drop for Shards {
    fn drop(&mut self) {
        // The arbiters' threads end once they have run what was already sent to them.
        for a in &self.arbiters {
            a.stop();
        }
    }
}
