//! LaCAM: Lazy Constraints Addition search for MAPF (Okumura, "LaCAM: Search-Based Algorithm for
//! Quick Multi-Agent Pathfinding", AAAI 2023; "Improving LaCAM for Scalable Eventually Optimal
//! Multi-Agent Pathfinding", IJCAI 2023, which names the complete variant LaCAM*).
//!
//! The high level is a depth-first search over joint configurations. Each high-level node owns
//! a low-level *constraint tree*, explored breadth-first and built lazily: a low-level node fixes
//! the next vertex of the first `d` agents in the node's priority order, and expanding it adds
//! one child per choice (wait or any neighbour) for agent `d + 1`. Every time a high-level node
//! is visited, one low-level node is taken and PIBT ([`crate::pibt`]) completes its constraints
//! into a successor configuration. Usually the first, unconstrained, PIBT step is good and the
//! search runs as fast as plain PIBT; when PIBT goes round in circles, revisited configurations
//! send the search back and the growing constraints force the alternatives.
//!
//! Because a full-depth low-level node pins every agent, every valid successor of a
//! configuration is eventually generated, and configurations are never expanded twice: the search
//! is complete. It returns a plan if one exists and [`MapfError::Unsolvable`] once every
//! reachable configuration has been exhausted; the exhaustive part is exponential, so real
//! callers give a time or expansion budget ([`Options`]) and get [`MapfError::Timeout`] past it.
//! When a successor is a configuration seen before, the search goes back to that configuration,
//! or with a small probability to the start (random insertion, as in the authors' later LaCAM
//! implementation): depth-first search can otherwise spend long in one bad region.
//!
//! The first solution found is returned; LaCAM*'s further anytime refinement towards optimal
//! cost is not done.

use std::cmp::Reverse;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::time::{Duration, Instant};

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::MapfError;
use crate::graph::Graph;
use crate::pibt::{check_vertices, Pibt, NONE};
use crate::plan::Solution;

/// Search settings. The default has seed 0, no budget and PIBT's swap operation on.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Options {
    /// Seeds the tie-breaking of PIBT and the order of low-level children: equal seeds give
    /// equal plans.
    pub seed: u64,
    /// Wall-clock budget; past it the search stops with [`MapfError::Timeout`].
    pub time_limit: Option<Duration>,
    /// Budget of low-level expansions (configuration generator calls); past it the search stops
    /// with [`MapfError::Timeout`]. Deterministic, unlike the time limit.
    pub max_expansions: Option<u64>,
    /// Whether PIBT uses the swap operation (see [`crate::pibt`]); without it, agents meeting
    /// head-on in narrow corridors are left to the search.
    pub swap: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            seed: 0,
            time_limit: None,
            max_expansions: None,
            swap: true,
        }
    }
}

/// What a search did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SearchStats {
    /// Low-level expansions, i.e. configuration generator (PIBT) calls.
    pub expansions: u64,
    /// Distinct configurations reached (high-level nodes).
    pub configurations: usize,
    /// Wall-clock time, including the distance tables computed for the goals.
    pub elapsed: Duration,
}

/// Plans paths from `starts` to `goals` (one of each per agent, all distinct) on `graph`.
pub fn solve(
    graph: &Graph,
    starts: &[u32],
    goals: &[u32],
    options: &Options,
) -> Result<Solution, MapfError> {
    solve_with_stats(graph, starts, goals, options).0
}

/// Like [`solve`], also reporting the effort spent whatever the outcome.
pub fn solve_with_stats(
    graph: &Graph,
    starts: &[u32],
    goals: &[u32],
    options: &Options,
) -> (Result<Solution, MapfError>, SearchStats) {
    let began = Instant::now();
    let mut stats = SearchStats::default();
    let result =
        Search::new(graph, starts, goals, options, began).and_then(|search| search.run(&mut stats));
    stats.elapsed = began.elapsed();
    (result, stats)
}

/// Chance of resuming the start instead of a revisited configuration.
const RESTART_PROBABILITY: f64 = 0.01;

/// A configuration of the search; the configuration itself is in `Search::configs`.
struct HighNode {
    parent: u32,
    /// The next node whose configuration has the same hash, or [`NONE`].
    same_hash: u32,
    /// Agents by decreasing priority: the order of PIBT and of the constraint tree's levels.
    order: Vec<u32>,
    /// The constraint tree; nodes are appended as they are created, and since the tree is
    /// explored breadth-first, `tree[head..]` is exactly the queue of nodes not yet used.
    tree: Vec<LowNode>,
    head: usize,
}

#[derive(Clone, Copy)]
struct LowNode {
    parent: u32,
    agent: u32,
    vertex: u32,
    depth: u32,
}

const ROOT_CONSTRAINT: LowNode = LowNode {
    parent: NONE,
    agent: NONE,
    vertex: NONE,
    depth: 0,
};

impl HighNode {
    fn new(parent: u32, order: Vec<u32>) -> Self {
        Self {
            parent,
            same_hash: NONE,
            order,
            tree: vec![ROOT_CONSTRAINT],
            head: 0,
        }
    }
}

/// A hasher for keys that are hashes already ([`hash_config`]'s).
#[derive(Default)]
struct Prehashed(u64);

impl Hasher for Prehashed {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = self.0.rotate_left(8) ^ u64::from(b);
        }
    }

    fn write_u64(&mut self, hash: u64) {
        self.0 = hash;
    }
}

/// A multiply-rotate hash (as in rustc's FxHash) with a SplitMix64 finish, so that the low bits
/// the table indexes by depend on every agent. SipHash, the default, cost more than a PIBT step.
fn hash_config(config: &[u32]) -> u64 {
    let h = config.iter().fold(0u64, |h, &v| {
        (h.rotate_left(5) ^ u64::from(v)).wrapping_mul(0x517c_c1b7_2722_0a95)
    });
    let h = (h ^ (h >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    let h = (h ^ (h >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    h ^ (h >> 31)
}

struct Search<'g, 'a> {
    graph: &'g Graph,
    goals: &'a [u32],
    options: &'a Options,
    began: Instant,
    pibt: Pibt<'g>,
    rng: ChaCha8Rng,
    nodes: Vec<HighNode>,
    /// Configurations of `nodes`, back to back, one allocation for all.
    configs: Vec<u32>,
    /// Each configuration hash's most recent node; older ones are chained by `same_hash`.
    explored: HashMap<u64, u32, BuildHasherDefault<Prehashed>>,
    /// Agents by decreasing distance from start to goal, then index: LaCAM's tie-breaking.
    by_distance: Vec<u32>,
    open: Vec<u32>,
}

impl<'g, 'a> Search<'g, 'a> {
    fn new(
        graph: &'g Graph,
        starts: &'a [u32],
        goals: &'a [u32],
        options: &'a Options,
        began: Instant,
    ) -> Result<Self, MapfError> {
        if starts.len() != goals.len() {
            return Err(MapfError::LengthMismatch {
                starts: starts.len(),
                goals: goals.len(),
            });
        }
        check_vertices(graph, starts, |first, second, vertex| {
            MapfError::DuplicateStart {
                first,
                second,
                vertex,
            }
        })?;
        let pibt = Pibt::new(graph, goals, options.seed)?.with_swap(options.swap);
        // A goal in another component would make the search exhaust the whole configuration
        // space before saying what a BFS table says at once.
        if let Some(agent) =
            (0..starts.len()).find(|&i| graph.distance(starts[i], goals[i]).is_none())
        {
            return Err(MapfError::GoalUnreachable {
                agent,
                start: starts[agent],
                goal: goals[agent],
            });
        }
        let mut by_distance: Vec<u32> = (0..starts.len() as u32).collect();
        // Stable, so equal distances keep index order and runs are reproducible.
        by_distance
            .sort_by_key(|&a| Reverse(graph.distance(starts[a as usize], goals[a as usize])));
        let root = HighNode::new(NONE, by_distance.clone());
        Ok(Self {
            graph,
            goals,
            options,
            began,
            pibt,
            // A different stream from PIBT's, so that the two uses of the seed are independent.
            rng: ChaCha8Rng::seed_from_u64(options.seed ^ 0x9e37_79b9_7f4a_7c15),
            nodes: vec![root],
            configs: starts.to_vec(),
            explored: [(hash_config(starts), 0)].into_iter().collect(),
            by_distance,
            open: vec![0],
        })
    }

    fn run(mut self, stats: &mut SearchStats) -> Result<Solution, MapfError> {
        let n = self.goals.len();
        if self.configs == self.goals {
            return Ok(self.plan_to(0));
        }
        let mut constraints = Vec::new();
        let mut next = Vec::with_capacity(n);
        let mut children = Vec::new();
        while let Some(&top) = self.open.last() {
            stats.configurations = self.nodes.len();
            self.check_budget(stats.expansions)?;
            let node = &mut self.nodes[top as usize];
            let config = &self.configs[top as usize * n..][..n];
            let Some(&low) = node.tree.get(node.head) else {
                // Every constraint of this node has been tried: nothing more to learn from it.
                self.open.pop();
                node.order = Vec::new();
                node.tree = Vec::new();
                node.head = 0;
                continue;
            };
            let low_index = node.head as u32;
            node.head += 1;
            stats.expansions += 1;

            if (low.depth as usize) < n {
                let agent = node.order[low.depth as usize];
                let v = config[agent as usize];
                children.clear();
                children.extend_from_slice(self.graph.neighbors(v));
                children.push(v);
                children.shuffle(&mut self.rng);
                node.tree.extend(children.iter().map(|&vertex| LowNode {
                    parent: low_index,
                    agent,
                    vertex,
                    depth: low.depth + 1,
                }));
            }

            constraints.clear();
            let mut c = low;
            while c.depth > 0 {
                constraints.push((c.agent, c.vertex));
                c = node.tree[c.parent as usize];
            }
            if !self
                .pibt
                .generate(config, &node.order, &constraints, &mut next)
            {
                continue;
            }
            let slot = self.explored.entry(hash_config(&next)).or_insert(NONE);
            let mut seen = *slot;
            while seen != NONE && self.configs[seen as usize * n..][..n] != *next {
                seen = self.nodes[seen as usize].same_hash;
            }
            if seen != NONE {
                // Revisiting sends the search back to that configuration, as in LaCAM: its
                // remaining constraints are the way out of whatever loop led here. Now and then
                // the start is resumed instead (LaCAM3's random insertion): the depth-first
                // search otherwise can sink a long time into one bad region, and a restart cuts
                // that heavy tail. Completeness is unaffected, since nothing is discarded.
                let resume = if self.rng.gen_bool(RESTART_PROBABILITY) {
                    0
                } else {
                    seen
                };
                self.open.push(resume);
                continue;
            }
            // PIBT's priorities, without keeping them: an agent away from its goal gains one, an
            // agent on it drops below all others, to its tie-breaking rank. Those away thus keep
            // their order, and those on their goals follow in tie-breaking order, so the order
            // is built in linear time instead of sorted.
            let at_goal = |&a: &u32| next[a as usize] == self.goals[a as usize];
            let mut order = Vec::with_capacity(n);
            let parent_order = &self.nodes[top as usize].order;
            order.extend(parent_order.iter().filter(|a| !at_goal(a)));
            order.extend(self.by_distance.iter().filter(|a| at_goal(a)));
            let id = self.nodes.len() as u32;
            let mut child = HighNode::new(top, order);
            child.same_hash = std::mem::replace(slot, id);
            self.nodes.push(child);
            self.configs.extend_from_slice(&next);
            self.open.push(id);
            if next == self.goals {
                stats.configurations = self.nodes.len();
                return Ok(self.plan_to(id));
            }
        }
        Err(MapfError::Unsolvable {
            configurations: self.nodes.len(),
        })
    }

    fn check_budget(&self, expansions: u64) -> Result<(), MapfError> {
        let out_of_expansions = self.options.max_expansions.is_some_and(|m| expansions >= m);
        let elapsed = self.began.elapsed();
        if out_of_expansions || self.options.time_limit.is_some_and(|t| elapsed >= t) {
            return Err(MapfError::Timeout {
                expansions,
                elapsed,
            });
        }
        Ok(())
    }

    fn plan_to(&self, mut id: u32) -> Solution {
        let n = self.goals.len();
        let mut configs = Vec::new();
        while id != NONE {
            configs.push(self.configs[id as usize * n..][..n].to_vec());
            id = self.nodes[id as usize].parent;
        }
        configs.reverse();
        Solution::from_configurations(&configs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::validate;

    #[test]
    fn trivial_instance_is_a_one_step_plan() {
        let g = Graph::grid(3, 3, None).unwrap();
        let plan = solve(&g, &[0, 4], &[0, 4], &Options::default()).unwrap();
        assert_eq!(plan.paths, vec![vec![0], vec![4]]);
        let empty = solve(&g, &[], &[], &Options::default()).unwrap();
        assert_eq!(empty.num_agents(), 0);
    }

    #[test]
    fn unreachable_goal_is_reported_at_once() {
        let g = Graph::from_edges(4, [(0, 1), (2, 3)]).unwrap();
        let err = solve(&g, &[0], &[3], &Options::default()).unwrap_err();
        assert_eq!(
            err,
            MapfError::GoalUnreachable {
                agent: 0,
                start: 0,
                goal: 3
            }
        );
        assert!(err.is_unsolvable());
    }

    #[test]
    fn expansion_budget_gives_timeout() {
        // Two agents swapping on a path: unsolvable, so only the budget can stop it early.
        let g = Graph::from_edges(4, [(0, 1), (1, 2), (2, 3)]).unwrap();
        let options = Options {
            max_expansions: Some(3),
            ..Options::default()
        };
        let (result, stats) = solve_with_stats(&g, &[0, 3], &[3, 0], &options);
        assert!(matches!(
            result,
            Err(MapfError::Timeout { expansions: 3, .. })
        ));
        assert_eq!(stats.expansions, 3);
    }

    #[test]
    fn equal_seeds_give_equal_plans() {
        let g = Graph::grid(6, 6, None).unwrap();
        let starts: Vec<u32> = (0..12).collect();
        let goals: Vec<u32> = (24..36).rev().collect();
        let options = Options {
            seed: 3,
            ..Options::default()
        };
        let a = solve(&g, &starts, &goals, &options).unwrap();
        let b = solve(&g, &starts, &goals, &options).unwrap();
        assert_eq!(a, b);
        assert_eq!(validate(&g, &a, &starts, &goals), Ok(()));
    }
}
