//! Plans and their validation.

use thiserror::Error;

use crate::graph::Graph;

/// A timestep-synchronous joint plan: `paths[i][t]` is the vertex of agent `i` at step `t`,
/// `paths[i][0]` its start and the last entry its goal. All paths have the same length.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Solution {
    /// One path per agent, all of one length.
    pub paths: Vec<Vec<u32>>,
}

impl Solution {
    /// Builds a plan from the sequence of joint configurations `configs[t][i]`.
    pub fn from_configurations(configs: &[Vec<u32>]) -> Self {
        let agents = configs.first().map_or(0, Vec::len);
        Self {
            paths: (0..agents)
                .map(|i| configs.iter().map(|c| c[i]).collect())
                .collect(),
        }
    }

    /// Number of agents.
    pub fn num_agents(&self) -> usize {
        self.paths.len()
    }

    /// Number of steps (path length minus one; 0 for an empty plan).
    pub fn makespan(&self) -> usize {
        self.paths.first().map_or(0, |p| p.len().saturating_sub(1))
    }

    /// Sum over agents of the step at which each reaches its final vertex for good.
    pub fn sum_of_costs(&self) -> usize {
        self.paths
            .iter()
            .map(|p| match p.last() {
                Some(goal) => p.iter().rposition(|v| v != goal).map_or(0, |t| t + 1),
                None => 0,
            })
            .sum()
    }

    /// Joint configuration at step `t` (vertex of each agent), if `t <= makespan()`.
    pub fn configuration(&self, t: usize) -> Option<Vec<u32>> {
        self.paths.iter().map(|p| p.get(t).copied()).collect()
    }
}

/// The first thing found wrong with a plan by [`validate`].
#[derive(Clone, Debug, Error, PartialEq, Eq)]
pub enum Conflict {
    /// The plan has another number of agents than the instance.
    #[error("plan has {found} agents, instance {expected}")]
    AgentCount {
        /// Agents in the instance.
        expected: usize,
        /// Paths in the plan.
        found: usize,
    },
    /// A path is empty or not as long as the first one.
    #[error("agent {agent}: path of {found} steps, expected {expected}")]
    PathLength {
        /// The agent.
        agent: usize,
        /// Length of path 0 (at least 1).
        expected: usize,
        /// Length of this path.
        found: usize,
    },
    /// A path names a vertex outside the graph.
    #[error("agent {agent} at step {time}: {vertex} is not a vertex")]
    NotAVertex {
        /// The agent.
        agent: usize,
        /// The step.
        time: usize,
        /// The id.
        vertex: u32,
    },
    /// A path does not begin at its agent's start.
    #[error("agent {agent} starts at {found}, expected {expected}")]
    WrongStart {
        /// The agent.
        agent: usize,
        /// Its start.
        expected: u32,
        /// First vertex of its path.
        found: u32,
    },
    /// A path does not end at its agent's goal.
    #[error("agent {agent} ends at {found}, expected {expected}")]
    WrongGoal {
        /// The agent.
        agent: usize,
        /// Its goal.
        expected: u32,
        /// Last vertex of its path.
        found: u32,
    },
    /// Consecutive vertices are neither equal nor adjacent.
    #[error("agent {agent} jumps from {from} to {to} at step {time}")]
    NotAdjacent {
        /// The agent.
        agent: usize,
        /// Step of departure.
        time: usize,
        /// Vertex at `time`.
        from: u32,
        /// Vertex at `time + 1`.
        to: u32,
    },
    /// Two agents on one vertex at one step.
    #[error("agents {first} and {second} both on {vertex} at step {time}")]
    Vertex {
        /// The lower-numbered agent.
        first: usize,
        /// The other agent.
        second: usize,
        /// The vertex.
        vertex: u32,
        /// The step.
        time: usize,
    },
    /// Two agents traverse one edge in opposite directions during one step.
    #[error("agents {first} and {second} swap {from} and {to} at step {time}")]
    Swap {
        /// The agent going `from` → `to`.
        first: usize,
        /// The agent going `to` → `from`.
        second: usize,
        /// Vertex of `first` at `time`.
        from: u32,
        /// Vertex of `second` at `time`.
        to: u32,
        /// Step of departure.
        time: usize,
    },
    /// Three or more agents move around a cycle in one step, each into the vertex the next one
    /// leaves. Rejected because robots that enter a vertex only once it is vacated (see
    /// [`crate::Adg`]) would wait on each other forever.
    #[error("agents {agents:?} rotate around a cycle at step {time}")]
    Rotation {
        /// The agents of the cycle, in the order each follows the previous one.
        agents: Vec<usize>,
        /// Step of departure.
        time: usize,
    },
}

/// Checks `plan` against the instance: one equal-length path per agent from its start to its
/// goal, every step a wait or an edge of `graph`, and no vertex, swap or rotation conflicts.
pub fn validate(
    graph: &Graph,
    plan: &Solution,
    starts: &[u32],
    goals: &[u32],
) -> Result<(), Conflict> {
    let agents = starts.len();
    if plan.paths.len() != agents || goals.len() != agents {
        return Err(Conflict::AgentCount {
            expected: agents,
            found: plan.paths.len(),
        });
    }
    if agents == 0 {
        return Ok(());
    }
    let len = plan.paths[0].len().max(1);
    validate_paths(graph, plan, starts, goals, len)?;
    validate_meetings(graph, plan, len)
}

/// Each agent's path alone: of the common length, on the graph's vertices, from its start to its
/// goal, along edges.
fn validate_paths(
    graph: &Graph,
    plan: &Solution,
    starts: &[u32],
    goals: &[u32],
    len: usize,
) -> Result<(), Conflict> {
    for (agent, path) in plan.paths.iter().enumerate() {
        if path.len() != len {
            return Err(Conflict::PathLength {
                agent,
                expected: len,
                found: path.len(),
            });
        }
        if let Some((time, &vertex)) = path.iter().enumerate().find(|(_, &v)| !graph.contains(v)) {
            return Err(Conflict::NotAVertex {
                agent,
                time,
                vertex,
            });
        }
        if path[0] != starts[agent] {
            return Err(Conflict::WrongStart {
                agent,
                expected: starts[agent],
                found: path[0],
            });
        }
        if path[len - 1] != goals[agent] {
            return Err(Conflict::WrongGoal {
                agent,
                expected: goals[agent],
                found: path[len - 1],
            });
        }
        for time in 0..len - 1 {
            let (from, to) = (path[time], path[time + 1]);
            if from != to && !graph.has_edge(from, to) {
                return Err(Conflict::NotAdjacent {
                    agent,
                    time,
                    from,
                    to,
                });
            }
        }
    }
    Ok(())
}

/// The agents together: no two on one vertex at a time, and no cycle of agents following each
/// other (a swap is a cycle of two).
fn validate_meetings(graph: &Graph, plan: &Solution, len: usize) -> Result<(), Conflict> {
    let agents = plan.paths.len();
    // Sparse scratch indexed by vertex; entries are reset after each step so the cost per step
    // is O(agents), not O(vertices).
    const NONE: usize = usize::MAX;
    let mut occupant = vec![NONE; graph.num_vertices()];
    let mut mark = vec![0u8; agents];
    for time in 0..len {
        let mut conflict = None;
        for (agent, path) in plan.paths.iter().enumerate() {
            let v = path[time] as usize;
            if occupant[v] != NONE {
                conflict = Some(Conflict::Vertex {
                    first: occupant[v],
                    second: agent,
                    vertex: path[time],
                    time,
                });
                break;
            }
            occupant[v] = agent;
        }
        if conflict.is_none() && time + 1 < len {
            conflict = following_cycle(plan, time, &occupant, &mut mark);
        }
        for path in &plan.paths {
            occupant[path[time] as usize] = NONE;
        }
        if let Some(c) = conflict {
            return Err(c);
        }
    }
    Ok(())
}

/// Finds a cycle of agents each moving into the vertex the next one occupies at `time`.
///
/// "Follows" is a partial function (each agent enters at most one vertex, and at most one agent
/// is on it), so cycles are found by walking from every agent with three-colour marking.
fn following_cycle(
    plan: &Solution,
    time: usize,
    occupant: &[usize],
    mark: &mut [u8],
) -> Option<Conflict> {
    const NONE: usize = usize::MAX;
    let next = |a: usize| {
        let (from, to) = (plan.paths[a][time], plan.paths[a][time + 1]);
        if from == to {
            NONE
        } else {
            occupant[to as usize]
        }
    };
    mark.fill(0);
    let mut result = None;
    'agents: for start in 0..mark.len() {
        let mut a = start;
        while a != NONE && mark[a] == 0 {
            mark[a] = 1;
            a = next(a);
        }
        if a != NONE && mark[a] == 1 {
            let mut cycle = vec![a];
            let mut b = next(a);
            while b != a {
                cycle.push(b);
                b = next(b);
            }
            result = Some(if let [first, second] = cycle[..] {
                Conflict::Swap {
                    first,
                    second,
                    from: plan.paths[first][time],
                    to: plan.paths[second][time],
                    time,
                }
            } else {
                Conflict::Rotation {
                    agents: cycle,
                    time,
                }
            });
            break 'agents;
        }
        let mut b = start;
        while b != NONE && mark[b] == 1 {
            mark[b] = 2;
            b = next(b);
        }
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path3() -> Graph {
        Graph::from_edges(3, [(0, 1), (1, 2)]).unwrap()
    }

    #[test]
    fn accepts_a_valid_plan_with_following() {
        let g = path3();
        let plan = Solution {
            paths: vec![vec![1, 2, 2], vec![0, 1, 1]],
        };
        assert_eq!(validate(&g, &plan, &[1, 0], &[2, 1]), Ok(()));
        assert_eq!(plan.makespan(), 2);
        assert_eq!(plan.sum_of_costs(), 2);
    }

    #[test]
    fn reports_each_kind_of_fault() {
        let g = path3();
        let p = |paths: Vec<Vec<u32>>| Solution { paths };
        assert!(matches!(
            validate(&g, &p(vec![vec![0, 2]]), &[0], &[2]),
            Err(Conflict::NotAdjacent { .. })
        ));
        assert!(matches!(
            validate(&g, &p(vec![vec![0, 1], vec![1, 1]]), &[0, 1], &[1, 1]),
            Err(Conflict::Vertex {
                vertex: 1,
                time: 1,
                ..
            })
        ));
        assert!(matches!(
            validate(&g, &p(vec![vec![0, 1], vec![1, 0]]), &[0, 1], &[1, 0]),
            Err(Conflict::Swap { time: 0, .. })
        ));
        assert!(matches!(
            validate(&g, &p(vec![vec![0, 1], vec![2]]), &[0, 2], &[1, 2]),
            Err(Conflict::PathLength { agent: 1, .. })
        ));
        assert!(matches!(
            validate(&g, &p(vec![vec![0, 1]]), &[1], &[1]),
            Err(Conflict::WrongStart { .. })
        ));
        assert!(matches!(
            validate(&g, &p(vec![vec![0, 1]]), &[0], &[2]),
            Err(Conflict::WrongGoal { .. })
        ));
        assert!(matches!(
            validate(&g, &p(vec![vec![0, 7]]), &[0], &[7]),
            Err(Conflict::NotAVertex { vertex: 7, .. })
        ));
    }

    #[test]
    fn rejects_a_rotation() {
        let triangle = Graph::from_edges(3, [(0, 1), (1, 2), (2, 0)]).unwrap();
        let plan = Solution {
            paths: vec![vec![0, 1], vec![1, 2], vec![2, 0]],
        };
        match validate(&triangle, &plan, &[0, 1, 2], &[1, 2, 0]) {
            Err(Conflict::Rotation {
                mut agents,
                time: 0,
            }) => {
                agents.sort_unstable();
                assert_eq!(agents, vec![0, 1, 2]);
            }
            other => panic!("expected a rotation, got {other:?}"),
        }
    }
}
