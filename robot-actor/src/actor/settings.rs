//! The settings mirror: a byte copy of the robot's settings, read back in field-aligned chunks
//! after every hello; writes confirmed by their read-back and replayed after a reconnect; saves
//! and factory restores.

use std::collections::{BTreeMap, VecDeque};

use actix::prelude::*;
use protocol::packets::{self, NackReason};
use protocol::{Layout, Settings};
use tokio::sync::oneshot;

use super::{
    ReadSettings, Reply, RestoreDefaults, RobotActor, RobotError, SaveSettings, WriteSettings,
};
use crate::odometry::{Geometry, Odometry};
use crate::settings::read_chunks;

/// The host's copy of the robot's settings and the operations on them still in flight.
pub(super) struct SettingsMirror {
    /// The settings as last read back (whole once `chunks_missing` is 0 after a hello).
    pub(super) settings: Settings,
    /// Chunks of the latest full read still to come, and which (offset, length) they are: a
    /// write's read-back of the same range is answered after them (the robot answers in order),
    /// so the first such reply is the chunk's, with the value from before the write.
    pub(super) chunks_missing: usize,
    chunks: Vec<(usize, usize)>,
    /// Fields the host wrote, re-applied after a reconnect.
    pub(super) host_writes: BTreeMap<usize, Vec<u8>>,
    /// Writes waiting for their read-back, oldest first: offset, length, the bytes written and
    /// the caller's reply.
    read_backs: VecDeque<(usize, usize, Vec<u8>, Reply<()>)>,
    /// Callers waiting for a full read.
    full_reads: Vec<Reply<Settings>>,
    /// Saves waiting for the robot's confirmation, oldest first.
    saves: VecDeque<Reply<()>>,
}

impl SettingsMirror {
    /// Starts from `settings` (the factory defaults until the robot's are read back).
    pub(super) fn new(settings: Settings) -> Self {
        Self {
            settings,
            chunks_missing: 0,
            chunks: Vec::new(),
            host_writes: BTreeMap::new(),
            read_backs: VecDeque::new(),
            full_reads: Vec::new(),
            saves: VecDeque::new(),
        }
    }

    /// Fails every pending read, write and save with `lost()`.
    pub(super) fn link_lost(&mut self, lost: impl Fn() -> RobotError) {
        for (_, _, _, w) in self.read_backs.drain(..) {
            let _ = w.send(Err(lost()));
        }
        for w in self.full_reads.drain(..) {
            let _ = w.send(Err(lost()));
        }
        for w in self.saves.drain(..) {
            let _ = w.send(Err(lost()));
        }
    }

    /// The robot stored its settings: the oldest save is done.
    pub(super) fn saved(&mut self) {
        if let Some(w) = self.saves.pop_front() {
            let _ = w.send(Ok(()));
        }
    }

    /// The robot refused a save: the oldest one fails with `err`.
    pub(super) fn save_refused(&mut self, err: RobotError) {
        if let Some(w) = self.saves.pop_front() {
            let _ = w.send(Err(err));
        }
    }
}

impl RobotActor {
    pub(super) fn request_all_settings(&mut self) {
        let chunks = read_chunks();
        self.mirror.chunks_missing = chunks.len();
        self.mirror.chunks = chunks.clone();
        for (offset, len) in chunks {
            let _ = self.send(&packets::SettingsRead {
                offset: offset as u16,
                len: len as u8,
            });
        }
    }

    /// A refused write fails its pending `set`. The robot answers in order, so every earlier
    /// write's read-back has already arrived and the oldest pending write is the refused one. It
    /// is not replayed after a reconnect.
    pub(super) fn on_settings_refused(&mut self, n: packets::Nack, reason: Option<NackReason>) {
        let offset = n.field_offset;
        let field = (offset != packets::Nack::NO_FIELD).then(|| {
            Settings::path_of(usize::from(offset))
                .map_or_else(|| format!("offset {offset}"), |p| p.to_string())
        });
        if let Some((write_offset, _, _, reply)) = self.mirror.read_backs.pop_front() {
            self.mirror.host_writes.remove(&write_offset);
            let _ = reply.send(Err(RobotError::SettingRefused {
                robot: self.robot_id(),
                field,
                reason,
            }));
        }
    }

    pub(super) fn on_settings_data(&mut self, d: packets::SettingsData) {
        let offset = usize::from(d.offset);
        let bytes = d.bytes().to_vec();
        if self.mirror.settings.write(offset, &bytes).is_err() {
            return;
        }
        let chunk = self
            .mirror
            .chunks
            .iter()
            .position(|&c| c == (offset, bytes.len()));
        if let Some(k) = chunk {
            self.mirror.chunks.remove(k);
            self.mirror.chunks_missing = self.mirror.chunks.len();
            if self.mirror.chunks_missing == 0 {
                if self.odometry.totals() == (0, 0) {
                    // Odometry uses the robot's own wheel geometry once it is known.
                    let pose = self.odometry.pose();
                    self.odometry =
                        Odometry::new(Geometry::from_settings(&self.mirror.settings), pose);
                }
                let s = self.mirror.settings;
                for w in self.mirror.full_reads.drain(..) {
                    let _ = w.send(Ok(s));
                }
            }
            return;
        }
        let robot = self.robot_id();
        if let Some(pos) = self
            .mirror
            .read_backs
            .iter()
            .position(|(o, l, _, _)| *o == offset && *l == bytes.len())
        {
            if let Some((_, _, expected, reply)) = self.mirror.read_backs.remove(pos) {
                let r = if expected == bytes {
                    Ok(())
                } else {
                    Err(RobotError::ReadBackMismatch { robot, offset })
                };
                let _ = reply.send(r);
            }
        }
    }
}

impl Handler<WriteSettings> for RobotActor {
    type Result = ResponseFuture<Result<(), RobotError>>;
    fn handle(&mut self, msg: WriteSettings, _: &mut Self::Context) -> Self::Result {
        let (offset, len) = (msg.offset, msg.bytes.len());
        let prepared = self.layout_ok().and_then(|()| {
            Settings::check_range(offset, len)
                .map_err(|_| RobotError::BadSettingsRange { offset, len })?;
            packets::SettingsUpdate::new(offset as u16, &msg.bytes)
                .ok_or(RobotError::BadSettingsRange { offset, len })
        });
        let update = match prepared {
            Ok(u) => u,
            Err(e) => return Box::pin(async move { Err(e) }),
        };
        if let Err(e) = self.send(&update).and_then(|()| {
            self.send(&packets::SettingsRead {
                offset: offset as u16,
                len: len as u8,
            })
        }) {
            return Box::pin(async move { Err(e) });
        }
        self.mirror.host_writes.insert(offset, msg.bytes.clone());
        let (tx, rx) = oneshot::channel();
        self.mirror
            .read_backs
            .push_back((offset, len, msg.bytes, tx));
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}

impl Handler<ReadSettings> for RobotActor {
    type Result = ResponseFuture<Result<Settings, RobotError>>;
    fn handle(&mut self, _: ReadSettings, _: &mut Self::Context) -> Self::Result {
        if let Err(e) = self.layout_ok() {
            return Box::pin(async move { Err(e) });
        }
        let (tx, rx) = oneshot::channel();
        self.mirror.full_reads.push(tx);
        self.request_all_settings();
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}

impl Handler<SaveSettings> for RobotActor {
    type Result = ResponseFuture<Result<(), RobotError>>;
    fn handle(&mut self, _: SaveSettings, _: &mut Self::Context) -> Self::Result {
        if let Err(e) = self
            .layout_ok()
            .and_then(|()| self.send(&packets::SettingsSave {}))
        {
            return Box::pin(async move { Err(e) });
        }
        let (tx, rx) = oneshot::channel();
        self.mirror.saves.push_back(tx);
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}

impl Handler<RestoreDefaults> for RobotActor {
    type Result = ResponseFuture<Result<Settings, RobotError>>;
    fn handle(&mut self, _: RestoreDefaults, _: &mut Self::Context) -> Self::Result {
        if let Err(e) = self
            .layout_ok()
            .and_then(|()| self.send(&packets::SettingsRestoreDefaults {}))
        {
            return Box::pin(async move { Err(e) });
        }
        self.mirror.host_writes.clear();
        let (tx, rx) = oneshot::channel();
        self.mirror.full_reads.push(tx);
        self.request_all_settings();
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}

/// Which settings layout hash this host was built with (for reports).
pub fn host_settings_layout() -> u64 {
    Settings::LAYOUT.hash
}
