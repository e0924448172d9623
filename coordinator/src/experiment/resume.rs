//! Taking over a run whose coordinator died (`coordinator --resume FILE.mcap`): the killed run's
//! recording names its behaviour, world, seed and robot addresses, and its last world snapshot
//! says where each robot was; the robots are adopted as they are (never rebooted), their
//! odometry carried on from the counters in that snapshot, and the world model starts from it,
//! widened for what the counters cannot tell about the gap.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, Context as _, Result};
use robot_actor::actor::{ContinueOdometry, Continued};
use robot_actor::{Pose, Robot};
use serde_json::Value;

use crate::plan::{Plan, Transport};

/// One robot as the killed run last recorded it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Recorded {
    /// Robot id.
    pub id: u16,
    /// The world model's pose.
    pub pose: Pose,
    /// Its 1σ, position (worst direction) and heading.
    pub sigma_m: f64,
    /// Heading 1σ, radians.
    pub sigma_rad: f64,
    /// The model had it lost.
    pub lost: bool,
    /// The robot's clock and encoder counters in the state the pose came from.
    pub uptime_ms: u32,
    /// Left and right counters.
    pub counters: (i32, i32),
}

/// What a resumed run takes over.
#[derive(Clone, Debug, PartialEq)]
pub struct Resume {
    /// The recording.
    pub from: PathBuf,
    /// Time of its last world snapshot, on the killed run's clock.
    pub at: Duration,
    /// Every robot in that snapshot.
    pub robots: Vec<Recorded>,
}

/// How one robot was taken over.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Adopted {
    /// Robot id.
    pub id: u16,
    /// Robot time from the recorded state to the first state on the new link, seconds.
    pub gap_s: f64,
    /// Distance its counters say it drove in the gap, metres (coasting after the host fell
    /// silent, then standing stopped by its watchdog).
    pub driven_m: f64,
    /// Its clock went back: it restarted in the gap (odometry then starts afresh at the recorded
    /// pose, as uncertain as a lost robot).
    pub rebooted: bool,
    /// The model's 1σ it starts from, metres and degrees.
    pub sigma_mm: f64,
    /// Heading 1σ it starts from, degrees.
    pub sigma_deg: f64,
}

/// A resumed run, as its report states it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Resumed {
    /// The recording it took over from.
    pub from: String,
    /// The recording's last snapshot, seconds of the killed run.
    pub at_s: f64,
    /// Every robot, as adopted.
    pub robots: Vec<Adopted>,
}

/// Position 1σ added per metre the counters say a robot drove in the gap: they give the distance
/// and the heading exactly, but not the path's shape (one arc of constant curvature is assumed,
/// which a line follower on a curve or a straight drives; a straight run into a curve is off by
/// up to a tenth of the distance), and a robot that coasted to a stop may have slipped.
const GAP_SHARE: f64 = 0.1;
/// And at least this (one tick's travel and the snapshot's own lag).
const GAP_FLOOR_M: f64 = 0.002;
/// Heading 1σ added per radian turned in the gap, and at least this.
const GAP_TURN_SHARE: f64 = 0.1;
const GAP_TURN_FLOOR_RAD: f64 = 0.0175;
/// A robot that restarted in the gap, or was lost when last recorded, starts this uncertain:
/// the model's own threshold for not knowing where a robot is.
const UNKNOWN_M: f64 = world_model::LOST_SIGMA_M;
const UNKNOWN_RAD: f64 = 0.35;
/// How long a robot may take to report its first state after its hello.
const FIRST_STATE: Duration = Duration::from_secs(2);

impl Resume {
    /// Reads a killed run's recording (a torn tail is fine: its last whole chunk is used) into the
    /// plan that takes it over and what it takes over.
    ///
    /// # Errors
    /// A recording that cannot be read, that was of robots simulated inside the coordinator (they
    /// died with it), that names no robot addresses, or whose last snapshot lacks a robot's state.
    pub fn load(path: &Path) -> Result<(Plan, Resume)> {
        let rec = crate::instruments::replay::load(path)?;
        let info = &rec.info;
        let shown = path.display();
        if info.simulated {
            bail!(
                "{shown}: its robots were simulated inside the coordinator that ran it and ended \
                 with it; there is nothing to take over (run the experiment again)"
            );
        }
        if info.addresses.is_empty() {
            bail!(
                "{shown}: the recording does not say where its robots are (a run over zenoh, or \
                 one recorded before `--resume` existed)"
            );
        }
        let Some((at, snapshot)) = rec.snapshots.last() else {
            bail!("{shown}: no world snapshot was recorded before the run ended");
        };
        let robots = snapshot["robots"]
            .as_array()
            .with_context(|| format!("{shown}: the last snapshot lists no robots"))?
            .iter()
            .map(recorded)
            .collect::<Result<Vec<_>>>()
            .with_context(|| format!("{shown}: the snapshot at {:.2} s", at.as_secs_f64()))?;
        if robots.len() != info.addresses.len() {
            bail!(
                "{shown}: the last snapshot holds {} robots, the run had {} addresses",
                robots.len(),
                info.addresses.len()
            );
        }
        let limit = info
            .duration_s
            .map_or(Plan::DEFAULT_DURATION, Duration::from_secs_f64);
        // What is left of the time limit, at least a minute to reach a verdict in.
        let duration = limit.saturating_sub(*at).max(Duration::from_secs(60));
        let plan = Plan {
            world: Some(info.world.clone()),
            transport: Transport::Addresses(info.addresses.clone()),
            seed: info.seed,
            realtime: true,
            duration,
            params: info.params.clone(),
            ..Plan::sim(info.behaviour.clone())
        };
        let resume = Resume {
            from: path.to_path_buf(),
            at: *at,
            robots,
        };
        Ok((plan, resume))
    }

    /// Carries each connected robot's odometry on from its record, and says how uncertain the
    /// model must start it.
    ///
    /// # Errors
    /// A robot the recording does not hold, or one that reports no state in time.
    pub(super) async fn adopt(&self, robots: &[(u16, Robot)]) -> Result<Resumed> {
        let mut adopted = Vec::with_capacity(robots.len());
        for (id, robot) in robots {
            let Some(r) = self.robots.iter().find(|r| r.id == *id) else {
                bail!(
                    "robot {id} answered, but {} holds no robot {id}: resume takes over the same \
                     robots",
                    self.from.display()
                );
            };
            let msg = ContinueOdometry {
                pose: r.pose,
                uptime_ms: r.uptime_ms,
                counters: r.counters,
            };
            let c: Continued = tokio::time::timeout(FIRST_STATE, robot.addr().send(msg))
                .await
                .with_context(|| format!("robot {id} reported no state within {FIRST_STATE:?}"))?
                .with_context(|| format!("robot {id}'s actor stopped"))?;
            let (sigma_m, sigma_rad) = if c.rebooted || r.lost {
                (UNKNOWN_M.max(r.sigma_m), UNKNOWN_RAD.max(r.sigma_rad))
            } else {
                let add_m = GAP_SHARE * c.driven_m.abs() + GAP_FLOOR_M;
                let add_rad = GAP_TURN_SHARE * c.turned_rad.abs() + GAP_TURN_FLOOR_RAD;
                (r.sigma_m.hypot(add_m), r.sigma_rad.hypot(add_rad))
            };
            tracing::info!(
                robot = id,
                gap_s = f64::from(c.elapsed_ms) / 1e3,
                driven_mm = c.driven_m * 1e3,
                rebooted = c.rebooted,
                "adopted"
            );
            adopted.push(Adopted {
                id: *id,
                gap_s: if c.rebooted {
                    0.0
                } else {
                    f64::from(c.elapsed_ms) / 1e3
                },
                driven_m: c.driven_m,
                rebooted: c.rebooted,
                sigma_mm: sigma_m * 1e3,
                sigma_deg: sigma_rad.to_degrees(),
            });
        }
        Ok(Resumed {
            from: self.from.display().to_string(),
            at_s: self.at.as_secs_f64(),
            robots: adopted,
        })
    }
}

/// One robot of a recorded world snapshot.
fn recorded(v: &Value) -> Result<Recorded> {
    let num = |v: &Value, what: &str| {
        v.as_f64()
            .with_context(|| format!("a robot's {what} is missing"))
    };
    let id = v["id"].as_u64().context("a robot without an id")? as u16;
    if v["updates"].as_u64().unwrap_or(0) == 0 {
        bail!("robot {id} had not reported a state yet");
    }
    let state = &v["state"];
    let int = |v: &Value, what: &str| {
        v.as_i64()
            .with_context(|| format!("robot {id}'s {what} is missing"))
    };
    Ok(Recorded {
        id,
        pose: Pose {
            x: num(&v["pose"]["x"], "pose")?,
            y: num(&v["pose"]["y"], "pose")?,
            theta: num(&v["pose"]["theta"], "pose")?,
        },
        sigma_m: num(&v["uncertainty"]["position_m"], "uncertainty")?,
        sigma_rad: num(&v["uncertainty"]["heading_rad"], "uncertainty")?,
        lost: v["localisation"].as_str() == Some("lost"),
        uptime_ms: int(&state["uptime_ms"], "uptime")? as u32,
        counters: (
            int(&state["encoders"]["left_ticks"], "left counter")? as i32,
            int(&state["encoders"]["right_ticks"], "right counter")? as i32,
        ),
    })
}
