//! Reproducible random instances, for tests, benchmarks and experiments.

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::graph::Graph;

/// A MAPF instance: a graph and one start and one goal per agent.
#[derive(Clone, Debug)]
pub struct Scenario {
    /// The graph.
    pub graph: Graph,
    /// Start vertex of each agent (distinct).
    pub starts: Vec<u32>,
    /// Goal vertex of each agent (distinct).
    pub goals: Vec<u32>,
}

impl Scenario {
    /// A `width` × `height` 4-connected grid with about `obstacle_ratio` of the cells blocked
    /// at random, and `agents` distinct random starts and goals, all drawn from the largest
    /// connected region so that every goal is reachable. Equal arguments give equal scenarios.
    ///
    /// # Panics
    /// If the largest region has fewer than `agents` cells.
    pub fn random_grid(
        width: u32,
        height: u32,
        obstacle_ratio: f64,
        agents: usize,
        seed: u64,
    ) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let cells = (width * height) as usize;
        let blocked: Vec<bool> = (0..cells).map(|_| rng.gen_bool(obstacle_ratio)).collect();
        let graph =
            Graph::grid(width, height, Some(&blocked)).expect("mask has one entry per cell");
        // Cells cut off by obstacles would make instances unsolvable for a trivial reason.
        let region = largest_component(&graph);
        assert!(
            region.len() >= agents,
            "{agents} agents do not fit {} free cells",
            region.len()
        );
        let pick = |rng: &mut ChaCha8Rng| {
            let mut r = region.clone();
            r.shuffle(rng);
            r.truncate(agents);
            r
        };
        let starts = pick(&mut rng);
        let goals = pick(&mut rng);
        Self {
            graph,
            starts,
            goals,
        }
    }
}

/// Vertices of the largest connected component (the lowest-numbered one on ties).
pub fn largest_component(graph: &Graph) -> Vec<u32> {
    let n = graph.num_vertices();
    let mut seen = vec![false; n];
    let mut best = Vec::new();
    for root in 0..n as u32 {
        if seen[root as usize] {
            continue;
        }
        seen[root as usize] = true;
        let mut component = vec![root];
        let mut head = 0;
        while let Some(&v) = component.get(head) {
            head += 1;
            for &u in graph.neighbors(v) {
                if !std::mem::replace(&mut seen[u as usize], true) {
                    component.push(u);
                }
            }
        }
        if component.len() > best.len() {
            best = component;
        }
    }
    best.sort_unstable();
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_grid_is_reproducible_and_connected() {
        let a = Scenario::random_grid(20, 20, 0.1, 30, 5);
        let b = Scenario::random_grid(20, 20, 0.1, 30, 5);
        assert_eq!((&a.starts, &a.goals), (&b.starts, &b.goals));
        let mut s = a.starts.clone();
        s.sort_unstable();
        s.dedup();
        assert_eq!(s.len(), 30);
        for (&s, &g) in a.starts.iter().zip(&a.goals) {
            assert!(a.graph.distance(s, g).is_some());
        }
    }
}
