//! LaCAM planning time on a 100 × 100 grid (about 3 % obstacles, largest connected region) with
//! 100 and 1,000 agents, against the time of one PIBT step for the same agents: LaCAM costs at
//! least one PIBT step per configuration on its path, so the ratio says how much search was
//! needed beyond plain PIBT.
//!
//! "cold" includes the distance tables of all goals (a fresh graph each run); "warm" reuses
//! them, as a coordinator replanning with the same goal set would.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{BatchSize, Criterion};
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

fn main() {
    // `cargo test --benches` runs this binary without `--bench`: keep that run short.
    if std::env::args().any(|a| a == "--bench") {
        print_figures();
    }
    let mut c = Criterion::default().configure_from_args();
    bench(&mut c);
    c.final_summary();
}
