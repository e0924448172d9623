//! `Robot`: an async handle over a [`RobotActor`] address, the API an application programmer uses
//! (thesis A.1): connect, read the pose, queue moves and await them, change one setting.

use std::sync::Arc;

use actix::{Actor, Addr, ArbiterHandle, MailboxError, Recipient};
use futures::future::BoxFuture;
use futures::FutureExt;
use protocol::packets::{Hello, MoveOutcome};
use protocol::Settings;

use crate::actor::*;
use crate::link::Connector;
use crate::odometry::Pose;
use crate::settings::Field;

/// Why a call on a [`Robot`] failed.
#[derive(Debug, thiserror::Error)]
pub enum CallError {
    /// The robot refused or the link failed.
    #[error(transparent)]
    Robot(#[from] RobotError),
    /// The actor is gone.
    #[error("robot actor stopped: {0}")]
    Mailbox(#[from] MailboxError),
}

/// A robot on the host.
#[derive(Clone)]
pub struct Robot {
    addr: Addr<RobotActor>,
}

impl Robot {
    /// Starts a robot actor on the current arbiter, connecting through `connector`.
    pub fn start(connector: Arc<dyn Connector>, config: RobotConfig) -> Self {
        Self {
            addr: RobotActor::new(connector, config).start(),
        }
    }

    /// Starts a robot actor on `arbiter` (see [`crate::Shards`]).
    pub fn start_in(
        arbiter: &ArbiterHandle,
        connector: Arc<dyn Connector>,
        config: RobotConfig,
    ) -> Self {
        Self {
            addr: RobotActor::start_in_arbiter(arbiter, move |_| {
                RobotActor::new(connector, config)
            }),
        }
    }

    /// The actor's address, for messages this handle does not wrap.
    pub fn addr(&self) -> &Addr<RobotActor> {
        &self.addr
    }

    /// Waits for the robot's hello.
    pub async fn connected(&self) -> Result<Hello, CallError> {
        Ok(self.addr.send(WaitConnected).await??)
    }

    /// Everything the actor knows.
    pub async fn snapshot(&self) -> Result<RobotSnapshot, CallError> {
        Ok(self.addr.send(GetSnapshot).await?)
    }

    /// Odometry pose.
    pub async fn pose(&self) -> Result<Pose, CallError> {
        Ok(self.snapshot().await?.pose)
    }

    /// Calls `on_state` with every reflected state.
    pub fn subscribe(&self, on_state: Recipient<StateUpdated>) {
        self.addr.do_send(Subscribe(on_state));
    }

    /// Sends every reflected state to `on_states` in [`StateBatch`]es: one per pass of the robot's
    /// arbiter when it is on a shard, one per state otherwise.
    pub fn subscribe_batches(&self, on_states: Recipient<StateBatch>) {
        self.addr.do_send(SubscribeBatches(on_states));
    }

    /// Calls `on_event` with every robot event.
    pub fn subscribe_events(&self, on_event: Recipient<RobotEvent>) {
        self.addr.do_send(SubscribeEvents(on_event));
    }

    /// Queues a move now and returns a future of its end: moves queued back to back keep their
    /// order whether or not their futures are awaited in between.
    pub fn queue(&self, m: MoveCommand) -> BoxFuture<'static, Result<MoveOutcome, CallError>> {
        let sent = self.addr.send(Enqueue::new(m));
        async move { Ok(sent.await??) }.boxed()
    }

    /// Queues a straight move (see [`Robot::queue`]).
    pub fn straight(
        &self,
        distance_m: f32,
        speed_mps: f32,
    ) -> BoxFuture<'static, Result<MoveOutcome, CallError>> {
        self.queue(MoveCommand::Straight {
            distance_m,
            speed_mps,
        })
    }

    /// Queues a rotation in place, degrees CCW positive (see [`Robot::queue`]).
    pub fn rotate(
        &self,
        angle_deg: f32,
        speed_mps: f32,
    ) -> BoxFuture<'static, Result<MoveOutcome, CallError>> {
        self.queue(MoveCommand::Rotate {
            angle_deg,
            speed_mps,
        })
    }

    /// Waits until no queued move is left.
    pub async fn wait_idle(&self) -> Result<(), CallError> {
        Ok(self.addr.send(WaitIdle).await??)
    }

    /// Sends a command.
    pub async fn command(&self, c: Command) -> Result<(), CallError> {
        Ok(self.addr.send(c).await??)
    }

    /// Writes one setting: one update packet with exactly the field's bytes, confirmed by read-back.
    pub async fn set<T: bytemuck::Pod>(&self, field: Field<T>, value: T) -> Result<(), CallError> {
        let msg = WriteSettings {
            offset: field.offset(),
            bytes: field.bytes(value),
        };
        Ok(self.addr.send(msg).await??)
    }

    /// Reads every setting back.
    pub async fn read_settings(&self) -> Result<Settings, CallError> {
        Ok(self.addr.send(ReadSettings).await??)
    }

    /// Saves the settings to the robot's flash.
    pub async fn save_settings(&self) -> Result<(), CallError> {
        Ok(self.addr.send(SaveSettings).await??)
    }

    /// Restores the factory settings and reads them back.
    pub async fn restore_defaults(&self) -> Result<Settings, CallError> {
        Ok(self.addr.send(RestoreDefaults).await??)
    }

    /// Closes the link and stops the actor.
    pub fn close(&self) {
        self.addr.do_send(Close);
    }
}
