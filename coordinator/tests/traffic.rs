//! `traffic_control` from the starts a user's world file allows and with its defaults, run
//! through the coordinator on simulated robots and judged from the simulator's ground truth.

use std::collections::BTreeMap;
use std::time::Duration;

use behaviours::Registry;
use coordinator::{Plan, Report, Transport};

/// Two lanes joined by single-lane rungs, every robot placed on a node.
const LADDER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/ladder.toml");

fn run(world: &str, seed: u64, duration_s: u64, params: &[(&str, &str)]) -> Report {
    let plan = Plan {
        behaviour: "traffic_control".into(),
        world: Some(world.into()),
        robots: None,
        transport: Transport::Sim,
        seed,
        realtime: false,
        duration: Duration::from_secs(duration_s),
        params: params
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect::<BTreeMap<_, _>>(),
        faults: Vec::new(),
        body_faults: Vec::new(),
        kicks: Vec::new(),
    };
    coordinator::actor_system(true)
        .block_on(coordinator::run(plan, &Registry::builtin()))
        .expect("experiment runs")
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
