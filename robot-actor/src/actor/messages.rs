//! The actor's public vocabulary: its configuration, the messages it answers, the events and
//! state updates it publishes, and the snapshot it gives.

use std::time::Duration;

use actix::prelude::*;
use protocol::packets::{self, CalibrationAction, Hello, MoveOutcome};
use protocol::{RobotState, Settings};
use tokio::time::Instant;

use super::{LinkStats, RobotError};
use crate::odometry::Pose;

/// The state reflector's mode and period (thesis 9.7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReflectorSetup {
    /// What to reflect.
    pub mode: packets::ReflectorMode,
    /// Period, milliseconds.
    pub period_ms: u16,
}

/// Tunables of a robot actor.
#[derive(Clone, Debug)]
pub struct RobotConfig {
    /// State reflector set on every connect.
    pub reflector: ReflectorSetup,
    /// Ping period; also keeps the robot's link watchdog fed.
    pub ping_period: Duration,
    /// Silence after which the link counts as lost.
    pub link_timeout: Duration,
    /// First reconnect delay; doubles up to `max_backoff`.
    pub min_backoff: Duration,
    /// Longest reconnect delay.
    pub max_backoff: Duration,
    /// Where odometry starts.
    pub origin: Pose,
    /// Batch subscribers get this robot's states gathered with its arbiter's other robots', once
    /// per pass of the arbiter, instead of a message per state: for robots on shard arbiters
    /// (see [`crate::Shards`]), whose subscriber is on another thread. Off, each state is sent at
    /// once, as a batch of one, so a single-threaded (paused-clock) run keeps its interleaving.
    pub batch_states: bool,
}

impl Default for RobotConfig {
    fn default() -> Self {
        Self {
            reflector: ReflectorSetup {
                mode: packets::ReflectorMode::Full,
                period_ms: 50,
            },
            ping_period: Duration::from_millis(100),
            link_timeout: Duration::from_millis(1000),
            min_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_secs(2),
            origin: Pose::default(),
            batch_states: false,
        }
    }
}

pub use protocol::MoveCommand;

/// Something the robot reported, or the link did.
#[derive(Clone, Debug, PartialEq)]
pub enum RobotEventKind {
    /// The robot introduced itself.
    Connected(Hello),
    /// The link was lost.
    LinkLost,
    /// A move ended.
    MoveFinished {
        /// Move id.
        id: u16,
        /// The tag the move was queued with ([`Enqueue::tag`]; 0 when none was given).
        tag: u32,
        /// How.
        outcome: MoveOutcome,
    },
    /// The queue ran empty.
    QueueEmpty,
    /// An obstacle reflection.
    Obstacle(packets::Obstacle),
    /// Another robot identified.
    Encounter(packets::RobotEncountered),
    /// Line lost (`true`) or found.
    Line(bool),
    /// The robot's watchdog stopped it.
    WatchdogStop,
    /// The robot's main loop overran.
    Overrun(u32),
    /// The robot felt a bump.
    Bump(packets::Bump),
    /// The robot's proximity reflex stopped it.
    Reflex(packets::Reflex),
    /// A command was refused.
    Refused(packets::Nack),
}

/// An event from one robot.
#[derive(Clone, Debug, Message)]
#[rtype(result = "()")]
pub struct RobotEvent {
    /// Robot id.
    pub robot_id: u16,
    /// When it arrived.
    pub at: Instant,
    /// When it happened, the robot's uptime in milliseconds (events the robot numbers; `None`
    /// for what the host itself noticed: a hello, a lost link, a refusal).
    pub robot_ms: Option<u32>,
    /// What happened.
    pub kind: RobotEventKind,
}

/// A new reflected state (full or reduced) and the odometry pose from it.
#[derive(Clone, Copy, Debug, Message)]
#[rtype(result = "()")]
pub struct StateUpdated {
    /// Robot id.
    pub robot_id: u16,
    /// When it arrived.
    pub at: Instant,
    /// The reflected state (fields a reduced packet does not carry keep their last value).
    pub state: RobotState,
    /// Whether this update came from a reduced packet.
    pub reduced: bool,
    /// Odometry pose.
    pub pose: Pose,
    /// The longest of the link's recent round trips (`None` before the first pong): how long a
    /// command sent now may take to reach the robot, and its answer to come back.
    pub rtt: Option<Duration>,
}

/// Everything the actor knows about its robot.
#[derive(Clone, Debug)]
pub struct RobotSnapshot {
    /// Robot id (0 before the first hello).
    pub robot_id: u16,
    /// The link's peer.
    pub peer: String,
    /// Whether a link is up and the hello arrived.
    pub connected: bool,
    /// The hello.
    pub hello: Option<Hello>,
    /// Reflected state.
    pub state: RobotState,
    /// When the last full state arrived.
    pub full_state_at: Option<Instant>,
    /// When the last reduced state arrived.
    pub reduced_state_at: Option<Instant>,
    /// Settings mirror (valid once `settings_known`).
    pub settings: Settings,
    /// Whether every settings chunk was read back since the last connect.
    pub settings_known: bool,
    /// Odometry pose.
    pub pose: Pose,
    /// Encoder totals since the odometry origin.
    pub odometry_totals: (i64, i64),
    /// Link statistics.
    pub link: LinkStats,
    /// Moves waiting for their finish event.
    pub pending_moves: usize,
    /// Why the latest attempt to open a link failed, until one opens.
    pub link_error: Option<String>,
    /// Why the robot was refused after its hello, if it was.
    pub refused: Option<RobotError>,
}

/// Registers a state subscriber.
#[derive(Message)]
#[rtype(result = "()")]
pub struct Subscribe(pub Recipient<StateUpdated>);

/// Registers an event subscriber.
#[derive(Message)]
#[rtype(result = "()")]
pub struct SubscribeEvents(pub Recipient<RobotEvent>);

/// Asks for a [`RobotSnapshot`].
#[derive(Message)]
#[rtype(result = "RobotSnapshot")]
pub struct GetSnapshot;

/// Waits until the robot has said hello (resolves at once if it has).
#[derive(Message)]
#[rtype(result = "Result<Hello, RobotError>")]
pub struct WaitConnected;

/// Enqueues a move; resolves when the robot reports it finished.
#[derive(Message)]
#[rtype(result = "Result<MoveOutcome, RobotError>")]
pub struct Enqueue {
    /// The move.
    pub command: MoveCommand,
    /// A word of the caller's that comes back in the move's [`RobotEventKind::MoveFinished`], so
    /// a subscriber can tell which of its moves ended without knowing the robot's move ids.
    pub tag: u32,
}

impl Enqueue {
    /// A move with no tag (0).
    pub fn new(command: MoveCommand) -> Self {
        Self { command, tag: 0 }
    }

    /// A move carrying `tag` back in its finished event.
    pub fn tagged(command: MoveCommand, tag: u32) -> Self {
        Self { command, tag }
    }
}

/// Resolves when the robot has no queued move left.
#[derive(Message)]
#[rtype(result = "Result<(), RobotError>")]
pub struct WaitIdle;

/// A command with no answer beyond being sent.
#[derive(Clone, Copy, Debug, Message)]
#[rtype(result = "Result<(), RobotError>")]
pub enum Command {
    /// Drop every queued move.
    ClearQueue,
    /// Stop everything now.
    Stop,
    /// Hold wheel speeds (m/s).
    WheelSpeeds(f32, f32),
    /// Apply motor duties (permille).
    MotorPower(i16, i16),
    /// Follow the line at a speed (m/s), or stop following (`None`).
    FollowLine(Option<f32>),
    /// A line sensor calibration step.
    CalibrateLine(CalibrationAction),
    /// Set the status LED.
    Led(u8, u8, u8),
    /// Attach a message word to the robot's IR frames.
    IrMessage(u16),
    /// Reconfigure the state reflector.
    Reflector(ReflectorSetup),
}

/// Writes one settings range; resolves when read-back confirms it.
#[derive(Message)]
#[rtype(result = "Result<(), RobotError>")]
pub struct WriteSettings {
    /// Byte offset.
    pub offset: usize,
    /// New bytes.
    pub bytes: Vec<u8>,
}

/// Reads every setting back from the robot.
#[derive(Message)]
#[rtype(result = "Result<Settings, RobotError>")]
pub struct ReadSettings;

/// Stores the robot's settings in its flash.
#[derive(Message)]
#[rtype(result = "Result<(), RobotError>")]
pub struct SaveSettings;

/// Restores the factory settings and reads them back.
#[derive(Message)]
#[rtype(result = "Result<Settings, RobotError>")]
pub struct RestoreDefaults;

/// Moves the odometry origin.
#[derive(Message)]
#[rtype(result = "()")]
pub struct SetOdometryOrigin(pub Pose);

/// Carries the odometry on from an earlier host's record of this robot (`coordinator --resume`):
/// at `pose` when its clock read `uptime_ms` and its counters `counters`. Says how far the robot
/// went since, by its counters, or that it restarted (then nothing since is known).
#[derive(Message)]
#[rtype(result = "Continued")]
pub struct ContinueOdometry {
    /// Where the robot was.
    pub pose: Pose,
    /// Its clock then.
    pub uptime_ms: u32,
    /// Its encoder counters then, left and right.
    pub counters: (i32, i32),
}

/// What the robot's own counters say happened since a [`ContinueOdometry`] record.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Continued {
    /// A state has arrived on this link since the hello (otherwise nothing is known yet).
    pub reported: bool,
    /// Its clock went back: it restarted, its counters are new and the odometry starts afresh at
    /// the recorded pose.
    pub rebooted: bool,
    /// Distance driven since the record (mean of the wheels), metres.
    pub driven_m: f64,
    /// Heading turned since the record, radians.
    pub turned_rad: f64,
    /// Robot time since the record, milliseconds.
    pub elapsed_ms: u32,
}

/// Closes the link and stops the actor.
#[derive(Message)]
#[rtype(result = "()")]
pub struct Close;
