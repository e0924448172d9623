//! Why a command to a robot failed, and how a robot's hello can be incompatible with this host.

use std::time::Duration;

use protocol::packets::{Hello, NackReason};
use protocol::{Layout, RobotState};

/// Why a robot command failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RobotError {
    /// The link is down (and being re-established).
    #[error("robot {robot}: not connected")]
    NotConnected {
        /// Robot id (0 before the hello).
        robot: u16,
    },
    /// The link was lost while the command was pending.
    #[error("robot {robot}: link lost after {after:?}")]
    LinkLost {
        /// Robot id.
        robot: u16,
        /// How long the command had been pending.
        after: Duration,
    },
    /// The robot's hello shows a protocol or a layout other than this host's: the link was closed
    /// and the actor does not reconnect (moves or settings would be misread on either side).
    #[error("robot {robot} refused: {}", list(differences))]
    Incompatible {
        /// Robot id.
        robot: u16,
        /// What differs, in the order version, state layout, settings layout.
        differences: Vec<Incompatibility>,
    },
    /// The robot refused the command.
    #[error("robot {robot}: refused {packet}: {reason:?}")]
    Refused {
        /// Robot id.
        robot: u16,
        /// Which packet.
        packet: &'static str,
        /// Why.
        reason: Option<NackReason>,
    },
    /// The robot refused a settings write; `field` is the offending field's dotted path when the
    /// robot named one.
    #[error("robot {robot}: refused settings write: {reason:?}{}", .field.as_deref().map(|f| format!(" in {f}")).unwrap_or_default())]
    SettingRefused {
        /// Robot id.
        robot: u16,
        /// Dotted path of the offending field (`"geometry.ticks_per_rev"`), if named.
        field: Option<String>,
        /// Why.
        reason: Option<NackReason>,
    },
    /// A settings range is not whole fields inside the structure.
    #[error("bad settings range at {offset} (+{len})")]
    BadSettingsRange {
        /// Offset.
        offset: usize,
        /// Length.
        len: usize,
    },
    /// Read-back after a write returned other bytes.
    #[error("robot {robot}: settings at {offset} read back differently")]
    ReadBackMismatch {
        /// Robot id.
        robot: u16,
        /// Offset.
        offset: usize,
    },
    /// The send queue to the robot is full.
    #[error("robot {robot}: send queue full")]
    Congested {
        /// Robot id.
        robot: u16,
    },
}

/// One way a robot's hello differs from what this host speaks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Incompatibility {
    /// Another [`protocol::PROTOCOL_VERSION`].
    #[error("protocol version {robot}, host speaks {host}")]
    ProtocolVersion {
        /// The robot's.
        robot: u16,
        /// The host's.
        host: u16,
    },
    /// Another [`RobotState`] layout hash: reflected states would be misread.
    #[error("state layout {robot:#018x}, host knows {host:#018x}")]
    StateLayout {
        /// The robot's.
        robot: u64,
        /// The host's.
        host: u64,
    },
    /// Another [`Settings`](protocol::Settings) layout hash: settings would be written at the wrong
    /// offsets.
    #[error("settings layout {robot:#018x}, host knows {host:#018x}")]
    SettingsLayout {
        /// The robot's.
        robot: u64,
        /// The host's.
        host: u64,
    },
}

/// How `hello` differs from this host's protocol version and layouts (empty when it does not).
pub fn incompatibilities(hello: &Hello) -> Vec<Incompatibility> {
    let mut out = Vec::new();
    if hello.protocol_version != protocol::PROTOCOL_VERSION {
        out.push(Incompatibility::ProtocolVersion {
            robot: hello.protocol_version,
            host: protocol::PROTOCOL_VERSION,
        });
    }
    if hello.state_hash != RobotState::LAYOUT.hash {
        out.push(Incompatibility::StateLayout {
            robot: hello.state_hash,
            host: RobotState::LAYOUT.hash,
        });
    }
    if hello.settings_hash != protocol::SETTINGS_LAYOUT_HASH {
        out.push(Incompatibility::SettingsLayout {
            robot: hello.settings_hash,
            host: protocol::SETTINGS_LAYOUT_HASH,
        });
    }
    out
}

fn list(differences: &[Incompatibility]) -> String {
    let parts: Vec<String> = differences.iter().map(ToString::to_string).collect();
    parts.join("; ")
}
