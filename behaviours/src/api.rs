//! The behaviour contract: what a behaviour sees ([`WorldSnapshot`]), what it may ask for
//! ([`Intent`]), how it ends ([`Verdict`]), and how it is found by name ([`Registry`]).

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use protocol::RobotState;
use robot_actor::{MoveCommand, Pose, RobotEventKind};
use simulator::world::Track;

/// What the supervisor knows about one robot.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotView {
    /// Robot id.
    pub id: u16,
    /// Whether its link is up and it said hello.
    pub connected: bool,
    /// Best pose estimate in the world frame: odometry, corrected against the track geometry
    /// whenever the line sensor sees tape that the model can match.
    pub pose: Pose,
    /// Raw odometry pose in the world frame, as the robot's encoders alone give it.
    pub odometry: Pose,
    /// Latest reflected state.
    pub state: RobotState,
    /// Moves the host is still waiting for.
    pub pending_moves: usize,
    /// Where on the track graph it is: (track edge, offset along it in metres, distance from the
    /// tape in metres), if it is near the tape.
    pub on_track: Option<(usize, f64, f64)>,
}

/// A sighting of one robot by another (thesis 7.2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Encounter {
    /// Who saw.
    pub observer: u16,
    /// Whom.
    pub seen: u16,
    /// With which receiver (0 front, 1 rear).
    pub side: u8,
    /// Estimated heading of the seen robot relative to the observer's, degrees.
    pub relative_heading_deg: i16,
    /// Estimated range, millimetres.
    pub range_mm: u16,
    /// When, since the experiment started.
    pub at: Duration,
}

/// Everything a behaviour is shown at one instant.
#[derive(Clone, Debug, PartialEq)]
pub struct WorldSnapshot {
    /// Time since the experiment started.
    pub time: Duration,
    /// Every robot, in id order.
    pub robots: Vec<RobotView>,
    /// Encounters since the previous snapshot.
    pub encounters: Vec<Encounter>,
    /// Arena size, metres.
    pub arena: (f64, f64),
}

impl WorldSnapshot {
    /// The robot with `id`.
    pub fn robot(&self, id: u16) -> Option<&RobotView> {
        self.robots.iter().find(|r| r.id == id)
    }
}

/// What a behaviour asks the supervisor to do; every intent passes its safety check first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Intent {
    /// Queue a move.
    Move {
        /// Robot id.
        robot: u16,
        /// The move.
        command: MoveCommand,
    },
    /// Follow the line at a speed, or stop following (`None`).
    FollowLine {
        /// Robot id.
        robot: u16,
        /// Speed, m/s.
        speed: Option<f32>,
    },
    /// Hold wheel speeds, m/s.
    WheelSpeeds {
        /// Robot id.
        robot: u16,
        /// Left wheel.
        left: f32,
        /// Right wheel.
        right: f32,
    },
    /// Drop the robot's queued moves.
    ClearQueue {
        /// Robot id.
        robot: u16,
    },
    /// Stop one robot.
    Stop {
        /// Robot id.
        robot: u16,
    },
    /// Set a robot's LED.
    Led {
        /// Robot id.
        robot: u16,
        /// Colour.
        rgb: [u8; 3],
    },
    /// Attach a message word to a robot's IR frames.
    IrMessage {
        /// Robot id.
        robot: u16,
        /// Message.
        message: u16,
    },
}

impl Intent {
    /// The robot the intent is for.
    pub fn robot(&self) -> u16 {
        match *self {
            Intent::Move { robot, .. }
            | Intent::FollowLine { robot, .. }
            | Intent::WheelSpeeds { robot, .. }
            | Intent::ClearQueue { robot }
            | Intent::Stop { robot }
            | Intent::Led { robot, .. }
            | Intent::IrMessage { robot, .. } => robot,
        }
    }
}

/// How a behaviour judged its run.
#[derive(Clone, Debug, PartialEq)]
pub struct Verdict {
    /// Whether its success criteria held.
    pub success: bool,
    /// One line for the report.
    pub summary: String,
    /// Named figures for the report.
    pub metrics: Vec<(String, f64)>,
}

impl Verdict {
    /// A success.
    pub fn success(summary: impl Into<String>) -> Self {
        Self {
            success: true,
            summary: summary.into(),
            metrics: Vec::new(),
        }
    }

    /// A failure.
    pub fn failure(summary: impl Into<String>) -> Self {
        Self {
            success: false,
            summary: summary.into(),
            metrics: Vec::new(),
        }
    }

    /// Adds a figure.
    pub fn with(mut self, name: impl Into<String>, value: f64) -> Self {
        self.metrics.push((name.into(), value));
        self
    }
}

/// A behaviour: decision logic over snapshots and events, testable without actors.
pub trait Behaviour: Send + 'static {
    /// First intents, given the world as the experiment starts.
    fn start(&mut self, world: &WorldSnapshot) -> Vec<Intent>;
    /// Intents for a new snapshot.
    fn on_snapshot(&mut self, world: &WorldSnapshot) -> Vec<Intent>;
    /// Intents for a robot event (a move finished, an encounter, a lost line, …).
    fn on_event(
        &mut self,
        _robot: u16,
        _event: &RobotEventKind,
        _world: &WorldSnapshot,
    ) -> Vec<Intent> {
        Vec::new()
    }
    /// Intents for an intent of this behaviour that the supervisor's safety check held back
    /// (it never reached the robot); a behaviour that counts its moves must count this one out.
    fn on_held(&mut self, _intent: &Intent, _reason: &str, _world: &WorldSnapshot) -> Vec<Intent> {
        Vec::new()
    }
    /// The verdict once the behaviour is done; `None` while it runs.
    fn verdict(&self) -> Option<Verdict>;
}

/// Options every behaviour is built from.
#[derive(Clone, Debug, Default)]
pub struct BehaviourConfig {
    /// Robot ids taking part.
    pub robots: Vec<u16>,
    /// Seed for any randomness.
    pub seed: u64,
    /// Free-form parameters (`--param key=value`).
    pub params: BTreeMap<String, String>,
    /// The tape layout of the world, as the world file describes it (empty on a bare floor).
    pub track: Arc<Track>,
}

impl BehaviourConfig {
    /// Parameter `key` parsed as `T` and checked against `range`, or `default` when absent.
    ///
    /// # Errors
    /// A present value that does not parse or lies outside `range`, naming the key.
    pub fn param_in<T>(
        &self,
        key: &str,
        default: T,
        range: std::ops::RangeInclusive<T>,
    ) -> Result<T, String>
    where
        T: std::str::FromStr + PartialOrd + std::fmt::Display,
    {
        let v = self.param(key, default)?;
        if range.contains(&v) {
            Ok(v)
        } else {
            Err(format!(
                "parameter {key}={v}: expected {} to {}",
                range.start(),
                range.end()
            ))
        }
    }

    /// Parameter `key` parsed as `T`, or `default` when absent.
    ///
    /// # Errors
    /// A present value that does not parse, naming the key and the value.
    pub fn param<T: std::str::FromStr>(&self, key: &str, default: T) -> Result<T, String> {
        match self.params.get(key) {
            None => Ok(default),
            Some(v) => v
                .parse()
                .map_err(|_| format!("parameter {key}={v:?} is not a valid value")),
        }
    }
}

/// Builds a behaviour from its config, or says which parameter is wrong.
pub type Constructor = fn(&BehaviourConfig) -> Result<Box<dyn Behaviour>, String>;

/// One registered behaviour.
#[derive(Clone, Copy, Debug)]
pub struct Entry {
    /// What it does, one line.
    pub description: &'static str,
    /// The world preset it is meant for.
    pub world: &'static str,
    /// How to build it.
    pub constructor: Constructor,
}

/// Behaviours by name.
#[derive(Clone, Debug, Default)]
pub struct Registry {
    entries: BTreeMap<&'static str, Entry>,
}

impl Registry {
    /// An empty registry.
    pub fn new() -> Self {
        Self::default()
    }

    /// The built-in behaviours.
    pub fn builtin() -> Self {
        let mut r = Self::new();
        r.register(
            "square_walk",
            "every robot walks a 0.1 m square (thesis A.1); success when each closes within 10 mm \
             and its encoders measured the walk",
            "open",
            |cfg| Ok(Box::new(crate::square_walk::SquareWalk::new(cfg)?)),
        );
        r.register(
            "cooperative_push",
            "two robots find a box too heavy for one on the track and push it off together \
             (thesis A.2); success when it is clear and both lap again, pushes and laps measured by \
             their encoders",
            "push",
            |cfg| {
                Ok(Box::new(crate::cooperative_push::CooperativePush::new(
                    cfg,
                )?))
            },
        );
        r.register(
            "token_ring",
            "a token passes round robots following a track when they identify each other by IR \
             (thesis A.3), around a box, reversing each round; success after three rounds with \
             half a loop per round on each robot's encoders",
            "ring",
            |cfg| Ok(Box::new(crate::token_ring::TokenRing::new(cfg)?)),
        );
        r.register(
            "traffic_control",
            "robots serve streams of goal nodes on a track graph with a deadlock-free plan \
             (LaCAM) run as a dependency graph; success after 100 tasks without collision, the \
             edges driven measured by the encoders",
            "junction",
            |cfg| Ok(Box::new(crate::traffic_control::TrafficControl::new(cfg)?)),
        );
        r.register(
            "line_follow",
            "robots follow a closed track at their own speeds, keeping their distance; success \
             when each has driven its laps, measured by its encoders",
            "oval",
            |cfg| Ok(Box::new(crate::line_follow::LineFollow::new(cfg)?)),
        );
        r
    }

    /// Adds (or replaces) a behaviour.
    pub fn register(
        &mut self,
        name: &'static str,
        description: &'static str,
        world: &'static str,
        constructor: Constructor,
    ) {
        self.entries.insert(
            name,
            Entry {
                description,
                world,
                constructor,
            },
        );
    }

    /// A behaviour by name.
    pub fn get(&self, name: &str) -> Option<&Entry> {
        self.entries.get(name)
    }

    /// Every name, sorted.
    pub fn names(&self) -> Vec<&'static str> {
        self.entries.keys().copied().collect()
    }
}
