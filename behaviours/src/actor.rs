//! `BehaviourActor`: the thin actix shell a behaviour runs in. The supervisor sends it snapshots
//! and events; each reply carries the behaviour's intents and, once it is done, its verdict. A
//! panic inside the behaviour is caught and reported, so the supervisor can stop every robot and
//! restart it.

use std::panic::{catch_unwind, AssertUnwindSafe};

use actix::prelude::*;
use robot_actor::RobotEventKind;

use crate::api::{Behaviour, Intent, LocalisationEvent, Verdict, WorldSnapshot};

/// The experiment starts.
#[derive(Message)]
#[rtype(result = "Result<Reply, Panicked>")]
pub struct Start(pub WorldSnapshot);

/// A new world snapshot.
#[derive(Message)]
#[rtype(result = "Result<Reply, Panicked>")]
pub struct Snapshot(pub WorldSnapshot);

/// A robot event, with the latest snapshot.
#[derive(Message)]
#[rtype(result = "Result<Reply, Panicked>")]
pub struct Event {
    /// Robot id.
    pub robot: u16,
    /// What happened.
    pub kind: RobotEventKind,
    /// The latest snapshot.
    pub world: WorldSnapshot,
}

/// Intents the supervisor's safety check held back, with the reasons.
#[derive(Message)]
#[rtype(result = "Result<Reply, Panicked>")]
pub struct Held {
    /// Each held intent and why.
    pub held: Vec<(Intent, String)>,
    /// The latest snapshot.
    pub world: WorldSnapshot,
}

/// A robot was found lost or re-localised, with the latest snapshot.
#[derive(Message)]
#[rtype(result = "Result<Reply, Panicked>")]
pub struct Localised {
    /// Robot id.
    pub robot: u16,
    /// What happened.
    pub event: LocalisationEvent,
    /// The latest snapshot.
    pub world: WorldSnapshot,
}

/// What the behaviour answered.
#[derive(Debug, Default)]
pub struct Reply {
    /// Intents for the supervisor to check and carry out.
    pub intents: Vec<Intent>,
    /// Set once the behaviour is done.
    pub verdict: Option<Verdict>,
}

/// The behaviour panicked; the message is its panic payload when it was text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Panicked(pub String);

/// Runs one behaviour.
pub struct BehaviourActor {
    behaviour: Box<dyn Behaviour>,
}

impl BehaviourActor {
    /// Wraps a behaviour.
    pub fn new(behaviour: Box<dyn Behaviour>) -> Self {
        Self { behaviour }
    }

    fn guarded(
        &mut self,
        f: impl FnOnce(&mut dyn Behaviour) -> Vec<Intent>,
    ) -> Result<Reply, Panicked> {
        let b = &mut self.behaviour;
        catch_unwind(AssertUnwindSafe(|| {
            let intents = f(b.as_mut());
            Reply {
                intents,
                verdict: b.verdict(),
            }
        }))
        .map_err(|payload| {
            let text = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "non-text panic".into());
            Panicked(text)
        })
    }
}

impl Actor for BehaviourActor {
    type Context = Context<Self>;
}

impl Handler<Start> for BehaviourActor {
    type Result = Result<Reply, Panicked>;
    fn handle(&mut self, msg: Start, _: &mut Context<Self>) -> Self::Result {
        self.guarded(|b| b.start(&msg.0))
    }
}

impl Handler<Snapshot> for BehaviourActor {
    type Result = Result<Reply, Panicked>;
    fn handle(&mut self, msg: Snapshot, _: &mut Context<Self>) -> Self::Result {
        self.guarded(|b| b.on_snapshot(&msg.0))
    }
}

impl Handler<Event> for BehaviourActor {
    type Result = Result<Reply, Panicked>;
    fn handle(&mut self, msg: Event, _: &mut Context<Self>) -> Self::Result {
        self.guarded(|b| b.on_event(msg.robot, &msg.kind, &msg.world))
    }
}

impl Handler<Held> for BehaviourActor {
    type Result = Result<Reply, Panicked>;
    fn handle(&mut self, msg: Held, _: &mut Context<Self>) -> Self::Result {
        self.guarded(|b| {
            let mut out = Vec::new();
            for (intent, reason) in &msg.held {
                out.extend(b.on_held(intent, reason, &msg.world));
            }
            out
        })
    }
}

impl Handler<Localised> for BehaviourActor {
    type Result = Result<Reply, Panicked>;
    fn handle(&mut self, msg: Localised, _: &mut Context<Self>) -> Self::Result {
        self.guarded(|b| b.on_localisation(msg.robot, &msg.event, &msg.world))
    }
}
