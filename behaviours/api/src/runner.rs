//! [`Runner`]: a behaviour with its [`Team`], calling its hooks through the team's books and
//! nothing more once it has a verdict. The supervisor's actor shell and the testing
//! [`Harness`](crate::testing::Harness) both drive a behaviour through it.

use crate::behaviour::Behaviour;
use crate::event::Event;
use crate::intent::Intent;
use crate::snapshot::{LocalisationEvent, WorldSnapshot};
use crate::team::Team;
use crate::verdict::Verdict;

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

/// A behaviour with its [`Team`]: calls its hooks, keeps the team's books on what goes in and
/// out, and calls nothing more once it has a verdict. The supervisor's actor shell and
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

    /// A new snapshot; held moves under `HeldPolicy::Retry` and `RetryThenReplan` go out
    /// again first.
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
        match event {
            LocalisationEvent::Lost { .. } => self.team.lost(robot),
            LocalisationEvent::Found => self.team.found(),
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
