//! PIBT: Priority Inheritance with Backtracking (Okumura, Machida, Défago, Tamura, "Priority
//! inheritance with backtracking for iterative multi-agent path finding", IJCAI 2019 and
//! Artificial Intelligence 2022).
//!
//! One step plans every agent's next vertex. Agents are taken in priority order; each tries its
//! neighbours and its own vertex, nearest to its goal first. An agent that wants a vertex held by
//! an agent that has not planned yet lends it its priority: the occupant must plan now, and may
//! not take the vertex of its benefactor (that would be a swap). If the occupant cannot move
//! anywhere, it stays, and the benefactor backtracks to its next candidate.
//!
//! Beyond the published rules this implementation also refuses *rotations* (three or more agents
//! moving round a cycle, each into the vertex the next one leaves): robots executing the plan
//! through an [`crate::Adg`] wait for a vertex to be vacated before entering it, so a rotation
//! would never start. Swaps are the two-agent case of the same check.
//!
//! Two agents meeting head-on in a corridor cannot pass, and plain PIBT lets the stronger one
//! push the other back only as far as the pusher wants to go. The *swap* operation (Okumura,
//! "Improving LaCAM for Scalable Eventually Optimal Multi-Agent Pathfinding", IJCAI 2023, and
//! the authors' LaCAM3 code) handles this: when the two must pass each other and the corridor
//! behind the agent leads to a junction, the agent takes its candidates in reverse order,
//! backing away, and *pulls* the other into the vertex it leaves, until both reach the
//! junction, where one can step aside. Pulling is following, never a swap or rotation: the
//! pulled agent enters a vertex its owner leaves for another one, and the pull is checked for
//! closing a cycle like any other move.

use crate::error::MapfError;
use crate::graph::{DistanceTable, Graph};

/// Marks "no agent" in vertex-indexed tables and "not planned yet" in agent-indexed ones.
pub(crate) const NONE: u32 = u32::MAX;

/// A reusable PIBT step planner for one set of goals.
///
/// Holds vertex-indexed scratch tables, so creating one costs `O(vertices)` and each step costs
/// `O(agents × degree)` on top of the distance tables of the goals (computed on the first use of
/// each goal and cached in the [`Graph`]).
#[derive(Debug)]
pub struct Pibt<'g> {
    graph: &'g Graph,
    goals: Vec<u32>,
    dist: Vec<&'g DistanceTable>,
    /// Tie-breaking state: a draw per candidate, so it must be cheap.
    tie: SplitMix64,
    swap: bool,
    /// Agent on each vertex now.
    occupied_now: Vec<u32>,
    /// Agent that has reserved each vertex for the next step.
    occupied_next: Vec<u32>,
    current: Vec<u32>,
    next: Vec<u32>,
    /// Candidate vertices of every frame on the explicit recursion stack, back to back.
    candidates: Vec<u32>,
    keys: Vec<(u64, u32)>,
    stack: Vec<Frame>,
    order: Vec<u32>,
}

#[derive(Clone, Copy, Debug)]
struct Frame {
    agent: u32,
    /// First candidate, as an index into `Pibt::candidates`.
    start: u32,
    /// Next candidate to try.
    cursor: u32,
    end: u32,
    /// Agent to pull into this agent's vertex if it gets its first candidate, or [`NONE`].
    pull: u32,
}

/// SplitMix64 (Steele, Lea, Flood, "Fast splittable pseudorandom number generators", 2014):
/// a few arithmetic operations a draw, against a ChaCha block every sixteen.
#[derive(Clone, Debug)]
struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
}

impl<'g> Pibt<'g> {
    /// A planner for agents with these `goals`, with the swap operation on; `seed` drives the
    /// tie-breaking among equally good vertices, so equal seeds give equal steps.
    pub fn new(graph: &'g Graph, goals: &[u32], seed: u64) -> Result<Self, MapfError> {
        check_vertices(graph, goals, |first, second, vertex| {
            MapfError::DuplicateGoal {
                first,
                second,
                vertex,
            }
        })?;
        let n = graph.num_vertices();
        Ok(Self {
            graph,
            goals: goals.to_vec(),
            dist: goals.iter().map(|&g| graph.distances(g)).collect(),
            tie: SplitMix64(seed),
            swap: true,
            occupied_now: vec![NONE; n],
            occupied_next: vec![NONE; n],
            current: Vec::with_capacity(goals.len()),
            next: Vec::with_capacity(goals.len()),
            candidates: Vec::new(),
            keys: Vec::new(),
            stack: Vec::new(),
            order: Vec::with_capacity(goals.len()),
        })
    }

    /// Turns the swap operation on or off (plain PIBT, with its corridor deadlocks).
    pub fn with_swap(mut self, swap: bool) -> Self {
        self.swap = swap;
        self
    }

    /// The goals this planner steers to.
    pub fn goals(&self) -> &[u32] {
        &self.goals
    }

    /// Plans one step from `current`, agents with a higher `priorities` value first (ties by
    /// lower index). The result has no vertex, swap or rotation conflicts, and every agent
    /// either waits or moves along an edge.
    pub fn step(&mut self, current: &[u32], priorities: &[f32]) -> Result<Vec<u32>, MapfError> {
        if priorities.len() != self.goals.len() {
            return Err(MapfError::LengthMismatch {
                starts: priorities.len(),
                goals: self.goals.len(),
            });
        }
        let mut order = std::mem::take(&mut self.order);
        order.clear();
        order.extend(0..self.goals.len() as u32);
        order.sort_by(|&a, &b| priorities[b as usize].total_cmp(&priorities[a as usize]));
        let result = self.step_ordered(current, &order);
        self.order = order;
        result
    }

    /// Like [`step`](Self::step) with the planning order given directly (`order` is a
    /// permutation of the agent indices, highest priority first).
    ///
    /// # Panics
    /// If `order` is not a permutation of `0..agents`.
    pub fn step_ordered(&mut self, current: &[u32], order: &[u32]) -> Result<Vec<u32>, MapfError> {
        if current.len() != self.goals.len() {
            return Err(MapfError::LengthMismatch {
                starts: current.len(),
                goals: self.goals.len(),
            });
        }
        check_vertices(self.graph, current, |first, second, vertex| {
            MapfError::DuplicateStart {
                first,
                second,
                vertex,
            }
        })?;
        let mut seen = vec![false; current.len()];
        let is_permutation = order.len() == current.len()
            && order.iter().all(|&a| {
                (a as usize) < seen.len() && !std::mem::replace(&mut seen[a as usize], true)
            });
        assert!(is_permutation, "order must be a permutation of the agents");
        let mut out = Vec::with_capacity(current.len());
        let planned = self.generate(current, order, &[], &mut out);
        // Without constraints the top agent of every chain can always fall back to waiting,
        // because nobody can reserve its vertex without making it plan first.
        debug_assert!(planned, "unconstrained PIBT step failed");
        Ok(out)
    }

    /// The configuration generator of LaCAM: plans the step from `current` in `order`, with the
    /// agents of `constraints` (agent, vertex) forced onto the given next vertices. Returns false
    /// when the constraints conflict among themselves or leave some agent nowhere to go.
    ///
    /// `current` must be a valid configuration and every constrained vertex a neighbour of (or
    /// equal to) its agent's current vertex.
    pub(crate) fn generate(
        &mut self,
        current: &[u32],
        order: &[u32],
        constraints: &[(u32, u32)],
        out: &mut Vec<u32>,
    ) -> bool {
        self.current.clear();
        self.current.extend_from_slice(current);
        self.next.clear();
        self.next.resize(current.len(), NONE);
        for (a, &v) in current.iter().enumerate() {
            self.occupied_now[v as usize] = a as u32;
        }
        let ok = self.apply_constraints(constraints)
            && order
                .iter()
                .all(|&a| self.next[a as usize] != NONE || self.plan_chain(a));
        if ok {
            out.clear();
            out.extend_from_slice(&self.next);
        }
        // Only the entries touched this step are reset, keeping a step O(agents).
        for (&v, &u) in self.current.iter().zip(&self.next) {
            self.occupied_now[v as usize] = NONE;
            if u != NONE {
                self.occupied_next[u as usize] = NONE;
            }
        }
        for &(_, u) in constraints {
            self.occupied_next[u as usize] = NONE;
        }
        ok
    }

    fn apply_constraints(&mut self, constraints: &[(u32, u32)]) -> bool {
        for &(a, u) in constraints {
            if self.occupied_next[u as usize] != NONE {
                return false;
            }
            self.occupied_next[u as usize] = a;
            self.next[a as usize] = u;
        }
        // Constrained agents skip the checks of `plan_chain`, so cycles among them are caught
        // here; later agents' checks then only ever meet cycle-free chains.
        constraints.iter().all(|&(a, u)| {
            let k = self.occupied_now[u as usize];
            k == NONE || k == a || self.next[k as usize] == NONE || !self.closes_cycle(k, a)
        })
    }

    /// Whether agent `target` entering the vertex of the planned agent `from` would close a
    /// cycle: following the chain of "moves into the vertex of" from `from` leads back to it.
    fn closes_cycle(&self, from: u32, target: u32) -> bool {
        let mut x = from;
        // Chains among planned agents are acyclic (that is what this check maintains), so the
        // walk ends; the bound only guards against a broken invariant.
        for _ in 0..=self.current.len() {
            let w = self.next[x as usize];
            if w == self.current[x as usize] {
                return false;
            }
            let y = self.occupied_now[w as usize];
            if y == target {
                return true;
            }
            if y == NONE || self.next[y as usize] == NONE {
                return false;
            }
            x = y;
        }
        debug_assert!(false, "cycle among planned agents");
        true
    }

    /// Pushes the frame of `agent` with its candidates sorted best first: nearer to the goal,
    /// then unoccupied now (so agents prefer not to push others), then random; or worst first
    /// when a swap is due.
    fn push_frame(&mut self, agent: u32) {
        let v = self.current[agent as usize];
        let dist = self.dist[agent as usize];
        self.keys.clear();
        for &u in self.graph.neighbors(v).iter().chain(std::iter::once(&v)) {
            let occupied = u64::from(self.occupied_now[u as usize] != NONE && u != v);
            let tie = self.tie.next() >> 33;
            let key = (u64::from(dist.raw(u)) << 32) | (occupied << 31) | tie;
            self.keys.push((key, u));
        }
        self.keys.sort_unstable_by_key(|&(k, _)| k);
        let pull = if self.swap {
            self.swap_partner(agent, self.keys[0].1)
        } else {
            NONE
        };
        if pull != NONE {
            self.keys.reverse();
        }
        let start = self.candidates.len() as u32;
        self.candidates.extend(self.keys.iter().map(|&(_, u)| u));
        self.stack.push(Frame {
            agent,
            start,
            cursor: start,
            end: self.candidates.len() as u32,
            pull,
        });
    }

    /// LaCAM3's `is_swap_required_and_possible`: the agent that `i` should pull along while
    /// backing away from `best`, its best next vertex, or [`NONE`]. Either the unplanned
    /// occupant of `best` must get past `i` (head-on in a corridor), or a neighbour of `i` will
    /// have to, once `i` has moved on to `best`; in both cases only if the corridor behind `i`
    /// leads to a junction where the two can pass.
    fn swap_partner(&self, i: u32, best: u32) -> u32 {
        let v = self.current[i as usize];
        if best == v {
            return NONE;
        }
        let j = self.occupied_now[best as usize];
        if j != NONE
            && self.next[j as usize] == NONE
            && self.swap_required(i, j, v, best)
            && self.swap_possible(best, v)
        {
            return j;
        }
        for &u in self.graph.neighbors(v) {
            let k = self.occupied_now[u as usize];
            if k != NONE
                && u != best
                && self.swap_required(k, i, v, best)
                && self.swap_possible(best, v)
            {
                return k;
            }
        }
        NONE
    }

    /// Whether `pusher` on `pusher_at` and `puller` on the adjacent `puller_at` must pass each
    /// other: walking the pusher forward along the corridor (while that brings it nearer to its
    /// goal) meets no junction, and at the end the puller wants to go where the pusher is while
    /// the pusher wants to go on (or is at its goal).
    fn swap_required(&self, pusher: u32, puller: u32, pusher_at: u32, puller_at: u32) -> bool {
        let (dp, dq) = (self.dist[pusher as usize], self.dist[puller as usize]);
        let (mut behind, mut ahead) = (pusher_at, puller_at);
        // The pusher's distance falls every round, so this ends.
        while dp.raw(ahead) < dp.raw(behind) {
            match self.exits(ahead, behind) {
                (0, _) => break,
                (1, next) => (behind, ahead) = (ahead, next),
                _ => return false,
            }
        }
        dq.raw(behind) < dq.raw(ahead) && (dp.raw(behind) == 0 || dp.raw(ahead) < dp.raw(behind))
    }

    /// Whether the corridor from `from` through `to` and onwards leads to a junction (a vertex
    /// with two ways on) rather than a dead end.
    fn swap_possible(&self, from: u32, to: u32) -> bool {
        let (mut behind, mut ahead) = (from, to);
        // A walk along a corridor returns to its start only round a cycle; the bound guards
        // against walking that cycle forever should it avoid `from`.
        for _ in 0..self.graph.num_vertices() {
            if ahead == from {
                return false;
            }
            match self.exits(ahead, behind) {
                (0, _) => return false,
                (1, next) => (behind, ahead) = (ahead, next),
                _ => return true,
            }
        }
        false
    }

    /// Ways on from `v` when coming from `from`, and the last of them: neighbours other than
    /// `from`, not counting dead ends held by an agent at its goal (it will not make room).
    fn exits(&self, v: u32, from: u32) -> (u32, u32) {
        let mut count = 0;
        let mut last = NONE;
        for &u in self.graph.neighbors(v) {
            let a = self.occupied_now[u as usize];
            let parked = a != NONE && self.goals[a as usize] == u && self.graph.degree(u) == 1;
            if u != from && !parked {
                count += 1;
                last = u;
            }
        }
        (count, last)
    }

    /// After `frame`'s agent has settled, pulls its swap partner into the vertex it leaves, if
    /// it got its first candidate, the partner is still unplanned and the vertex still free.
    fn pull(&mut self, frame: Frame) {
        let (i, j) = (frame.agent, frame.pull);
        if j == NONE || self.next[j as usize] != NONE {
            return;
        }
        let v = self.current[i as usize];
        if self.next[i as usize] == self.candidates[frame.start as usize]
            && self.occupied_next[v as usize] == NONE
            && !self.closes_cycle(i, j)
        {
            self.occupied_next[v as usize] = j;
            self.next[j as usize] = v;
        }
    }

    /// PIBT for the chain started by `root`, with an explicit stack so that long chains of
    /// priority inheritance cannot overflow the thread stack. Returns whether `root` found a
    /// vertex; on failure it stays put, which at the root is only valid if nobody else reserved
    /// its vertex, hence the caller treats failure as a failed step.
    fn plan_chain(&mut self, root: u32) -> bool {
        self.push_frame(root);
        // Outcome of the frame just popped, reported to the frame below it.
        let mut child_result: Option<bool> = None;
        let mut root_result = false;
        while let Some(frame) = self.stack.last().copied() {
            let i = frame.agent;
            if child_result.take() == Some(true) {
                self.pull(frame);
                self.pop_frame(&mut child_result, &mut root_result, true);
                continue;
            }
            let mut cursor = frame.cursor;
            let mut outcome = None; // Some(true): settled; Some(false): recurse pushed.
            while cursor < frame.end {
                let u = self.candidates[cursor as usize];
                cursor += 1;
                if self.occupied_next[u as usize] != NONE {
                    continue;
                }
                let k = self.occupied_now[u as usize];
                if k != NONE && k != i && self.next[k as usize] != NONE && self.closes_cycle(k, i) {
                    continue;
                }
                self.occupied_next[u as usize] = i;
                self.next[i as usize] = u;
                if k == NONE || k == i || self.next[k as usize] != NONE {
                    outcome = Some(true);
                } else {
                    // Priority inheritance: the occupant plans now, and this frame resumes
                    // at `cursor` if it fails.
                    outcome = Some(false);
                    self.stack.last_mut().expect("frame").cursor = cursor;
                    self.push_frame(k);
                }
                break;
            }
            match outcome {
                Some(true) => {
                    self.pull(frame);
                    self.pop_frame(&mut child_result, &mut root_result, true);
                }
                Some(false) => {}
                None => {
                    // Nowhere to go: stay, taking the vertex back from whoever reserved it
                    // (the parent frame, which then tries its next candidate).
                    let v = self.current[i as usize];
                    self.occupied_next[v as usize] = i;
                    self.next[i as usize] = v;
                    self.pop_frame(&mut child_result, &mut root_result, false);
                }
            }
        }
        root_result
    }

    fn pop_frame(&mut self, child_result: &mut Option<bool>, root_result: &mut bool, ok: bool) {
        if let Some(frame) = self.stack.pop() {
            self.candidates.truncate(frame.start as usize);
        }
        if self.stack.is_empty() {
            *root_result = ok;
        } else {
            *child_result = Some(ok);
        }
    }
}

/// Checks that every vertex exists and none is repeated.
pub(crate) fn check_vertices(
    graph: &Graph,
    vertices: &[u32],
    duplicate: impl Fn(usize, usize, u32) -> MapfError,
) -> Result<(), MapfError> {
    let mut owner = std::collections::HashMap::with_capacity(vertices.len());
    for (agent, &vertex) in vertices.iter().enumerate() {
        if !graph.contains(vertex) {
            return Err(MapfError::VertexOutOfRange {
                agent,
                vertex,
                num_vertices: graph.num_vertices(),
            });
        }
        if let Some(first) = owner.insert(vertex, agent) {
            return Err(duplicate(first, agent, vertex));
        }
    }
    Ok(())
}

/// Initial priorities as in LaCAM: each agent's distance to its goal, scaled into `[0, 1)` so
/// that the dynamic part added by [`update_priorities`] dominates and this only breaks ties.
pub fn initial_priorities(graph: &Graph, current: &[u32], goals: &[u32]) -> Vec<f32> {
    let scale = graph.num_vertices().max(1) as f32;
    current
        .iter()
        .zip(goals)
        .map(|(&v, &g)| graph.distance(v, g).map_or(0.0, |d| d as f32 / scale))
        .collect()
}

/// PIBT's dynamic priorities after a step: an agent away from its goal gains one, an agent on it
/// drops back to its tie-breaking fraction. Agents that keep being pushed away thus climb until
/// they win, which is why every agent reaches its goal eventually.
pub fn update_priorities(priorities: &mut [f32], current: &[u32], goals: &[u32]) {
    for ((p, &v), &g) in priorities.iter_mut().zip(current).zip(goals) {
        if v == g {
            *p = p.fract();
        } else {
            *p += 1.0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::{validate, Solution};

    #[test]
    fn agents_walk_to_their_goals_on_a_grid() {
        let g = Graph::grid(6, 6, None).unwrap();
        let starts = [0, 5, 30, 35];
        let goals = [35, 30, 5, 0];
        let mut pibt = Pibt::new(&g, &goals, 1).unwrap();
        let mut config = starts.to_vec();
        let mut priorities = initial_priorities(&g, &config, &goals);
        let mut configs = vec![config.clone()];
        for _ in 0..100 {
            if config == goals {
                break;
            }
            config = pibt.step(&config, &priorities).unwrap();
            update_priorities(&mut priorities, &config, &goals);
            configs.push(config.clone());
        }
        let plan = Solution::from_configurations(&configs);
        assert_eq!(validate(&g, &plan, &starts, &goals), Ok(()));
    }

    #[test]
    fn higher_priority_pushes_a_lower_one_out_of_the_way() {
        // Corridor 0-1-2-3 with a siding 4 at 1. Agent 0 at 0 wants 3; agent 1 sits on its
        // goal at 1 and must step aside, which only the siding allows without swapping.
        let g = Graph::from_edges(5, [(0, 1), (1, 2), (2, 3), (1, 4)]).unwrap();
        let mut pibt = Pibt::new(&g, &[3, 1], 7).unwrap();
        let next = pibt.step(&[0, 1], &[1.0, 0.0]).unwrap();
        assert_eq!(next[0], 1);
        assert!(
            next[1] == 2 || next[1] == 4,
            "pushed agent went to {}",
            next[1]
        );
    }

    #[test]
    fn blocked_agent_waits_rather_than_swapping() {
        let g = Graph::from_edges(2, [(0, 1)]).unwrap();
        let mut pibt = Pibt::new(&g, &[1, 0], 0).unwrap();
        assert_eq!(pibt.step(&[0, 1], &[1.0, 0.0]).unwrap(), vec![0, 1]);
    }

    #[test]
    fn head_on_agent_backs_out_and_pulls_the_other_along() {
        // Corridor 1-2-3 (dead end at 3) off junction 0, which has two more branches 4 and 5.
        // Agent 0 on 1 wants 3, agent 1 on 2 wants 0: they must pass at the junction.
        let g = Graph::from_edges(6, [(0, 1), (1, 2), (2, 3), (0, 4), (0, 5)]).unwrap();
        for seed in 0..10 {
            let mut pibt = Pibt::new(&g, &[3, 0], seed).unwrap();
            assert_eq!(pibt.step(&[1, 2], &[1.0, 0.0]).unwrap(), vec![0, 1]);
            // Plain PIBT pushes agent 1 into the dead end instead.
            let mut plain = Pibt::new(&g, &[3, 0], seed).unwrap().with_swap(false);
            assert_eq!(plain.step(&[1, 2], &[1.0, 0.0]).unwrap(), vec![2, 3]);
        }
    }

    #[test]
    fn never_rotates_round_a_full_cycle() {
        let ring = Graph::from_edges(3, [(0, 1), (1, 2), (2, 0)]).unwrap();
        let goals = [1, 2, 0];
        for seed in 0..20 {
            let mut pibt = Pibt::new(&ring, &goals, seed).unwrap();
            assert_eq!(
                pibt.step(&[0, 1, 2], &[2.0, 1.0, 0.0]).unwrap(),
                vec![0, 1, 2]
            );
        }
    }

    #[test]
    fn equal_seeds_give_equal_steps() {
        let g = Graph::grid(8, 8, None).unwrap();
        let goals: Vec<u32> = (0..16).map(|i| 63 - i * 2).collect();
        let current: Vec<u32> = (0..16).map(|i| i * 3).collect();
        let p = initial_priorities(&g, &current, &goals);
        let a = Pibt::new(&g, &goals, 42)
            .unwrap()
            .step(&current, &p)
            .unwrap();
        let b = Pibt::new(&g, &goals, 42)
            .unwrap()
            .step(&current, &p)
            .unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn rejects_bad_configurations() {
        let g = Graph::grid(3, 3, None).unwrap();
        assert!(matches!(
            Pibt::new(&g, &[1, 1], 0),
            Err(MapfError::DuplicateGoal { vertex: 1, .. })
        ));
        let mut pibt = Pibt::new(&g, &[1, 2], 0).unwrap();
        assert!(matches!(
            pibt.step(&[0, 0], &[0.0, 0.0]),
            Err(MapfError::DuplicateStart { .. })
        ));
        assert!(matches!(
            pibt.step(&[0, 9], &[0.0, 0.0]),
            Err(MapfError::VertexOutOfRange { vertex: 9, .. })
        ));
        assert!(matches!(
            pibt.step(&[0], &[0.0]),
            Err(MapfError::LengthMismatch { .. })
        ));
    }
}
