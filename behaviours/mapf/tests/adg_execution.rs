//! Executing plans through the action dependency graph with random action durations: no two
//! robots ever hold one vertex, nobody swaps, and execution always finishes at the goals.

mod common;

use std::collections::HashMap;

use mapf::lacam::{self, Options};
use mapf::{Action, Adg, Graph, MapfError, Scenario, Solution};
use proptest::prelude::*;
use rand::seq::SliceRandom;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Runs `plan` as an event simulation. Each robot has its own slowness and each move a random
/// duration; a ready robot may also dawdle before starting. A moving robot holds both ends of
/// its edge (it is somewhere between them), which makes a swap show up as two robots holding
/// one vertex. Returns the finishing time, or what went wrong.
fn execute(plan: &Solution, rng: &mut ChaCha8Rng) -> Result<u64, String> {
    let mut adg = Adg::new(plan).map_err(|e| e.to_string())?;
    let n = adg.num_agents();
    let slowness: Vec<u64> = (0..n).map(|_| rng.gen_range(1..=10)).collect();
    let mut moving: Vec<Option<(u64, Action)>> = vec![None; n];
    let mut order: Vec<usize> = (0..n).collect();
    let mut now = 0u64;
    loop {
        order.shuffle(rng);
        for &a in &order {
            if moving[a].is_some() {
                continue;
            }
            let Some(action) = adg.ready(a) else { continue };
            let idle = moving.iter().all(Option::is_none);
            if idle || rng.gen_bool(0.6) {
                if action.from != adg.position(a) {
                    return Err(format!("robot {a} starts {action:?} away from its vertex"));
                }
                moving[a] = Some((now + slowness[a] * rng.gen_range(1..=20), action));
                check_exclusive(&adg, &moving)?;
            }
        }
        if adg.is_done() {
            break;
        }
        let Some(t) = moving.iter().flatten().map(|&(end, _)| end).min() else {
            if (0..n).any(|a| adg.ready(a).is_some()) {
                continue;
            }
            return Err(format!("deadlock at time {now}"));
        };
        now = t;
        for &a in &order {
            if let Some((end, action)) = moving[a] {
                if end == now {
                    adg.complete(a, action.index).map_err(|e| e.to_string())?;
                    moving[a] = None;
                }
            }
        }
        check_exclusive(&adg, &moving)?;
    }
    for (a, path) in plan.paths.iter().enumerate() {
        if Some(&adg.position(a)) != path.last() {
            return Err(format!(
                "robot {a} finished at {}, not its goal",
                adg.position(a)
            ));
        }
    }
    Ok(now)
}

fn check_exclusive(adg: &Adg, moving: &[Option<(u64, Action)>]) -> Result<(), String> {
    let mut holder = HashMap::new();
    for (a, m) in moving.iter().enumerate() {
        let held = [Some(adg.position(a)), m.map(|(_, action)| action.to)];
        for v in held.into_iter().flatten() {
            if let Some(b) = holder.insert(v, a) {
                return Err(format!("robots {b} and {a} both hold vertex {v}"));
            }
        }
    }
    Ok(())
}

#[test]
fn corridor_swap_survives_very_uneven_speeds() {
    let g = Graph::from_edges(8, [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (3, 7)]).unwrap();
    let plan = lacam::solve(&g, &[0, 6], &[6, 0], &Options::default()).unwrap();
    for seed in 0..50 {
        execute(&plan, &mut common::rng(seed)).unwrap();
    }
}

#[test]
fn the_checker_catches_an_unsafe_execution() {
    // A follower that ignores the ADG: robot 1 enters vertex 1 while robot 0 is still leaving.
    let plan = Solution {
        paths: vec![vec![1, 2], vec![0, 1]],
    };
    let adg = Adg::new(&plan).unwrap();
    let follower = adg.actions(1)[0];
    let leader = adg.actions(0)[0];
    assert!(check_exclusive(&adg, &[Some((5, leader)), Some((5, follower))]).is_err());
    assert!(adg.ready(1).is_none());
}

#[test]
fn busy_grid_plan_executes_at_random_speeds() {
    let s = Scenario::random_grid(16, 16, 0.1, 80, 4);
    let options = Options {
        max_expansions: Some(200_000),
        ..Options::default()
    };
    let plan = lacam::solve(&s.graph, &s.starts, &s.goals, &options).unwrap();
    for seed in 0..10 {
        execute(&plan, &mut common::rng(seed)).unwrap();
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn adg_execution_is_safe_and_finishes(
        seed in any::<u64>(),
        w in 3u32..10,
        h in 3u32..10,
        obstacles in 0.0f64..0.2,
        density in 0.05f64..0.45,
    ) {
        let cells = (w * h) as usize;
        let agents = ((cells as f64 * density) as usize).max(1);
        let probe = Scenario::random_grid(w, h, obstacles, 0, seed);
        prop_assume!(mapf::scenario::largest_component(&probe.graph).len() >= agents + 2);
        let s = Scenario::random_grid(w, h, obstacles, agents, seed);
        let options = Options { seed, max_expansions: Some(100_000), ..Options::default() };
        let plan = match lacam::solve(&s.graph, &s.starts, &s.goals, &options) {
            Ok(plan) => plan,
            Err(MapfError::Unsolvable { .. } | MapfError::Timeout { .. }) => return Ok(()),
            Err(e) => return Err(TestCaseError::fail(format!("{e:?}"))),
        };
        let mut rng = common::rng(seed);
        for _ in 0..5 {
            prop_assert_eq!(execute(&plan, &mut rng).map(|_| ()), Ok(()));
        }
    }
}
