//! Unit-testing a behaviour without actors or physics: [`world()`] builds snapshots, and a
//! [`Harness`] drives a behaviour through the same books ([`Team`]) as the shell the supervisor
//! runs it in.
//!
//! ```
//! use behaviour_api::testing::{world, Harness};
//! use behaviour_api::{Behaviour, Intent, MoveCommand, Team, WorldSnapshot};
//!
//! struct Nudge;
//! impl Behaviour for Nudge {
//!     fn start(&mut self, world: &WorldSnapshot, _: &mut Team) -> Vec<Intent> {
//!         let step = MoveCommand::Straight { distance_m: 0.01, speed_mps: 0.05 };
//!         world.robots.iter().map(|r| Intent::Move { robot: r.id, command: step, tag: 1 }).collect()
//!     }
//! }
//!
//! let mut h = Harness::new(Nudge);
//! let w = world().robot(1, 0.1, 0.1, 0.0).robot(2, 0.3, 0.1, 90.0).build();
//! assert_eq!(h.start(&w).len(), 2);
//! assert_eq!(h.team().outstanding(2), 1);
//! h.finish_move(2, 1, &w);
//! assert!(h.team().idle(2));
//! ```

use std::sync::Arc;
use std::time::Duration;

use protocol::packets::MoveOutcome;
use world::Pose;

use crate::behaviour::Behaviour;
use crate::event::Event;
use crate::intent::Intent;
use crate::runner::Runner;
use crate::snapshot::{LocalisationEvent, RobotView, TrackPosition, WorldSnapshot};
use crate::team::Team;
use crate::verdict::Verdict;

/// Builds a [`WorldSnapshot`] robot by robot.
#[derive(Clone, Debug)]
pub struct WorldBuilder {
    snapshot: WorldSnapshot,
}

/// An empty 1 m × 1 m world at time zero, to add robots to.
pub fn world() -> WorldBuilder {
    WorldBuilder {
        snapshot: WorldSnapshot {
            time: Duration::ZERO,
            robots: Default::default(),
            encounters: Vec::new(),
            arena: (1.0, 1.0),
        },
    }
}

impl WorldBuilder {
    /// A connected robot at (`x`, `y`) metres facing `heading_deg`, its odometry agreeing.
    pub fn robot(mut self, id: u16, x: f64, y: f64, heading_deg: f64) -> Self {
        let pose = Pose {
            x,
            y,
            theta: heading_deg.to_radians(),
        };
        self.snapshot.robots.make_mut().retain(|r| r.id != id);
        self.snapshot.robots.make_mut().push(Arc::new(RobotView {
            id,
            connected: true,
            pose,
            odometry: pose,
            ..Default::default()
        }));
        self.snapshot.robots.make_mut().sort_by_key(|r| r.id);
        self
    }

    /// Robots `ids` in a row along x, 0.1 m apart, facing +x.
    pub fn robots(self, ids: impl IntoIterator<Item = u16>) -> Self {
        ids.into_iter().enumerate().fold(self, |b, (k, id)| {
            b.robot(id, 0.1 * (k + 1) as f64, 0.5, 0.0)
        })
    }

    /// Robot `id`'s line sensor over the tape, `along_m` along track edge `edge`.
    pub fn on_track(self, id: u16, edge: usize, along_m: f64) -> Self {
        self.with(id, |r| {
            r.on_track = Some(TrackPosition {
                edge,
                along_m,
                offset_m: 0.0,
            })
        })
    }

    /// Robot `id`'s wheels turning at these speeds, m/s.
    pub fn wheels(self, id: u16, left_mps: f32, right_mps: f32) -> Self {
        self.with(id, |r| {
            r.state.wheels.left_mps = left_mps;
            r.state.wheels.right_mps = right_mps;
        })
    }

    /// Any other change to robot `id`'s view.
    pub fn with(mut self, id: u16, change: impl FnOnce(&mut RobotView)) -> Self {
        if let Some(r) = self
            .snapshot
            .robots
            .make_mut()
            .iter_mut()
            .find(|r| r.id == id)
        {
            change(Arc::make_mut(r));
        }
        self
    }

    /// The snapshot's time since the experiment started, seconds.
    pub fn at(mut self, seconds: f64) -> Self {
        self.snapshot.time = Duration::from_secs_f64(seconds);
        self
    }

    /// The arena's size, metres.
    pub fn arena(mut self, width_m: f64, height_m: f64) -> Self {
        self.snapshot.arena = (width_m, height_m);
        self
    }

    /// The snapshot.
    pub fn build(self) -> WorldSnapshot {
        self.snapshot
    }
}

/// Drives a behaviour by hand, keeping the team's books as the supervisor's shell does.
pub struct Harness<B: Behaviour + ?Sized = dyn Behaviour> {
    runner: Runner<B>,
}

impl<B: Behaviour> Harness<B> {
    /// Wraps `behaviour`.
    pub fn new(behaviour: B) -> Self {
        Self {
            runner: Runner::new(Box::new(behaviour)),
        }
    }
}

impl Harness {
    /// Wraps a behaviour built by a registry constructor.
    pub fn boxed(behaviour: Box<dyn Behaviour>) -> Self {
        Self {
            runner: Runner::new(behaviour),
        }
    }
}

impl<B: Behaviour + ?Sized> Harness<B> {
    /// The behaviour, to look at its state.
    pub fn behaviour(&self) -> &B {
        self.runner.behaviour()
    }

    /// The experiment starts; the team is the snapshot's robots.
    pub fn start(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        self.runner.start(world).intents
    }

    /// A snapshot arrives.
    pub fn snapshot(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        self.runner.snapshot(world).intents
    }

    /// Robot `robot` reports `event`.
    pub fn event(&mut self, robot: u16, event: Event, world: &WorldSnapshot) -> Vec<Intent> {
        self.runner.event(robot, &event, world).intents
    }

    /// Robot `robot`'s move tagged `tag` completed.
    pub fn finish_move(&mut self, robot: u16, tag: u32, world: &WorldSnapshot) -> Vec<Intent> {
        let done = Event::MoveFinished {
            tag,
            outcome: MoveOutcome::Completed,
        };
        self.event(robot, done, world)
    }

    /// The supervisor's safety check held `intent` back for `reason`.
    pub fn hold(&mut self, intent: Intent, reason: &str, world: &WorldSnapshot) -> Vec<Intent> {
        self.runner.held(&[(intent, reason.into())], world).intents
    }

    /// Robot `robot` was found lost, or re-localised.
    pub fn localise(
        &mut self,
        robot: u16,
        event: LocalisationEvent,
        world: &WorldSnapshot,
    ) -> Vec<Intent> {
        self.runner.localised(robot, &event, world).intents
    }

    /// The team's books.
    pub fn team(&self) -> &Team {
        self.runner.team()
    }

    /// The verdict, once given.
    pub fn verdict(&self) -> Option<&Verdict> {
        self.runner.verdict()
    }
}
