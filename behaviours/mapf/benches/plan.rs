//! LaCAM planning time on a 100 × 100 grid (about 3 % obstacles, largest connected region) with
//! 100 and 1,000 agents, against the time of one PIBT step for the same agents: LaCAM costs at
//! least one PIBT step per configuration on its path, so the ratio says how much search was
//! needed beyond plain PIBT.
//!
//! "cold" includes the distance tables of all goals (a fresh graph each run); "warm" reuses
//! them, as a coordinator replanning with the same goal set would.
//!
//! With `--bench` it first prints figures: the grid above, then the MovingAI rows of
//! `shared/bench/movingai/README.md` (time to first solution against the published LaCAM3's).
//! The maps are looked for in `POCKETFLEET_MOVINGAI`, else in [`MOVINGAI`] next to the
//! repository; a name given after `--` (`cargo bench -p mapf --bench plan -- warehouse`) keeps
//! only the rows and criterion benchmarks whose names contain it.

use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use criterion::{BatchSize, Criterion};
use mapf::movingai::{load_scen, GridMap};
use mapf::pibt::initial_priorities;
use mapf::{lacam, Pibt, Scenario};

const SIDE: u32 = 100;
const OBSTACLES: f64 = 0.03;
const SEED: u64 = 2024;
const AGENTS: [usize; 2] = [100, 1_000];

fn scenario(agents: usize) -> Scenario {
    Scenario::random_grid(SIDE, SIDE, OBSTACLES, agents, SEED)
}

fn bench(c: &mut Criterion) {
    for agents in AGENTS {
        let s = scenario(agents);
        let options = lacam::Options {
            seed: SEED,
            time_limit: Some(Duration::from_secs(30)),
            ..lacam::Options::default()
        };
        let mut group = c.benchmark_group(format!("grid100x100/{agents}_agents"));
        group.sample_size(10);
        group.bench_function("lacam_cold", |b| {
            b.iter_batched(
                || {
                    let mut g = s.graph.clone();
                    g.clear_distance_cache();
                    g
                },
                |g| lacam::solve(&g, &s.starts, &s.goals, &options).expect("solved"),
                BatchSize::LargeInput,
            )
        });
        group.bench_function("lacam_warm", |b| {
            b.iter(|| lacam::solve(&s.graph, &s.starts, &s.goals, &options).expect("solved"))
        });
        let mut pibt = Pibt::new(&s.graph, &s.goals, SEED).expect("valid goals");
        let priorities = initial_priorities(&s.graph, &s.starts, &s.goals);
        group.bench_function("pibt_step", |b| {
            b.iter(|| pibt.step(black_box(&s.starts), &priorities).expect("valid"))
        });
        group.finish();
    }
}

/// One timed run per size, printed as a table so the figures can be quoted as ratios.
fn print_figures() {
    println!(
        "agents  lacam_cold  lacam_warm  pibt_step  warm/step  configs  expansions  makespan  soc"
    );
    for agents in AGENTS {
        let s = scenario(agents);
        let options = lacam::Options {
            seed: SEED,
            ..lacam::Options::default()
        };
        let mut cold_graph = s.graph.clone();
        cold_graph.clear_distance_cache();
        let t = Instant::now();
        let cold = lacam::solve(&cold_graph, &s.starts, &s.goals, &options).expect("solved");
        let cold_time = t.elapsed();
        let (warm, stats) = lacam::solve_with_stats(&cold_graph, &s.starts, &s.goals, &options);
        let warm = warm.expect("solved");
        assert_eq!(cold, warm, "equal seeds, equal plans");
        mapf::validate(&s.graph, &warm, &s.starts, &s.goals).expect("valid plan");

        let mut pibt = Pibt::new(&cold_graph, &s.goals, SEED).expect("valid goals");
        let priorities = initial_priorities(&cold_graph, &s.starts, &s.goals);
        let reps = 200u32;
        let t = Instant::now();
        for _ in 0..reps {
            black_box(pibt.step(black_box(&s.starts), &priorities).expect("valid"));
        }
        let step = t.elapsed() / reps;
        println!(
            "{agents:>6}  {:>8.1}ms  {:>8.1}ms  {:>7.1}µs  {:>9.0}  {:>7}  {:>10}  {:>8}  {:>6}",
            cold_time.as_secs_f64() * 1e3,
            stats.elapsed.as_secs_f64() * 1e3,
            step.as_secs_f64() * 1e6,
            stats.elapsed.as_secs_f64() / step.as_secs_f64(),
            stats.configurations,
            stats.expansions,
            warm.makespan(),
            warm.sum_of_costs(),
        );
    }
}

/// The MovingAI maps, relative to this crate; not part of the repository.
const MOVINGAI: &str = "../../../shared/bench/movingai";
/// Per-instance limit, as for the reference figures.
const LIMIT: Duration = Duration::from_secs(30);
/// Random instances per row.
const RANDOM_INSTANCES: u64 = 5;
/// The rows of the README's table: map, agents, and LaCAM3's median time to first solution.
const ROWS: [(&str, usize, u32); 6] = [
    ("random-32-32-10", 400, 339),
    ("warehouse-10-20-10-2-1", 300, 531),
    ("warehouse-10-20-10-2-1", 500, 1_280),
    ("warehouse-10-20-10-2-1", 1_000, 6_317),
    ("empty-48-48", 1_000, 2_151),
    ("room-64-64-8", 200, 350),
];

fn movingai_dir() -> PathBuf {
    std::env::var_os("POCKETFLEET_MOVINGAI").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(MOVINGAI),
        PathBuf::from,
    )
}

/// Solves one instance from scratch (distance tables included) and returns the time and sum
/// of costs, or `None` if the limit passed first.
fn run(s: &Scenario) -> Option<(Duration, usize, usize)> {
    let options = lacam::Options {
        time_limit: Some(LIMIT),
        ..lacam::Options::default()
    };
    let t = Instant::now();
    let plan = lacam::solve(&s.graph, &s.starts, &s.goals, &options).ok()?;
    let elapsed = t.elapsed();
    mapf::validate(&s.graph, &plan, &s.starts, &s.goals).expect("valid plan");
    let lower_bound = s
        .starts
        .iter()
        .zip(&s.goals)
        .map(|(&a, &b)| s.graph.distance(a, b).unwrap_or(0) as usize)
        .sum();
    Some((elapsed, plan.sum_of_costs(), lower_bound))
}

fn median<T: Copy + Ord>(mut v: Vec<T>) -> Option<T> {
    v.sort_unstable();
    v.get(v.len() / 2).copied()
}

/// One line per instance set: solved count, median time (unsolved counting as past the
/// limit), median sum of costs of the solved ones and its ratio to the sum of distances.
fn print_row(map: &str, agents: usize, kind: &str, reference_ms: u32, scenarios: &[Scenario]) {
    let results: Vec<_> = scenarios.iter().map(run).collect();
    let solved: Vec<_> = results.iter().flatten().copied().collect();
    let time = median(
        results
            .iter()
            .map(|r| r.map_or(Duration::MAX, |r| r.0))
            .collect(),
    );
    let time = match time {
        Some(t) if t < Duration::MAX => format!("{:.0}", t.as_secs_f64() * 1e3),
        _ => "-".to_owned(),
    };
    let ratio = match time.parse::<f64>() {
        Ok(ms) => format!("{:.2}", ms / f64::from(reference_ms)),
        Err(_) => "-".to_owned(),
    };
    let soc = median(solved.iter().map(|r| r.1).collect());
    let gap = median(solved.iter().map(|r| r.1 * 1000 / r.2.max(1)).collect());
    println!(
        "{map:<24} {agents:>6} {kind:<7} {:>2}/{:<2} {time:>8} {reference_ms:>7} {ratio:>6} {:>9} {:>7}",
        solved.len(),
        results.len(),
        soc.map_or("-".to_owned(), |s| s.to_string()),
        gap.map_or("-".to_owned(), |g| format!("{:.3}", g as f64 / 1000.0)),
    );
}

/// The README's table, measured: five random instances per row, and for random-32-32-10 also
/// the first 400 agents of its scenario file.
fn print_movingai(filter: Option<&str>) {
    let dir = movingai_dir();
    if !dir.join("README.md").is_file() {
        println!(
            "MovingAI maps not found in {}; set POCKETFLEET_MOVINGAI to their folder",
            dir.display()
        );
        return;
    }
    println!(
        "map                      agents set     solved  med_ms  ref_ms  ratio  med_soc  soc/lb"
    );
    for (name, agents, reference_ms) in ROWS {
        if filter.is_some_and(|f| !name.contains(f)) {
            continue;
        }
        let map = match GridMap::load(dir.join(format!("{name}.map"))) {
            Ok(map) => map,
            Err(e) => {
                println!("{name}: {e}");
                continue;
            }
        };
        let scen = dir.join(format!("{name}-random-1.scen"));
        if scen.is_file() {
            match load_scen(&scen).and_then(|s| map.instance(&s, agents)) {
                Ok(s) => print_row(name, agents, "scen", reference_ms, &[s]),
                Err(e) => println!("{}: {e}", scen.display()),
            }
        }
        let random: Result<Vec<_>, _> = (0..RANDOM_INSTANCES)
            .map(|seed| map.random_instance(agents, seed))
            .collect();
        match random {
            Ok(r) => print_row(name, agents, "random", reference_ms, &r),
            Err(e) => println!("{name}: {e}"),
        }
    }
}

fn main() {
    // `cargo test --benches` runs this binary without `--bench`: keep that run short.
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.iter().any(|a| a == "--bench") {
        let filter = args
            .iter()
            .find(|a| !a.starts_with('-'))
            .map(String::as_str);
        if filter.is_none() {
            print_figures();
        }
        print_movingai(filter);
    }
    let mut c = Criterion::default().configure_from_args();
    bench(&mut c);
    c.final_summary();
}
