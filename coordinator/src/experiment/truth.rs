//! The run's ending as the report gives it: each robot's figures, the ground truth where the
//! robots are simulated, and the world model's error against it sampled through the run.

use super::*;

use world::robot::LINE_SENSOR_AHEAD_M as SENSOR_AHEAD_M;
use world::wrap_angle as wrap_rad;

/// The simulation's ground truth once stop commands have had time to reach the robots.
pub(super) async fn ground_truth(sim: Option<&SimHandle>) -> Option<Truth> {
    tokio::time::sleep(Duration::from_millis(300)).await;
    match sim {
        Some(h) => h.truth().await,
        None => None,
    }
}

/// What a run left to report once its robots stopped.
pub(super) struct Ending {
    pub(super) outcome: Outcome,
    pub(super) truth: Option<Truth>,
    pub(super) model_errors: ModelErrors,
    pub(super) experiment_time: Duration,
}

/// Each robot's final state, estimate and ground truth.
pub(super) async fn robot_reports(
    ending: &Ending,
    robots: &[(u16, Robot)],
    world: &World,
    model: &WorldModel,
) -> Result<Vec<RobotReport>> {
    let truth = ending.truth.as_ref();
    let mut per_robot = Vec::new();
    for (i, (id, robot)) in robots.iter().enumerate() {
        let snap = robot.snapshot().await?;
        let truth_pose =
            truth.and_then(|t| t.robots.iter().find(|(r, _)| r == id).map(|(_, p)| *p));
        let estimate = model.robots().get(id).map_or(snap.pose, |v| v.pose);
        let off_tape_m = truth_pose.and_then(|p| {
            let sensor = nalgebra::Point2::new(
                p.x + SENSOR_AHEAD_M * p.theta.cos(),
                p.y + SENSOR_AHEAD_M * p.theta.sin(),
            );
            world.track.nearest(sensor).map(|n| n.distance_m)
        });
        let worst = ending.model_errors.worst.get(id);
        per_robot.push(RobotReport {
            id: *id,
            worst_model_error_m: worst.map(|w| w.0),
            worst_model_heading_error_rad: worst.map(|w| w.1),
            localisation: ending
                .outcome
                .localisation
                .iter()
                .find(|(r, _)| r == id)
                .map(|(_, l)| *l)
                .unwrap_or_default(),
            odometry: snap.pose,
            estimate,
            off_tape_m,
            truth: truth_pose.map(|p| Pose {
                x: p.x,
                y: p.y,
                theta: p.theta,
            }),
            distance_m: truth.and_then(|t| t.distances_m.get(i).copied()),
            link: snap.link,
            wheels_mps: (
                f64::from(snap.state.wheels.left_mps),
                f64::from(snap.state.wheels.right_mps),
            ),
        });
    }
    Ok(per_robot)
}

/// The experiment's report.
pub(super) fn build_report(
    plan: &Plan,
    world: &World,
    ending: Ending,
    robots: Vec<RobotReport>,
    wall_time: Duration,
    (kicks, faults): (Vec<KickRecord>, Vec<FaultRecord>),
) -> Report {
    let Ending {
        outcome,
        truth,
        model_errors,
        experiment_time,
    } = ending;
    Report {
        behaviour: plan.behaviour.clone(),
        world: world.name.clone(),
        seed: plan.seed,
        verdict: outcome.verdict,
        robots,
        obstacles: truth
            .as_ref()
            .map(|t| obstacle_reports(world, t))
            .unwrap_or_default(),
        ground_truth: truth.as_ref().map(|t| GroundTruth {
            robot_contacts: t.robot_collisions,
            wall_contacts: t.wall_contacts,
            collision_log: t.collision_log.clone(),
            wall_contact_log: t.wall_contact_log.clone(),
            model_samples: model_errors.samples,
            physics_hz: plan.physics_hz(),
            longest_unattended_s: t.longest_unattended_s(),
        }),
        held_intents: outcome
            .held
            .iter()
            .map(|(t, i, why)| format!("{t:?}: {i:?}: {why}"))
            .collect(),
        links: outcome.links,
        encounters: outcome.encounters.len(),
        restarts: outcome.restarts,
        reflexes: outcome.reflexes,
        experiment_time,
        wall_time,
        peak_memory_bytes: crate::report::peak_memory_bytes(),
        conditions: crate::report::Conditions {
            realtime: plan.realtime,
            link_profile: plan.link.as_ref().map(|l| l.name.clone()),
            host_load: plan.host_load,
            resumed: None,
        },
        kicks,
        faults,
    }
}

/// The world model's worst error against the ground truth over a run.
#[derive(Clone, Debug, Default)]
pub(super) struct ModelErrors {
    /// Per robot id: the worst position error (metres) and the worst heading error (radians).
    pub(super) worst: std::collections::BTreeMap<u16, (f64, f64)>,
    /// How many times the model was checked.
    pub(super) samples: usize,
}

/// The model error sampler of a simulated run, from the supervisor's start to the verdict.
pub(super) struct ModelSampler {
    pub(super) stop: oneshot::Sender<()>,
    pub(super) task: Option<tokio::task::JoinHandle<ModelErrors>>,
}

impl ModelSampler {
    /// Starts sampling when there is a simulation to take the truth from.
    pub(super) fn start(sim: Option<&SimHandle>, model: &WorldModel) -> Self {
        let (stop, stopped) = oneshot::channel();
        let task = sim
            .cloned()
            .map(|h| tokio::spawn(sample_model_errors(h, model.robots(), stopped)));
        Self { stop, task }
    }

    /// Stops sampling and gives the worst errors seen.
    pub(super) async fn finish(self) -> Result<ModelErrors> {
        let _ = self.stop.send(());
        match self.task {
            Some(task) => task.await.context("the model error sampler failed"),
            None => Ok(ModelErrors::default()),
        }
    }
}

/// Compares every robot's model pose with its true pose each [`MODEL_SAMPLE_PERIOD`] until `stop`
/// fires or the simulation ends. A robot counts from its first report on: before it the model has
/// no pose of its own for it.
pub(super) async fn sample_model_errors(
    h: SimHandle,
    views: Arc<dashmap::DashMap<u16, Arc<behaviours::RobotView>>>,
    mut stop: oneshot::Receiver<()>,
) -> ModelErrors {
    let mut errors = ModelErrors::default();
    let mut tick = tokio::time::interval(MODEL_SAMPLE_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    // Model against ground truth once a second in the log, for studying the estimator.
    let log = tracing::enabled!(target: "coordinator::truth", tracing::Level::DEBUG);
    let log_every = (Duration::from_secs(1).as_millis() / MODEL_SAMPLE_PERIOD.as_millis()) as usize;
    loop {
        tokio::select! {
            biased;
            _ = &mut stop => break,
            _ = tick.tick() => {}
        }
        let Some(truth) = h.poses().await else { break };
        errors.samples += 1;
        for (id, p) in &truth.robots {
            let Some(v) = views.get(id) else { continue };
            if !v.connected && !errors.worst.contains_key(id) {
                continue;
            }
            let position = (p.x - v.pose.x).hypot(p.y - v.pose.y);
            let heading = wrap_rad(p.theta - v.pose.theta).abs();
            let worst = errors.worst.entry(*id).or_insert((0.0, 0.0));
            worst.0 = worst.0.max(position);
            worst.1 = worst.1.max(heading);
            if log && errors.samples % log_every == 0 {
                tracing::debug!(
                    target: "coordinator::truth",
                    robot = id,
                    t = truth.now.as_secs_f64(),
                    truth = ?(p.x, p.y, p.theta),
                    model = ?(v.pose.x, v.pose.y, v.pose.theta),
                    odometry = ?(v.odometry.x, v.odometry.y, v.odometry.theta),
                    line_um = { v.state.line.position_um },
                    line_flags = { v.state.line.flags },
                    sigma_mm = v.uncertainty.position_m * 1e3,
                    localisation = ?v.localisation,
                );
            }
        }
    }
    errors
}

pub(super) fn obstacle_reports(world: &World, truth: &Truth) -> Vec<ObstacleReport> {
    world
        .obstacles
        .iter()
        .zip(&truth.obstacles)
        .zip(&truth.obstacle_displacements_m)
        .map(|((spec, pose), moved)| {
            // The footprint's perimeter, sampled every 2 mm, against the tape's edges.
            let (s, c) = pose.theta.sin_cos();
            let (hw, hh) = (spec.width_m / 2.0, spec.height_m / 2.0);
            let steps = ((spec.width_m + spec.height_m) / 0.002).ceil().max(4.0) as usize;
            let mut clear = f64::INFINITY;
            for k in 0..=steps {
                let t = k as f64 / steps as f64;
                for (lx, ly) in [
                    (-hw + 2.0 * hw * t, -hh),
                    (-hw + 2.0 * hw * t, hh),
                    (-hw, -hh + 2.0 * hh * t),
                    (hw, -hh + 2.0 * hh * t),
                ] {
                    let q =
                        nalgebra::Point2::new(pose.x + c * lx - s * ly, pose.y + s * lx + c * ly);
                    if let Some(n) = world.track.nearest(q) {
                        let half_tape = world.track.edges()[n.edge].width_m / 2.0;
                        clear = clear.min((n.distance_m - half_tape).max(0.0));
                    }
                    if world.track.floor_at(q).ir_reflectance < 0.9 {
                        clear = 0.0;
                    }
                }
            }
            ObstacleReport {
                pose: [pose.x, pose.y, pose.theta],
                moved_m: *moved,
                clear_of_tape_m: clear,
            }
        })
        .collect()
}
