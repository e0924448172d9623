//! The live world model: each robot's latest pose (odometry corrected against the track
//! geometry), reflected state and place on the track, in a `DashMap` that the supervisor writes
//! and a recorder or panel reads concurrently.

use std::f64::consts::{PI, TAU};
use std::sync::Arc;

use behaviours::{Pose, RobotView};
use dashmap::DashMap;
use nalgebra::{Point2, Vector2};
use robot_actor::StateUpdated;
use simulator::world::Track;

/// Where the line sensor sits ahead of the robot centre, for placing a robot on the tape.
const SENSOR_AHEAD_M: f64 = 0.016;
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
/// Heading and tape must agree this well (either direction) before the tape corrects the heading:
/// a robot turning in place sweeps its sensor across tape it is not following.
const ALIGNED_RAD: f64 = 20.0 * PI / 180.0;
/// Near a junction several tapes are under the sensor at once, so it corrects nothing there:
/// at least this close, and on a fork as far as its branches stay within `BRANCHES_APART_M`.
const JUNCTION_CLEAR_M: f64 = 0.03;
/// Branches closer than this (the sensor's half-width plus a tape) look like one tape.
const BRANCHES_APART_M: f64 = 0.025;
/// Share of the lateral error taken per state update (50 Hz: a time constant of about 0.1 s).
const LATERAL_GAIN: f64 = 0.2;
/// Share of the heading error taken per state update; lower than the lateral gain because the
/// robot weaves about the tape while it follows it.
const HEADING_GAIN: f64 = 0.05;
/// On a curve a follower's heading differs from the tape's by how it cuts the curve (about 3°);
/// only heading errors beyond this are corrected there.
const CURVE_DEADBAND_RAD: f64 = 6.0 * PI / 180.0;
/// `LineState::flags` bits: no spot sees the line; line following is on.
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
}

/// The rigid transform taking a robot's odometry pose to its corrected pose.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Correction {
    dx: f64,
    dy: f64,
    dtheta: f64,
}

impl Correction {
    fn apply(&self, p: Pose) -> Pose {
        let (s, c) = self.dtheta.sin_cos();
        Pose {
            x: c * p.x - s * p.y + self.dx,
            y: s * p.x + c * p.y + self.dy,
            theta: p.theta + self.dtheta,
        }
    }

    /// The correction that takes `odometry` to `corrected`.
    fn between(odometry: Pose, corrected: Pose) -> Self {
        let dtheta = corrected.theta - odometry.theta;
        let (s, c) = dtheta.sin_cos();
        Self {
            dx: corrected.x - (c * odometry.x - s * odometry.y),
            dy: corrected.y - (s * odometry.x + c * odometry.y),
            dtheta,
        }
    }
}

/// Per robot: the correction, and how far it has followed tape without a match.
#[derive(Clone, Copy, Debug, Default)]
struct Estimate {
    correction: Correction,
    last_odometry: Option<Pose>,
    unmatched_m: f64,
    /// Colour last seen under the sensor (`protocol::packets::Mark` as a byte).
    last_mark: u8,
}

/// Every junction and the radius around it in which its tapes run too close together to be told
/// apart: a fork whose branch leaves tangentially on a 0.15 m arc needs about 8 cm, a crossing
/// only the minimum.
fn junction_zones(track: &Track) -> Vec<(Point2<f64>, f64)> {
    let mut at: Vec<Vec<(usize, bool)>> = vec![Vec::new(); track.nodes().len()];
    for (i, e) in track.edges().iter().enumerate() {
        at[e.from].push((i, true));
        at[e.to].push((i, false));
    }
    let along = |(edge, from_start): (usize, bool), s: f64| {
        let len = track.edge_length(edge);
        track.point_at(edge, if from_start { s } else { len - s }).0
    };
    at.iter()
        .enumerate()
        .filter(|(_, edges)| edges.len() >= 3)
        .map(|(n, edges)| {
            let mut radius = JUNCTION_CLEAR_M;
            for (k, a) in edges.iter().enumerate() {
                for b in &edges[k + 1..] {
                    let limit = track.edge_length(a.0).min(track.edge_length(b.0));
                    let mut s = 0.0;
                    while s < limit && (along(*a, s) - along(*b, s)).norm() < BRANCHES_APART_M {
                        s += 0.005;
                    }
                    radius = radius.max(s + 0.01);
                }
            }
            (track.nodes()[n].position, radius)
        })
        .collect()
}

fn wrap(a: f64) -> f64 {
    (a + PI).rem_euclid(TAU) - PI
}

/// The shared world model.
#[derive(Clone)]
pub struct WorldModel {
    robots: Arc<DashMap<u16, RobotView>>,
    estimates: Arc<DashMap<u16, Estimate>>,
    track: Arc<Track>,
    /// Nodes where three or more tapes meet, and how far around each the tapes are too close
    /// together for the sensor to tell them apart.
    junctions: Arc<Vec<(Point2<f64>, f64)>>,
}

impl WorldModel {
    /// An empty model over `track`.
    pub fn new(track: Arc<Track>) -> Self {
        let junctions = junction_zones(&track);
        Self {
            robots: Arc::new(DashMap::new()),
            estimates: Arc::new(DashMap::new()),
            track,
            junctions: Arc::new(junctions),
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
                odometry: Default::default(),
                state: Default::default(),
                pending_moves: 0,
                on_track: None,
                ..Default::default()
            },
        );
    }

    /// Takes one state update.
    pub fn apply(&self, u: &StateUpdated) {
        let mut estimate = self
            .estimates
            .get(&u.robot_id)
            .map(|e| *e)
            .unwrap_or_default();
        let driven = estimate
            .last_odometry
            .map_or(0.0, |p| (u.pose.x - p.x).hypot(u.pose.y - p.y));
        estimate.last_odometry = Some(u.pose);
        let mut pose = estimate.correction.apply(u.pose);
        // Only while the firmware follows the tape: then the tape is known to be the one the
        // robot is on. A robot driving moves crosses and skirts tapes it is not on (at forks,
        // sidings, crossings), and there a wrong match moved estimates by centimetres while its
        // odometry alone stayed within millimetres.
        if u.state.line.flags & LINE_LOST == 0 && u.state.line.flags & LINE_FOLLOWING != 0 {
            let widen = GATE_GROWTH_PER_M * estimate.unmatched_m;
            let gate_m = (MATCH_M + widen).min(MATCH_MAX_M);
            let gate_rad = (ALIGNED_RAD + widen / MATCH_MAX_M * ALIGNED_RAD).min(ALIGNED_MAX_RAD);
            if let Some(better) = self.match_tape(pose, u.state.line.position_um, gate_m, gate_rad)
            {
                pose = better;
                estimate.correction = Correction::between(u.pose, pose);
                estimate.unmatched_m = 0.0;
            } else {
                estimate.unmatched_m += driven;
            }
            let mark = u.state.line.mark;
            if mark != estimate.last_mark {
                let colour = if mark != 0 { mark } else { estimate.last_mark };
                if let Some(better) = self.at_mark_end(pose, colour) {
                    pose = better;
                    estimate.correction = Correction::between(u.pose, pose);
                }
            }
        }
        estimate.last_mark = u.state.line.mark;
        self.estimates.insert(u.robot_id, estimate);
        let (s, c) = pose.theta.sin_cos();
        let sensor = Point2::new(pose.x + SENSOR_AHEAD_M * c, pose.y + SENSOR_AHEAD_M * s);
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
            view.pose = pose;
            view.odometry = u.pose;
            view.state = u.state;
            view.pending_moves = usize::from(u.state.locomotion.queue_len);
            view.on_track = on_track;
        }
    }

    /// The pose moved part of the way towards agreeing with the tape the line sensor sees, or
    /// `None` when the sighting cannot be matched to one tape unambiguously.
    ///
    /// The sensor measures where the tape is across the robot (`position_um`, positive to the
    /// right); the track says where that tape is. Along the tape nothing is measured, so only the
    /// lateral offset and the heading are corrected.
    fn match_tape(&self, pose: Pose, position_um: i16, gate_m: f64, gate_rad: f64) -> Option<Pose> {
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let right = Vector2::new(heading.y, -heading.x);
        let centre = Point2::new(pose.x, pose.y);
        let sensor = centre + heading * SENSOR_AHEAD_M;
        let seen = sensor + right * (f64::from(position_um) * 1e-6);
        let at_seen = self.track.nearest(seen)?;
        if at_seen.distance_m > gate_m
            || self
                .junctions
                .iter()
                .any(|(j, r)| (j - at_seen.point).norm() < *r)
        {
            return None;
        }
        let along = at_seen.tangent.dot(&heading);
        if along.abs() < gate_rad.cos() {
            return None;
        }
        let at_centre = self.track.nearest(centre)?;
        // Only the mismatch across the tape is measured, so the pose moves along the tape's
        // normal beside the robot's centre: any other direction (the normal under the sensor,
        // which on a curve is turned by the sensor's lead; the robot's own lateral axis, turned
        // by its heading error) has a component along the tape, and a steady bias in the
        // readings would then walk the estimate along the track lap after lap.
        let normal = Vector2::new(-at_centre.tangent.y, at_centre.tangent.x);
        let lateral = normal * normal.dot(&(at_seen.point - seen));
        // On a straight a follower weaves about the tape's direction, so that is its heading on
        // average. On a curve its heading depends on how it cuts the curve, which is not known
        // here; odometry carries the heading through the curve.
        let straight = !self.track.edges()[at_centre.edge].is_arc()
            && !self.track.edges()[at_seen.edge].is_arc();
        let tape_dir = at_centre.tangent * at_centre.tangent.dot(&heading).signum();
        let err = wrap(tape_dir.y.atan2(tape_dir.x) - pose.theta);
        let dtheta = if straight {
            HEADING_GAIN * err
        } else {
            // Only the part beyond how a follower cuts a curve: a slip of the odometry on a curve
            // (16° was seen on a colour mark) would otherwise carry the estimate off the tape.
            HEADING_GAIN * (err - err.clamp(-CURVE_DEADBAND_RAD, CURVE_DEADBAND_RAD))
        };
        Some(Pose {
            x: pose.x + LATERAL_GAIN * lateral.x,
            y: pose.y + LATERAL_GAIN * lateral.y,
            theta: pose.theta + dtheta,
        })
    }

    /// The pose moved along the tape so that the sensor sits on the nearest end of a mark of
    /// `colour` (a `protocol::packets::Mark` byte), or `None` when no such end is near.
    fn at_mark_end(&self, pose: Pose, colour: u8) -> Option<Pose> {
        let wanted = match colour {
            1 => simulator::world::Mark::Red,
            2 => simulator::world::Mark::Blue,
            _ => return None,
        };
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let sensor = Point2::new(pose.x, pose.y) + heading * SENSOR_AHEAD_M;
        let nodes = self.track.nodes();
        let end = self
            .track
            .edges()
            .iter()
            .filter(|e| e.mark == Some(wanted))
            .flat_map(|e| [nodes[e.from].position, nodes[e.to].position])
            .map(|p| (p, (p - sensor).norm()))
            .filter(|(_, d)| *d < MARK_GATE_M)
            .min_by(|a, b| a.1.total_cmp(&b.1))?
            .0;
        let tangent = self.track.nearest(end)?.tangent;
        let shift = tangent * (tangent.dot(&(end - sensor)) * MARK_GAIN);
        Some(Pose {
            x: pose.x + shift.x,
            y: pose.y + shift.y,
            theta: pose.theta,
        })
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

    /// Every robot's localisation record so far, in id order.
    pub fn localisation_stats(&self) -> Vec<(u16, LocalisationStats)> {
        let mut v: Vec<(u16, LocalisationStats)> = self
            .robots
            .iter()
            .map(|e| (*e.key(), LocalisationStats::default()))
            .collect();
        v.sort_by_key(|(id, _)| *id);
        v
    }

    /// Whether every robot has reported.
    pub fn all_connected(&self) -> bool {
        self.robots.iter().all(|v| v.connected)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use simulator::world::presets;

    /// A simulated unicycle following the oval's tape (it steers its sensor onto the tape ahead,
    /// weaving a little), its odometry drifting in heading by 2° per metre: the model keeps its
    /// pose on the truth, the odometry does not.
    #[test]
    fn line_sightings_pull_a_drifting_odometry_back_onto_the_tape() {
        let world = presets::preset("oval").unwrap();
        let track = Arc::new(world.track.clone());
        let model = WorldModel::new(Arc::clone(&track));
        model.add(1);
        let (v, dt) = (0.15, 0.02);
        let mut truth = Pose {
            x: 0.35,
            y: 0.15,
            theta: 0.0,
        };
        let mut odo = truth;
        let (mut worst_lateral, mut worst_heading) = (0.0f64, 0.0f64);
        for k in 0..4000 {
            let heading = Vector2::new(truth.theta.cos(), truth.theta.sin());
            let sensor = Point2::new(truth.x, truth.y) + heading * SENSOR_AHEAD_M;
            let near = track.nearest(sensor).unwrap();
            // Pure pursuit of a tape point 20 mm ahead of the sensor, plus a slow weave.
            let target = near.point + near.tangent * 0.02;
            let want = (target.y - truth.y).atan2(target.x - truth.x);
            let omega = 8.0 * wrap(want - truth.theta) + 0.3 * (k as f64 * 0.05).sin();
            let dth = omega * dt;
            let ds = v * dt;
            let mid = truth.theta + dth / 2.0;
            truth = Pose {
                x: truth.x + ds * mid.cos(),
                y: truth.y + ds * mid.sin(),
                theta: truth.theta + dth,
            };
            let dth_odo = dth + ds * 2f64.to_radians();
            let mid = odo.theta + dth_odo / 2.0;
            odo = Pose {
                x: odo.x + ds * mid.cos(),
                y: odo.y + ds * mid.sin(),
                theta: odo.theta + dth_odo,
            };
            let heading = Vector2::new(truth.theta.cos(), truth.theta.sin());
            let right = Vector2::new(heading.y, -heading.x);
            let sensor = Point2::new(truth.x, truth.y) + heading * SENSOR_AHEAD_M;
            let near = track.nearest(sensor).unwrap();
            let mut state = protocol::RobotState::default();
            state.line.position_um = ((near.point - sensor).dot(&right) * 1e6) as i16;
            state.line.flags = LINE_FOLLOWING;
            model.apply(&StateUpdated {
                robot_id: 1,
                at: tokio::time::Instant::now(),
                state,
                reduced: false,
                pose: odo,
            });
            let est = model.views()[0].pose;
            if k > 200 {
                let lateral = right.dot(&Vector2::new(est.x - truth.x, est.y - truth.y));
                worst_lateral = worst_lateral.max(lateral.abs());
                worst_heading = worst_heading.max(wrap(est.theta - truth.theta).abs());
            }
        }
        let v = model.views()[0].clone();
        let odo_err = (v.odometry.x - truth.x).hypot(v.odometry.y - truth.y);
        let est_err = (v.pose.x - truth.x).hypot(v.pose.y - truth.y);
        let laps = 4000.0 * 0.003 / TrackLoopLen::oval();
        assert!(laps > 5.0, "{laps}");
        assert!(odo_err > 0.05, "the drift is real: {odo_err}");
        assert!(worst_lateral < 0.002, "lateral {worst_lateral}");
        assert!(worst_heading < 3f64.to_radians(), "heading {worst_heading}");
        // Along the tape nothing is measured, but the heading held on the tape keeps the error
        // along it to what the odometry's distance alone gets wrong.
        assert!(est_err < 0.005, "estimate {est_err} vs odometry {odo_err}");
    }

    struct TrackLoopLen;
    impl TrackLoopLen {
        fn oval() -> f64 {
            1.0 + 0.3 * PI
        }
    }
}
