//! `cooperative_push` (thesis A.2): robots follow the track until one finds it blocked by a box
//! too heavy for one robot. That robot stops; the other comes up behind it and stops. Both then
//! leave the tape for two slots side by side on one side of the box, face it, and push it together
//! with one synchronised command, far enough that it is clear of the tape by more than a body
//! length. They back onto the tape one after the other and follow it again. A box still found on
//! the tape afterwards means the push failed; it is tried again, at most twice.
//!
//! A disturbance while the team gathers at the box (a robot lost and found again, a move the
//! safety check held, an aborted manoeuvre) does not end the run: the team stops, drives back onto
//! the tape behind the box one robot after the other, and finds it again, at most three times;
//! then the run fails with what went wrong. From the push on, the pushers' slip under the box is
//! unmeasured until the tape finds them: a robot lost then (a felt bump) is searched for, each
//! robot gets back onto the tape where it stands, in turn, and the team laps; a push cut short
//! counts only if the box gave way to every pusher, and otherwise the laps find the box again for
//! another push. A held move or an aborted one then ends the run.
//!
//! The box is found by the front IR receiver: a robot with a reflection ahead (within 50 mm) and no
//! robot ahead in the world model creeps, and stops at the first reflection at the weakest power
//! level (within 15 mm); where the box is comes from the finder's pose and that reach.
//!
//! Success: the box gave way (every pusher's line sensor crossed the tape the box stood on), each
//! pusher's encoders measured at least 90 % of the push it was sent (134 mm of the default
//! 12 + 150 mm, slipping or not: a robot that never drove has not pushed), and after the push
//! the team lapped the track again without finding the box, each robot's encoders measuring at
//! least 90 % of those laps (1.75 m for the default lap of the push world's loop). A robot whose
//! wheels are driven for 3 s without an encoder pulse fails the run at once (see
//! [`behaviour_api::evidence`]).

use std::collections::BTreeMap;
use std::time::Duration;

use behaviour_api::{MoveCommand, Pose};
use nalgebra::{Point2, Vector2};
use protocol::packets::Side;
use world::wrap_angle;

use behaviour_api::event::Event;
use behaviour_api::evidence::{Odometer, EVIDENCE_SHARE};
use behaviour_api::moves::Manoeuvre;
use behaviour_api::team::{HeldPolicy, Team};
use behaviour_api::track_loop::TrackLoop;
use behaviour_api::{
    params, Behaviour, BehaviourConfig, Intent, Localisation, LocalisationEvent, Register,
    RobotView, Verdict, WorldSnapshot,
};

mod manoeuvres;
mod regroup;
mod rejoin;
mod step;

/// Half the body length, metres.
const HALF_LEN: f64 = world::robot::LENGTH_M / 2.0;
/// Space between a waiting pusher's front and the box, metres.
const LANE_GAP: f64 = 0.012;
/// The approach lane runs this far below the slots: a robot turning there clears one waiting in
/// the next slot (its corners sweep a 29 mm circle), and one passing leaves 15 mm between their
/// bodies, room for the safety check's margins and for twice the uncertainty of each pose; any
/// lower and a turn in the lane would come too near the arena's edge.
const APPROACH_BELOW: f64 = 0.055;
/// The first robot into the slots, with no one beside them yet, takes a lane this far below
/// them: a turn there clears the box, and a leg along it stays 58 mm from the arena's edge, so
/// that a heading nothing on the robot measures off the tape (a turn by hand while it drives)
/// can be 20° wrong over the whole leg without a corner reaching the edge.
const FIRST_BELOW: f64 = 0.020;
/// A robot leaves the tape for the slots this far behind where the finder stood when it saw the
/// box: the finder's own back-up before its first turn. The helper follows the tape up to
/// there first, so that its leg along the deep lane, 23 mm from the arena's edge, is short.
const TURN_BACK: f64 = 0.015;
/// Pushers stand this far either side of the box's centre line: 16 mm between their bodies, so
/// that the second can turn into its slot beside the first with room for a few millimetres of
/// pose error, while each still covers 12 mm of a 40 mm box.
const SLOT_OFFSET: f64 = 0.024;
/// A robot whose reflex stopped it on its way into the slot counts as there when the model has it
/// at most this short of it: the reflex sees the box within about 15 mm, the slot's front is 12 mm
/// from it; a robot stopped farther back stopped at something else.
const SLOT_SHORT: f64 = 0.012;
/// The gap between the finder's front and the box in its first state report that sees the box at
/// the shortest reach (15 mm): the reach less the creep between the IR's sample and the report
/// (measured in the simulator: 12.7 mm). Pose and reading come from one report, so the link's
/// latency does not enter.
const SIGHTED_GAP: f64 = 0.0127;
/// A follower stops when the robot ahead is this close (sensor to sensor) and goes on past the
/// second figure.
const STOP_GAP: f64 = 0.12;
const GO_GAP: f64 = 0.16;
/// The helper backs onto the tape only once the finder is this far along it.
const REJOIN_GAP: f64 = 0.16;
/// Backing speed towards the tape, and how far the robot runs on after its sensor crosses it
/// (a report's latency at that speed, then braking).
const BACK_MPS: f32 = 0.03;
const BACK_OVERSHOOT: f64 = 0.002;
/// A tape report counts only once the robot has backed this far: after a push that moved the box
/// clear, the sensor stands well beyond the tape, and over a wall-clock link a report of the
/// push's own crossing can arrive late, with the robot still beside the other pusher.
const MIN_BACK_M: f64 = 0.02;
/// A pusher facing the push direction this far off, and no farther, pushes along an arc that ends
/// facing along it (see `start_push`).
const ARC_MIN_RAD: f64 = 0.3 * std::f64::consts::PI / 180.0;
const ARC_MAX_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;
/// A robot stopped on the tape waits for the model to put its line sensor this close to the tape
/// before its route along it is planned, and this long at most.
const ALIGN_AGREE_M: f64 = 0.008;
const ALIGN_WAIT: Duration = Duration::from_millis(1000);
/// A held route along the tape is tried again this much later, this many times.
const ALIGN_RETRY: Duration = Duration::from_millis(500);
const ALIGN_HOLDS: u32 = 10;
/// Line sensor ahead of the robot's centre, metres.
const SENSOR_AHEAD: f64 = world::robot::LINE_SENSOR_AHEAD_M;
/// Following speed with an unknown obstacle close ahead.
const CREEP_MPS: f32 = 0.03;
/// Speed of manoeuvres off the tape, and of the push.
const MANOEUVRE_MPS: f32 = 0.08;
const PUSH_MPS: f32 = 0.05;
/// The robots' own proximity reflex away from the box: a surface within about 15 mm.
const REFLEX_ON: u8 = 1;
/// A phase that takes longer than this has failed.
const PHASE_LIMIT: Duration = Duration::from_secs(30);
/// A regroup or a rejoin takes longer: it waits for a lost robot's search (a sweep at 3 cm/s
/// takes 10 s or more, and is made up to three times) before the team's routes.
const REGROUP_LIMIT: Duration = Duration::from_secs(60);
/// Attempts before giving up.
const MAX_PUSHES: u32 = 2;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    /// Following until someone finds the box.
    Approach,
    /// The finder has stopped; the helper closes up behind it.
    Gather,
    /// The finder drives to its slot.
    FinderToSlot,
    /// The helper drives to its slot.
    HelperToSlot,
    /// Both push.
    Push,
    /// The finder backs onto the tape and follows it.
    FinderRejoins,
    /// The helper waits for room, then backs onto the tape.
    HelperWaits,
    /// The helper backs onto the tape.
    HelperRejoins,
    /// Both follow the track again.
    Lapping,
    /// After a disturbance before the push: back onto the tape behind the box, one after the
    /// other.
    Regroup,
    /// After a disturbance from the push on: each robot onto the tape where it stands, in turn.
    Rejoin,
}

/// Where the box is: its estimated centre, the tape's direction there and the push direction.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Site {
    centre: Point2<f64>,
    along: Vector2<f64>,
    push: Vector2<f64>,
}

impl Site {
    fn at(&self, along: f64, push: f64) -> Point2<f64> {
        self.centre + self.along * along + self.push * push
    }

    fn heading(v: Vector2<f64>) -> f64 {
        v.y.atan2(v.x)
    }

    /// How far across the tape, along the push direction, a robot at `pose` has its line sensor.
    fn sensor_across(&self, pose: Pose) -> f64 {
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        (Vector2::new(pose.x, pose.y) - self.centre.coords + heading * SENSOR_AHEAD).dot(&self.push)
    }
}

#[derive(Clone, Debug, Default)]
struct Bot {
    /// Loop coordinate at the last snapshot while lapping.
    last_s: Option<f64>,
    /// Metres lapped since rejoining.
    lapped_m: f64,
    /// The odometer's reading when lapping began.
    lap_odometer_m: Option<f64>,
    /// The odometer's reading when the push began.
    push_odometer_m: f64,
    /// Backing up towards the tape after the push, since then.
    backing: Option<Duration>,
    /// The odometer's reading when backing began.
    backing_odometer_m: f64,
    /// Driving forwards onto the tape rather than backing (a rejoin from short of it).
    onto_forwards: bool,
    /// The line sensor crossed the tape during the push: the box gave way.
    crossed_tape: bool,
    /// On its route into its slot, whose last leg the robot's reflex may end short of the box.
    seeking: bool,
    /// Back on the tape after the push, facing along it.
    rejoined: bool,
    /// Stopped on the tape, waiting to drive its centre onto it and turn along it.
    aligning: Option<Align>,
    /// How often that was held so far.
    align_holds: u32,
}

/// A robot stopped where its sensor crossed the tape, waiting for its route along it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Align {
    /// Since when it waits for the model to agree.
    since: Duration,
    /// Not sent before this (after a hold).
    not_before: Duration,
}

/// The cooperative pushing behaviour.
#[derive(Clone, Debug)]
pub struct CooperativePush {
    track: TrackLoop,
    speed: f32,
    push_m: f64,
    box_half: f64,
    laps: f64,
    bots: BTreeMap<u16, Bot>,
    /// Robots following the tape whose link was lost and has not come back.
    link_down: std::collections::BTreeSet<u16>,
    phase: Phase,
    phase_since: Duration,
    finder: Option<u16>,
    site: Option<Site>,
    /// The finder's pose when it first saw the box at the shortest reach.
    sighted: Option<Pose>,
    pushes: u32,
    push_started: Duration,
    push_time: Option<Duration>,
    odometer: Odometer,
    verdict: Option<Verdict>,
    /// Regroups so far, why the last one began, the robots sent on their way back in it, and
    /// when a held route is tried again.
    regroups: u32,
    regroup_why: Option<String>,
    routed: Vec<u16>,
    retry_at: Option<Duration>,
    /// Each robot's counts of interrupted and reflex-blocked moves already acted on.
    interrupts_seen: BTreeMap<u16, (u32, u32)>,
}

params! {
    /// Parameters of `cooperative_push`.
    pub struct CooperativePushParams {
        /// Box width across the push, metres.
        r#box: f64 = 0.04, 0.01 => 0.1;
        /// Laps each pusher drives after the push.
        laps: f64 = 1.0, 0.01 => 20.0;
        /// How far the pushers drive into the box, metres (their wheels slip under the load, so the box moves less).
        push: f64 = 0.15, 0.02 => 0.3;
        /// Following speed, m/s.
        speed: f32 = 0.1, 0.04 => 0.3;
    }
}

impl Register for CooperativePush {
    type Params = CooperativePushParams;

    /// Builds it.
    ///
    /// # Errors
    /// A track that is not one closed loop, or no robot.
    fn build(p: CooperativePushParams, cfg: &BehaviourConfig) -> Result<Self, String> {
        let track = TrackLoop::new(&cfg.track)?;
        let (speed, push_m, box_m, laps) = (p.speed, p.push, p.r#box, p.laps);
        if cfg.robots.is_empty() {
            return Err("needs at least one robot".into());
        }
        Ok(Self {
            track,
            speed,
            push_m,
            box_half: box_m / 2.0,
            laps,
            bots: cfg.robots.iter().map(|&id| (id, Bot::default())).collect(),
            phase: Phase::Approach,
            phase_since: Duration::ZERO,
            finder: None,
            site: None,
            sighted: None,
            pushes: 0,
            push_started: Duration::ZERO,
            push_time: None,
            odometer: Odometer::new(),
            verdict: None,
            regroups: 0,
            link_down: Default::default(),
            regroup_why: None,
            routed: Vec::new(),
            retry_at: None,
            interrupts_seen: BTreeMap::new(),
        })
    }
}
