//! The greeting: the robot says hello when a link opens and when asked; the actor takes one hello
//! per link, refuses a robot whose protocol or layouts differ from the host's, and otherwise sets
//! the reflector, replays the host's settings writes and reads the settings back.

use actix::prelude::*;
use protocol::packets::{self, Hello};
use tokio::sync::oneshot;
use tracing::{info, warn};

use super::{incompatibilities, Reply, RobotActor, RobotError, RobotEventKind, WaitConnected};

/// What the robot said and whether the actor accepted it.
#[derive(Default)]
pub(super) struct Greeting {
    /// The latest hello, kept across links: it names the robot.
    pub(super) hello: Option<Hello>,
    /// Whether the robot said hello on the current link.
    pub(super) greeted: bool,
    /// Set when the hello showed an incompatible robot: the actor then stays disconnected.
    pub(super) refused: Option<RobotError>,
    /// Callers of [`WaitConnected`] waiting for the next hello.
    waiters: Vec<Reply<Hello>>,
}

impl RobotActor {
    pub(super) fn on_hello(&mut self, hello: Hello) {
        // A robot greets when a link opens and after a reboot: either way its event numbers
        // start again.
        self.delivery.reset();
        if self.greeting.greeted || self.greeting.refused.is_some() {
            // The robot greets on connect and on request: one link, one greeting.
            return;
        }
        let reconnect = self.greeting.hello.is_some();
        self.greeting.hello = Some(hello);
        let differences = incompatibilities(&hello);
        if !differences.is_empty() {
            self.refuse(RobotError::Incompatible {
                robot: hello.robot_id,
                differences,
            });
            return;
        }
        self.greeting.greeted = true;
        self.moves.greeted();
        let r = self.config.reflector;
        let _ = self.send(&packets::ReflectorConfig {
            mode: r.mode as u8,
            period_ms: r.period_ms,
        });
        info!(robot = { hello.robot_id }, "hello");
        if reconnect {
            self.link.stats.reconnects += 1;
        }
        // Host-made changes survive a robot reboot or a reconnect.
        let writes: Vec<(usize, Vec<u8>)> = self
            .mirror
            .host_writes
            .iter()
            .map(|(o, b)| (*o, b.clone()))
            .collect();
        for (offset, bytes) in writes {
            if let Some(u) = packets::SettingsUpdate::new(offset as u16, &bytes) {
                let _ = self.send(&u);
            }
        }
        self.request_all_settings();
        for w in self.greeting.waiters.drain(..) {
            let _ = w.send(Ok(hello));
        }
        self.emit(RobotEventKind::Connected(hello));
    }

    /// Closes the link for good: every waiter and every later command gets `refusal`.
    fn refuse(&mut self, refusal: RobotError) {
        warn!(error = %refusal, "robot refused");
        // Dropping the only sender ends the link's I/O task, which closes the connection; its
        // last events belong to an old generation and are ignored.
        self.link.generation += 1;
        self.link.tx = None;
        self.link.counters = None;
        self.greeting.greeted = false;
        for w in self.greeting.waiters.drain(..) {
            let _ = w.send(Err(refusal.clone()));
        }
        self.greeting.refused = Some(refusal);
    }
}

impl Handler<WaitConnected> for RobotActor {
    type Result = ResponseFuture<Result<Hello, RobotError>>;
    fn handle(&mut self, _: WaitConnected, _: &mut Self::Context) -> Self::Result {
        if let (Some(h), true) = (
            self.greeting.hello,
            self.link.tx.is_some() && self.greeting.greeted,
        ) {
            return Box::pin(async move { Ok(h) });
        }
        if let Some(refusal) = self.greeting.refused.clone() {
            return Box::pin(async move { Err(refusal) });
        }
        let (tx, rx) = oneshot::channel();
        self.greeting.waiters.push(tx);
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}
