//! `BehaviourActor`: the thin actix shell a behaviour runs in. The supervisor sends it snapshots
//! and events; each reply carries the behaviour's intents and, once it is done, its verdict. A
//! panic inside the behaviour is caught and reported, so the supervisor can stop every robot and
//! restart it. Robot actor events become the behaviour's typed [`Event`]s here, so the behaviour
//! contract knows nothing of links.

use std::panic::{catch_unwind, AssertUnwindSafe};

use actix::prelude::*;
use behaviours::{
    Behaviour, Event, Intent, LocalisationEvent, Obstacle, Reply, Runner, Sighting, WorldSnapshot,
};
use protocol::packets::{NackReason, Side};
use robot_actor::RobotEventKind;

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

/// The behaviour panicked; the message is its panic payload when it was text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Panicked(pub String);

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
        let event = event_from_robot(&msg.kind);
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

/// The behaviour's view of a robot actor event.
pub fn event_from_robot(kind: &RobotEventKind) -> Event {
    let side = |code: u8| Side::try_from(code).unwrap_or(Side::Front);
    match kind {
        RobotEventKind::Connected(_) => Event::Connected,
        RobotEventKind::LinkLost => Event::LinkLost,
        RobotEventKind::MoveFinished { tag, outcome, .. } => Event::MoveFinished {
            tag: *tag,
            outcome: *outcome,
        },
        RobotEventKind::QueueEmpty => Event::QueueEmpty,
        RobotEventKind::Obstacle(o) => Event::Obstacle(Obstacle {
            side: side(o.side),
            power_level: o.power_level,
        }),
        RobotEventKind::Encounter(e) => Event::Sighting(Sighting {
            robot: e.robot_id,
            side: side(e.side),
            relative_heading_deg: e.relative_heading_deg,
            range_mm: e.range_mm,
            message: e.message,
        }),
        RobotEventKind::Line(true) => Event::LineLost,
        RobotEventKind::Line(false) => Event::LineFound,
        RobotEventKind::WatchdogStop => Event::WatchdogStop,
        RobotEventKind::Overrun(n) => Event::Overrun(*n),
        RobotEventKind::Bump(b) => Event::Bumped {
            moved_m: f64::from(b.moved_mm) * 1e-3,
        },
        RobotEventKind::Reflex(r) => Event::Reflexed { side: side(r.side) },
        RobotEventKind::Refused(n) => Event::Refused {
            packet_type: n.packet_type,
            reason: NackReason::try_from(n.reason).ok(),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::packets;

    #[test]
    fn wire_codes_become_names() {
        let seen = RobotEventKind::Encounter(packets::RobotEncountered {
            at_ms: 10,
            seq: 1,
            robot_id: 3,
            side: 1,
            led: 0,
            power_level: 2,
            relative_heading_deg: -90,
            range_mm: 40,
            message: 0,
        });
        let Event::Sighting(s) = event_from_robot(&seen) else {
            panic!("not a sighting");
        };
        assert_eq!((s.robot, s.side, s.range_mm), (3, Side::Rear, 40));
        let front = RobotEventKind::Obstacle(packets::Obstacle {
            at_ms: 20,
            seq: 2,
            side: 0,
            power_level: 1,
            led: 0,
        });
        assert_eq!(
            event_from_robot(&front),
            Event::Obstacle(Obstacle {
                side: Side::Front,
                power_level: 1
            })
        );
        assert_eq!(
            event_from_robot(&RobotEventKind::Line(true)),
            Event::LineLost
        );
    }
}
