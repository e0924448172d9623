//! The live world model: each robot's latest odometry pose, reflected state and place on the
//! track, in a `DashMap` that the supervisor writes and a recorder or panel reads concurrently.

use std::sync::Arc;

use behaviours::RobotView;
use dashmap::DashMap;
use robot_actor::StateUpdated;
use simulator::world::Track;

/// Where the line sensor sits ahead of the robot centre, for placing a robot on the tape.
const SENSOR_AHEAD_M: f64 = 0.016;
/// A robot whose sensor is farther than this from any tape is not on the track.
const ON_TRACK_M: f64 = 0.02;

/// The shared world model.
#[derive(Clone)]
pub struct WorldModel {
    robots: Arc<DashMap<u16, RobotView>>,
    track: Arc<Track>,
}

impl WorldModel {
    /// An empty model over `track`.
    pub fn new(track: Arc<Track>) -> Self {
        Self {
            robots: Arc::new(DashMap::new()),
            track,
        }
    }

    /// The map itself, for readers on other threads.
    pub fn robots(&self) -> Arc<DashMap<u16, RobotView>> {
        Arc::clone(&self.robots)
    }

    /// Adds a robot that has not reported yet.
    pub fn add(&self, id: u16) {
        self.robots.insert(
            id,
            RobotView {
                id,
                connected: false,
                pose: Default::default(),
                state: Default::default(),
                pending_moves: 0,
                on_track: None,
            },
        );
    }

    /// Takes one state update.
    pub fn apply(&self, u: &StateUpdated) {
        let (s, c) = u.pose.theta.sin_cos();
        let sensor =
            nalgebra::Point2::new(u.pose.x + SENSOR_AHEAD_M * c, u.pose.y + SENSOR_AHEAD_M * s);
        // Only robots over tape are looked up: most of the floor is white.
        let on_track = if self.track.floor_at(sensor).ir_reflectance < 0.9 {
            self.track
                .nearest(sensor)
                .filter(|n| n.distance_m < ON_TRACK_M)
                .map(|n| (n.edge, n.offset_m, n.distance_m))
        } else {
            None
        };
        if let Some(mut view) = self.robots.get_mut(&u.robot_id) {
            view.connected = true;
            view.pose = u.pose;
            view.state = u.state;
            view.pending_moves = usize::from(u.state.locomotion.queue_len);
            view.on_track = on_track;
        }
    }

    /// Marks a robot's link as down.
    pub fn lost(&self, id: u16) {
        if let Some(mut v) = self.robots.get_mut(&id) {
            v.connected = false;
        }
    }

    /// Every robot, in id order.
    pub fn views(&self) -> Vec<RobotView> {
        let mut v: Vec<RobotView> = self.robots.iter().map(|e| e.value().clone()).collect();
        v.sort_by_key(|r| r.id);
        v
    }

    /// Whether every robot has reported.
    pub fn all_connected(&self) -> bool {
        self.robots.iter().all(|v| v.connected)
    }
}
