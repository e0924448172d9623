//! `traffic_control` over seeds 1–10, judged from the simulator's ground truth: with its defaults
//! on `junction`, and 200 tasks on the 12-robot `grid` (runs of about 600 s simulated, where
//! odometry drift used to grow until robots collided). Every run must succeed with no robot–robot
//! and no wall contact, and the world model must stay within 30 mm of the truth at every
//! snapshot (sampled every 100 ms).
//!
//! These take minutes, so they are ignored by the default `cargo test`; CI runs them in a step
//! of their own, in the test profile the suite has already built (about 2 minutes on 2 cores):
//! `cargo test -p coordinator --test many_seeds -- --ignored`.

use std::time::Duration;

use behaviours::Registry;
use coordinator::{Plan, Report};

/// The model's error bound at every snapshot: a third of a robot's width.
const MODEL_ERROR_BOUND_M: f64 = 0.03;

fn plan(world: &str, seed: u64, duration_s: u64, params: &[(&str, &str)]) -> Plan {
    Plan::sim("traffic_control")
        .world(world)
        .seed(seed)
        .duration(Duration::from_secs(duration_s))
        .params(params.iter().copied())
}

/// Runs seeds 1–10 two at a time (each in its own actor system) and checks each report.
fn seeds_1_to_10(world: &str, duration_s: u64, params: &[(&str, &str)]) {
    let seeds: Vec<u64> = (1..=10).collect();
    let reports: Vec<(u64, Report)> = std::thread::scope(|s| {
        let handles: Vec<_> = seeds
            .chunks(5)
            .map(|chunk| {
                s.spawn(move || {
                    chunk
                        .iter()
                        .map(|&seed| {
                            let r = coordinator::run_blocking(
                                plan(world, seed, duration_s, params),
                                &Registry::builtin(),
                            )
                            .expect("experiment runs");
                            (seed, r)
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().expect("runner thread"))
            .collect()
    });
    assert_eq!(reports.len(), 10);
    for (seed, r) in &reports {
        assert!(r.success(), "{world} seed {seed}: {r}");
        assert_eq!(r.robot_collisions(), Some(0), "{world} seed {seed}: {r}");
        assert_eq!(r.wall_contacts(), Some(0), "{world} seed {seed}: {r}");
        let worst = r.worst_model_error_m().expect("sampled against the truth");
        assert!(
            worst < MODEL_ERROR_BOUND_M,
            "{world} seed {seed}: model {:.1} mm from the truth: {r}",
            worst * 1e3
        );
        assert_eq!(r.lost_episodes(), 0, "{world} seed {seed}: {r}");
    }
}

#[test]
#[ignore = "minutes: CI's many-seed step runs it"]
fn traffic_control_with_its_defaults_on_junction_for_seeds_1_to_10() {
    seeds_1_to_10("junction", 600, &[]);
}

#[test]
#[ignore = "minutes: CI's many-seed step runs it"]
fn traffic_control_does_200_tasks_on_the_grid_for_seeds_1_to_10() {
    seeds_1_to_10("grid", 1200, &[("tasks", "200")]);
}
