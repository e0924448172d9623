//! The behaviour contract: what a behaviour sees ([`WorldSnapshot`]), what it may ask for
//! ([`Intent`]), how it ends ([`Verdict`]), and how it is found by name ([`Registry`]).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use protocol::packets::Side;
use protocol::RobotState;
use robot_actor::{MoveCommand, Pose};
use world::Track;

use crate::event::Event;
use crate::team::{HeldPolicy, Team};

/// How well the world model knows a robot's pose: one standard deviation of its position (along
/// the worst direction) and of its heading. It grows with the distance driven and the angle
/// turned since the last fix and shrinks when the robot's sensors match the known world.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PoseUncertainty {
    /// Position, metres (1σ, major axis).
    pub position_m: f64,
    /// Heading, radians (1σ).
    pub heading_rad: f64,
}

/// Whether the world model trusts a robot's pose.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Localisation {
    /// The pose is tracked: what the robot senses agrees with the model.
    #[default]
    Tracking,
    /// What the robot senses contradicted the model: the supervisor has stopped it and holds
    /// every intent for it while it re-localises the robot.
    Lost,
}

/// A change in how the world model trusts a robot's pose, told to the behaviour.
#[derive(Clone, Debug, PartialEq)]
pub enum LocalisationEvent {
    /// The robot is lost: stopped, its queued moves dropped, its intents held until it is found.
    Lost {
        /// What contradicted the model.
        why: String,
    },
    /// The robot was re-localised and takes intents again.
    Found,
}

/// What the supervisor knows about one robot.
#[derive(Clone, Debug, Default, PartialEq)]
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
    /// Where on the tape its line sensor is, if it is over the tape.
    pub on_track: Option<TrackPosition>,
    /// How well the pose is known.
    pub uncertainty: PoseUncertainty,
    /// Whether the pose is trusted.
    pub localisation: Localisation,
    /// The pose in the first state report whose front IR saw something at the weakest power
    /// (within about 15 mm), while it still does. Pose and reading come from one report, so
    /// where an obstacle is follows from it whatever the link's latency.
    pub front_close_at: Option<Pose>,
}

/// A place on the tape: which track edge, how far along it, how far beside it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrackPosition {
    /// Track edge index (`world::Track::edges`).
    pub edge: usize,
    /// Distance along the edge from its start node, metres.
    pub along_m: f64,
    /// Distance from the tape's centre line, metres.
    pub offset_m: f64,
}

/// A sighting of one robot by another (thesis 7.2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Encounter {
    /// Who saw.
    pub observer: u16,
    /// Whom.
    pub seen: u16,
    /// With which receiver.
    pub side: Side,
    /// Estimated heading of the seen robot relative to the observer's, degrees.
    pub relative_heading_deg: i16,
    /// Estimated range, millimetres.
    pub range_mm: u16,
    /// When, since the experiment started.
    pub at: Duration,
}

/// Every robot's view, in id order, behind one shared pointer: cloning it or a snapshot copies
/// no view.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Robots(pub Arc<Vec<Arc<RobotView>>>);

impl std::ops::Deref for Robots {
    type Target = [Arc<RobotView>];
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl Robots {
    /// The list to change, copied first if another snapshot shares it.
    pub fn make_mut(&mut self) -> &mut Vec<Arc<RobotView>> {
        Arc::make_mut(&mut self.0)
    }
}

impl<'a> IntoIterator for &'a Robots {
    type Item = &'a Arc<RobotView>;
    type IntoIter = std::slice::Iter<'a, Arc<RobotView>>;
    fn into_iter(self) -> Self::IntoIter {
        self.0.iter()
    }
}

impl FromIterator<Arc<RobotView>> for Robots {
    fn from_iter<I: IntoIterator<Item = Arc<RobotView>>>(iter: I) -> Self {
        Self(Arc::new(iter.into_iter().collect()))
    }
}

impl From<Vec<Arc<RobotView>>> for Robots {
    fn from(v: Vec<Arc<RobotView>>) -> Self {
        Self(Arc::new(v))
    }
}

/// Everything a behaviour is shown at one instant.
#[derive(Clone, Debug, PartialEq)]
pub struct WorldSnapshot {
    /// Time since the experiment started.
    pub time: Duration,
    /// Every robot, in id order. The list and its views are shared with the world model and
    /// between snapshots: a snapshot copies a pointer per robot at most, and only a robot whose
    /// state changed since is copied again.
    pub robots: Robots,
    /// Encounters since the previous snapshot.
    pub encounters: Vec<Encounter>,
    /// Arena size, metres.
    pub arena: (f64, f64),
}

impl RobotView {
    /// Whether both wheels read zero speed.
    pub fn resting(&self) -> bool {
        self.state.wheels.left_mps == 0.0 && self.state.wheels.right_mps == 0.0
    }

    /// How far `other` is off this robot's heading (radians, 0 to π) and how far away it is
    /// (centre to centre, metres).
    pub fn bearing_to(&self, other: &RobotView) -> (f64, f64) {
        let (dx, dy) = (other.pose.x - self.pose.x, other.pose.y - self.pose.y);
        (
            world::wrap_angle(dy.atan2(dx) - self.pose.theta).abs(),
            dx.hypot(dy),
        )
    }
}

impl WorldSnapshot {
    /// The robot with `id`.
    pub fn robot(&self, id: u16) -> Option<&RobotView> {
        self.robots.iter().find(|r| r.id == id).map(|r| &**r)
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
        /// The behaviour's word for the move, returned in its `Event::MoveFinished`.
        tag: u32,
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
    /// A success or a failure, as `success` says.
    pub fn new(success: bool, summary: impl Into<String>) -> Self {
        Self {
            success,
            summary: summary.into(),
            metrics: Vec::new(),
        }
    }

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

impl Intent {
    /// `commands` for `robot`, in order, each tagged `tag`.
    pub fn moves(
        robot: u16,
        commands: impl IntoIterator<Item = MoveCommand>,
        tag: u32,
    ) -> Vec<Intent> {
        commands
            .into_iter()
            .map(|command| Intent::Move {
                robot,
                command,
                tag,
            })
            .collect()
    }
}

/// A behaviour: decision logic over snapshots and events, testable without actors.
///
/// Every hook gets the latest snapshot and the [`Team`], which keeps the books (outstanding
/// moves, follow speeds, held moves) and takes the verdict; each returns intents for the
/// supervisor's safety check. Once a verdict is given the hooks are no longer called.
pub trait Behaviour: Send + 'static {
    /// First intents, given the world as the experiment starts.
    fn start(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent>;
    /// Intents for a new snapshot (every 100 ms).
    fn on_snapshot(&mut self, _world: &WorldSnapshot, _team: &mut Team) -> Vec<Intent> {
        Vec::new()
    }
    /// Intents for a robot's event (a move finished, a sighting, a lost line, …).
    fn on_event(
        &mut self,
        _robot: u16,
        _event: &Event,
        _world: &WorldSnapshot,
        _team: &mut Team,
    ) -> Vec<Intent> {
        Vec::new()
    }
    /// Intents for an intent the supervisor's safety check held back (it never reached the
    /// robot). Moves come here only under [`HeldPolicy::Tell`].
    fn on_held(
        &mut self,
        _intent: &Intent,
        _reason: &str,
        _world: &WorldSnapshot,
        _team: &mut Team,
    ) -> Vec<Intent> {
        Vec::new()
    }
    /// Intents for a robot that was found lost or re-localised. When it is lost the supervisor
    /// has already stopped it (the team has dropped its outstanding moves) and holds its intents
    /// until `Found`; a behaviour that drives it must plan it again from its pose then.
    fn on_localisation(
        &mut self,
        _robot: u16,
        _event: &LocalisationEvent,
        _world: &WorldSnapshot,
        _team: &mut Team,
    ) -> Vec<Intent> {
        Vec::new()
    }
    /// What the team does with a move the safety check held back.
    fn held_policy(&self) -> HeldPolicy {
        HeldPolicy::Tell
    }
    /// A verdict judged from the behaviour's own state, asked after every hook; `None` while it
    /// runs. A behaviour may instead give it through [`Team::finish`] or [`Team::fail`].
    fn verdict(&self) -> Option<Verdict> {
        None
    }
    /// Figures of the work done so far (tasks, passes, pushes), asked after every hook while the
    /// behaviour runs: a run stopped before its verdict (the time limit, Ctrl-C, the panel's
    /// stop) reports them with its failure.
    fn progress(&self) -> Vec<(String, f64)> {
        Vec::new()
    }
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
    /// The parameter keys looked up so far (see [`BehaviourConfig::check_params`]).
    pub looked_up: LookedUp,
}

/// The parameter keys a behaviour looked up through a [`BehaviourConfig`].
///
/// Behaviours are built from a shared `&BehaviourConfig`, so the record sits behind a lock; a
/// clone copies the keys recorded so far.
#[derive(Debug, Default)]
pub struct LookedUp(Mutex<BTreeSet<String>>);

impl LookedUp {
    fn insert(&self, key: &str) {
        // A poisoned set is still a set of strings: keep recording.
        let mut keys = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        if !keys.contains(key) {
            keys.insert(key.to_owned());
        }
    }

    /// Every key looked up, sorted.
    pub fn keys(&self) -> Vec<String> {
        let keys = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        keys.iter().cloned().collect()
    }
}

impl Clone for LookedUp {
    fn clone(&self) -> Self {
        let keys = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        Self(Mutex::new(keys.clone()))
    }
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
        match self.param_text(key) {
            None => Ok(default),
            Some(v) => v
                .parse()
                .map_err(|_| format!("parameter {key}={v:?} is not a valid value")),
        }
    }

    /// Parameter `key` as given, if it was; for values a behaviour parses itself.
    pub fn param_text(&self, key: &str) -> Option<&str> {
        self.looked_up.insert(key);
        self.params.get(key).map(String::as_str)
    }

    /// Refuses parameters the behaviour `name` never looked up while it was built from this
    /// config: a typo must not silently run with the default.
    ///
    /// A behaviour's constructor therefore looks up every parameter it accepts, given or not, on
    /// its successful path (through [`param`](Self::param), [`param_in`](Self::param_in) or
    /// [`param_text`](Self::param_text)).
    ///
    /// # Errors
    /// The first unknown key, with the keys the behaviour does take.
    pub fn check_params(&self, name: &str) -> Result<(), String> {
        let known = self.looked_up.keys();
        let Some(unknown) = self.params.keys().find(|k| !known.contains(k)) else {
            return Ok(());
        };
        if known.is_empty() {
            Err(format!(
                "unknown parameter {unknown:?} for {name}; it takes no parameters"
            ))
        } else {
            Err(format!(
                "unknown parameter {unknown:?} for {name}; its parameters: {}",
                known.join(", ")
            ))
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
             (LaCAM) run as a dependency graph, replanned when held up; success after 1.5 tasks \
             per robot (12 on junction, 18 on grid: well within the 600 s default) without \
             collision, the edges driven measured by the encoders",
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

#[cfg(test)]
mod tests {
    use super::*;
    use world::presets;

    /// A config on the behaviour's own world, as the coordinator builds it.
    fn config(registry: &Registry, name: &str, params: &[(&str, &str)]) -> BehaviourConfig {
        let entry = registry.get(name).expect("registered");
        let world = presets::preset(entry.world).expect("the behaviour's world is a preset");
        BehaviourConfig {
            robots: world.robots.iter().map(|r| r.id).collect(),
            params: params
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect(),
            track: Arc::new(world.track),
            ..Default::default()
        }
    }

    #[test]
    fn every_builtin_looks_up_all_its_parameters_and_refuses_others() {
        let registry = Registry::builtin();
        let expected: &[(&str, &[&str])] = &[
            ("cooperative_push", &["box", "laps", "push", "speed"]),
            ("line_follow", &["laps", "spacing", "speed", "spread"]),
            ("square_walk", &["side"]),
            ("token_ring", &["reverse", "rounds", "speed"]),
            (
                "traffic_control",
                &["flow", "goals", "quota", "replan", "segment_m", "tasks"],
            ),
        ];
        assert_eq!(
            registry.names(),
            expected.iter().map(|(n, _)| *n).collect::<Vec<_>>()
        );
        for (name, keys) in expected {
            let constructor = registry.get(name).expect("registered").constructor;
            let cfg = config(&registry, name, &[]);
            constructor(&cfg).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(cfg.looked_up.keys(), *keys, "{name}");
            assert_eq!(cfg.check_params(name), Ok(()));

            let cfg = config(&registry, name, &[(keys[0], "x"), ("bogus", "1")]);
            assert!(constructor(&cfg).is_err(), "{name}: {}=x accepted", keys[0]);
            let cfg = config(&registry, name, &[("bogus", "1")]);
            constructor(&cfg).unwrap_or_else(|e| panic!("{name}: {e}"));
            let err = cfg.check_params(name).unwrap_err();
            assert_eq!(
                err,
                format!(
                    "unknown parameter \"bogus\" for {name}; its parameters: {}",
                    keys.join(", ")
                )
            );
        }
    }

    #[test]
    fn a_behaviour_without_parameters_says_so() {
        let cfg = BehaviourConfig {
            params: [("speed".to_string(), "1".to_string())].into(),
            ..Default::default()
        };
        assert_eq!(
            cfg.check_params("teleop").unwrap_err(),
            "unknown parameter \"speed\" for teleop; it takes no parameters"
        );
    }

    #[test]
    fn a_clone_keeps_the_keys_looked_up_so_far() {
        let cfg = BehaviourConfig::default();
        assert_eq!(cfg.param("a", 1), Ok(1));
        let copy = cfg.clone();
        assert_eq!(cfg.param_text("b"), None);
        assert_eq!(copy.looked_up.keys(), ["a"]);
        assert_eq!(cfg.looked_up.keys(), ["a", "b"]);
    }
}
