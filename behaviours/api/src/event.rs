//! What a behaviour hears from a robot, typed: the robot actor's events with the wire codes
//! turned into names ([`Side`], [`MoveOutcome`]) and the fields a behaviour needs.

use std::time::Duration;

use protocol::packets::{MoveOutcome, NackReason, Side};

/// An IR reflection: something (a box, a wall, a robot) in front of or behind the robot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Obstacle {
    /// Which proximity unit saw it.
    pub side: Side,
    /// The weakest emitter power whose reflection came back: 1 is the weakest, so the closest.
    pub power_level: u8,
}

impl Obstacle {
    /// Seen at the weakest power: within a few centimetres.
    pub fn is_close(&self) -> bool {
        self.power_level == 1
    }
}

/// Another robot identified by its IR frames (thesis 7.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sighting {
    /// The robot seen.
    pub robot: u16,
    /// Which receiver saw it.
    pub side: Side,
    /// Its heading relative to the observer's, degrees (counter-clockwise positive).
    pub relative_heading_deg: i16,
    /// Estimated range, millimetres.
    pub range_mm: u16,
    /// The message word it carries (0: none; see `Intent::IrMessage`).
    pub message: u16,
}

/// The latest robot a front receiver identified: when, and the reach of the weakest power that
/// got through, an upper bound on the distance from the receiver to that robot's LED.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrontSighting {
    at: Duration,
    reach_m: f64,
}

impl FrontSighting {
    /// `s` heard at `at`, if the front receiver saw it.
    pub fn of(s: &Sighting, at: Duration) -> Option<Self> {
        (s.side == Side::Front).then(|| Self {
            at,
            reach_m: f64::from(s.range_mm) * 1e-3,
        })
    }

    /// The most the gap to the robot in front can be at `now`, sensor to sensor (the reach plus
    /// a robot's length), while the sighting is younger than `fresh`; infinite after that. A
    /// robot in view is reported again every report period, one out of view is not.
    pub fn gap_bound(&self, now: Duration, fresh: Duration) -> f64 {
        if now.saturating_sub(self.at) < fresh {
            self.reach_m + world::robot::LENGTH_M
        } else {
            f64::INFINITY
        }
    }
}

/// One robot's event, as a behaviour hears it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    /// The robot (re)connected and said hello; after a link loss its queue is empty.
    Connected,
    /// The link was lost: its queued moves are gone (the robot's watchdog stopped it).
    LinkLost,
    /// A move of this behaviour ended.
    MoveFinished {
        /// The tag the move was sent with (`Intent::Move::tag`).
        tag: u32,
        /// How it ended.
        outcome: MoveOutcome,
    },
    /// The robot's move queue ran empty.
    QueueEmpty,
    /// An IR reflection.
    Obstacle(Obstacle),
    /// Another robot identified.
    Sighting(Sighting),
    /// The line sensor lost the tape while following it.
    LineLost,
    /// The line sensor found the tape again.
    LineFound,
    /// The robot's watchdog stopped it (the host fell silent).
    WatchdogStop,
    /// The robot's main loop overran its period this many times.
    Overrun(u32),
    /// The robot felt itself moved by something other than its wheels (the world model has
    /// already widened its pose; where tape could fix it, the supervisor also stopped it to
    /// re-localise it, and elsewhere it drives on).
    Bumped {
        /// How far the bump moved it, as the robot estimated, metres.
        moved_m: f64,
    },
    /// The robot's proximity reflex stopped it short of something close on `side` (its moves
    /// ended `Blocked`).
    Reflexed {
        /// The receiver that saw it.
        side: Side,
    },
    /// The robot refused a command.
    Refused {
        /// The refused packet's type code.
        packet_type: u8,
        /// Why, when the robot gave a reason this host knows.
        reason: Option<NackReason>,
    },
}
