//! The live world model: each robot's latest pose (odometry corrected against the track
//! geometry), reflected state and place on the track, in a `DashMap` that the supervisor writes
//! and a recorder or panel reads concurrently.

use std::f64::consts::PI;
use std::sync::{Arc, Mutex};

use behaviour_api::{Localisation, Pose, PoseUncertainty, RobotView};
use dashmap::DashMap;
use nalgebra::{Matrix3, Point2, RowVector3, Vector2, Vector3};
use robot_actor::StateUpdated;
use world::robot::LINE_SENSOR_AHEAD_M;
use world::wrap_angle;
use world::Track;

mod contradiction;
mod estimate;
mod tape;
#[cfg(test)]
mod tests;
mod update;
mod zones;

pub use update::Felt;

use estimate::{
    corrected, sigma_along, sigmas, widen, Correction, Estimate, Lost, TapeAlong, TapeMatch,
    RECENT_MS,
};
use zones::{junction_zones, through_nodes};

/// A robot whose sensor is farther than this from any tape is not on the track.
const ON_TRACK_M: f64 = 0.02;
/// The tape the sensor sees is matched to the modelled tape only this close: farther, the pose
/// estimate is too far off to know which tape it is.
const MATCH_M: f64 = 0.012;
/// While the firmware follows a tape that the estimate cannot be matched to, the match gates
/// widen by this much per metre driven (the estimate's uncertainty grows with distance), up to
/// the caps; a curve that slipped the odometry by 16° left a robot's estimate outside the fixed
/// gates for good.
const GATE_GROWTH_PER_M: f64 = 0.25;
const MATCH_MAX_M: f64 = 0.04;
const ALIGNED_MAX_RAD: f64 = 35.0 * PI / 180.0;
/// A colour mark's ends are landmarks along the tape: when the colour under the sensor changes
/// to or from a mark, the sensor is at an end of such a mark. The nearest end within this
/// distance of the estimate is taken, and this share of the mismatch along the tape corrected.
/// Nothing else measures where a robot is along a straight, and slips (a detour's turns, a
/// stop against an obstacle) leave several centimetres there.
const MARK_GATE_M: f64 = 0.1;
const MARK_GAIN: f64 = 0.8;
/// A position uncertainty (1σ) beyond this comes from a loss or a bump that widened the
/// estimate, not from odometry: then a follower's mark gate is the uncertainty's too.
const WIDENED_SIGMA_M: f64 = 0.01;
/// A robot driving moves takes a change of colour as a mark's end only after the old colour held
/// for this much travel.
const MARK_SETTLED_M: f64 = 0.02;
/// Its gate is three standard deviations of its position, at least this: a colour sensor that
/// flickers beside a mark mid-edge must not be taken for one at the mark's end.
const MARK_GATE_MIN_M: f64 = 0.015;
/// Heading and tape must agree this well (either direction) before the tape corrects the heading:
/// a robot turning in place sweeps its sensor across tape it is not following.
const ALIGNED_RAD: f64 = 20.0 * PI / 180.0;
/// Near a junction several tapes are under the sensor at once, so it corrects nothing there:
/// at least this close, and on a fork as far as its branches stay within `BRANCHES_APART_M`.
const JUNCTION_CLEAR_M: f64 = 0.03;
/// Branches closer than this (the sensor's half-width plus a tape) look like one tape.
const BRANCHES_APART_M: f64 = 0.025;
/// Two tapes' nearest points to a sighting this far apart are different tapes, not one tape
/// running on through a node.
const AMBIGUOUS_APART_M: f64 = 0.01;
/// Share of the lateral error taken per state update (50 Hz: a time constant of about 0.1 s).
const LATERAL_GAIN: f64 = 0.2;
/// Share of the heading error taken per state update; lower than the lateral gain because the
/// robot weaves about the tape while it follows it.
const HEADING_GAIN: f64 = 0.05;
/// On a curve a follower's heading differs from the tape's by how it cuts the curve (about 3°);
/// only heading errors beyond this are corrected there.
const CURVE_DEADBAND_RAD: f64 = 6.0 * PI / 180.0;
/// Odometry noise, as variance per metre driven: along the heading (wheel diameter and slip),
/// and of the heading itself (wheel base, uneven slip); and of the heading per radian turned.
/// Chosen against the odometry errors measured in physics: 0.6–4 mm and 0.1–3° after 8 m of
/// moves on the junction world (one robot in eight: 20 mm after a brush with the track's edge).
const Q_ALONG_M2_PER_M: f64 = 0.002 * 0.002;
const Q_HEADING_RAD2_PER_M: f64 = 0.0087 * 0.0087;
const Q_HEADING_RAD2_PER_RAD: f64 = 0.0070 * 0.0070;
/// Variance of one sighting of the tape across the robot (spot pitch, tape edges, weave) and of
/// the heading a straight tape gives; of a mark end's position along the tape.
const R_LATERAL_M2: f64 = 0.002 * 0.002;
const R_HEADING_RAD2: f64 = 0.05 * 0.05;
const R_MARK_M2: f64 = 0.005 * 0.005;
/// How well the world file's start poses are known.
const START_SIGMA_M: f64 = 0.001;
const START_SIGMA_RAD: f64 = 0.0175;
/// Contradictions: this much travel with the sensor seeing no tape where the model puts it
/// squarely on one, or seeing tape where the model has none, and the robot is lost.
const CONTRADICTION_M: f64 = 0.025;
/// Travel with no tape seen where the estimate's mean has the sensor plainly over one, however
/// uncertain it is, before the model is contradicted.
const PLAIN_CONTRADICTION_M: f64 = 2.0 * CONTRADICTION_M;
/// And this long standing still: a robot knocked off the tape at rest never drives the distance.
const CONTRADICTION_AT_REST: std::time::Duration = std::time::Duration::from_millis(500);
/// A robot standing still whose line reading moves this far from what it read when it stopped,
/// in this many updates running, was moved without its wheels turning (knocked, pushed, picked up
/// and put down). Over a tape the reading tends to move in steps of half the spots' pitch
/// (1.5 mm), and one at rest may flicker by one step: more than one step is a move.
const DISPLACED_AT_REST_UM: i32 = 2000;
const DISPLACED_READS: u32 = 3;
/// From the line sensor's centre to its outermost spots, and how far over a tape's edge a spot
/// must be to see it for certain.
const SPOTS_REACH_M: f64 = 3.5 * world::robot::LINE_SPOT_PITCH_M;
const SPOT_MARGIN_M: f64 = 0.0015;
/// "Squarely on a tape": the sensor, with twice its uncertainty, within this of the tape's
/// centre line (the spots reach about 13 mm either side) and clear of every node, where tapes
/// end or meet.
const SQUARELY_M: f64 = 0.008;
const NODE_CLEAR_M: f64 = 0.03;
/// Tape seen where the model has none: the seen point this far from every tape, or three times
/// the uncertainty if that is more.
const STRAY_M: f64 = 0.02;
/// A position uncertainty (1σ) beyond this and the model no longer knows where the robot is.
pub const LOST_SIGMA_M: f64 = 0.03;
/// A robot found lost is at least this uncertain (1σ) until a fix: the line sensor reaches
/// about 13 mm either side, and it lost the tape.
const LOST_FLOOR_M: f64 = 0.015;
/// And its heading this uncertain: a turn on the spot that slipped by 17° was seen to cause it.
const LOST_FLOOR_RAD: f64 = 15.0 * PI / 180.0;
/// A bumped robot's position is this many times as uncertain (1σ) as the move it felt, at least
/// [`LOST_FLOOR_M`]; its heading this uncertain: a hand turns it up to 20° as it shoves.
const BUMP_MARGIN: f64 = 1.5;
const BUMP_MAX_M: f64 = 0.9 * LOST_SIGMA_M;
/// A lost bumped robot's estimate is put halfway along the move it felt, and its position is
/// this share of the felt move uncertain (1σ), plus the slack, at least [`LOST_FLOOR_M`]: across
/// its heading the felt move is right within 4 mm, along it the accelerometer can read up to
/// five times the true move (a robot driving into a load as it is shoved) or half of it, so the
/// true move lies between none and all of it. Over 243 shoves the true move lay within 1σ of
/// that 233 times and within 1.4σ always.
const HALF_BUMP_MARGIN: f64 = 0.5;
const HALF_BUMP_SLACK_M: f64 = 0.005;
/// The most a reported bump is believed to have moved a robot: random kicks draw up to 3 cm,
/// and the robot's integral has read 56 mm for one of them.
const BUMP_CREDIBLE_M: f64 = 0.1;
/// A jolt under this along the heading, with no more than this (or a quarter of it) to the side,
/// leaves the robot tracked, its heading this uncertain.
const BUMP_LOST_M: f64 = 0.015;
const ALONG_ONLY_M: f64 = 0.003;
const SMALL_BUMP_TURN_RAD: f64 = 10.0 * PI / 180.0;
/// The estimate a bump goes back to is at least this older than the jolt's start, which the
/// robot dates by the main loop that crossed the threshold.
const BUMP_BEFORE_MS: u32 = 10;
const BUMP_TURN_RAD: f64 = 20.0 * PI / 180.0;
/// While lost, a tape seen within this of the estimate is taken as the one the robot is beside.
pub const RELOCATE_M: f64 = 0.08;
/// `LineState::flags` bits: no spot sees the line; line following is on.
/// A robot whose heading is this far or more from a tape's crosses it rather than drives along.
const CROSSING_RAD: f64 = 45.0 * PI / 180.0;
const LINE_LOST: u8 = 1;
const LINE_FOLLOWING: u8 = 2;

/// How one robot's localisation went over a run.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LocalisationStats {
    /// Times the robot was found lost.
    pub lost_episodes: u32,
    /// Time spent lost (stopped and re-localising).
    pub lost_time: std::time::Duration,
    /// The largest position uncertainty (1σ) the model gave it, metres.
    pub worst_uncertainty_m: f64,
    /// Times the line sensor ran along a tape the model did not expect and the estimate was
    /// moved across onto it (the only tape within reach), instead of declaring the robot lost.
    pub reassociations: u32,
}

/// A change in how the model trusts a robot's pose, from one state update.
#[derive(Clone, Debug, PartialEq)]
pub enum Transition {
    /// What the robot senses contradicts the model.
    Lost(String),
    /// While lost, a tape seen near the estimate fixed the position across it.
    Fixed,
    /// The robot is tracked again: its sensor matches the tape it drives along.
    Found,
}

/// The views in id order, kept between snapshots: a snapshot with few changed robots costs a
/// lookup per changed robot instead of a pass over the map and a sort.
#[derive(Default)]
struct Ordered {
    /// Every view, in id order.
    views: Arc<Vec<Arc<RobotView>>>,
    /// The ids of `views`, in the same order.
    ids: Vec<u16>,
    /// Robots whose view changed since `views` was brought up to date.
    dirty: Vec<u16>,
    /// A robot was added: `views` must be rebuilt.
    stale: bool,
}

/// The shared world model.
#[derive(Clone)]
pub struct WorldModel {
    /// Each view behind its own `Arc`, so a snapshot shares the views instead of copying them;
    /// an update copies a view only while a snapshot still holds it (`Arc::make_mut`).
    robots: Arc<DashMap<u16, Arc<RobotView>>>,
    /// The views in id order as the last snapshot saw them, and which robots changed since.
    ordered: Arc<Mutex<Ordered>>,
    estimates: Arc<DashMap<u16, Estimate>>,
    track: Arc<Track>,
    /// Nodes where three or more tapes meet, and how far around each the tapes are too close
    /// together for the sensor to tell them apart.
    junctions: Arc<Vec<(Point2<f64>, f64)>>,
    /// Per node: whether exactly two tapes meet there in line, so the tape runs on through it.
    through: Arc<Vec<bool>>,
}

impl WorldModel {
    /// An empty model over `track`.
    pub fn new(track: Arc<Track>) -> Self {
        let junctions = junction_zones(&track);
        let through = through_nodes(&track);
        Self {
            robots: Arc::new(DashMap::new()),
            ordered: Arc::default(),
            estimates: Arc::new(DashMap::new()),
            track,
            junctions: Arc::new(junctions),
            through: Arc::new(through),
        }
    }

    /// The track the model places robots on.
    pub fn track(&self) -> &Arc<Track> {
        &self.track
    }

    /// The junction zones (centre, radius): there the tapes run too close together for a
    /// sighting to say which one the sensor sees.
    pub fn junctions(&self) -> &[(Point2<f64>, f64)] {
        &self.junctions
    }

    /// The map itself, for readers on other threads.
    pub fn robots(&self) -> Arc<DashMap<u16, Arc<RobotView>>> {
        Arc::clone(&self.robots)
    }

    /// Adds a robot that has not reported yet.
    pub fn add(&self, id: u16) {
        self.robots.insert(
            id,
            Arc::new(RobotView {
                id,
                connected: false,
                pose: Default::default(),
                odometry: Default::default(),
                state: Default::default(),
                pending_moves: 0,
                on_track: None,
                ..Default::default()
            }),
        );
        // After the insert, so a snapshot that rebuilds the list in between cannot miss it.
        self.ordered().stale = true;
    }

    /// Marks a robot's link as down.
    pub fn lost(&self, id: u16) {
        self.changed(id);
        if let Some(mut v) = self.robots.get_mut(&id) {
            Arc::make_mut(&mut v).connected = false;
        }
    }

    /// Every robot, in id order.
    pub fn views(&self) -> Vec<RobotView> {
        self.shared_views().iter().map(|v| (**v).clone()).collect()
    }

    /// Every robot, in id order, sharing the model's views: the list is shared with the last
    /// snapshot and only the robots that changed since are looked up again.
    pub fn shared_views(&self) -> Arc<Vec<Arc<RobotView>>> {
        let mut guard = self.ordered();
        let o = &mut *guard;
        if o.stale {
            let mut v: Vec<(u16, Arc<RobotView>)> = self
                .robots
                .iter()
                .map(|e| (*e.key(), Arc::clone(e.value())))
                .collect();
            // Sorted by the map's keys: reading each view's id would visit every view's memory.
            v.sort_unstable_by_key(|&(id, _)| id);
            o.ids = v.iter().map(|&(id, _)| id).collect();
            o.views = Arc::new(v.into_iter().map(|(_, view)| view).collect());
            o.stale = false;
            o.dirty.clear();
        } else if !o.dirty.is_empty() {
            // Copies the list only while an earlier snapshot still holds it.
            let views = Arc::make_mut(&mut o.views);
            for id in o.dirty.drain(..) {
                if let (Ok(k), Some(view)) = (o.ids.binary_search(&id), self.robots.get(&id)) {
                    views[k] = Arc::clone(&view);
                }
            }
        }
        Arc::clone(&o.views)
    }

    fn ordered(&self) -> std::sync::MutexGuard<'_, Ordered> {
        // The list is rebuilt whole when stale, so a panic while it was held loses nothing.
        self.ordered.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Notes that robot `id`'s view is about to change, for the next snapshot.
    fn changed(&self, id: u16) {
        let mut o = self.ordered();
        if o.stale {
            return;
        }
        // A model nobody takes snapshots of would otherwise grow the list without end.
        if o.dirty.len() >= o.ids.len() {
            o.stale = true;
            o.dirty.clear();
        } else {
            o.dirty.push(id);
        }
    }

    /// Every robot's localisation record so far, in id order (time lost counts an episode still
    /// in progress up to `now`).
    pub fn localisation_stats(&self, now: tokio::time::Instant) -> Vec<(u16, LocalisationStats)> {
        let mut v: Vec<(u16, LocalisationStats)> = self
            .estimates
            .iter()
            .map(|e| {
                let mut stats = e.value().stats;
                if let Some(l) = &e.value().lost {
                    stats.lost_time += now.saturating_duration_since(l.since);
                }
                (*e.key(), stats)
            })
            .collect();
        v.sort_by_key(|(id, _)| *id);
        v
    }

    /// Whether every robot has reported.
    pub fn all_connected(&self) -> bool {
        self.robots.iter().all(|v| v.connected)
    }
}
