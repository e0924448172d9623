//! `token_ring` (thesis A.3): three or more robots follow a round track; one carries a token (its
//! LED orange). The carrier runs faster than the rest; when it comes up behind the next robot and
//! its front receiver identifies that robot by its IR frames, the token passes to it. A box on the
//! track is driven around: a robot that finds it stops, leaves the tape to the right, passes it
//! and rejoins. The host starts the robots one by one, sets their speeds, and after each round of
//! the token reverses the team's direction (every robot turns on the spot and follows the other
//! way).
//!
//! Success: the token went round the team the given number of times, and every robot's encoders
//! measured at least half a loop per round (2.9 m for the default three rounds of the ring's
//! 1.94 m loop). To hand the token on, each carrier must close up on the robot ahead while the
//! others run at half its speed; on seeds 1 to 10 every robot drove more than two loops in three
//! rounds, and half a loop per round leaves room for detours and waits. A robot whose wheels are
//! driven for 3 s without an encoder pulse fails the run at once (see [`behaviour_api::evidence`]).

use std::collections::BTreeMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::time::Duration;

use protocol::packets::Side;

use behaviour_api::event::{Event, FrontSighting};
use behaviour_api::evidence::Odometer;
use behaviour_api::moves::{Leg, Legs};
use behaviour_api::team::Team;
use behaviour_api::track_loop::TrackLoop;
use behaviour_api::{
    params, Behaviour, BehaviourConfig, Intent, LocalisationEvent, Register, RobotView, Verdict,
    WorldSnapshot,
};

mod sensing;
mod step;

/// The carrier's LED, and everyone else's.
const TOKEN_RGB: [u8; 3] = [255, 110, 0];
const PLAIN_RGB: [u8; 3] = [0, 0, 40];
/// A follower stops when the robot ahead is this close (sensor to sensor) and goes on past the
/// second figure.
const STOP_GAP: f64 = 0.11;
const GO_GAP: f64 = 0.15;
/// The token passes only to the robot ahead within this distance along the track.
const PASS_RANGE: f64 = 0.25;
/// Any robot in front within this distance counts as ahead, whatever its bearing.
const NEAR: f64 = 0.2;
/// A robot off the tape counts as ahead within this half-angle of the heading.
const AHEAD_CONE: f64 = 40.0 * PI / 180.0;
/// Following speed with an unknown obstacle close ahead.
const CREEP_MPS: f32 = 0.03;
/// Manoeuvre speed (detours, turning round).
const MANOEUVRE_MPS: f32 = 0.05;
/// Detour geometry: sideways offset from the tape, and the length driven beside it (from 7 mm
/// short of a 40 mm box to clear of it with the robot's length and a margin).
const DETOUR_SIDE: f64 = 0.05;
const DETOUR_ALONG: f64 = 0.125;
/// A detour first backs this far from where the robot stopped short of the box: its first leg
/// then starts beyond the reach of its own proximity reflex (about 15 mm), which would stop a
/// drive that begins with the box's corner in its front receiver's cone.
const DETOUR_BACK: f64 = 0.025;
/// No other robot may be this close to where a detour rejoins the tape when it starts.
const REJOIN_CLEAR: f64 = 0.15;
/// How far the front receiver sees a reflection at each power level: half the default reach of
/// the level (the light goes there and back).
const REFLECT_REACH_M: [f64; 4] = {
    let r = world::robot::IR_RANGE_M;
    [r[0] / 2.0, r[1] / 2.0, r[2] / 2.0, r[3] / 2.0]
};
/// Slack for the world model's error when asking whether a known body explains a reflection.
const MODEL_SLACK_M: f64 = 0.03;
/// Half a robot's length: from its centre to its front, where the emitter and receiver sit.
const HALF_LEN: f64 = world::robot::LENGTH_M / 2.0;
/// A manoeuvre's next move waits until the wheels have read zero speed this long: a wheel
/// creeping slower than the speed meter resolves reads zero for a moment, and a move planned
/// from there is off by the rest of the creep (and a reversing wheel miscounts it).
const SETTLE: Duration = Duration::from_millis(100);
/// Robots start this long after one another.
const START_STAGGER: Duration = Duration::from_secs(1);
/// Nothing may take longer than this without a token pass.
const PASS_LIMIT: Duration = Duration::from_secs(90);
/// A front sighting bounds the gap this long: a robot in view is reported again every report
/// period (500 ms by default) with the weakest power seen in it, and one out of view is not.
const SIGHTING_FRESH: Duration = Duration::from_millis(600);
/// The share of the loop every robot's encoders must measure per round of the token.
const LOOP_SHARE_PER_ROUND: f64 = 0.5;

#[derive(Clone, Debug, Default)]
struct Bot {
    /// The detour or turn under way, driven closed-loop one move at a time.
    legs: Legs,
    /// Since when the robot's wheels have read zero speed, if they do.
    still_since: Option<Duration>,
    started: bool,
    /// The last robot its front receiver identified.
    front_sighting: Option<FrontSighting>,
    /// Its interrupted moves the supervisor's handling of a lost robot accounts for.
    forgiven: u32,
}

/// The token ring behaviour.
#[derive(Clone, Debug)]
pub struct TokenRing {
    track: TrackLoop,
    tape: std::sync::Arc<world::Track>,
    speed: f32,
    rounds: u32,
    order: Vec<u16>,
    bots: BTreeMap<u16, Bot>,
    holder: u16,
    passes: u32,
    /// +1 along the track's edges, −1 against them.
    direction: f64,
    /// Passes after which the direction is reversed next.
    reverse_at: u32,
    turning: bool,
    reversals: u32,
    detours: u32,
    last_pass: Duration,
    /// Until when moves interrupted are the supervisor's doing: it stopped a lost robot and the
    /// robots moving near it, whose detours and turns go on from where they stand once it is
    /// found.
    forgive_until: Duration,
    /// Robots lost and not yet found again: what they sense while their search turns them
    /// about (another robot seen ahead) is no pass of the token.
    lost: std::collections::BTreeSet<u16>,
    /// Robots whose link was lost and has not come back: stopped by their watchdogs, sensing
    /// nothing the team hears of.
    link_down: std::collections::BTreeSet<u16>,
    /// When each robot last backed away to make room.
    room_made: BTreeMap<u16, Duration>,
    odometer: Odometer,
    verdict: Option<Verdict>,
}

params! {
    /// Parameters of `token_ring`.
    pub struct TokenRingParams {
        /// Whether the team reverses after every round.
        reverse: bool = true;
        /// Token rounds to complete.
        rounds: u32 = 3, 1 => 50;
        /// The carrier's speed, m/s (the others run at half).
        speed: f32 = 0.12, 0.08 => 0.3;
    }
}

impl Register for TokenRing {
    type Params = TokenRingParams;

    /// Builds it.
    ///
    /// # Errors
    /// Fewer than two robots, or a track that is not one closed loop.
    fn build(p: TokenRingParams, cfg: &BehaviourConfig) -> Result<Self, String> {
        let track = TrackLoop::new(&cfg.track)?;
        let (speed, rounds, reverse) = (p.speed, p.rounds, p.reverse);
        if cfg.robots.len() < 2 {
            return Err("a token ring needs at least two robots".into());
        }
        let n = cfg.robots.len() as u32;
        Ok(Self {
            track,
            tape: cfg.track.clone(),
            speed,
            rounds,
            order: cfg.robots.clone(),
            bots: cfg.robots.iter().map(|&id| (id, Bot::default())).collect(),
            holder: cfg.robots[0],
            passes: 0,
            direction: 1.0,
            reverse_at: if reverse { n } else { u32::MAX },
            turning: false,
            reversals: 0,
            detours: 0,
            last_pass: Duration::ZERO,
            forgive_until: Duration::ZERO,
            lost: Default::default(),
            link_down: Default::default(),
            room_made: BTreeMap::new(),
            odometer: Odometer::new(),
            verdict: None,
        })
    }
}
