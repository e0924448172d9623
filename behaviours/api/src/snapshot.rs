//! What a behaviour is shown: every robot's view ([`RobotView`]) in a [`WorldSnapshot`], how well
//! the world model knows each pose, and the encounters between robots.

use std::sync::Arc;
use std::time::Duration;

use protocol::packets::Side;
use protocol::RobotState;
use world::Pose;

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
