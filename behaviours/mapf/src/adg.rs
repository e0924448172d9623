//! Action dependency graph (Hönig, Kiesel, Tinka, Durham, Ayanian, "Persistent and Robust
//! Execution of MAPF Schedules in Warehouses", IEEE RA-L 2019).
//!
//! A [`Solution`] is timestep-synchronous, but real robots drive at different and varying speeds.
//! The ADG keeps only what makes the plan safe: the order in which agents pass through each
//! vertex. Each agent's plan becomes a list of moves (waits are dropped), and a move of agent `b`
//! into vertex `v` depends on the move by which the agent that was on `v` before `b` in the plan
//! leaves it. Executing each move only once its dependency has *completed* (the previous
//! occupant has arrived at its next vertex) keeps every vertex to one robot at a time and makes
//! swaps impossible, whatever the durations of the moves, and since every dependency points
//! from an earlier step of the plan to a later or equal one, no deadlock can arise unless the
//! plan contains a rotation (which [`crate::validate`] rejects and the planners never produce).

use thiserror::Error;

use crate::plan::Solution;

/// One move of one agent.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Action {
    /// Vertex the agent leaves.
    pub from: u32,
    /// Vertex the agent enters (a neighbour of `from`).
    pub to: u32,
    /// Position of this action in the agent's action list.
    pub index: usize,
}

/// Why an ADG could not be built or an action not be marked complete.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
pub enum AdgError {
    /// The plan puts two agents on a vertex at once, or one on a vertex another never leaves.
    #[error("plan puts agents {first} and {second} on vertex {vertex} together")]
    Overlap {
        /// One agent.
        first: usize,
        /// The other.
        second: usize,
        /// The vertex.
        vertex: u32,
    },
    /// The plan's dependencies form a cycle (agents rotating round a cycle in one step), so
    /// execution would deadlock.
    #[error("plan has cyclic dependencies (a rotation); it cannot be executed")]
    Cyclic,
    /// Paths are empty or not all of one length.
    #[error("paths of the plan are empty or differ in length")]
    RaggedPlan,
    /// `complete` named an action that is not the agent's next one or whose dependency is not
    /// complete yet.
    #[error("action {index} of agent {agent} is not ready")]
    NotReady {
        /// The agent.
        agent: usize,
        /// The action index given.
        index: usize,
    },
}

/// The action dependency graph of a plan, with the execution state: how many actions of each
/// agent are complete.
#[derive(Clone, Debug)]
pub struct Adg {
    starts: Vec<u32>,
    actions: Vec<Vec<Action>>,
    /// For each action, the (agent, action index) that must be complete before it may start.
    /// Within one agent actions are sequential, so at most one cross-agent dependency is needed
    /// per action: the departure of the previous occupant of the vertex it enters.
    depends_on: Vec<Vec<Option<(u32, u32)>>>,
    /// The inverse of `depends_on`: the action waiting for each action, if any.
    waiter: Vec<Vec<Option<(u32, u32)>>>,
    completed: Vec<usize>,
    remaining: usize,
}

/// One stay of an agent on a vertex, in plan order.
#[derive(Clone, Copy)]
struct Visit {
    vertex: u32,
    arrival: usize,
    agent: u32,
    /// Action that brings the agent here (none for its start).
    entry: Option<u32>,
    /// Action that takes it away (none if it stays to the end).
    exit: Option<u32>,
}

impl Adg {
    /// Builds the ADG of `plan`; the plan should have passed [`crate::validate`].
    pub fn new(plan: &Solution) -> Result<Self, AdgError> {
        let len = plan.paths.first().map_or(0, Vec::len);
        if plan.paths.iter().any(|p| p.len() != len) || (len == 0 && !plan.paths.is_empty()) {
            return Err(AdgError::RaggedPlan);
        }
        let mut actions = Vec::with_capacity(plan.paths.len());
        let mut visits = Vec::new();
        for (agent, path) in plan.paths.iter().enumerate() {
            let mut list: Vec<Action> = Vec::new();
            let mut visit = Visit {
                // Non-empty: checked above.
                vertex: path[0],
                arrival: 0,
                agent: agent as u32,
                entry: None,
                exit: None,
            };
            for (t, w) in path.windows(2).enumerate() {
                if w[0] == w[1] {
                    continue;
                }
                let index = list.len() as u32;
                list.push(Action {
                    from: w[0],
                    to: w[1],
                    index: index as usize,
                });
                visit.exit = Some(index);
                visits.push(visit);
                visit = Visit {
                    vertex: w[1],
                    arrival: t + 1,
                    agent: agent as u32,
                    entry: Some(index),
                    exit: None,
                };
            }
            visits.push(visit);
            actions.push(list);
        }

        let mut depends_on: Vec<Vec<Option<(u32, u32)>>> =
            actions.iter().map(|a| vec![None; a.len()]).collect();
        let mut waiter = depends_on.clone();
        visits.sort_unstable_by_key(|v| (v.vertex, v.arrival, v.agent));
        for pair in visits.windows(2) {
            let (before, after) = (pair[0], pair[1]);
            if before.vertex != after.vertex || before.agent == after.agent {
                continue;
            }
            let overlap = AdgError::Overlap {
                first: before.agent as usize,
                second: after.agent as usize,
                vertex: after.vertex,
            };
            match (before.exit, after.entry) {
                (Some(exit), Some(entry)) => {
                    depends_on[after.agent as usize][entry as usize] = Some((before.agent, exit));
                    waiter[before.agent as usize][exit as usize] = Some((after.agent, entry));
                }
                _ => return Err(overlap),
            }
        }

        let adg = Self {
            starts: plan
                .paths
                .iter()
                .filter_map(|p| p.first().copied())
                .collect(),
            remaining: actions.iter().map(Vec::len).sum(),
            completed: vec![0; actions.len()],
            actions,
            depends_on,
            waiter,
        };
        if !adg.is_acyclic() {
            return Err(AdgError::Cyclic);
        }
        Ok(adg)
    }

    /// Whether every action can eventually run: Kahn's algorithm on the dependency edges and the
    /// agents' own sequencing. An agent is blocked on at most one action, and only the waiter of
    /// a completed action can have been unblocked by it, so each action is examined O(1) times.
    fn is_acyclic(&self) -> bool {
        let mut sim = self.clone();
        let mut frontier: Vec<usize> = (0..sim.num_agents()).collect();
        while let Some(agent) = frontier.pop() {
            while let Some(action) = sim.ready(agent) {
                sim.completed[agent] += 1;
                sim.remaining -= 1;
                if let Some((b, _)) = sim.waiter[agent][action.index] {
                    frontier.push(b as usize);
                }
            }
        }
        sim.remaining == 0
    }

    /// Number of agents.
    pub fn num_agents(&self) -> usize {
        self.actions.len()
    }

    /// All actions of `agent`, in order.
    pub fn actions(&self, agent: usize) -> &[Action] {
        &self.actions[agent]
    }

    /// The action of another agent that must complete before `actions(agent)[index]` may start.
    pub fn dependency(&self, agent: usize, index: usize) -> Option<(usize, usize)> {
        self.depends_on[agent][index].map(|(a, i)| (a as usize, i as usize))
    }

    /// The next action of `agent` if it may start now: its earlier actions and the one it
    /// depends on are complete. `None` if it must wait or has finished.
    pub fn ready(&self, agent: usize) -> Option<Action> {
        let k = self.completed[agent];
        let action = *self.actions[agent].get(k)?;
        match self.depends_on[agent][k] {
            Some((a, i)) if self.completed[a as usize] <= i as usize => None,
            _ => Some(action),
        }
    }

    /// Marks action `index` of `agent` complete (the robot has arrived at its `to` vertex).
    pub fn complete(&mut self, agent: usize, index: usize) -> Result<(), AdgError> {
        match self.ready(agent) {
            Some(a) if a.index == index => {
                self.completed[agent] += 1;
                self.remaining -= 1;
                Ok(())
            }
            _ => Err(AdgError::NotReady { agent, index }),
        }
    }

    /// Number of completed actions of `agent`.
    pub fn completed(&self, agent: usize) -> usize {
        self.completed[agent]
    }

    /// The vertex `agent` is on once its completed actions are done.
    pub fn position(&self, agent: usize) -> u32 {
        match self.completed[agent] {
            0 => self.starts[agent],
            k => self.actions[agent][k - 1].to,
        }
    }

    /// Whether every action of every agent is complete.
    pub fn is_done(&self) -> bool {
        self.remaining == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waits_are_collapsed_and_followers_wait_for_the_leader() {
        // Agent 0 goes 1 -> 2 after waiting; agent 1 follows into 1 right behind it.
        let plan = Solution {
            paths: vec![vec![1, 1, 2], vec![0, 0, 1]],
        };
        let mut adg = Adg::new(&plan).unwrap();
        assert_eq!(
            adg.actions(0),
            &[Action {
                from: 1,
                to: 2,
                index: 0
            }]
        );
        assert_eq!(adg.dependency(1, 0), Some((0, 0)));
        assert_eq!(adg.ready(1), None);
        assert_eq!(
            adg.complete(1, 0),
            Err(AdgError::NotReady { agent: 1, index: 0 })
        );
        assert_eq!(adg.ready(0).map(|a| a.to), Some(2));
        adg.complete(0, 0).unwrap();
        assert_eq!(adg.ready(0), None);
        assert_eq!(adg.position(0), 2);
        assert!(!adg.is_done());
        adg.complete(1, 0).unwrap();
        assert!(adg.is_done());
        assert_eq!(adg.position(1), 1);
    }

    #[test]
    fn rotation_is_rejected_as_cyclic() {
        let plan = Solution {
            paths: vec![vec![0, 1], vec![1, 2], vec![2, 0]],
        };
        assert_eq!(Adg::new(&plan).unwrap_err(), AdgError::Cyclic);
    }

    #[test]
    fn empty_or_ragged_paths_are_rejected() {
        let empty = Solution {
            paths: vec![vec![]],
        };
        assert_eq!(Adg::new(&empty).unwrap_err(), AdgError::RaggedPlan);
        let ragged = Solution {
            paths: vec![vec![0, 1], vec![2]],
        };
        assert_eq!(Adg::new(&ragged).unwrap_err(), AdgError::RaggedPlan);
        assert!(Adg::new(&Solution::default()).unwrap().is_done());
    }

    #[test]
    fn overlapping_plan_is_rejected() {
        let plan = Solution {
            paths: vec![vec![0, 1], vec![1, 1]],
        };
        assert!(matches!(Adg::new(&plan), Err(AdgError::Overlap { .. })));
    }
}
