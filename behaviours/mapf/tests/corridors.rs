//! Narrow warehouse aisles: agents meeting head-on in one-cell-wide aisles need PIBT's swap
//! operation to pass each other quickly. Budgets are in expansions, so the verdicts do not
//! depend on the machine.

use mapf::lacam::{self, Options};
use mapf::{validate, Adg, GridMap, MapfError};

/// Shelves (`T`) ten cells long with one-cell aisles between them, joined by cross aisles at
/// both ends and in the middle: a small cut of `warehouse-10-20-10-2-1`.
const WAREHOUSE: &str = "type octile
height 9
width 25
map
.........................
.TTTTTTTTTT...TTTTTTTTTT.
.........................
.TTTTTTTTTT...TTTTTTTTTT.
.........................
.TTTTTTTTTT...TTTTTTTTTT.
.........................
.TTTTTTTTTT...TTTTTTTTTT.
.........................
";

const AGENTS: usize = 40;
const SEEDS: u64 = 8;
/// With swap each of these instances takes at most a few hundred expansions; without it none
/// is solved in a million.
const BUDGET: u64 = 5_000;

fn options(seed: u64, swap: bool) -> Options {
    Options {
        seed,
        max_expansions: Some(BUDGET),
        swap,
        ..Options::default()
    }
}

#[test]
fn swap_solves_dense_aisles_within_the_budget() {
    let map = GridMap::parse(WAREHOUSE).unwrap();
    for seed in 0..SEEDS {
        let s = map.random_instance(AGENTS, seed).unwrap();
        let plan = lacam::solve(&s.graph, &s.starts, &s.goals, &options(seed, true))
            .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
        assert_eq!(validate(&s.graph, &plan, &s.starts, &s.goals), Ok(()));
        assert!(Adg::new(&plan).is_ok(), "seed {seed}: plan not executable");
    }
}

#[test]
fn without_swap_the_same_budget_is_not_enough() {
    // The counterpart of the test above: it shows that these instances need swap, so that the
    // test above fails if swap stops working.
    let map = GridMap::parse(WAREHOUSE).unwrap();
    for seed in 0..SEEDS {
        let s = map.random_instance(AGENTS, seed).unwrap();
        let result = lacam::solve(&s.graph, &s.starts, &s.goals, &options(seed, false));
        assert!(
            matches!(result, Err(MapfError::Timeout { .. })),
            "seed {seed}: {result:?}"
        );
    }
}

#[test]
fn head_on_in_an_aisle_is_resolved_by_backing_out() {
    // Two agents enter one aisle from opposite ends: one must back out to the cross aisle.
    let map = GridMap::parse(WAREHOUSE).unwrap();
    let cell = |x, y| map.vertex(x, y).unwrap();
    let (starts, goals) = ([cell(2, 2), cell(9, 2)], [cell(10, 2), cell(1, 2)]);
    let plan = lacam::solve(map.graph(), &starts, &goals, &options(0, true)).unwrap();
    assert_eq!(validate(map.graph(), &plan, &starts, &goals), Ok(()));
    assert!(Adg::new(&plan).is_ok());
}
