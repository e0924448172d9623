//! The live world model: each robot's latest pose (odometry corrected against the track
//! geometry), reflected state and place on the track, in a `DashMap` that the supervisor writes
//! and a recorder or panel reads concurrently.

use std::f64::consts::PI;
use std::sync::{Arc, Mutex};

use behaviours::{Localisation, Pose, PoseUncertainty, RobotView};
use dashmap::DashMap;
use nalgebra::{Matrix3, Point2, RowVector3, Vector2, Vector3};
use robot_actor::StateUpdated;
use simulator::world::Track;
use world::robot::LINE_SENSOR_AHEAD_M;
use world::wrap_angle;

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
/// And this long standing still: a robot knocked off the tape at rest never drives the distance.
const CONTRADICTION_AT_REST: std::time::Duration = std::time::Duration::from_millis(500);
/// A robot standing still whose line reading moves this far from what it read when it stopped,
/// in this many updates running, was moved without its wheels turning (knocked, pushed, picked up
/// and put down). Over a tape the reading tends to move in steps of half the spots' pitch
/// (1.5 mm), and one at rest may flicker by one step: more than one step is a move.
const DISPLACED_AT_REST_UM: i32 = 2000;
const DISPLACED_READS: u32 = 3;
/// The most heading uncertainty such a move gives the robot: a turn of this much puts the sensor
/// 8 mm across, past where a single reading at rest says anything.
const DISPLACED_TURN_MAX_RAD: f64 = 30.0 * PI / 180.0;
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
#[derive(Clone, Debug)]
struct Estimate {
    correction: Correction,
    last_odometry: Option<Pose>,
    unmatched_m: f64,
    /// Colour last seen under the sensor (`protocol::packets::Mark` as a byte).
    last_mark: u8,
    /// Travel since the colour under the sensor last changed.
    mark_held_m: f64,
    /// Covariance of the corrected pose (x, y, θ).
    cov: Matrix3<f64>,
    /// Travel with no tape under the sensor where the model puts it squarely on one.
    no_tape_m: f64,
    /// Time standing still in that state.
    no_tape_at_rest: std::time::Duration,
    /// When the previous update was made.
    last_at: Option<tokio::time::Instant>,
    /// Travel with tape under the sensor where the model has none.
    stray_tape_m: f64,
    /// Whether the line sensor saw tape at the previous update.
    saw_tape: bool,
    /// The line reading when the robot came to rest on a tape, and how many updates running
    /// have read it moved since.
    rest_line: Option<i16>,
    displaced_reads: u32,
    /// Whether the firmware followed a tape it saw at the previous update.
    was_following: bool,
    /// Set while the robot is lost.
    lost: Option<Lost>,
    stats: LocalisationStats,
}

impl Default for Estimate {
    fn default() -> Self {
        Self {
            correction: Correction::default(),
            last_odometry: None,
            unmatched_m: 0.0,
            last_mark: 0,
            mark_held_m: 0.0,
            cov: Matrix3::from_diagonal(&nalgebra::Vector3::new(
                START_SIGMA_M * START_SIGMA_M,
                START_SIGMA_M * START_SIGMA_M,
                START_SIGMA_RAD * START_SIGMA_RAD,
            )),
            no_tape_m: 0.0,
            no_tape_at_rest: std::time::Duration::ZERO,
            last_at: None,
            stray_tape_m: 0.0,
            saw_tape: false,
            rest_line: None,
            displaced_reads: 0,
            was_following: false,
            lost: None,
            stats: LocalisationStats::default(),
        }
    }
}

/// A tape the robot faces along, as the model has it under the line sensor.
#[derive(Clone, Copy, Debug)]
struct TapeAlong {
    /// From the sensor's centre to the tape's centre line.
    distance_m: f64,
    /// Cosine of the angle between the heading and the tape.
    cos: f64,
    /// 1σ of the position across the tape.
    sigma_m: f64,
    width_m: f64,
}

/// A lost episode in progress.
#[derive(Clone, Debug)]
struct Lost {
    since: tokio::time::Instant,
    /// A tape found while lost has fixed the position across it.
    fixed: bool,
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

/// The covariance after a correction of gain `k` (a column) on a measurement `h` (a row) of
/// variance `r`, in Joseph form, so it holds for a gain that is fixed rather than optimal.
fn corrected(cov: &Matrix3<f64>, h: RowVector3<f64>, k: Vector3<f64>, r: f64) -> Matrix3<f64> {
    let a = Matrix3::identity() - k * h;
    a * cov * a.transpose() + k * k.transpose() * r
}

/// Raises the position's variance on each axis to at least `position_m`² and the heading's to
/// `heading_rad`²: what a contradiction says the estimate may be off by.
fn widen(cov: &mut Matrix3<f64>, position_m: f64, heading_rad: f64) {
    for i in 0..2 {
        cov[(i, i)] = cov[(i, i)].max(position_m * position_m);
    }
    cov[(2, 2)] = cov[(2, 2)].max(heading_rad * heading_rad);
}

/// 1σ of the position along its worst direction, and of the heading.
fn sigmas(cov: &Matrix3<f64>) -> PoseUncertainty {
    let (a, b, c) = (cov[(0, 0)], cov[(0, 1)], cov[(1, 1)]);
    let major = (a + c) / 2.0 + (((a - c) / 2.0).powi(2) + b * b).sqrt();
    PoseUncertainty {
        position_m: major.max(0.0).sqrt(),
        heading_rad: cov[(2, 2)].max(0.0).sqrt(),
    }
}

/// 1σ of the position along unit vector `n`.
fn sigma_along(cov: &Matrix3<f64>, n: Vector2<f64>) -> f64 {
    let v = n.x * n.x * cov[(0, 0)] + 2.0 * n.x * n.y * cov[(0, 1)] + n.y * n.y * cov[(1, 1)];
    v.max(0.0).sqrt()
}

/// A tape sighting matched to the model: the corrected pose, the tape's normal the correction
/// moved it along, and the gain applied to the heading (0 when the heading was left alone).
struct TapeMatch {
    pose: Pose,
    normal: Vector2<f64>,
    heading_gain: f64,
}

/// Per node of `track`: whether exactly two edges end there and their tapes run on in line
/// (within 10°), as where an oval's bend meets its straight; there a sensor sees tape on both
/// sides of the node.
fn through_nodes(track: &Track) -> Vec<bool> {
    let mut ends: Vec<Vec<Vector2<f64>>> = vec![Vec::new(); track.nodes().len()];
    for (i, e) in track.edges().iter().enumerate() {
        let len = track.edge_length(i);
        ends[e.from].push(track.point_at(i, 0.0).1);
        ends[e.to].push(track.point_at(i, len).1);
    }
    ends.iter()
        .map(|t| t.len() == 2 && t[0].dot(&t[1]).abs() > 10f64.to_radians().cos())
        .collect()
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

    /// Takes one state update; says when the robot's localisation changed.
    pub fn apply(&self, u: &StateUpdated) -> Option<Transition> {
        let mut e = self
            .estimates
            .get(&u.robot_id)
            .map(|e| e.clone())
            .unwrap_or_default();
        let (driven, turned) = e.last_odometry.map_or((0.0, 0.0), |p| {
            let turned = wrap_angle(u.pose.theta - p.theta);
            let mid = p.theta + turned / 2.0;
            let step = Vector2::new(u.pose.x - p.x, u.pose.y - p.y);
            (step.dot(&Vector2::new(mid.cos(), mid.sin())), turned)
        });
        if e.last_odometry.is_none() {
            // A robot may start on a mark: that is no mark's end.
            e.last_mark = u.state.line.mark;
        }
        e.last_odometry = Some(u.pose);
        let mut pose = e.correction.apply(u.pose);
        // The odometry step carries the covariance forward: the heading's uncertainty becomes
        // uncertainty across the path, and each step adds its own noise.
        let mid = pose.theta - turned / 2.0;
        let (s, c) = mid.sin_cos();
        let f = Matrix3::new(1.0, 0.0, -driven * s, 0.0, 1.0, driven * c, 0.0, 0.0, 1.0);
        let g = Vector3::new(c, s, 0.0);
        let q_heading = Q_HEADING_RAD2_PER_M * driven.abs() + Q_HEADING_RAD2_PER_RAD * turned.abs();
        e.cov = f * e.cov * f.transpose()
            + g * g.transpose() * (Q_ALONG_M2_PER_M * driven.abs())
            + Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, q_heading));
        let sees_tape = u.state.line.flags & LINE_LOST == 0;
        let following = sees_tape && u.state.line.flags & LINE_FOLLOWING != 0;
        let position_um = u.state.line.position_um;
        let mut transition = None;
        let searching = e.lost.as_ref().is_some_and(|l| !l.fixed);
        if searching {
            if sees_tape {
                if let Some((better, n)) = self.relocate(pose, position_um) {
                    pose = better;
                    e.correction = Correction::between(u.pose, pose);
                    let h = RowVector3::new(n.x, n.y, 0.0);
                    e.cov = corrected(&e.cov, h, h.transpose(), R_LATERAL_M2);
                    if let Some(l) = e.lost.as_mut() {
                        l.fixed = true;
                    }
                    transition = Some(Transition::Fixed);
                }
            }
        } else if sees_tape {
            let sigma = sigmas(&e.cov);
            let (gate_m, gate_rad) = if following {
                // A follower is on some tape whatever the model says: the gates widen with the
                // distance it followed tape without a match.
                let widen = GATE_GROWTH_PER_M * e.unmatched_m;
                (
                    (MATCH_M + widen)
                        .max(3.0 * sigma.position_m)
                        .min(MATCH_MAX_M),
                    (ALIGNED_RAD + widen / MATCH_MAX_M * ALIGNED_RAD).min(ALIGNED_MAX_RAD),
                )
            } else {
                (
                    MATCH_M.max(3.0 * sigma.position_m).min(MATCH_MAX_M),
                    (ALIGNED_RAD + 3.0 * sigma.heading_rad).min(ALIGNED_MAX_RAD),
                )
            };
            // A robot driving moves is corrected by the filter's own gain, through which a
            // lateral offset that keeps growing as it drives also corrects its heading; one
            // standing still reads the same offset again and again, which is no new evidence.
            let moved = driven.abs() > 1e-4 || turned.abs() > 1e-3;
            let matched = if following {
                self.match_tape(pose, position_um, gate_m, gate_rad)
                    .map(|m| {
                        let h = RowVector3::new(m.normal.x, m.normal.y, 0.0);
                        e.cov = corrected(&e.cov, h, h.transpose() * LATERAL_GAIN, R_LATERAL_M2);
                        if m.heading_gain > 0.0 {
                            let h = RowVector3::new(0.0, 0.0, 1.0);
                            e.cov = corrected(
                                &e.cov,
                                h,
                                h.transpose() * m.heading_gain,
                                R_HEADING_RAD2,
                            );
                        }
                        m.pose
                    })
            } else if moved {
                self.filter_tape(pose, &e.cov, position_um, gate_rad)
                    .map(|(better, cov)| {
                        e.cov = cov;
                        better
                    })
            } else {
                None
            };
            if let Some(better) = matched {
                pose = better;
                e.correction = Correction::between(u.pose, pose);
                e.unmatched_m = 0.0;
                if let Some(l) = e.lost.take() {
                    e.stats.lost_time += u.at.saturating_duration_since(l.since);
                    transition = Some(Transition::Found);
                }
            } else if following {
                e.unmatched_m += driven.abs();
            }
            let mark = u.state.line.mark;
            // A robot driving moves counts a change of colour only after the old colour held for
            // a while: at a mark's edge its colour sensor flickers.
            // It must also be driving along, not turning on the spot (which sweeps the sensor
            // off a mark and back), and the end must be within what its uncertainty allows.
            let settled = following
                || (e.mark_held_m > MARK_SETTLED_M && driven.abs() > 1e-4 && turned.abs() < 0.01);
            let gate_m = if following {
                MARK_GATE_M
            } else {
                (3.0 * sigmas(&e.cov).position_m).clamp(MARK_GATE_MIN_M, MARK_GATE_M)
            };
            if mark != e.last_mark && settled {
                let colour = if mark != 0 { mark } else { e.last_mark };
                let entering = mark != 0;
                let end = self.at_mark_end(pose, colour, entering, following, gate_m);
                if let Some((better, t)) = end {
                    pose = better;
                    e.correction = Correction::between(u.pose, pose);
                    let h = RowVector3::new(t.x, t.y, 0.0);
                    e.cov = corrected(&e.cov, h, h.transpose() * MARK_GAIN, R_MARK_M2);
                }
            }
        }
        if u.state.line.mark == e.last_mark {
            e.mark_held_m += driven.abs();
        } else {
            e.mark_held_m = 0.0;
        }
        e.last_mark = u.state.line.mark;
        let since_last = e.last_at.map_or(std::time::Duration::ZERO, |t| {
            u.at.saturating_duration_since(t)
        });
        e.last_at = Some(u.at);
        if e.lost.is_none() {
            let at_rest = (driven.abs() <= 1e-4 && turned.abs() <= 1e-3).then_some(since_last);
            let why = self.contradiction(&mut e, pose, sees_tape, position_um, driven, at_rest);
            // A contradiction may have been resolved by moving the estimate.
            pose = e.correction.apply(u.pose);
            if let Some(why) = why {
                e.lost = Some(Lost {
                    since: u.at,
                    fixed: false,
                });
                e.stats.lost_episodes += 1;
                e.no_tape_m = 0.0;
                e.no_tape_at_rest = std::time::Duration::ZERO;
                e.stray_tape_m = 0.0;
                e.rest_line = None;
                e.displaced_reads = 0;
                // The contradiction says the estimate is off by at least what the line sensor
                // reaches either side; the safety check keeps everyone that much farther away.
                // The heading may be what is wrong (a turn that slipped): once the tape fixes
                // the position across it, driving along it measures the heading again.
                widen(&mut e.cov, LOST_FLOOR_M, LOST_FLOOR_RAD);
                transition = Some(Transition::Lost(why));
            }
        }
        e.saw_tape = sees_tape;
        e.was_following = following;
        let uncertainty = sigmas(&e.cov);
        e.stats.worst_uncertainty_m = e.stats.worst_uncertainty_m.max(uncertainty.position_m);
        let localisation = if e.lost.is_some() {
            Localisation::Lost
        } else {
            Localisation::Tracking
        };
        self.estimates.insert(u.robot_id, e);
        let (s, c) = pose.theta.sin_cos();
        let sensor = Point2::new(
            pose.x + LINE_SENSOR_AHEAD_M * c,
            pose.y + LINE_SENSOR_AHEAD_M * s,
        );
        // Only robots over tape are looked up: most of the floor is white.
        let on_track = if self.track.floor_at(sensor).ir_reflectance < 0.9 {
            self.track
                .nearest(sensor)
                .filter(|n| n.distance_m < ON_TRACK_M)
                .map(|n| behaviours::TrackPosition {
                    edge: n.edge,
                    along_m: n.offset_m,
                    offset_m: n.distance_m,
                })
        } else {
            None
        };
        // Noted before the map's write guard is taken: a snapshot holds the list's lock while it
        // reads the map, so the other order could deadlock across threads.
        self.changed(u.robot_id);
        if let Some(mut entry) = self.robots.get_mut(&u.robot_id) {
            let view = Arc::make_mut(&mut entry);
            view.connected = true;
            view.pose = pose;
            view.odometry = u.pose;
            view.state = u.state;
            view.front_close_at = if u.state.proximity.front_obstacle == 1 {
                view.front_close_at.or(Some(pose))
            } else {
                None
            };
            view.pending_moves = usize::from(u.state.locomotion.queue_len);
            view.on_track = on_track;
            view.uncertainty = uncertainty;
            view.localisation = localisation;
        }
        transition
    }

    /// Why what the robot senses contradicts the model, once it has for long enough; `at_rest`
    /// is the time since the last update when the robot did not move in it.
    fn contradiction(
        &self,
        e: &mut Estimate,
        pose: Pose,
        sees_tape: bool,
        position_um: i16,
        driven: f64,
        at_rest: Option<std::time::Duration>,
    ) -> Option<String> {
        let sigma = sigmas(&e.cov);
        if sigma.position_m > LOST_SIGMA_M {
            return Some(format!(
                "its position is uncertain by {:.0} mm (1σ), beyond {:.0} mm",
                sigma.position_m * 1e3,
                LOST_SIGMA_M * 1e3
            ));
        }
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let sensor = Point2::new(pose.x, pose.y) + heading * LINE_SENSOR_AHEAD_M;
        if at_rest.is_none() {
            e.rest_line = None;
            e.displaced_reads = 0;
        }
        if sees_tape {
            if let Some(moved_m) = self.displaced_at_rest(e, sensor, position_um, at_rest) {
                // Moved while standing, still on the tape: the sensor moved across the tape by
                // `moved_m`, by a shift or a turn about the robot's centre, and only driving along
                // the tape can tell the two apart again.
                let turn = (moved_m / LINE_SENSOR_AHEAD_M).min(DISPLACED_TURN_MAX_RAD);
                widen(&mut e.cov, moved_m, turn);
            }
            e.no_tape_m = 0.0;
            e.no_tape_at_rest = std::time::Duration::ZERO;
            let right = Vector2::new(heading.y, -heading.x);
            let seen = sensor + right * (f64::from(position_um) * 1e-6);
            let far = self
                .track
                .nearest(seen)
                .is_none_or(|n| n.distance_m > STRAY_M.max(3.0 * sigma.position_m));
            e.stray_tape_m = if far {
                e.stray_tape_m + driven.abs()
            } else {
                0.0
            };
            // Crossing a tape, the sensor sees it for no more than its width, never the 25 mm
            // the rule below waits for; but the moment it comes onto a tape is as good a fix
            // across that tape.
            let crosses = far
                && !e.saw_tape
                && self
                    .track
                    .nearest(seen)
                    .is_some_and(|n| n.tangent.dot(&heading).abs() < CROSSING_RAD.cos());
            if e.stray_tape_m > CONTRADICTION_M || crosses {
                // The tape the sensor follows is evidence of where the robot is: when it can be
                // only one tape near the estimate, the estimate moves across onto it (a pusher
                // whose wheels slipped under the load, backing up onto the track) and the robot
                // is not lost.
                if let Some((better, n)) = self.relocate(pose, position_um) {
                    e.stray_tape_m = 0.0;
                    e.correction = Correction::between(e.last_odometry.unwrap_or(pose), better);
                    let h = RowVector3::new(n.x, n.y, 0.0);
                    e.cov = corrected(&e.cov, h, h.transpose(), R_LATERAL_M2);
                    e.stats.reassociations += 1;
                    return None;
                }
                // A crossing that matches no tape unambiguously is no evidence either way; only
                // tape seen for longer contradicts the model.
                if e.stray_tape_m <= CONTRADICTION_M {
                    return None;
                }
                return Some(format!(
                    "its line sensor saw tape for {:.0} mm where the model has none",
                    e.stray_tape_m * 1e3
                ));
            }
        } else {
            e.stray_tape_m = 0.0;
            let tape = self.tape_along(&e.cov, sensor, heading);
            let squarely = tape.is_some_and(|t| t.distance_m + 2.0 * t.sigma_m < SQUARELY_M);
            e.no_tape_m = if squarely {
                e.no_tape_m + driven.abs()
            } else {
                0.0
            };
            // Time counts only while the robot stands: one that drives is judged by distance.
            // The row of spots stands across the heading: along it the tape is farther than across
            // the tape by 1/cos. One spot must be over the tape by a margin.
            let under_a_spot = tape.is_some_and(|t| {
                t.distance_m / t.cos + 2.0 * t.sigma_m
                    < SPOTS_REACH_M + t.width_m / 2.0 - SPOT_MARGIN_M
            });
            e.no_tape_at_rest = match at_rest {
                Some(dt) if under_a_spot => e.no_tape_at_rest + dt,
                _ => std::time::Duration::ZERO,
            };
            if e.no_tape_m > CONTRADICTION_M {
                return Some(format!(
                    "its line sensor saw no tape for {:.0} mm where the model puts it on one",
                    e.no_tape_m * 1e3
                ));
            }
            // A follower loses its tape only by leaving it: where the model has it squarely on
            // one, the model is wrong (it was knocked aside, or slid off in a bend).
            if e.was_following && squarely {
                return Some("its follower lost the tape where the model puts it on one".into());
            }
            if e.no_tape_at_rest > CONTRADICTION_AT_REST {
                return Some(format!(
                    "its line sensor saw no tape for {:.1} s standing where the model puts it on one",
                    e.no_tape_at_rest.as_secs_f64()
                ));
            }
        }
        None
    }

    /// How far the line reading of a robot standing still on a tape moved while its wheels did
    /// not, once it has for long enough: the robot was moved. Such a kick can turn the robot or
    /// shift it across its tape by centimetres while the sensor still sees the tape, and a
    /// sighting at rest is no evidence for the filter; the robot then drives off on a heading the
    /// model does not have, and by the time its sensor loses the tape it is far from where the
    /// model puts it. Junctions and tape ends are left out: there a spot can see another tape's
    /// edge come and go.
    fn displaced_at_rest(
        &self,
        e: &mut Estimate,
        sensor: Point2<f64>,
        position_um: i16,
        at_rest: Option<std::time::Duration>,
    ) -> Option<f64> {
        at_rest?;
        let clear = !self.in_junction(sensor)
            && self
                .track
                .nearest(sensor)
                .is_some_and(|n| self.clear_of_ends(&n, self.track.edge_length(n.edge)));
        if !clear {
            e.rest_line = None;
            e.displaced_reads = 0;
            return None;
        }
        let first = *e.rest_line.get_or_insert(position_um);
        let moved_um = (i32::from(position_um) - i32::from(first)).abs();
        if moved_um <= DISPLACED_AT_REST_UM {
            e.displaced_reads = 0;
            return None;
        }
        e.displaced_reads += 1;
        if e.displaced_reads < DISPLACED_READS {
            return None;
        }
        // Where it stands now is the new reference: the move is counted once.
        e.rest_line = Some(position_um);
        e.displaced_reads = 0;
        Some(f64::from(moved_um) * 1e-6)
    }

    /// The tape nearest the line sensor at `sensor`, when the robot faces along it (facing
    /// `heading`) clear of tape ends and junctions, where the model expects the sensor to see it
    /// if near enough; `cov` gives the uncertainty across it.
    fn tape_along(
        &self,
        cov: &Matrix3<f64>,
        sensor: Point2<f64>,
        heading: Vector2<f64>,
    ) -> Option<TapeAlong> {
        let n = self.track.nearest(sensor)?;
        let cos = n.tangent.dot(&heading).abs();
        let len = self.track.edge_length(n.edge);
        (cos > ALIGNED_RAD.cos() && self.clear_of_ends(&n, len) && !self.in_junction(n.point)).then(
            || TapeAlong {
                distance_m: n.distance_m,
                cos,
                sigma_m: sigma_along(cov, Vector2::new(-n.tangent.y, n.tangent.x)),
                width_m: self.track.edges()[n.edge].width_m,
            },
        )
    }

    /// An extended Kalman filter update from one sighting of a tape along the robot's heading:
    /// the offset across the tape is measured, and through the covariance's cross terms it moves
    /// the heading too. `None` when the sighting cannot be matched to one tape: near a junction,
    /// across the heading, or beyond three standard deviations of the expected offset.
    fn filter_tape(
        &self,
        pose: Pose,
        cov: &Matrix3<f64>,
        position_um: i16,
        gate_rad: f64,
    ) -> Option<(Pose, Matrix3<f64>)> {
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let right = Vector2::new(heading.y, -heading.x);
        let centre = Point2::new(pose.x, pose.y);
        let arm = heading * LINE_SENSOR_AHEAD_M + right * (f64::from(position_um) * 1e-6);
        let seen = centre + arm;
        let at = self.track.nearest(seen)?;
        if self.in_junction(at.point) || at.tangent.dot(&heading).abs() < gate_rad.cos() {
            return None;
        }
        let normal = Vector2::new(-at.tangent.y, at.tangent.x);
        let innovation = normal.dot(&(at.point - seen));
        // d(seen)/dθ is the arm turned by 90°.
        let h = RowVector3::new(normal.x, normal.y, normal.dot(&Vector2::new(-arm.y, arm.x)));
        let s = (h * cov * h.transpose())[(0, 0)] + R_LATERAL_M2;
        if innovation.abs() > MATCH_MAX_M
            || innovation * innovation > 9.0 * s.max(MATCH_M * MATCH_M / 9.0)
        {
            return None;
        }
        let k = cov * h.transpose() / s;
        let dx = k * innovation;
        let cov = corrected(cov, h, k, R_LATERAL_M2);
        Some((
            Pose {
                x: pose.x + dx[0],
                y: pose.y + dx[1],
                theta: pose.theta + dx[2],
            },
            cov,
        ))
    }

    /// Whether a point on an edge `len` long is clear of where its tape ends or meets others:
    /// far enough from each end node, or that node only carries the tape on in line.
    fn clear_of_ends(&self, n: &world::track::TrackPoint, len: f64) -> bool {
        let e = &self.track.edges()[n.edge];
        (n.offset_m > NODE_CLEAR_M || self.through[e.from])
            && (n.offset_m < len - NODE_CLEAR_M || self.through[e.to])
    }

    fn in_junction(&self, p: Point2<f64>) -> bool {
        self.junctions.iter().any(|(j, r)| (j - p).norm() < *r)
    }

    /// While lost: the tape the sensor sees, taken to be the nearest one to where the model
    /// puts the sighting, and the pose moved across that tape to agree with it.
    fn relocate(&self, pose: Pose, position_um: i16) -> Option<(Pose, Vector2<f64>)> {
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let right = Vector2::new(heading.y, -heading.x);
        let seen = Point2::new(pose.x, pose.y)
            + heading * LINE_SENSOR_AHEAD_M
            + right * (f64::from(position_um) * 1e-6);
        let n = self.track.nearest(seen)?;
        if n.distance_m > RELOCATE_M || self.in_junction(n.point) {
            return None;
        }
        let normal = Vector2::new(-n.tangent.y, n.tangent.x);
        let shift = normal * normal.dot(&(n.point - seen));
        Some((
            Pose {
                x: pose.x + shift.x,
                y: pose.y + shift.y,
                theta: pose.theta,
            },
            normal,
        ))
    }

    /// The pose moved part of the way towards agreeing with the tape the line sensor sees, or
    /// `None` when the sighting cannot be matched to one tape unambiguously.
    ///
    /// The sensor measures where the tape is across the robot (`position_um`, positive to the
    /// right); the track says where that tape is. Along the tape nothing is measured, so only the
    /// lateral offset and the heading are corrected.
    fn match_tape(
        &self,
        pose: Pose,
        position_um: i16,
        gate_m: f64,
        gate_rad: f64,
    ) -> Option<TapeMatch> {
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let right = Vector2::new(heading.y, -heading.x);
        let centre = Point2::new(pose.x, pose.y);
        let sensor = centre + heading * LINE_SENSOR_AHEAD_M;
        let seen = sensor + right * (f64::from(position_um) * 1e-6);
        let at_seen = self.track.nearest(seen)?;
        if at_seen.distance_m > gate_m || self.in_junction(at_seen.point) {
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
        let err = wrap_angle(tape_dir.y.atan2(tape_dir.x) - pose.theta);
        let (dtheta, heading_gain) = if straight {
            (HEADING_GAIN * err, HEADING_GAIN)
        } else {
            // Only the part beyond how a follower cuts a curve: a slip of the odometry on a curve
            // (16° was seen on a colour mark) would otherwise carry the estimate off the tape.
            let beyond = err - err.clamp(-CURVE_DEADBAND_RAD, CURVE_DEADBAND_RAD);
            (
                HEADING_GAIN * beyond,
                if beyond != 0.0 { HEADING_GAIN } else { 0.0 },
            )
        };
        Some(TapeMatch {
            pose: Pose {
                x: pose.x + LATERAL_GAIN * lateral.x,
                y: pose.y + LATERAL_GAIN * lateral.y,
                theta: pose.theta + dtheta,
            },
            normal,
            heading_gain,
        })
    }

    /// The pose moved along the tape so that the sensor sits on the nearest end of a mark of
    /// `colour` (a `protocol::packets::Mark` byte), or `None` when no such end is near.
    fn at_mark_end(
        &self,
        pose: Pose,
        colour: u8,
        entering: bool,
        following: bool,
        gate_m: f64,
    ) -> Option<(Pose, Vector2<f64>)> {
        let wanted = match colour {
            1 => simulator::world::Mark::Red,
            2 => simulator::world::Mark::Blue,
            _ => return None,
        };
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let sensor = Point2::new(pose.x, pose.y) + heading * LINE_SENSOR_AHEAD_M;
        let nodes = self.track.nodes();
        let end = self
            .track
            .edges()
            .iter()
            .enumerate()
            .filter(|(_, e)| e.mark == Some(wanted))
            .flat_map(|(i, e)| {
                // Each end with the tape's direction into the mark from there.
                let len = self.track.edge_length(i);
                [
                    (nodes[e.from].position, self.track.point_at(i, 0.0).1),
                    (nodes[e.to].position, -self.track.point_at(i, len).1),
                ]
            })
            .filter(|(_, into)| {
                // A robot driving moves may pass a mark's end on another tape, or see a mark
                // flicker while it runs along its edge: only an end it drives into (or out of)
                // along the marked tape is where it is.
                following
                    || (into.dot(&heading) > ALIGNED_RAD.cos()) == entering
                        && into.dot(&heading).abs() > ALIGNED_RAD.cos()
            })
            .map(|(p, _)| (p, (p - sensor).norm()))
            .filter(|(_, d)| *d < gate_m)
            .min_by(|a, b| a.1.total_cmp(&b.1))?
            .0;
        let tangent = self.track.nearest(end)?.tangent;
        let shift = tangent * (tangent.dot(&(end - sensor)) * MARK_GAIN);
        Some((
            Pose {
                x: pose.x + shift.x,
                y: pose.y + shift.y,
                theta: pose.theta,
            },
            tangent,
        ))
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

#[cfg(test)]
mod tests {
    use super::*;
    use simulator::world::presets;

    /// A snapshot keeps the world as it was taken; the next one shows every robot that changed
    /// since, shares the views of those that did not, and takes in robots added and lost.
    #[test]
    fn snapshots_follow_every_change_and_keep_their_own_time() {
        let world = presets::grid(4, 4, 1);
        let model = WorldModel::new(Arc::new(world.track.clone()));
        for id in [3, 1, 2] {
            model.add(id);
        }
        let update = |id: u16, x: f64| StateUpdated {
            robot_id: id,
            at: tokio::time::Instant::now(),
            state: protocol::RobotState::default(),
            reduced: false,
            pose: Pose {
                x,
                y: 0.0,
                theta: 0.0,
            },
        };
        let ids = |v: &[Arc<RobotView>]| v.iter().map(|r| r.id).collect::<Vec<_>>();
        let first = model.shared_views();
        assert_eq!(ids(&first), [1, 2, 3]);
        model.apply(&update(2, 0.5));
        let second = model.shared_views();
        assert!(!first[1].connected, "the earlier snapshot changed");
        assert!(second[1].connected && second[1].odometry.x == 0.5);
        assert!(Arc::ptr_eq(&first[0], &second[0]) && Arc::ptr_eq(&first[2], &second[2]));
        model.lost(2);
        model.add(0);
        let third = model.shared_views();
        assert_eq!(ids(&third), [0, 1, 2, 3]);
        assert!(!third[2].connected && third[2].odometry.x == 0.5);
        // More changes than robots between two snapshots, as the observer's model has.
        for k in 0..20 {
            model.apply(&update(3, f64::from(k) * 0.01));
        }
        let fourth = model.shared_views();
        assert!(
            (fourth[3].odometry.x - 0.19).abs() < 1e-12,
            "{}",
            fourth[3].odometry.x
        );
        for v in fourth.iter() {
            assert!(
                Arc::ptr_eq(v, &model.robots().get(&v.id).unwrap()),
                "robot {}",
                v.id
            );
        }
    }

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
            let sensor = Point2::new(truth.x, truth.y) + heading * LINE_SENSOR_AHEAD_M;
            let near = track.nearest(sensor).unwrap();
            // Pure pursuit of a tape point 20 mm ahead of the sensor, plus a slow weave.
            let target = near.point + near.tangent * 0.02;
            let want = (target.y - truth.y).atan2(target.x - truth.x);
            let omega = 8.0 * wrap_angle(want - truth.theta) + 0.3 * (k as f64 * 0.05).sin();
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
            let sensor = Point2::new(truth.x, truth.y) + heading * LINE_SENSOR_AHEAD_M;
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
                worst_heading = worst_heading.max(wrap_angle(est.theta - truth.theta).abs());
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

    /// What the line sensor of a robot at `truth` reports over `track`: eight spots 3 mm apart
    /// across the heading, each dark over tape; the tape's offset to the right in µm is the
    /// centroid of the dark ones, and the line is lost when none is.
    fn sense(track: &Track, truth: Pose) -> protocol::RobotState {
        let heading = Vector2::new(truth.theta.cos(), truth.theta.sin());
        let right = Vector2::new(heading.y, -heading.x);
        let sensor = Point2::new(truth.x, truth.y) + heading * LINE_SENSOR_AHEAD_M;
        let dark: Vec<f64> = (0..8)
            .map(|k| (k as f64 - 3.5) * 0.003)
            .filter(|&off| {
                track
                    .nearest(sensor + right * off)
                    .is_some_and(|n| n.distance_m < 0.003)
            })
            .collect();
        let mut state = protocol::RobotState::default();
        if dark.is_empty() {
            state.line.flags = LINE_LOST;
        } else {
            let centroid = dark.iter().sum::<f64>() / dark.len() as f64;
            state.line.position_um = (centroid * 1e6) as i16;
        }
        state
    }

    /// A unicycle step: `ds` along an arc turning `dth`.
    fn step(p: Pose, ds: f64, dth: f64) -> Pose {
        let mid = p.theta + dth / 2.0;
        Pose {
            x: p.x + ds * mid.cos(),
            y: p.y + ds * mid.sin(),
            theta: p.theta + dth,
        }
    }

    struct Drive {
        model: WorldModel,
        track: Arc<Track>,
        truth: Pose,
        odometry: Pose,
        at: tokio::time::Instant,
        /// Each transition and the true pose when it came.
        transitions: Vec<Transition>,
        transition_at: Vec<Pose>,
        /// Whether the firmware follows the tape while its sensor sees one.
        following: bool,
    }

    impl Drive {
        fn new(track: Track, start: Pose) -> Self {
            let track = Arc::new(track);
            let model = WorldModel::new(Arc::clone(&track));
            model.add(1);
            let mut d = Self {
                model,
                track,
                truth: start,
                odometry: start,
                at: tokio::time::Instant::now(),
                transitions: Vec::new(),
                transition_at: Vec::new(),
                following: false,
            };
            d.report();
            d
        }

        /// Moves the robot by `ds` and `dth`; its odometry reads `ds·(1 + scale)` and turns
        /// `drift` radians per metre more than it did.
        fn go(&mut self, ds: f64, dth: f64, scale: f64, drift: f64) {
            self.truth = step(self.truth, ds, dth);
            self.odometry = step(self.odometry, ds * (1.0 + scale), dth + ds.abs() * drift);
            self.report();
        }

        fn report(&mut self) {
            self.at += std::time::Duration::from_millis(20);
            let mut state = sense(&self.track, self.truth);
            if self.following && state.line.flags & LINE_LOST == 0 {
                state.line.flags |= LINE_FOLLOWING;
            }
            let u = StateUpdated {
                robot_id: 1,
                at: self.at,
                state,
                reduced: false,
                pose: self.odometry,
            };
            if let Some(t) = self.model.apply(&u) {
                self.transitions.push(t);
                self.transition_at.push(self.truth);
            }
        }

        fn view(&self) -> RobotView {
            self.model.views()[0].clone()
        }

        fn error_m(&self) -> f64 {
            let p = self.view().pose;
            (p.x - self.truth.x).hypot(p.y - self.truth.y)
        }

        /// Drives straight to `(x, y)` at 0.1 m/s in 2 mm steps, first turning on the spot
        /// towards it.
        fn drive_to(&mut self, x: f64, y: f64, scale: f64, drift: f64) -> f64 {
            let want = (y - self.truth.y).atan2(x - self.truth.x);
            let turn = wrap_angle(want - self.truth.theta);
            let n = (turn.abs() / 0.05).ceil() as usize;
            for _ in 0..n {
                self.go(0.0, turn / n as f64, scale, drift);
            }
            let d = (x - self.truth.x).hypot(y - self.truth.y);
            let n = (d / 0.002).ceil() as usize;
            let mut worst = 0.0f64;
            for _ in 0..n {
                self.go(d / n as f64, 0.0, scale, drift);
                worst = worst.max(self.error_m());
            }
            worst
        }
    }

    /// A robot driving moves along a grid's tapes (not following them), its odometry 0.5 % long
    /// and drifting 3° per metre: every turn onto a crossing tape takes out what the last one
    /// could not see, and the model stays within millimetres while the odometry goes astray.
    #[test]
    fn a_robot_driving_moves_along_tapes_is_localised_by_them() {
        let world = presets::grid(4, 4, 1);
        let node = |c: usize, r: usize| {
            let id = format!("c{c}r{r}");
            world.track.nodes()[world.track.node_index(&id).unwrap()].position
        };
        let start = node(0, 0);
        let mut d = Drive::new(
            world.track.clone(),
            Pose {
                x: start.x,
                y: start.y,
                theta: 0.0,
            },
        );
        let (scale, drift) = (0.005, 3f64.to_radians());
        let route = [
            (3, 0),
            (3, 3),
            (0, 3),
            (0, 0),
            (2, 0),
            (2, 2),
            (1, 2),
            (1, 0),
        ];
        let mut worst = 0.0f64;
        for lap in 0..3 {
            for &(c, r) in &route {
                let p = node(c, r);
                let w = d.drive_to(p.x, p.y, scale, drift);
                if lap > 0 {
                    worst = worst.max(w);
                }
            }
        }
        let v = d.view();
        let odo_err = (v.odometry.x - d.truth.x).hypot(v.odometry.y - d.truth.y);
        assert!(odo_err > 0.05, "the drift is real: {odo_err}");
        assert!(worst < 0.006, "model error {worst}");
        assert!(d.transitions.is_empty(), "{:?}", d.transitions);
        let sigma = v.uncertainty.position_m;
        assert!(sigma > 0.0005 && sigma < 0.01, "uncertainty {sigma}");
        assert_eq!(v.localisation, Localisation::Tracking);
    }

    /// Off the tape the uncertainty grows with the distance driven; back on a tape it shrinks
    /// across the tape.
    #[test]
    fn uncertainty_grows_off_the_tape_and_shrinks_on_it() {
        let world = presets::grid(4, 4, 1);
        let mut d = Drive::new(
            world.track.clone(),
            Pose {
                x: 0.3,
                y: 0.3,
                theta: 0.0,
            },
        );
        let s0 = d.view().uncertainty.position_m;
        // Round a square inside one cell five times, never over tape.
        for _ in 0..5 {
            for (x, y) in [(0.35, 0.3), (0.35, 0.35), (0.3, 0.35), (0.3, 0.3)] {
                d.drive_to(x, y, 0.0, 0.0);
            }
        }
        let s1 = d.view().uncertainty.position_m;
        let h1 = d.view().uncertainty.heading_rad;
        assert!(s1 > s0 * 2.0, "{s0} -> {s1}");
        assert!(h1 > START_SIGMA_RAD, "{h1}");
        // Then onto the tape at y = 0.4 and along it.
        d.drive_to(0.3, 0.4, 0.0, 0.0);
        d.drive_to(0.39, 0.4, 0.0, 0.0);
        let normal = Vector2::new(0.0, 1.0);
        let est = d.model.estimates.get(&1).unwrap().cov;
        assert!(
            sigma_along(&est, normal) < 0.002,
            "{}",
            sigma_along(&est, normal)
        );
        assert!(d.transitions.is_empty(), "{:?}", d.transitions);
    }

    /// Kicked 30 mm sideways off the tape it drives along, a robot no longer sees the tape where
    /// the model puts it: it is lost within a few centimetres. Creeping across, its sensor finds
    /// the tape, which fixes the position across it; driving along it again, it is tracked.
    #[test]
    fn a_kicked_robot_is_found_lost_and_relocated_by_the_tape() {
        let world = presets::grid(4, 4, 1);
        let mut d = Drive::new(
            world.track.clone(),
            Pose {
                x: 0.2,
                y: 0.2,
                theta: 0.0,
            },
        );
        d.drive_to(0.27, 0.2, 0.0, 0.0);
        d.truth.y += 0.03;
        let kicked_at = d.truth.x;
        d.drive_to(0.35, 0.23, 0.0, 0.0);
        let lost_after = match d.transitions.first() {
            Some(Transition::Lost(why)) => {
                assert!(why.contains("no tape"), "{why}");
                d.transition_at[0].x - kicked_at
            }
            other => panic!("{other:?}"),
        };
        assert!(lost_after < 0.06, "lost only after {lost_after} m");
        assert_eq!(d.view().localisation, Localisation::Lost);
        assert!(d.view().uncertainty.position_m >= LOST_FLOOR_M * 0.99);
        // The search: face across the tape and creep towards it.
        d.drive_to(d.truth.x, 0.15, 0.0, 0.0);
        assert!(
            d.transitions.contains(&Transition::Fixed),
            "{:?}",
            d.transitions
        );
        let across = (d.view().pose.y - d.truth.y).abs();
        assert!(across < 0.003, "across the tape {across}");
        // Onto the tape and along it.
        d.drive_to(d.truth.x, 0.2, 0.0, 0.0);
        d.drive_to(d.truth.x + 0.05, 0.2, 0.0, 0.0);
        assert_eq!(d.transitions.last(), Some(&Transition::Found));
        assert_eq!(d.view().localisation, Localisation::Tracking);
        assert!(d.error_m() < 0.005, "{}", d.error_m());
        let stats = d.model.localisation_stats(d.at);
        assert_eq!(stats[0].1.lost_episodes, 1);
        assert!(stats[0].1.lost_time > std::time::Duration::ZERO);
    }

    /// A robot driven along the tape at y = 0.2 of a grid from its node at x = 0.2 to `x`,
    /// following it or not.
    fn on_the_tape_at_x(x: f64, following: bool) -> Drive {
        let world = presets::grid(4, 4, 1);
        let start = Pose {
            x: 0.2,
            y: 0.2,
            theta: 0.0,
        };
        let mut d = Drive::new(world.track.clone(), start);
        d.following = following;
        d.drive_to(x, 0.2, 0.0, 0.0);
        d
    }

    /// Knocked off the tape while it stands, a robot never drives the distance the rule above
    /// waits for: its sensor seeing no tape for half a second where the model puts it on one is
    /// enough. Standing on the tape, it is not lost however long it waits.
    #[test]
    fn a_robot_knocked_off_the_tape_at_rest_is_found_lost() {
        let mut d = on_the_tape_at_x(0.27, false);
        for _ in 0..100 {
            d.report();
        }
        assert!(d.transitions.is_empty(), "{:?}", d.transitions);
        d.truth.y += 0.03;
        for _ in 0..20 {
            d.report();
        }
        assert!(
            d.transitions.is_empty(),
            "lost after 0.4 s: {:?}",
            d.transitions
        );
        for _ in 0..10 {
            d.report();
        }
        match d.transitions.first() {
            Some(Transition::Lost(why)) => assert!(why.contains("standing"), "{why}"),
            other => panic!("{other:?}"),
        }
        assert_eq!(d.view().localisation, Localisation::Lost);
    }

    /// A robot turned where it stands, its sensor still on the tape, is not lost, but the model
    /// no longer claims to know its heading; driving on along the tape then measures it again,
    /// which a model still sure of the old heading would not let the sightings do.
    #[test]
    fn a_robot_turned_where_it_stands_is_uncertain_of_its_heading_until_it_drives() {
        let mut d = on_the_tape_at_x(0.27, false);
        for _ in 0..50 {
            d.report();
        }
        let calm = d.view().uncertainty.heading_rad;
        assert!(calm < 3f64.to_radians(), "{calm}");
        d.truth.theta -= 12f64.to_radians();
        for _ in 0..10 {
            d.report();
        }
        assert!(d.transitions.is_empty(), "{:?}", d.transitions);
        let kicked = d.view().uncertainty.heading_rad;
        assert!(
            kicked > 10f64.to_radians(),
            "heading 1σ {:.1}° after a 12° turn at rest",
            kicked.to_degrees()
        );
        // On along the tape as the odometry has it: the true path drifts across the tape.
        for _ in 0..40 {
            d.go(0.002, 0.0, 0.0, 0.0);
        }
        let v = d.view();
        let err = wrap_angle(v.pose.theta - d.truth.theta).abs();
        assert!(
            err < 5f64.to_radians(),
            "heading still {:.1}° off after 8 cm along the tape",
            err.to_degrees()
        );
        assert!(d.transitions.is_empty(), "{:?}", d.transitions);
    }

    /// A follower knocked off its tape loses it at once: where the model has it squarely on the
    /// tape, that alone makes it lost, before it drives or stands for any time.
    #[test]
    fn a_follower_that_loses_its_tape_where_the_model_has_one_is_lost_at_once() {
        let mut d = on_the_tape_at_x(0.27, true);
        assert!(d.transitions.is_empty(), "{:?}", d.transitions);
        d.truth.y += 0.03;
        d.report();
        match d.transitions.first() {
            Some(Transition::Lost(why)) => assert!(why.contains("follower"), "{why}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_robot_backing_across_a_tape_is_fixed_across_it_when_it_comes_onto_it() {
        let world = presets::grid(4, 4, 1);
        let north = std::f64::consts::FRAC_PI_2;
        let mut d = Drive::new(
            world.track.clone(),
            Pose {
                x: 0.3,
                y: 0.2 - LINE_SENSOR_AHEAD_M,
                theta: north,
            },
        );
        // Pushing: the wheels turn half as far again as the body goes, 60 mm off the tape.
        for _ in 0..30 {
            d.go(0.002, 0.0, 0.5, 0.0);
        }
        let off = d.error_m();
        assert!(off > 0.025, "the odometry is {off} m off");
        // Backing straight down until the sensor is on the tape again.
        let mut steps = 0;
        while d.view().state.line.flags & LINE_LOST != 0 && steps < 100 {
            d.go(-0.002, 0.0, 0.0, 0.0);
            steps += 1;
        }
        assert!(steps < 100, "never came onto the tape");
        let across = (d.view().pose.y - d.truth.y).abs();
        assert!(
            across < 0.004,
            "still {across} m off across the tape (was {off})"
        );
        assert_eq!(
            d.view().localisation,
            Localisation::Tracking,
            "not lost: fixed"
        );
    }

    struct TrackLoopLen;
    impl TrackLoopLen {
        fn oval() -> f64 {
            1.0 + 0.3 * PI
        }
    }
}
