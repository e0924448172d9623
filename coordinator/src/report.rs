//! The experiment report: the behaviour's verdict and figures, what the simulator's ground truth
//! saw (contacts), per-robot odometry against ground truth, distances, link statistics, and
//! simulated and wall time; as text or JSON.
//!
//! The overall result ([`Report::success`]) is the behaviour's verdict overruled by the ground
//! truth: a simulated run in which robots touched each other or a wall failed, whatever the
//! behaviour concluded from what the robots reported.

use std::fmt;
use std::time::Duration;

use behaviours::Verdict;

use robot_actor::actor::LinkStats;
use robot_actor::Pose;
use serde::Serialize;
use world_model::LocalisationStats;

/// One robot's part of the report.
#[derive(Clone, Debug)]
pub struct RobotReport {
    /// Robot id.
    pub id: u16,
    /// Final odometry pose.
    pub odometry: Pose,
    /// Final pose estimate of the world model (odometry corrected against the track).
    pub estimate: Pose,
    /// Final true pose (simulated robots only).
    pub truth: Option<Pose>,
    /// True distance from the line sensor to the nearest tape centre line at the end, metres
    /// (simulated robots on a world with a track only).
    pub off_tape_m: Option<f64>,
    /// True distance driven, metres (simulated robots only).
    pub distance_m: Option<f64>,
    /// Link statistics.
    pub link: LinkStats,
    /// Measured wheel speeds (left, right) in the last state the robot reflected, m/s: zero
    /// once the experiment has stopped it.
    pub wheels_mps: (f64, f64),
    /// The world model's worst position error against ground truth over the run, sampled every
    /// 100 ms of experiment time, metres (simulated robots only).
    pub worst_model_error_m: Option<f64>,
    /// The world model's worst heading error against ground truth over the run, radians
    /// (simulated robots only).
    pub worst_model_heading_error_rad: Option<f64>,
    /// How the robot's localisation went: lost episodes, time lost, worst uncertainty.
    pub localisation: LocalisationStats,
}

impl RobotReport {
    /// Odometry position error against ground truth, metres.
    pub fn odometry_error_m(&self) -> Option<f64> {
        self.truth
            .map(|t| (t.x - self.odometry.x).hypot(t.y - self.odometry.y))
    }

    /// Odometry heading error against ground truth, degrees in (−180, 180].
    pub fn heading_error_deg(&self) -> Option<f64> {
        self.truth
            .map(|t| wrap_deg((t.theta - self.odometry.theta).to_degrees()))
    }

    /// World-model position error against ground truth, metres.
    pub fn estimate_error_m(&self) -> Option<f64> {
        self.truth
            .map(|t| (t.x - self.estimate.x).hypot(t.y - self.estimate.y))
    }

    /// World-model heading error against ground truth, degrees in (−180, 180].
    pub fn estimate_heading_error_deg(&self) -> Option<f64> {
        self.truth
            .map(|t| wrap_deg((t.theta - self.estimate.theta).to_degrees()))
    }
}

fn wrap_deg(a: f64) -> f64 {
    (a + 180.0).rem_euclid(360.0) - 180.0
}

/// One obstacle's part of the report (simulated worlds only).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ObstacleReport {
    /// Final true pose: x, y (metres), heading (radians).
    pub pose: [f64; 3],
    /// How far it moved from its start, metres.
    pub moved_m: f64,
    /// Distance from its footprint to the nearest tape edge, metres (0 when it covers tape).
    pub clear_of_tape_m: f64,
}

/// What the simulator's ground truth saw over a run (simulated robots only).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GroundTruth {
    /// Robot–robot contacts.
    pub robot_contacts: usize,
    /// Robot–wall contacts.
    pub wall_contacts: usize,
    /// When each robot–robot contact began (simulated seconds) and between which robots.
    pub collision_log: Vec<(f64, u16, u16)>,
    /// When each robot–wall contact began (simulated seconds) and which robot touched.
    pub wall_contact_log: Vec<(f64, u16)>,
    /// How many times the world model was checked against the true poses.
    pub model_samples: usize,
    /// The simulated robots' physics rate, Hz.
    pub physics_hz: u32,
    /// The longest any robot's wheels kept turning while its host was silent, seconds.
    pub longest_unattended_s: f64,
}

impl GroundTruth {
    /// Whether nothing the ground truth forbids happened: no robot touched another or a wall.
    pub fn clean(&self) -> bool {
        self.robot_contacts == 0 && self.wall_contacts == 0
    }

    /// Why the ground truth fails the run, in one line; `None` when it is clean.
    pub fn objection(&self) -> Option<String> {
        (!self.clean()).then(|| {
            format!(
                "the ground truth saw {} robot–robot contact{} and {} wall contact{}",
                self.robot_contacts,
                if self.robot_contacts == 1 { "" } else { "s" },
                self.wall_contacts,
                if self.wall_contacts == 1 { "" } else { "s" },
            )
        })
    }
}

/// A fault as it landed on a simulated robot.
#[derive(Clone, Debug, PartialEq)]
pub struct FaultRecord {
    /// The fault.
    pub spec: crate::plan::FaultSpec,
    /// When it began, simulated seconds.
    pub at_s: f64,
}

impl FaultRecord {
    /// When it ended, simulated seconds.
    pub fn until_s(&self) -> f64 {
        self.at_s + self.spec.lasting.as_secs_f64()
    }
}

/// A kick as it landed on a simulated robot.
#[derive(Clone, Debug, PartialEq)]
pub struct KickRecord {
    /// Robot id.
    pub robot: u16,
    /// When it landed, simulated seconds.
    pub at_s: f64,
    /// Teleport or shove.
    pub how: crate::plan::KickHow,
    /// Shift along x and y (metres) and turn (radians).
    pub by: [f64; 3],
    /// The robot's true pose when the kick landed: x, y (metres), heading (radians).
    pub from: [f64; 3],
    /// Why it was not given, if it was not.
    pub refused: Option<String>,
}

impl KickRecord {
    /// Contacts beginning up to this long after a kick's end are the kick's own: the body it
    /// moved was still settling, and no motion approved after it could have closed a gap yet.
    pub const OWN_CONTACT_S: f64 = 0.02;

    /// When the kick's own contacts end, simulated seconds.
    pub fn own_until_s(&self) -> f64 {
        let lasts = match self.how {
            crate::plan::KickHow::Teleport => 0.0,
            crate::plan::KickHow::Shove(d) => d.as_secs_f64(),
        };
        self.at_s + lasts + Self::OWN_CONTACT_S
    }

    /// The kick in one line: `shove of robot 2 at 12.30 s by (+4.1, -12.0) mm and +7.5°`.
    pub fn describe(&self) -> String {
        let how = match self.how {
            crate::plan::KickHow::Teleport => "teleport".to_string(),
            crate::plan::KickHow::Shove(d) => format!("{} ms shove", d.as_millis()),
        };
        let mut s = format!(
            "{how} of robot {} at {:.2} s by ({:+.1}, {:+.1}) mm and {:+.1}°",
            self.robot,
            self.at_s,
            self.by[0] * 1e3,
            self.by[1] * 1e3,
            self.by[2].to_degrees()
        );
        if let Some(why) = &self.refused {
            s.push_str(&format!(" not given: {why}"));
        }
        s
    }
}

/// Everything an experiment produced.
#[derive(Clone, Debug)]
pub struct Report {
    /// Behaviour name.
    pub behaviour: String,
    /// World name.
    pub world: String,
    /// Seed.
    pub seed: u64,
    /// The behaviour's verdict, as the behaviour gave it.
    pub verdict: Verdict,
    /// What the ground truth saw (simulated robots only).
    pub ground_truth: Option<GroundTruth>,
    /// Per-robot results.
    pub robots: Vec<RobotReport>,
    /// Obstacles at the end (ground truth; simulated robots only).
    pub obstacles: Vec<ObstacleReport>,
    /// Intents the safety check held back.
    pub held_intents: Vec<String>,
    /// Robot links lost and (re)connected during the run.
    pub links: Vec<crate::supervisor::LinkRecord>,
    /// Encounters reported by the robots.
    pub encounters: usize,
    /// Behaviour restarts.
    pub restarts: u32,
    /// Drives the robots' proximity reflexes stopped.
    pub reflexes: u32,
    /// Experiment time on the experiment's clock (simulated when simulating).
    pub experiment_time: Duration,
    /// Wall-clock time of the whole run.
    pub wall_time: Duration,
    /// The process's peak resident memory when the report was made, bytes (where the system
    /// says; several runs in one process share it).
    pub peak_memory_bytes: Option<u64>,
    /// Kicks given to simulated robots, as they landed.
    pub kicks: Vec<KickRecord>,
    /// Faults injected into simulated robots' links and firmware, as they began.
    pub faults: Vec<FaultRecord>,
    /// How the run was paced and loaded: the clock, the links' profile, busy threads beside it.
    pub conditions: Conditions,
}

/// The conditions a run met that its world does not say.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Conditions {
    /// Paced to the wall clock (not lockstep).
    pub realtime: bool,
    /// The `--link-profile` given, if one was.
    pub link_profile: Option<String>,
    /// Threads kept busy beside the experiment.
    pub host_load: usize,
    /// The killed run this one took over (`--resume`), and how each robot was adopted.
    pub resumed: Option<crate::experiment::resume::Resumed>,
}

/// The peak resident set size of this process so far, bytes: `VmHWM` in `/proc/self/status`, so
/// `None` off Linux.
pub fn peak_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line
        .trim_start_matches("VmHWM:")
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kib * 1024)
}

#[derive(Serialize)]
struct JsonRobot {
    id: u16,
    odometry: [f64; 3],
    estimate: [f64; 3],
    truth: Option<[f64; 3]>,
    odometry_error_mm: Option<f64>,
    heading_error_deg: Option<f64>,
    estimate_error_mm: Option<f64>,
    estimate_heading_error_deg: Option<f64>,
    off_tape_mm: Option<f64>,
    distance_m: Option<f64>,
    final_wheels_mps: [f64; 2],
    worst_model_error_mm: Option<f64>,
    worst_model_heading_error_deg: Option<f64>,
    lost_episodes: u32,
    lost_s: f64,
    worst_uncertainty_mm: f64,
    packets_in: u64,
    packets_out: u64,
    checksum_errors: u64,
    dropped_frames: u64,
    rtt_mean_ms: Option<f64>,
    delivery: robot_actor::DeliveryCounts,
    link_losses: u64,
    reconnects: u64,
}

/// One link's figures: how fast commands reach the robot, what was lost, how late events came.
#[derive(Serialize)]
struct JsonLink {
    robot: u16,
    /// One way, taken as half the round trip.
    latency_p50_ms: Option<f64>,
    latency_p99_ms: Option<f64>,
    rtt_p50_ms: Option<f64>,
    rtt_p99_ms: Option<f64>,
    packets_in: u64,
    packets_out: u64,
    /// Frames that arrived broken, and events and commands the delivery layer had to recover.
    dropped_frames: u64,
    checksum_errors: u64,
    events_recovered: u64,
    events_lost: u64,
    commands_resent: u64,
    link_losses: u64,
    reconnects: u64,
    events_timed: u64,
    event_late_p50_ms: Option<f64>,
    event_late_p99_ms: Option<f64>,
}

impl JsonLink {
    fn of(robot: u16, l: &LinkStats) -> Self {
        let ms = |d: Option<std::time::Duration>| d.map(|d| d.as_secs_f64() * 1e3);
        Self {
            robot,
            latency_p50_ms: ms(l.rtt_p50).map(|v| v / 2.0),
            latency_p99_ms: ms(l.rtt_p99).map(|v| v / 2.0),
            rtt_p50_ms: ms(l.rtt_p50),
            rtt_p99_ms: ms(l.rtt_p99),
            packets_in: l.packets_in,
            packets_out: l.packets_out,
            dropped_frames: l.dropped_frames,
            checksum_errors: l.checksum_errors,
            events_recovered: l.delivery.events_recovered,
            events_lost: l.delivery.events_lost,
            commands_resent: l.delivery.commands_resent,
            link_losses: l.losses,
            reconnects: l.reconnects,
            events_timed: l.events_timed,
            event_late_p50_ms: ms(l.event_late_p50),
            event_late_p99_ms: ms(l.event_late_p99),
        }
    }
}

#[derive(Serialize)]
struct JsonKick {
    robot: u16,
    at_s: f64,
    how: String,
    dx_mm: f64,
    dy_mm: f64,
    turn_deg: f64,
    from: [f64; 3],
    refused: Option<String>,
    text: String,
}

#[derive(Serialize)]
struct JsonFault {
    robot: u16,
    kind: &'static str,
    at_s: f64,
    for_s: f64,
    text: String,
}

#[derive(Serialize)]
struct JsonReport<'a> {
    behaviour: &'a str,
    world: &'a str,
    seed: u64,
    success: bool,
    behaviour_success: bool,
    ground_truth_objection: Option<String>,
    summary: &'a str,
    metrics: std::collections::BTreeMap<&'a str, f64>,
    robots: Vec<JsonRobot>,
    obstacles: &'a [ObstacleReport],
    robot_collisions: Option<usize>,
    wall_contacts: Option<usize>,
    kicks: Vec<JsonKick>,
    faults: Vec<JsonFault>,
    longest_unattended_s: Option<f64>,
    contacts_at_kick: Option<usize>,
    contacts_other: Option<usize>,
    worst_model_error_mm: Option<f64>,
    worst_model_heading_error_deg: Option<f64>,
    model_samples: Option<usize>,
    physics_hz: Option<u32>,
    lost_episodes: u32,
    lost_s: f64,
    worst_uncertainty_mm: f64,
    held_intents: &'a [String],
    /// Per link: latency, losses, event lateness.
    links: Vec<JsonLink>,
    /// Links lost and robots (re)connected during the run.
    link_events: &'a [crate::supervisor::LinkRecord],
    encounters: usize,
    restarts: u32,
    reflexes: u32,
    experiment_time_s: f64,
    wall_time_s: f64,
    peak_memory_mb: Option<f64>,
    conditions: &'a Conditions,
}

impl Report {
    /// The overall result: the behaviour succeeded and the ground truth, where there is one, saw
    /// no contact.
    pub fn success(&self) -> bool {
        self.verdict.success && self.ground_truth.as_ref().is_none_or(GroundTruth::clean)
    }

    /// Why the ground truth fails a run the behaviour called a success; `None` otherwise.
    pub fn overruled(&self) -> Option<String> {
        if !self.verdict.success {
            return None;
        }
        self.ground_truth.as_ref().and_then(GroundTruth::objection)
    }

    /// Robot–robot contacts (ground truth; simulated robots only).
    pub fn robot_collisions(&self) -> Option<usize> {
        self.ground_truth.as_ref().map(|g| g.robot_contacts)
    }

    /// Robot–wall contacts (ground truth; simulated robots only).
    pub fn wall_contacts(&self) -> Option<usize> {
        self.ground_truth.as_ref().map(|g| g.wall_contacts)
    }

    /// Contacts (robot–robot and wall) that began while a kick was landing, and those that began
    /// at any other time: the first the kick caused, the second the supervision let happen
    /// (simulated robots only).
    pub fn contacts_at_kick_and_other(&self) -> Option<(usize, usize)> {
        let g = self.ground_truth.as_ref()?;
        let at_kick = |t: f64| {
            self.kicks
                .iter()
                .filter(|k| k.refused.is_none())
                .any(|k| t >= k.at_s - 1e-9 && t <= k.own_until_s())
        };
        let times = g
            .collision_log
            .iter()
            .map(|c| c.0)
            .chain(g.wall_contact_log.iter().map(|c| c.0));
        let (mut own, mut other) = (0, 0);
        for t in times {
            if at_kick(t) {
                own += 1;
            } else {
                other += 1;
            }
        }
        Some((own, other))
    }

    /// The world model's worst position error against ground truth over every robot and the
    /// whole run, metres (simulated robots only).
    pub fn worst_model_error_m(&self) -> Option<f64> {
        self.robots
            .iter()
            .filter_map(|r| r.worst_model_error_m)
            .reduce(f64::max)
    }

    /// The world model's worst heading error against ground truth over every robot and the whole
    /// run, radians (simulated robots only).
    pub fn worst_model_heading_error_rad(&self) -> Option<f64> {
        self.robots
            .iter()
            .filter_map(|r| r.worst_model_heading_error_rad)
            .reduce(f64::max)
    }

    /// Lost episodes summed over the robots.
    pub fn lost_episodes(&self) -> u32 {
        self.robots
            .iter()
            .map(|r| r.localisation.lost_episodes)
            .sum()
    }

    /// Time lost summed over the robots.
    pub fn lost_time(&self) -> Duration {
        self.robots.iter().map(|r| r.localisation.lost_time).sum()
    }

    /// The largest position uncertainty the model gave any robot, metres.
    pub fn worst_uncertainty_m(&self) -> f64 {
        self.robots
            .iter()
            .map(|r| r.localisation.worst_uncertainty_m)
            .fold(0.0, f64::max)
    }

    /// The report as JSON.
    pub fn to_json(&self) -> String {
        let pose = |p: Pose| [p.x, p.y, p.theta];
        let split = self.contacts_at_kick_and_other();
        let j = JsonReport {
            behaviour: &self.behaviour,
            world: &self.world,
            seed: self.seed,
            success: self.success(),
            behaviour_success: self.verdict.success,
            ground_truth_objection: self.ground_truth.as_ref().and_then(GroundTruth::objection),
            summary: &self.verdict.summary,
            metrics: self
                .verdict
                .metrics
                .iter()
                .map(|(k, v)| (k.as_str(), *v))
                .collect(),
            robots: self
                .robots
                .iter()
                .map(|r| JsonRobot {
                    id: r.id,
                    odometry: pose(r.odometry),
                    estimate: pose(r.estimate),
                    truth: r.truth.map(pose),
                    odometry_error_mm: r.odometry_error_m().map(|e| e * 1e3),
                    heading_error_deg: r.heading_error_deg(),
                    estimate_error_mm: r.estimate_error_m().map(|e| e * 1e3),
                    estimate_heading_error_deg: r.estimate_heading_error_deg(),
                    off_tape_mm: r.off_tape_m.map(|e| e * 1e3),
                    distance_m: r.distance_m,
                    final_wheels_mps: [r.wheels_mps.0, r.wheels_mps.1],
                    worst_model_error_mm: r.worst_model_error_m.map(|e| e * 1e3),
                    worst_model_heading_error_deg: r
                        .worst_model_heading_error_rad
                        .map(f64::to_degrees),
                    lost_episodes: r.localisation.lost_episodes,
                    lost_s: r.localisation.lost_time.as_secs_f64(),
                    worst_uncertainty_mm: r.localisation.worst_uncertainty_m * 1e3,
                    packets_in: r.link.packets_in,
                    packets_out: r.link.packets_out,
                    checksum_errors: r.link.checksum_errors,
                    dropped_frames: r.link.dropped_frames,
                    rtt_mean_ms: r.link.rtt_mean.map(|d| d.as_secs_f64() * 1e3),
                    delivery: r.link.delivery,
                    link_losses: r.link.losses,
                    reconnects: r.link.reconnects,
                })
                .collect(),
            obstacles: &self.obstacles,
            robot_collisions: self.robot_collisions(),
            wall_contacts: self.wall_contacts(),
            kicks: self
                .kicks
                .iter()
                .map(|k| JsonKick {
                    robot: k.robot,
                    at_s: k.at_s,
                    how: match k.how {
                        crate::plan::KickHow::Teleport => "teleport".into(),
                        crate::plan::KickHow::Shove(d) => format!("shove/{}", d.as_millis()),
                    },
                    dx_mm: k.by[0] * 1e3,
                    dy_mm: k.by[1] * 1e3,
                    turn_deg: k.by[2].to_degrees(),
                    from: k.from,
                    refused: k.refused.clone(),
                    text: k.describe(),
                })
                .collect(),
            faults: self
                .faults
                .iter()
                .map(|f| JsonFault {
                    robot: f.spec.robot,
                    kind: f.spec.kind.name(),
                    at_s: f.at_s,
                    for_s: f.spec.lasting.as_secs_f64(),
                    text: f.spec.describe(),
                })
                .collect(),
            longest_unattended_s: self.ground_truth.as_ref().map(|g| g.longest_unattended_s),
            contacts_at_kick: split.map(|c| c.0),
            contacts_other: split.map(|c| c.1),
            worst_model_error_mm: self.worst_model_error_m().map(|e| e * 1e3),
            worst_model_heading_error_deg: self
                .worst_model_heading_error_rad()
                .map(f64::to_degrees),
            model_samples: self.ground_truth.as_ref().map(|g| g.model_samples),
            physics_hz: self.ground_truth.as_ref().map(|g| g.physics_hz),
            lost_episodes: self.lost_episodes(),
            lost_s: self.lost_time().as_secs_f64(),
            worst_uncertainty_mm: self.worst_uncertainty_m() * 1e3,
            held_intents: &self.held_intents,
            links: self
                .robots
                .iter()
                .map(|r| JsonLink::of(r.id, &r.link))
                .collect(),
            link_events: &self.links,
            encounters: self.encounters,
            restarts: self.restarts,
            reflexes: self.reflexes,
            experiment_time_s: self.experiment_time.as_secs_f64(),
            wall_time_s: self.wall_time.as_secs_f64(),
            peak_memory_mb: self.peak_memory_bytes.map(|b| b as f64 / 1e6),
            conditions: &self.conditions,
        };
        serde_json::to_string_pretty(&j).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.fmt_verdict(f)?;
        self.fmt_robots(f)?;
        self.fmt_ground_truth(f)?;
        self.fmt_run(f)
    }
}

impl Report {
    /// The verdict line, why the ground truth overruled it, its summary and figures, and the
    /// robot table's header.
    fn fmt_verdict(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let verdict = if self.success() { "SUCCESS" } else { "FAILURE" };
        writeln!(
            f,
            "{} on {} (seed {}): {verdict}",
            self.behaviour, self.world, self.seed
        )?;
        if let Some(why) = self.overruled() {
            writeln!(f, "  the behaviour reported success, but {why}")?;
        }
        writeln!(f, "  {}", self.verdict.summary)?;
        for (k, v) in &self.verdict.metrics {
            writeln!(f, "  {k}: {v:.3}")?;
        }
        writeln!(
            f,
            "  robot   odometry x,y [mm]   truth x,y [mm]   error [mm]  heading err [deg]  model err [mm, deg]  worst model err [mm, deg]  lost [n, s]  worst σ [mm]  driven [m]  rtt [ms]  in/out packets  losses"
        )?;
        Ok(())
    }

    /// One line per robot: odometry, truth, the model's errors, localisation and link figures.
    fn fmt_robots(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for r in &self.robots {
            let truth = r.truth.map_or("        -        ".to_string(), |t| {
                format!("{:7.1},{:7.1}", t.x * 1e3, t.y * 1e3)
            });
            let num = |v: Option<f64>, w: usize, p: usize| {
                v.map_or(format!("{:>w$}", "-"), |v| format!("{v:w$.p$}"))
            };
            writeln!(
                f,
                "  {:5}   {:7.1},{:7.1}   {truth}   {}  {}  {} {}  {} {}  {:>3} {:7.2}  {:12.1}  {}  {}  {:>7}/{:<7} {:>6}",
                r.id,
                r.odometry.x * 1e3,
                r.odometry.y * 1e3,
                num(r.odometry_error_m().map(|e| e * 1e3), 10, 1),
                num(r.heading_error_deg(), 17, 2),
                num(r.estimate_error_m().map(|e| e * 1e3), 10, 1),
                num(r.estimate_heading_error_deg(), 9, 2),
                num(r.worst_model_error_m.map(|e| e * 1e3), 15, 1),
                num(r.worst_model_heading_error_rad.map(f64::to_degrees), 9, 2),
                r.localisation.lost_episodes,
                r.localisation.lost_time.as_secs_f64(),
                r.localisation.worst_uncertainty_m * 1e3,
                num(r.distance_m, 10, 3),
                num(r.link.rtt_mean.map(|d| d.as_secs_f64() * 1e3), 8, 1),
                r.link.packets_in,
                r.link.packets_out,
                r.link.losses,
            )?;
        }
        Ok(())
    }

    /// Per link: one-way latency (half the round trip), losses, how late events arrived.
    fn fmt_links(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ms = |d: Option<std::time::Duration>, half: bool| {
            d.map_or("-".to_string(), |d| {
                let v = d.as_secs_f64() * 1e3;
                format!("{:.1}", if half { v / 2.0 } else { v })
            })
        };
        for r in &self.robots {
            let l = &r.link;
            writeln!(
                f,
                "  link {}: latency p50 {} ms, p99 {} ms; lost: {} frames broken, {} events recovered, {} events lost, {} commands resent, {} links lost; events late p99 {} ms ({} timed)",
                r.id,
                ms(l.rtt_p50, true),
                ms(l.rtt_p99, true),
                l.dropped_frames + l.checksum_errors,
                l.delivery.events_recovered,
                l.delivery.events_lost,
                l.delivery.commands_resent,
                l.losses,
                ms(l.event_late_p99, false),
                l.events_timed,
            )?;
        }
        Ok(())
    }

    /// Where the obstacles ended, and the simulator's contacts and model errors.
    fn fmt_ground_truth(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, o) in self.obstacles.iter().enumerate() {
            writeln!(
                f,
                "  obstacle {i}: at {:.1},{:.1} mm, moved {:.1} mm, {:.1} mm clear of the tape",
                o.pose[0] * 1e3,
                o.pose[1] * 1e3,
                o.moved_m * 1e3,
                o.clear_of_tape_m * 1e3
            )?;
        }
        if let Some(g) = &self.ground_truth {
            writeln!(
                f,
                "  ground truth ({} Hz physics): robot-robot contacts: {}; wall contacts: {}",
                g.physics_hz, g.robot_contacts, g.wall_contacts
            )?;
            for (t, a, b) in g.collision_log.iter().take(5) {
                writeln!(f, "    at {t:.2} s: robots {a} and {b}")?;
            }
            for (t, r) in g.wall_contact_log.iter().take(5) {
                writeln!(f, "    at {t:.2} s: robot {r} and the wall")?;
            }
            for k in &self.kicks {
                writeln!(f, "  kick: {}", k.describe())?;
            }
            for x in &self.faults {
                writeln!(
                    f,
                    "  fault: {} (began at {:.2} s)",
                    x.spec.describe(),
                    x.at_s
                )?;
            }
            if g.longest_unattended_s > 0.0 {
                writeln!(
                    f,
                    "  ground truth: the longest a robot's wheels turned with its host silent: \
                     {:.0} ms",
                    g.longest_unattended_s * 1e3
                )?;
            }
            if let (false, Some((own, other))) =
                (self.kicks.is_empty(), self.contacts_at_kick_and_other())
            {
                writeln!(
                    f,
                    "  contacts: {own} while a kick landed, {other} at other times (supervised)"
                )?;
            }
            if let (Some(e), Some(h)) = (
                self.worst_model_error_m(),
                self.worst_model_heading_error_rad(),
            ) {
                writeln!(
                    f,
                    "  ground truth: worst model error {:.1} mm, {:.2}° (checked {} times)",
                    e * 1e3,
                    h.to_degrees(),
                    g.model_samples
                )?;
            }
        }
        Ok(())
    }

    /// Localisation, encounters, held intents, link news, and the run's times and memory.
    fn fmt_run(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "  localisation: {} lost episodes, {:.2} s lost in all; worst uncertainty {:.1} mm",
            self.lost_episodes(),
            self.lost_time().as_secs_f64(),
            self.worst_uncertainty_m() * 1e3
        )?;
        writeln!(
            f,
            "  encounters: {}; behaviour restarts: {}; drives stopped by the proximity reflex: {}",
            self.encounters, self.restarts, self.reflexes
        )?;
        if !self.held_intents.is_empty() {
            writeln!(
                f,
                "  intents held back by the safety check: {}",
                self.held_intents.len()
            )?;
            for h in self.held_intents.iter().take(5) {
                writeln!(f, "    {h}")?;
            }
        }
        // Each robot's first connection is the normal start; only what happened after is news.
        let mut seen = std::collections::HashSet::new();
        let news: Vec<String> = self
            .links
            .iter()
            .filter(|l| l.what != "connected" || !seen.insert(l.robot))
            .map(|l| format!("robot {} {} at {:.2} s", l.robot, l.what, l.at_s))
            .collect();
        if !news.is_empty() {
            writeln!(f, "  link events: {}", news.join(", "))?;
        }
        self.fmt_links(f)?;
        let c = &self.conditions;
        let mut pace = vec![if c.realtime { "wall clock" } else { "lockstep" }.to_string()];
        pace.extend(c.link_profile.as_ref().map(|l| format!("link {l}")));
        if c.host_load > 0 {
            pace.push(format!("host load {}", c.host_load));
        }
        if let Some(r) = &c.resumed {
            let rebooted: Vec<String> = r
                .robots
                .iter()
                .filter(|a| a.rebooted)
                .map(|a| a.id.to_string())
                .collect();
            let driven = r
                .robots
                .iter()
                .map(|a| a.driven_m.abs())
                .fold(0.0, f64::max);
            pace.push(format!(
                "resumed from {} at {:.2} s: {} robots adopted, the farthest driven in the gap {:.0} mm{}",
                r.from,
                r.at_s,
                r.robots.len(),
                driven * 1e3,
                if rebooted.is_empty() {
                    ", none restarted".to_string()
                } else {
                    format!(", robots {} had restarted", rebooted.join(", "))
                }
            ));
        }
        write!(
            f,
            "  experiment time {:.2} s ({}), wall time {:.2} s",
            self.experiment_time.as_secs_f64(),
            pace.join(", "),
            self.wall_time.as_secs_f64()
        )?;
        if let Some(b) = self.peak_memory_bytes {
            write!(f, ", peak memory {:.0} MB", b as f64 / 1e6)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(contacts: (usize, usize)) -> Report {
        Report {
            behaviour: "token_ring".into(),
            world: "oval".into(),
            seed: 7,
            verdict: Verdict::success("three rounds"),
            ground_truth: Some(GroundTruth {
                robot_contacts: contacts.0,
                wall_contacts: contacts.1,
                collision_log: vec![(1.5, 1, 2); contacts.0],
                wall_contact_log: vec![(3.0, 1); contacts.1],
                model_samples: 100,
                physics_hz: 1000,
                longest_unattended_s: 0.0,
            }),
            robots: Vec::new(),
            obstacles: Vec::new(),
            held_intents: Vec::new(),
            links: Vec::new(),
            encounters: 0,
            restarts: 0,
            reflexes: 0,
            experiment_time: Duration::from_secs(10),
            wall_time: Duration::from_secs(1),
            peak_memory_bytes: Some(50_000_000),
            conditions: Conditions::default(),
            kicks: Vec::new(),
            faults: Vec::new(),
        }
    }

    #[test]
    fn contacts_while_a_kick_lands_are_told_from_the_others() {
        let mut r = report((2, 1));
        assert_eq!(r.contacts_at_kick_and_other(), Some((0, 3)));
        r.kicks.push(KickRecord {
            robot: 1,
            at_s: 1.48,
            how: crate::plan::KickHow::Shove(Duration::from_millis(20)),
            by: [0.01, 0.0, 0.0],
            from: [0.5, 0.5, 0.0],
            refused: None,
        });
        // Both robot contacts began 20 ms into the shove; the wall contact long after.
        assert_eq!(r.contacts_at_kick_and_other(), Some((2, 1)));
        assert!(
            r.to_string()
                .contains("2 while a kick landed, 1 at other times"),
            "{r}"
        );
        let json: serde_json::Value = serde_json::from_str(&r.to_json()).unwrap();
        assert_eq!(json["contacts_at_kick"], 2);
        assert_eq!(json["contacts_other"], 1);
        assert!(json["kicks"][0]["text"]
            .as_str()
            .unwrap()
            .starts_with("20 ms shove of robot 1 at 1.48 s by (+10.0, +0.0) mm"));
    }

    #[test]
    fn the_report_ends_with_the_times_and_the_peak_memory() {
        let r = report((0, 0));
        assert!(
            r.to_string().ends_with(
                "  experiment time 10.00 s (lockstep), wall time 1.00 s, peak memory 50 MB"
            ),
            "{r}"
        );
        let json: serde_json::Value = serde_json::from_str(&r.to_json()).unwrap();
        assert_eq!(json["peak_memory_mb"], 50.0);
        // This process holds at least its own code and the report: some megabytes, not bytes.
        if cfg!(target_os = "linux") {
            let peak = peak_memory_bytes().expect("Linux reports VmHWM");
            assert!(peak > 1_000_000 && peak < 100_000_000_000, "{peak}");
        }
    }

    #[test]
    fn contacts_overrule_the_behaviours_success() {
        let r = report((3, 0));
        assert!(!r.success());
        let text = r.to_string();
        let mut lines = text.lines();
        assert_eq!(
            lines.next(),
            Some("token_ring on oval (seed 7): FAILURE"),
            "{text}"
        );
        assert_eq!(
            lines.next(),
            Some(
                "  the behaviour reported success, but the ground truth saw 3 robot–robot \
                 contacts and 0 wall contacts"
            ),
            "{text}"
        );
        let json: serde_json::Value = serde_json::from_str(&r.to_json()).unwrap();
        assert_eq!(json["success"], false);
        assert_eq!(json["behaviour_success"], true);
        assert_eq!(json["robot_collisions"], 3);
    }

    #[test]
    fn a_clean_ground_truth_keeps_the_verdict_and_a_failure_is_not_overruled() {
        let r = report((0, 0));
        assert!(r.success());
        assert!(r
            .to_string()
            .starts_with("token_ring on oval (seed 7): SUCCESS\n  three"));
        let mut failed = report((0, 1));
        failed.verdict = Verdict::failure("lost the token");
        assert!(!failed.success());
        assert_eq!(failed.overruled(), None);
        assert!(!failed
            .to_string()
            .contains("the behaviour reported success"));
        // Without a ground truth (real robots) the behaviour's word stands.
        failed.verdict = Verdict::success("three rounds");
        failed.ground_truth = None;
        assert!(failed.success());
    }
}
