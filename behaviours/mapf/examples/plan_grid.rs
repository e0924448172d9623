//! Plans one random grid scenario and prints what the search did.
//!
//! `cargo run --release -p mapf --example plan_grid -- [width height obstacle_ratio agents seed [time_limit_s]]`
//! (defaults: 100 100 0.03 1000 2024 10).

use std::time::Duration;

use mapf::{lacam, validate, Adg, Scenario};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: &str| args.get(i).cloned().unwrap_or_else(|| default.to_owned());
    let width: u32 = arg(0, "100").parse().expect("width");
    let height: u32 = arg(1, "100").parse().expect("height");
    let obstacles: f64 = arg(2, "0.03").parse().expect("obstacle ratio");
    let agents: usize = arg(3, "1000").parse().expect("agents");
    let seed: u64 = arg(4, "2024").parse().expect("seed");
    let limit: f64 = arg(5, "10").parse().expect("time limit in seconds");

    let s = Scenario::random_grid(width, height, obstacles, agents, seed);
    let options = lacam::Options {
        seed,
        time_limit: Some(Duration::from_secs_f64(limit)),
        ..lacam::Options::default()
    };
    let (result, stats) = lacam::solve_with_stats(&s.graph, &s.starts, &s.goals, &options);
    println!(
        "{width}x{height} grid, {} edges, {agents} agents: {:.1} ms, {} configurations, {} expansions, distance cache {} KiB",
        s.graph.num_edges(),
        stats.elapsed.as_secs_f64() * 1e3,
        stats.configurations,
        stats.expansions,
        s.graph.distance_cache_bytes() / 1024,
    );
    match result {
        Ok(plan) => {
            validate(&s.graph, &plan, &s.starts, &s.goals).expect("valid plan");
            let adg = Adg::new(&plan).expect("executable plan");
            let actions: usize = (0..adg.num_agents()).map(|a| adg.actions(a).len()).sum();
            println!(
                "plan: makespan {}, sum of costs {}, {actions} moves",
                plan.makespan(),
                plan.sum_of_costs()
            );
        }
        Err(e) => println!("no plan: {e}"),
    }
}
