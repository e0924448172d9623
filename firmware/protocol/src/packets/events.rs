//! Events the robot reports: moves ending, the queue running empty, obstacles and other robots
//! seen, the line lost or found, the watchdog, and main loop overruns.

use crate::wire_struct;

wire_struct! {
    /// A queued move has ended.
    pub struct MoveFinished {
        /// When it happened, the robot's uptime in milliseconds.
        pub at_ms: u32,
        /// The robot's event number (1, 2, …, wrapping; 0 is never used), for the host to
        /// notice a lost event and ask for it again (`EventReplay`).
        pub seq: u16,
        /// The move's id.
        pub move_id: u16,
        /// A [`MoveOutcome`](super::MoveOutcome) code.
        pub outcome: u8,
    }
}

wire_struct! {
    /// The move queue ran empty.
    pub struct QueueEmpty {
        /// When it happened, the robot's uptime in milliseconds.
        pub at_ms: u32,
        /// The robot's event number (1, 2, …, wrapping; 0 is never used), for the host to
        /// notice a lost event and ask for it again (`EventReplay`).
        pub seq: u16,
    }
}

wire_struct! {
    /// The robot's own IR frame came back: something that is not a robot is close.
    pub struct Obstacle {
        /// When it happened, the robot's uptime in milliseconds.
        pub at_ms: u32,
        /// The robot's event number (1, 2, …, wrapping; 0 is never used), for the host to
        /// notice a lost event and ask for it again (`EventReplay`).
        pub seq: u16,
        /// A [`Side`](super::Side) code.
        pub side: u8,
        /// Weakest power level whose reflection was seen (1 = weakest = closest).
        pub power_level: u8,
        /// LED whose light came back.
        pub led: u8,
    }
}

wire_struct! {
    /// Another robot's IR frame was received (thesis 7.2).
    pub struct RobotEncountered {
        /// When it happened, the robot's uptime in milliseconds.
        pub at_ms: u32,
        /// The robot's event number (1, 2, …, wrapping; 0 is never used), for the host to
        /// notice a lost event and ask for it again (`EventReplay`).
        pub seq: u16,
        /// The other robot's id.
        pub robot_id: u16,
        /// A [`Side`](super::Side) code: which of our receivers saw it.
        pub side: u8,
        /// The other robot's LED that reached us (tells its orientation).
        pub led: u8,
        /// Weakest power level that reached us.
        pub power_level: u8,
        /// Estimated heading of the other robot relative to ours, degrees (CCW positive).
        pub relative_heading_deg: i16,
        /// Estimated distance, millimetres.
        pub range_mm: u16,
        /// Message word carried in its frames (0 = none).
        pub message: u16,
    }
}

wire_struct! {
    /// The line was lost or found again.
    pub struct LineEvent {
        /// When it happened, the robot's uptime in milliseconds.
        pub at_ms: u32,
        /// The robot's event number (1, 2, …, wrapping; 0 is never used), for the host to
        /// notice a lost event and ask for it again (`EventReplay`).
        pub seq: u16,
        /// 1 = lost, 0 = found.
        pub lost: u8,
        /// Line position before the change, micrometres.
        pub position_um: i16,
    }
}

wire_struct! {
    /// The link watchdog stopped the robot.
    pub struct WatchdogStop {
        /// When it happened, the robot's uptime in milliseconds.
        pub at_ms: u32,
        /// The robot's event number (1, 2, …, wrapping; 0 is never used), for the host to
        /// notice a lost event and ask for it again (`EventReplay`).
        pub seq: u16,
        /// How long the host had been silent, milliseconds.
        pub silent_ms: u32,
    }
}

wire_struct! {
    /// The main loop ran late by more than one period (thesis 11.1).
    pub struct LoopOverrun {
        /// When it happened, the robot's uptime in milliseconds.
        pub at_ms: u32,
        /// The robot's event number (1, 2, …, wrapping; 0 is never used), for the host to
        /// notice a lost event and ask for it again (`EventReplay`).
        pub seq: u16,
        /// How late, microseconds.
        pub late_us: u32,
    }
}

wire_struct! {
    /// The proximity reflex stopped the robot: it drove towards a surface close enough to return
    /// its own light at the reflex's power level (see `reflex.power_level`) within the last
    /// whole IR transmit cycle (about 0.1 s), not the state's obstacle summary, which remembers
    /// for two report periods.
    pub struct Reflex {
        /// When it stopped, the robot's uptime in milliseconds.
        pub at_ms: u32,
        /// The robot's event number, as every event carries it.
        pub seq: u16,
        /// The receiver that saw the surface, a [`Side`](super::Side) code.
        pub side: u8,
        /// The weakest power level that came back.
        pub power_level: u8,
    }
}

wire_struct! {
    /// The robot was moved by something other than its own wheels: a jolt its wheel speeds do
    /// not explain, or wheels turning while it stood idle.
    pub struct Bump {
        /// When the jolt began, the robot's uptime in milliseconds.
        pub at_ms: u32,
        /// The robot's event number, as every event carries it.
        pub seq: u16,
        /// The largest unexplained acceleration, milli-g.
        pub peak_mg: u16,
        /// How far the unexplained acceleration moved the robot, integrated twice over the
        /// jolt, millimetres; for wheels turned while idle, the wheels' travel.
        pub moved_mm: u16,
        /// The move along the robot's heading at the jolt's start, millimetres (negative:
        /// backwards; a wheel slipping forward under a load reads as a move backwards).
        pub along_mm: i16,
        /// The move to the robot's left, millimetres.
        pub left_mm: i16,
        /// A [`BumpCause`](super::BumpCause) code.
        pub cause: u8,
    }
}

/// An event: robot → host, stamped with the robot's time and numbered, so the host places it
/// when it happened and notices one that never arrived.
pub trait Event: crate::Packet {
    /// When it happened, the robot's uptime in milliseconds.
    fn at_ms(&self) -> u32;
    /// Its number.
    fn seq(&self) -> u16;
    /// Sets its time and number.
    fn stamp(&mut self, at_ms: u32, seq: u16);
}

macro_rules! events {
    ($($t:ty),*) => {$(
        impl Event for $t {
            fn at_ms(&self) -> u32 { self.at_ms }
            fn seq(&self) -> u16 { self.seq }
            fn stamp(&mut self, at_ms: u32, seq: u16) {
                self.at_ms = at_ms;
                self.seq = seq;
            }
        }
    )*};
}

events!(
    MoveFinished,
    QueueEmpty,
    Obstacle,
    RobotEncountered,
    LineEvent,
    WatchdogStop,
    LoopOverrun,
    Reflex,
    Bump
);
