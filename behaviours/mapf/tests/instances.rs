//! LaCAM on hand-made and random instances: plans validate, known-solvable instances are
//! solved, known-unsolvable ones end in `Unsolvable`, and on tiny graphs the verdict matches an
//! exhaustive search.

mod common;

use mapf::lacam::{self, Options};
use mapf::{validate, Adg, Graph, MapfError, Scenario};
use proptest::prelude::*;

fn options(seed: u64) -> Options {
    Options {
        seed,
        max_expansions: Some(2_000_000),
        ..Options::default()
    }
}

#[test]
fn corridor_swap_uses_the_siding() {
    // Corridor 0-1-2-3-4-5-6, single lane, with a one-vertex siding 7 off vertex 3.
    let g = Graph::from_edges(8, [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (3, 7)]).unwrap();
    let (starts, goals) = ([0, 6], [6, 0]);
    for seed in 0..10 {
        let plan = lacam::solve(&g, &starts, &goals, &options(seed)).unwrap();
        assert_eq!(validate(&g, &plan, &starts, &goals), Ok(()));
        // Passing is only possible through the siding.
        assert!(plan.paths.iter().any(|p| p.contains(&7)));
        assert!(Adg::new(&plan).is_ok());
    }
}

#[test]
fn robot_parked_on_a_corridor_moves_out_of_the_way() {
    // Agent 1 already sits on its goal in the middle of the corridor; agent 0 must pass.
    let g = Graph::from_edges(6, [(0, 1), (1, 2), (2, 3), (3, 4), (2, 5)]).unwrap();
    let (starts, goals) = ([0, 2], [4, 2]);
    let plan = lacam::solve(&g, &starts, &goals, &options(1)).unwrap();
    assert_eq!(validate(&g, &plan, &starts, &goals), Ok(()));
    assert!(
        plan.paths[1].iter().any(|&v| v != 2),
        "idle robot never moved"
    );
}

#[test]
fn swap_on_a_bare_corridor_is_unsolvable() {
    let g = Graph::from_edges(5, [(0, 1), (1, 2), (2, 3), (3, 4)]).unwrap();
    let err = lacam::solve(&g, &[0, 4], &[4, 0], &Options::default()).unwrap_err();
    // Agents keep their order on a path: 2 agents on 5 vertices, C(5, 2) configurations.
    assert_eq!(err, MapfError::Unsolvable { configurations: 10 });
}

#[test]
fn rotation_on_a_full_star_is_unsolvable() {
    // Star with centre 0 and leaves 1, 2, 3; three agents on the leaves want to rotate. Only
    // one agent at a time can stand in the centre, and it can only go back, so the reachable
    // configurations are the start and the three with one agent in the centre.
    let g = Graph::from_edges(4, [(0, 1), (0, 2), (0, 3)]).unwrap();
    let err = lacam::solve(&g, &[1, 2, 3], &[2, 3, 1], &Options::default()).unwrap_err();
    assert_eq!(err, MapfError::Unsolvable { configurations: 4 });
}

#[test]
fn reversal_on_a_long_path_exhausts_every_order_preserving_configuration() {
    let n = 12u32;
    let g = Graph::from_edges(n as usize, (0..n - 1).map(|v| (v, v + 1))).unwrap();
    let (result, stats) =
        lacam::solve_with_stats(&g, &[0, 1, 2, 3], &[11, 10, 9, 8], &Options::default());
    // 4 agents in fixed order on 12 vertices: C(12, 4) = 495 configurations.
    assert_eq!(
        result.unwrap_err(),
        MapfError::Unsolvable {
            configurations: 495
        }
    );
    assert_eq!(stats.configurations, 495);
}

#[test]
fn idle_robots_on_a_busy_grid_still_let_everyone_through() {
    let s = Scenario::random_grid(12, 12, 0.1, 60, 9);
    let plan = lacam::solve(&s.graph, &s.starts, &s.goals, &options(9)).unwrap();
    assert_eq!(validate(&s.graph, &plan, &s.starts, &s.goals), Ok(()));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    /// On tiny graphs the verdict is checked against exhaustive search, both ways: a plan iff a
    /// solution exists. Many of these are trees, where unsolvable instances are common.
    #[test]
    fn verdict_matches_exhaustive_search(
        seed in any::<u64>(),
        n in 2usize..8,
        extra in 0usize..3,
        agents in 1usize..4,
    ) {
        let mut rng = common::rng(seed);
        let g = common::tree_plus_edges(n, extra, &mut rng);
        let agents = agents.min(n);
        let all: Vec<u32> = (0..n as u32).collect();
        let starts = common::distinct(&all, agents, &mut rng);
        let goals = common::distinct(&all, agents, &mut rng);
        let solvable = common::brute_force_solvable(&g, &starts, &goals);
        match lacam::solve(&g, &starts, &goals, &options(seed)) {
            Ok(plan) => {
                prop_assert_eq!(validate(&g, &plan, &starts, &goals), Ok(()));
                prop_assert!(solvable, "plan found for an instance exhaustive search calls unsolvable");
            }
            Err(MapfError::Unsolvable { .. }) => prop_assert!(!solvable, "solvable instance declared unsolvable"),
            Err(e) => prop_assert!(false, "unexpected error {e:?}"),
        }
    }

    /// Biconnected graphs other than cycles, with at least two free vertices: always solvable.
    #[test]
    fn biconnected_with_two_free_vertices_is_solved(
        seed in any::<u64>(),
        n in 4usize..10,
        chords in 1usize..4,
        free in 2usize..6,
    ) {
        let mut rng = common::rng(seed);
        let g = common::cycle_with_chords(n, chords, &mut rng);
        let agents = n.saturating_sub(free).max(1);
        let all: Vec<u32> = (0..n as u32).collect();
        let starts = common::distinct(&all, agents, &mut rng);
        let goals = common::distinct(&all, agents, &mut rng);
        let plan = lacam::solve(&g, &starts, &goals, &options(seed));
        prop_assert!(plan.is_ok(), "{:?}", plan);
        prop_assert_eq!(validate(&g, &plan.unwrap(), &starts, &goals), Ok(()));
    }

    /// Larger random trees with extra edges: whatever the verdict, a returned plan is valid.
    #[test]
    fn plans_on_random_sparse_graphs_validate(
        seed in any::<u64>(),
        n in 5usize..40,
        extra in 0usize..10,
        density in 0.05f64..0.5,
    ) {
        let mut rng = common::rng(seed);
        let g = common::tree_plus_edges(n, extra, &mut rng);
        let agents = ((n as f64 * density) as usize).max(1);
        let all: Vec<u32> = (0..n as u32).collect();
        let starts = common::distinct(&all, agents, &mut rng);
        let goals = common::distinct(&all, agents, &mut rng);
        let budget = Options { max_expansions: Some(20_000), ..options(seed) };
        match lacam::solve(&g, &starts, &goals, &budget) {
            Ok(plan) => prop_assert_eq!(validate(&g, &plan, &starts, &goals), Ok(())),
            Err(MapfError::Unsolvable { .. } | MapfError::Timeout { .. }) => {}
            Err(e) => prop_assert!(false, "unexpected error {e:?}"),
        }
    }

    /// Random grids with obstacles (largest region kept): any plan is valid. Obstacle-free grids
    /// of at least 3 x 3 are biconnected and not cycles, so they must always be solved.
    #[test]
    fn random_grids_are_solved(
        seed in any::<u64>(),
        w in 3u32..12,
        h in 3u32..12,
        obstacles in prop_oneof![Just(0.0), 0.0f64..0.25],
        density in 0.05f64..0.4,
    ) {
        let cells = (w * h) as usize;
        let agents = ((cells as f64 * density) as usize).max(1);
        let probe = Scenario::random_grid(w, h, obstacles, 0, seed);
        let region = mapf::scenario::largest_component(&probe.graph).len();
        prop_assume!(region >= agents + 2);
        let s = Scenario::random_grid(w, h, obstacles, agents, seed);
        // Obstacles can leave dead ends and single-lane stretches where an instance may be
        // unsolvable, and proving that takes exhaustive search: a budget ends those.
        let budget = if obstacles > 0.0 {
            Options { max_expansions: Some(100_000), ..options(seed) }
        } else {
            options(seed)
        };
        match lacam::solve(&s.graph, &s.starts, &s.goals, &budget) {
            Ok(plan) => prop_assert_eq!(validate(&s.graph, &plan, &s.starts, &s.goals), Ok(())),
            Err(e) => prop_assert!(
                obstacles > 0.0 && matches!(e, MapfError::Unsolvable { .. } | MapfError::Timeout { .. }),
                "grid with obstacles {obstacles} not solved: {e:?}"
            ),
        }
    }
}
