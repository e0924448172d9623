//! `BehaviourActor`: the thin actix shell a behaviour runs in. The supervisor sends it snapshots
//! and events; each reply carries the behaviour's intents and, once it is done, its verdict. A
//! panic inside the behaviour is caught and reported, so the supervisor can stop every robot and
//! restart it.

use std::panic::{catch_unwind, AssertUnwindSafe};

use actix::prelude::*;
use robot_actor::RobotEventKind;

use crate::api::{Behaviour, Intent, LocalisationEvent, Verdict, WorldSnapshot};
use crate::event::Event;
use crate::team::Team;

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
pub struct FromRobot {
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
    /// The behaviour's [`Behaviour::progress`] while it runs.
    pub progress: Vec<(String, f64)>,
}

/// The behaviour panicked; the message is its panic payload when it was text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Panicked(pub String);

/// A behaviour with its [`Team`]: calls its hooks, keeps the team's books on what goes in and
/// out, and calls nothing more once it has a verdict. [`BehaviourActor`] and
/// [`crate::testing::Harness`] both drive a behaviour through it.
pub struct Runner<B: Behaviour + ?Sized = dyn Behaviour> {
    behaviour: Box<B>,
    team: Team,
    verdict: Option<Verdict>,
}

impl<B: Behaviour + ?Sized> Runner<B> {
    /// Wraps a behaviour; its team is formed from the robots of the first snapshot.
    pub fn new(behaviour: Box<B>) -> Self {
        let team = Team::new([], behaviour.held_policy());
        Self {
            behaviour,
            team,
            verdict: None,
        }
    }

    /// The team's books.
    pub fn team(&self) -> &Team {
        &self.team
    }

    /// The behaviour.
    pub fn behaviour(&self) -> &B {
        &self.behaviour
    }

    /// The verdict, once given.
    pub fn verdict(&self) -> Option<&Verdict> {
        self.verdict.as_ref()
    }

    /// The experiment starts.
    pub fn start(&mut self, world: &WorldSnapshot) -> Reply {
        self.team = Team::new(
            world.robots.iter().map(|r| r.id),
            self.behaviour.held_policy(),
        );
        self.team.observe(world);
        self.call(|b, team| b.start(world, team))
    }

    /// A new snapshot; held moves under `HeldPolicy::Retry` go out again first.
    pub fn snapshot(&mut self, world: &WorldSnapshot) -> Reply {
        if self.verdict.is_some() {
            return Reply::default();
        }
        self.team.observe(world);
        let retries = self.team.retries();
        let mut reply = self.call(|b, team| b.on_snapshot(world, team));
        if !retries.is_empty() {
            reply.intents.splice(0..0, retries);
        }
        reply
    }

    /// A robot's event.
    pub fn event(&mut self, robot: u16, event: &Event, world: &WorldSnapshot) -> Reply {
        if self.verdict.is_some() {
            return Reply::default();
        }
        if !self.team.event(robot, event) {
            return Reply::default();
        }
        self.call(|b, team| b.on_event(robot, event, world, team))
    }

    /// Intents the supervisor held back, with its reasons.
    pub fn held(&mut self, held: &[(Intent, String)], world: &WorldSnapshot) -> Reply {
        if self.verdict.is_some() {
            return Reply::default();
        }
        let tell: Vec<&(Intent, String)> = held
            .iter()
            .filter(|(intent, reason)| self.team.held(intent, reason, world.time))
            .collect();
        self.call(|b, team| {
            let mut out = Vec::new();
            for (intent, reason) in tell {
                out.extend(b.on_held(intent, reason, world, team));
            }
            out
        })
    }

    /// A robot was found lost or re-localised.
    pub fn localised(
        &mut self,
        robot: u16,
        event: &LocalisationEvent,
        world: &WorldSnapshot,
    ) -> Reply {
        if self.verdict.is_some() {
            return Reply::default();
        }
        if matches!(event, LocalisationEvent::Lost { .. }) {
            self.team.lost(robot);
        }
        self.call(|b, team| b.on_localisation(robot, event, world, team))
    }

    fn call(&mut self, f: impl FnOnce(&mut B, &mut Team) -> Vec<Intent>) -> Reply {
        if self.verdict.is_some() {
            return Reply::default();
        }
        let intents = f(&mut self.behaviour, &mut self.team);
        self.verdict = self
            .team
            .verdict()
            .cloned()
            .or_else(|| self.behaviour.verdict());
        let progress = if self.verdict.is_none() {
            self.behaviour.progress()
        } else {
            Vec::new()
        };
        Reply {
            intents: self.team.outgoing(intents),
            verdict: self.verdict.clone(),
            progress,
        }
    }
}

/// Runs one behaviour.
pub struct BehaviourActor {
    runner: Runner,
}

impl BehaviourActor {
    /// Wraps a behaviour.
    pub fn new(behaviour: Box<dyn Behaviour>) -> Self {
        Self {
            runner: Runner::new(behaviour),
        }
    }

    fn guarded(&mut self, f: impl FnOnce(&mut Runner) -> Reply) -> Result<Reply, Panicked> {
        let runner = &mut self.runner;
        catch_unwind(AssertUnwindSafe(|| f(runner))).map_err(|payload| {
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
        self.guarded(|r| r.start(&msg.0))
    }
}

impl Handler<Snapshot> for BehaviourActor {
    type Result = Result<Reply, Panicked>;
    fn handle(&mut self, msg: Snapshot, _: &mut Context<Self>) -> Self::Result {
        self.guarded(|r| r.snapshot(&msg.0))
    }
}

impl Handler<FromRobot> for BehaviourActor {
    type Result = Result<Reply, Panicked>;
    fn handle(&mut self, msg: FromRobot, _: &mut Context<Self>) -> Self::Result {
        let event = Event::from_robot(&msg.kind);
        self.guarded(|r| r.event(msg.robot, &event, &msg.world))
    }
}

impl Handler<Held> for BehaviourActor {
    type Result = Result<Reply, Panicked>;
    fn handle(&mut self, msg: Held, _: &mut Context<Self>) -> Self::Result {
        self.guarded(|r| r.held(&msg.held, &msg.world))
    }
}

impl Handler<Localised> for BehaviourActor {
    type Result = Result<Reply, Panicked>;
    fn handle(&mut self, msg: Localised, _: &mut Context<Self>) -> Self::Result {
        self.guarded(|r| r.localised(msg.robot, &msg.event, &msg.world))
    }
}
