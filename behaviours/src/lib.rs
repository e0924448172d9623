#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

pub mod actor;
pub mod api;
pub mod cooperative_push;
pub mod event;
pub mod evidence;
pub mod line_follow;
pub mod moves;
pub mod square_walk;
pub mod team;
pub mod testing;
pub mod token_ring;
pub mod track_loop;
pub mod traffic_control;

pub use actor::BehaviourActor;
pub use api::{
    Behaviour, BehaviourConfig, Constructor, Encounter, Entry, Intent, Localisation,
    LocalisationEvent, LookedUp, PoseUncertainty, Registry, RobotView, Robots, TrackPosition,
    Verdict, WorldSnapshot,
};
pub use event::{Event, Obstacle, Sighting};
pub use evidence::{Odometer, Stall};
pub use protocol::packets::{MoveOutcome, Side};
pub use robot_actor::{MoveCommand, Pose};
pub use team::{HeldPolicy, Team};
pub use track_loop::TrackLoop;
pub use world::graph::TrackGraph;
