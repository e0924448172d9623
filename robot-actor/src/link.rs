//! Links: whole protocol packets between the host and one robot, whatever carries them.
//!
//! A [`Connector`] knows how to reach one robot and opens a [`Link`]: a pair of channels fed by an
//! I/O task the binding spawns (SLIP over a byte stream, L2CAP sequenced packets, the in-process
//! simulator with feature `sim`). The robot actor sees only packets, so every transport looks the
//! same to it, and a reconnect is just another `connect()`.

use std::fmt;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use futures::future::BoxFuture;
use tokio::sync::mpsc;

#[cfg(feature = "bluetooth")]
pub mod bluetooth;
pub mod scripted;
pub mod seqpacket;
#[cfg(feature = "sim")]
pub mod sim;
pub mod stream;
#[cfg(feature = "zenoh")]
pub mod zenoh;

/// Packets queued towards one robot before `send` waits.
pub const SEND_QUEUE: usize = 256;

/// Why a link failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LinkError {
    /// The address could not be understood.
    #[error("bad robot address {address:?}: {reason}")]
    BadAddress {
        /// The address as given.
        address: String,
        /// What is wrong with it.
        reason: String,
    },
    /// Connecting failed.
    #[error("cannot connect to {peer}: {source}")]
    Connect {
        /// Whom we tried.
        peer: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The link broke while in use.
    #[error("link to {peer} lost: {source}")]
    Lost {
        /// The peer.
        peer: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The transport is not available in this build or on this machine.
    #[error("{0} is not available: {1}")]
    Unavailable(&'static str, String),
}

/// What the I/O task reports to the link's owner.
#[derive(Debug)]
pub enum LinkEvent {
    /// One whole packet's bytes (not yet checked).
    Packet(Vec<u8>),
    /// The link closed: cleanly (`None`) or with an error.
    Closed(Option<LinkError>),
}

/// Counters kept by a link's I/O task.
#[derive(Debug, Default)]
pub struct LinkCounters {
    /// Packets received.
    pub packets_in: AtomicU64,
    /// Packets sent.
    pub packets_out: AtomicU64,
    /// Frames the framing layer dropped (SLIP overflow or bad escape, oversize datagrams).
    pub framing_errors: AtomicU64,
}

impl LinkCounters {
    /// Adds one to a counter.
    pub fn bump(counter: &AtomicU64) {
        counter.fetch_add(1, Ordering::Relaxed);
    }
}

/// An open link: send packets with `tx`, receive [`LinkEvent`]s from `rx`.
pub struct Link {
    /// Who is at the other end.
    pub peer: String,
    /// Packets to the robot.
    pub tx: mpsc::Sender<Vec<u8>>,
    /// Packets and the close from the robot.
    pub rx: mpsc::UnboundedReceiver<LinkEvent>,
    /// Counters of the I/O task.
    pub counters: Arc<LinkCounters>,
}

impl fmt::Debug for Link {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Link").field("peer", &self.peer).finish()
    }
}

/// Reaches one robot; each `connect` opens a fresh link.
pub trait Connector: Send + Sync + 'static {
    /// Where the robot is, for logs and reports.
    fn peer(&self) -> String;
    /// Opens a link.
    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>>;
}

/// A discovered robot: its name and how to reach it.
#[derive(Clone)]
pub struct Discovered {
    /// Human-readable name (Bluetooth name, address, or simulator id).
    pub name: String,
    /// How to connect.
    pub connector: Arc<dyn Connector>,
}

impl fmt::Debug for Discovered {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Discovered")
            .field("name", &self.name)
            .field("peer", &self.connector.peer())
            .finish()
    }
}

/// Finds connectible robots (thesis 5.3).
pub trait Discoverer: Send + Sync {
    /// Every robot found.
    fn discover(&self) -> BoxFuture<'_, Result<Vec<Discovered>, LinkError>>;
}
