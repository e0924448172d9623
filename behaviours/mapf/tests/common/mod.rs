//! Instance generators and an independent brute-force oracle shared by the integration tests.

#![allow(dead_code)] // each test binary uses its own subset

use std::collections::{HashSet, VecDeque};

use mapf::Graph;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// A random tree on `n` vertices (each vertex joined to a random earlier one) plus `extra`
/// random edges: always connected.
pub fn tree_plus_edges(n: usize, extra: usize, rng: &mut ChaCha8Rng) -> Graph {
    let mut edges: Vec<(u32, u32)> = (1..n as u32).map(|v| (rng.gen_range(0..v), v)).collect();
    for _ in 0..extra {
        edges.push((rng.gen_range(0..n as u32), rng.gen_range(0..n as u32)));
    }
    Graph::from_edges(n, edges).unwrap()
}

/// A cycle through all `n >= 4` vertices in random order plus at least one chord: biconnected
/// and not a cycle, so any instance with two or more free vertices is solvable.
pub fn cycle_with_chords(n: usize, chords: usize, rng: &mut ChaCha8Rng) -> Graph {
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.shuffle(rng);
    let mut edges: Vec<(u32, u32)> = (0..n).map(|i| (order[i], order[(i + 1) % n])).collect();
    // A guaranteed chord between positions 0 and 2 on the cycle.
    edges.push((order[0], order[2]));
    for _ in 1..chords {
        edges.push((rng.gen_range(0..n as u32), rng.gen_range(0..n as u32)));
    }
    Graph::from_edges(n, edges).unwrap()
}

/// `k` distinct vertices drawn from `from`.
pub fn distinct(from: &[u32], k: usize, rng: &mut ChaCha8Rng) -> Vec<u32> {
    let mut v = from.to_vec();
    v.shuffle(rng);
    v.truncate(k);
    v
}

/// Whether the goals can be reached, by breadth-first search over all joint configurations.
/// Transitions: every agent waits or moves along an edge, no two agents end on one vertex, and
/// no cycle of agents each moves into the vertex the next one leaves (a swap being a cycle of
/// two). Independent of the crate's planners and validator; only for tiny instances.
pub fn brute_force_solvable(graph: &Graph, starts: &[u32], goals: &[u32]) -> bool {
    let mut seen = HashSet::from([starts.to_vec()]);
    let mut queue = VecDeque::from([starts.to_vec()]);
    while let Some(config) = queue.pop_front() {
        if config == goals {
            return true;
        }
        let options: Vec<Vec<u32>> = config
            .iter()
            .map(|&v| {
                let mut o = graph.neighbors(v).to_vec();
                o.push(v);
                o
            })
            .collect();
        let mut choice = vec![0usize; config.len()];
        loop {
            let next: Vec<u32> = choice.iter().zip(&options).map(|(&c, o)| o[c]).collect();
            if is_valid_transition(&config, &next) && seen.insert(next.clone()) {
                queue.push_back(next);
            }
            // Odometer increment over all combinations.
            let mut i = 0;
            while i < choice.len() {
                choice[i] += 1;
                if choice[i] < options[i].len() {
                    break;
                }
                choice[i] = 0;
                i += 1;
            }
            if i == choice.len() {
                break;
            }
        }
    }
    false
}

fn is_valid_transition(from: &[u32], to: &[u32]) -> bool {
    let distinct: HashSet<u32> = to.iter().copied().collect();
    if distinct.len() != to.len() {
        return false;
    }
    let n = from.len();
    let follows = |a: usize| -> Option<usize> {
        if from[a] == to[a] {
            return None;
        }
        (0..n).find(|&b| from[b] == to[a])
    };
    (0..n).all(|a| {
        let mut b = follows(a);
        for _ in 0..n {
            match b {
                Some(x) if x == a => return false,
                Some(x) => b = follows(x),
                None => return true,
            }
        }
        true
    })
}
