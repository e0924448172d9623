#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

pub mod actor;
pub mod api;
pub mod cooperative_push;
pub mod evidence;
pub mod line_follow;
pub mod moves;
pub mod square_walk;
pub mod token_ring;
pub mod track_loop;
pub mod traffic_control;

pub use actor::BehaviourActor;
pub use api::{
    Behaviour, BehaviourConfig, Constructor, Encounter, Entry, Intent, Localisation,
    LocalisationEvent, LookedUp, PoseUncertainty, Registry, RobotView, Verdict, WorldSnapshot,
};
pub use evidence::{Odometer, Stall};
pub use protocol::packets::MoveOutcome;
pub use robot_actor::{MoveCommand, Pose, RobotEventKind};
pub use world::graph::TrackGraph;
