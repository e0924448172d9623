//! Move futures: the actor numbers each move it queues on the robot and resolves the caller's
//! future, and its finished event's tag, from the robot's own `MoveFinished`.

use std::collections::HashMap;
use std::time::Duration;

use actix::prelude::*;
use protocol::packets::{self, MoveOutcome};
use tokio::sync::oneshot;
use tokio::time::Instant;

use super::{Enqueue, MoveCommand, Reply, RobotActor, RobotError, RobotEventKind, WaitIdle};

/// A move sent to the robot whose end has not been reported.
struct InFlight {
    /// When it was sent.
    sent_at: Instant,
    /// The caller's tag ([`Enqueue::tag`]), returned in the finished event.
    tag: u32,
    /// The caller's future.
    reply: Reply<MoveOutcome>,
}

/// The moves the actor has queued on the robot.
pub(super) struct Moves {
    /// The id the next move gets; never 0.
    next_id: u16,
    /// Moves in flight by the robot's move id.
    in_flight: HashMap<u16, InFlight>,
    /// Callers of [`WaitIdle`].
    idle_waiters: Vec<Reply<()>>,
}

impl Moves {
    /// None queued; the first move gets id 1.
    pub(super) fn new() -> Self {
        Self {
            next_id: 1,
            in_flight: HashMap::new(),
            idle_waiters: Vec::new(),
        }
    }

    /// Moves waiting for their finish event.
    pub(super) fn pending(&self) -> usize {
        self.in_flight.len()
    }

    /// Fails every move in flight (saying how long each had waited) and every idle waiter.
    pub(super) fn link_lost(&mut self, robot: u16, now: Instant) {
        for (_, m) in self.in_flight.drain() {
            let _ = m.reply.send(Err(RobotError::LinkLost {
                robot,
                after: now - m.sent_at,
            }));
        }
        for w in self.idle_waiters.drain(..) {
            let _ = w.send(Err(RobotError::LinkLost {
                robot,
                after: Duration::ZERO,
            }));
        }
    }
}

impl RobotActor {
    pub(super) fn on_move_finished(&mut self, m: packets::MoveFinished) {
        let outcome = MoveOutcome::try_from(m.outcome).unwrap_or(MoveOutcome::Stopped);
        let mut tag = 0;
        if let Some(f) = self.moves.in_flight.remove(&{ m.move_id }) {
            tag = f.tag;
            let _ = f.reply.send(Ok(outcome));
        }
        self.emit(RobotEventKind::MoveFinished {
            id: m.move_id,
            tag,
            outcome,
        });
    }

    pub(super) fn on_queue_empty(&mut self) {
        if self.moves.in_flight.is_empty() {
            for w in self.moves.idle_waiters.drain(..) {
                let _ = w.send(Ok(()));
            }
        }
        self.emit(RobotEventKind::QueueEmpty);
    }
}

impl Handler<Enqueue> for RobotActor {
    type Result = ResponseFuture<Result<MoveOutcome, RobotError>>;
    fn handle(&mut self, msg: Enqueue, _: &mut Self::Context) -> Self::Result {
        let id = self.moves.next_id;
        self.moves.next_id = self.moves.next_id.wrapping_add(1).max(1);
        let sent = match msg.command {
            MoveCommand::Straight {
                distance_m,
                speed_mps,
            } => self.send(&packets::StraightMovement {
                distance_m,
                speed_mps,
                move_id: id,
            }),
            MoveCommand::Rotate {
                angle_deg,
                speed_mps,
            } => self.send(&packets::RotationMovement {
                angle_deg,
                speed_mps,
                move_id: id,
            }),
            MoveCommand::Arc {
                radius_m,
                angle_deg,
                speed_mps,
            } => self.send(&packets::ArcMovement {
                radius_m,
                angle_deg,
                speed_mps,
                move_id: id,
            }),
        };
        if let Err(e) = sent {
            return Box::pin(async move { Err(e) });
        }
        let (tx, rx) = oneshot::channel();
        self.moves.in_flight.insert(
            id,
            InFlight {
                sent_at: Instant::now(),
                tag: msg.tag,
                reply: tx,
            },
        );
        let robot = self.robot_id();
        Box::pin(async move {
            rx.await.unwrap_or(Err(RobotError::LinkLost {
                robot,
                after: Duration::ZERO,
            }))
        })
    }
}

impl Handler<WaitIdle> for RobotActor {
    type Result = ResponseFuture<Result<(), RobotError>>;
    fn handle(&mut self, _: WaitIdle, _: &mut Self::Context) -> Self::Result {
        if self.moves.in_flight.is_empty() {
            return Box::pin(async { Ok(()) });
        }
        let (tx, rx) = oneshot::channel();
        self.moves.idle_waiters.push(tx);
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}
