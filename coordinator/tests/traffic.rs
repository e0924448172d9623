//! `traffic_control` from the starts a user's world file allows and with its defaults, run
//! through the coordinator on simulated robots and judged from the simulator's ground truth.

use std::time::Duration;

use behaviours::Registry;
use coordinator::{Plan, Report};

/// Two lanes joined by single-lane rungs, every robot placed on a node.
const LADDER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/ladder.toml");

fn run(world: &str, seed: u64, duration_s: u64, params: &[(&str, &str)]) -> Report {
    coordinator::run_blocking(
        plan_for(world, seed, duration_s, params),
        &Registry::builtin(),
    )
    .expect("experiment runs")
}

fn plan_for(world: &str, seed: u64, duration_s: u64, params: &[(&str, &str)]) -> Plan {
    Plan::sim("traffic_control")
        .world(world)
        .seed(seed)
        .duration(Duration::from_secs(duration_s))
        .params(params.iter().copied())
}

fn metric(r: &Report, name: &str) -> Option<f64> {
    r.verdict
        .metrics
        .iter()
        .find(|(k, _)| k == name)
        .map(|(_, v)| *v)
}

#[test]
fn robots_placed_on_nodes_of_a_hand_made_ladder_serve_tasks_without_contact() {
    for seed in 1..=3 {
        let r = run(LADDER, seed, 900, &[("tasks", "12")]);
        assert_eq!(r.robots.len(), 6);
        assert!(r.success(), "seed {seed}: {r}");
        assert!(
            metric(&r, "tasks").is_some_and(|t| t >= 12.0),
            "seed {seed}: {r}"
        );
        assert_eq!(r.robot_collisions(), Some(0), "seed {seed}: {r}");
        assert_eq!(r.wall_contacts(), Some(0), "seed {seed}: {r}");
    }
}

#[test]
fn the_default_task_count_fits_the_default_600_s_on_junction_and_grid() {
    for world in ["junction", "grid"] {
        let r = run(world, 1, 600, &[]);
        assert!(r.success(), "{world}: {r}");
        let robots = r.robots.len() as f64;
        assert!(
            metric(&r, "tasks").is_some_and(|t| t >= (1.5 * robots).ceil()),
            "{world}: {r}"
        );
        // With a margin: three quarters of the time limit at most (seed 1 on junction takes
        // 266 s; seeds 1-100 took 82-449 s).
        assert!(r.experiment_time < Duration::from_secs(450), "{world}: {r}");
        assert_eq!(r.robot_collisions(), Some(0), "{world}: {r}");
    }
}

#[test]
fn a_robot_placed_off_the_tape_is_refused_naming_it_and_the_distance() {
    let ladder = std::fs::read_to_string(LADDER).expect("ladder world");
    let moved = ladder.replace(
        "# on R2\nid = 6\nx = 0.6\n",
        "# off the tape\nid = 6\nx = 0.7\n",
    );
    assert_ne!(moved, ladder, "robot 6 is moved");
    let path = std::env::temp_dir().join(format!("ladder-off-tape-{}.toml", std::process::id()));
    std::fs::write(&path, moved).expect("temporary world");
    let r = run(path.to_str().unwrap(), 1, 60, &[]);
    std::fs::remove_file(&path).ok();
    assert!(!r.verdict.success, "{r}");
    let why = &r.verdict.summary;
    assert!(
        why.contains("robot 6") && why.contains("(0.700, 0.400)") && why.contains("10.0 cm"),
        "{r}"
    );
    assert!(
        r.experiment_time < Duration::from_secs(5),
        "refused at once: {r}"
    );
    assert_eq!(metric(&r, "tasks"), Some(0.0), "{r}");
}

/// A robot shoved 30 mm sideways while it drives no longer sees the tape where the model puts
/// it: the supervisor finds it lost, stops it, re-localises it on the tape and lets it go on;
/// the team finishes its tasks without contact and the model is back within millimetres.
#[test]
fn a_robot_kicked_sideways_is_found_lost_stopped_and_relocalised_without_contact() {
    let plan = plan_for("grid", 1, 600, &[]).kick(coordinator::Kick {
        robot: 1,
        at: Duration::from_secs(12),
        dx_m: 0.0,
        dy_m: 0.0,
        dtheta_rad: 0.0,
        sideways_m: 0.03,
        how: coordinator::KickHow::Teleport,
        drawn: None,
    });
    let r = coordinator::run_blocking(plan, &Registry::builtin()).expect("experiment runs");
    assert!(r.success(), "{r}");
    assert_eq!(r.robot_collisions(), Some(0), "{r}");
    assert_eq!(r.wall_contacts(), Some(0), "{r}");
    let kicked = r.robots.iter().find(|x| x.id == 1).expect("robot 1");
    assert!(kicked.localisation.lost_episodes >= 1, "{r}");
    assert!(kicked.localisation.lost_time > Duration::ZERO, "{r}");
    // The kick itself is the model's error until the robot is found lost and re-localised.
    assert!(kicked.worst_model_error_m.unwrap() >= 0.025, "{r}");
    assert!(kicked.estimate_error_m().unwrap() < 0.01, "{r}");
    for other in r.robots.iter().filter(|x| x.id != 1) {
        assert_eq!(other.localisation.lost_episodes, 0, "{r}");
        assert!(other.worst_model_error_m.unwrap() < 0.03, "{r}");
    }
}
