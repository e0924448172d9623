//! Move futures: the actor numbers each move it queues on the robot and resolves the caller's
//! future, and its finished event's tag, from the robot's own `MoveFinished`; a move the robot's
//! state shows it never took is sent again, in order (see `delivery`).

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
    /// When it was last sent (again).
    last_sent: Instant,
    /// Its frame, to send again.
    frame: Vec<u8>,
    /// The caller's tag ([`Enqueue::tag`]), returned in the finished event.
    tag: u32,
    /// The caller's future.
    reply: Reply<MoveOutcome>,
}

/// The moves the actor has queued on the robot.
pub(super) struct Moves {
    /// The id the next move gets; never 0.
    pub(super) next_id: u16,
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

    /// A robot greeted on a new link numbers its moves from 1 again; so does the host, once
    /// nothing from the old link is in flight (a lost link failed it all).
    pub(super) fn greeted(&mut self) {
        if self.in_flight.is_empty() {
            self.next_id = 1;
        }
    }

    /// Moves waiting for their finish event.
    pub(super) fn pending(&self) -> usize {
        self.in_flight.len()
    }

    /// The frames of the moves the robot has not taken (numbered after `taken`, its newest),
    /// oldest first, when the oldest was last sent at least `wait` ago; each counts as sent now.
    pub(super) fn not_taken(&mut self, taken: u16, wait: Duration) -> Vec<Vec<u8>> {
        let now = Instant::now();
        let mut ids: Vec<u16> = self
            .in_flight
            .keys()
            .copied()
            .filter(|&id| taken == 0 || super::delivery::after(id, taken))
            .collect();
        // Oldest first across a wrap: by distance from the robot's newest.
        ids.sort_by_key(|&id| id.wrapping_sub(taken));
        let Some(oldest) = ids.first().and_then(|id| self.in_flight.get(id)) else {
            return Vec::new();
        };
        if now - oldest.last_sent < wait {
            return Vec::new();
        }
        // A robot that took none since its hello (`taken` 0) and has moves in flight just
        // lost the first: the order is the host's, so the first id is the oldest in flight.
        let mut frames = Vec::with_capacity(ids.len());
        for id in ids {
            if let Some(m) = self.in_flight.get_mut(&id) {
                m.last_sent = now;
                frames.push(m.frame.clone());
            }
        }
        frames
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
        let at_ms = m.at_ms;
        let outcome = MoveOutcome::try_from(m.outcome).unwrap_or(MoveOutcome::Stopped);
        let mut tag = 0;
        if let Some(f) = self.moves.in_flight.remove(&{ m.move_id }) {
            tag = f.tag;
            let _ = f.reply.send(Ok(outcome));
        }
        self.emit_at(
            RobotEventKind::MoveFinished {
                id: m.move_id,
                tag,
                outcome,
            },
            Some(at_ms),
        );
    }

    pub(super) fn on_queue_empty(&mut self, at_ms: u32) {
        if self.moves.in_flight.is_empty() {
            for w in self.moves.idle_waiters.drain(..) {
                let _ = w.send(Ok(()));
            }
        }
        self.emit_at(RobotEventKind::QueueEmpty, Some(at_ms));
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
            } => self.send_frame(&packets::StraightMovement {
                distance_m,
                speed_mps,
                move_id: id,
            }),
            MoveCommand::Rotate {
                angle_deg,
                speed_mps,
            } => self.send_frame(&packets::RotationMovement {
                angle_deg,
                speed_mps,
                move_id: id,
            }),
            MoveCommand::Arc {
                radius_m,
                angle_deg,
                speed_mps,
            } => self.send_frame(&packets::ArcMovement {
                radius_m,
                angle_deg,
                speed_mps,
                move_id: id,
            }),
        };
        let frame = match sent {
            Ok(frame) => frame,
            Err(e) => return Box::pin(async move { Err(e) }),
        };
        let (tx, rx) = oneshot::channel();
        let now = Instant::now();
        self.moves.in_flight.insert(
            id,
            InFlight {
                sent_at: now,
                last_sent: now,
                frame,
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
