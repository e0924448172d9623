//! The host end of one robot's link, and its sending half for a second task.

use std::sync::atomic::Ordering;
use std::sync::Arc;

use tokio::sync::{mpsc, oneshot};

use super::buffer::{HostBuffer, Sink};
use super::Command;

/// The host end of one robot's link.
pub struct LinkEnd {
    /// Robot id.
    pub robot_id: u16,
    pub(super) index: usize,
    pub(super) to_robot: Arc<HostBuffer>,
    pub(super) from_robot: mpsc::UnboundedReceiver<Vec<u8>>,
    pub(super) commands: mpsc::UnboundedSender<Command>,
}

impl LinkEnd {
    /// Opens the link: the robot answers with its hello.
    pub fn connect(&self) {
        let _ = self.commands.send(Command::Connect(self.index));
    }

    /// Closes the link; the robot's packets go nowhere until it is opened again.
    pub fn disconnect(&self) {
        let _ = self.commands.send(Command::Disconnect(self.index, None));
    }

    /// Sends one packet's bytes to the robot; `false` once the simulation has stopped. A packet
    /// that finds the host buffer full is dropped and counted, as a serial link would.
    pub fn send(&self, packet: Vec<u8>) -> bool {
        self.to_robot.send(&packet)
    }

    /// The next packet from the robot; `None` once the simulation has stopped.
    pub async fn recv(&mut self) -> Option<Vec<u8>> {
        self.from_robot.recv().await
    }

    /// A packet from the robot if one is waiting.
    pub fn try_recv(&mut self) -> Option<Vec<u8>> {
        self.from_robot.try_recv().ok()
    }

    /// Splits into a sender half and a receiver half for two tasks.
    pub fn split(self) -> (LinkSender, mpsc::UnboundedReceiver<Vec<u8>>) {
        (
            LinkSender {
                robot_id: self.robot_id,
                index: self.index,
                to_robot: self.to_robot,
                commands: self.commands,
            },
            self.from_robot,
        )
    }
}

/// The sending half of a [`LinkEnd`].
#[derive(Clone)]
pub struct LinkSender {
    /// Robot id.
    pub robot_id: u16,
    index: usize,
    to_robot: Arc<HostBuffer>,
    commands: mpsc::UnboundedSender<Command>,
}

impl LinkSender {
    /// Sends one packet's bytes to the robot; `false` once the simulation has stopped. A packet
    /// that finds the host buffer full is dropped and counted.
    pub fn send(&self, packet: Vec<u8>) -> bool {
        self.to_robot.send(&packet)
    }
    /// As [`send`](Self::send), copying the bytes only if they fit.
    pub fn send_slice(&self, packet: &[u8]) -> bool {
        self.to_robot.send(packet)
    }
    /// Counts a robot packet of `bytes` that the host side dropped because its own client did not
    /// keep up; it shows in the robot's link statistics.
    pub fn count_dropped_to_host(&self, bytes: usize) {
        self.to_robot.dropped_to_host(bytes);
    }
    /// Opens the link.
    pub fn connect(&self) {
        let _ = self.commands.send(Command::Connect(self.index));
    }
    /// From now on the stepping task hands the robot's packets to `sink` as they arrive, instead
    /// of to the receiver half: one task's wake less per packet. Replaces an earlier sink; returns
    /// the key that [`clear_sink`](Self::clear_sink) takes. Once the simulation has stopped, the
    /// sink hears so at once.
    pub fn set_sink(&self, mut sink: Sink) -> u64 {
        static KEYS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
        let key = KEYS.fetch_add(1, Ordering::Relaxed);
        let mut slot = self.to_robot.sink();
        if self.to_robot.stopped.load(Ordering::Acquire) {
            drop(slot);
            sink(None);
        } else {
            *slot = Some((key, sink));
        }
        key
    }
    /// Removes the sink set with `key`, if it is still the one set; the robot's packets go to the
    /// receiver half again.
    pub fn clear_sink(&self, key: u64) {
        let mut slot = self.to_robot.sink();
        if slot.as_ref().is_some_and(|(k, _)| *k == key) {
            *slot = None;
        }
    }
    /// Closes the link.
    pub fn disconnect(&self) {
        let _ = self.commands.send(Command::Disconnect(self.index, None));
    }
    /// Closes the link and waits until the simulation has discarded what was queued either way:
    /// after it, nothing the old host sent reaches the robot and nothing the robot sent the old host
    /// is still to come. Returns at once if the simulation has stopped.
    pub async fn close(&self) {
        let (tx, rx) = oneshot::channel();
        if self
            .commands
            .send(Command::Disconnect(self.index, Some(tx)))
            .is_ok()
        {
            let _ = rx.await;
        }
    }
}
