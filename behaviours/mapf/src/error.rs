//! Errors of the planners.

use std::time::Duration;

use thiserror::Error;

/// Why no plan (or PIBT step) was produced.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
pub enum MapfError {
    /// Starts and goals (or a configuration and the goals) differ in length.
    #[error("{starts} starts for {goals} goals")]
    LengthMismatch {
        /// Number of start (or current) vertices.
        starts: usize,
        /// Number of goal vertices.
        goals: usize,
    },
    /// A start or goal is not a vertex of the graph.
    #[error("agent {agent}: {vertex} is not a vertex (the graph has {num_vertices})")]
    VertexOutOfRange {
        /// The agent whose start or goal it is.
        agent: usize,
        /// The offending id.
        vertex: u32,
        /// Number of vertices of the graph.
        num_vertices: usize,
    },
    /// Two agents start (or currently are) on one vertex.
    #[error("agents {first} and {second} both start on vertex {vertex}")]
    DuplicateStart {
        /// The lower-numbered agent.
        first: usize,
        /// The other agent.
        second: usize,
        /// The shared vertex.
        vertex: u32,
    },
    /// Two agents have one goal vertex.
    #[error("agents {first} and {second} both have goal {vertex}")]
    DuplicateGoal {
        /// The lower-numbered agent.
        first: usize,
        /// The other agent.
        second: usize,
        /// The shared vertex.
        vertex: u32,
    },
    /// An agent's goal is in another connected component than its start: the instance is
    /// unsolvable, known without searching.
    #[error("agent {agent} cannot reach goal {goal} from {start}")]
    GoalUnreachable {
        /// The agent.
        agent: usize,
        /// Its start.
        start: u32,
        /// Its goal.
        goal: u32,
    },
    /// Every configuration reachable from the starts was explored and none is the goal one.
    #[error("unsolvable: all {configurations} reachable configurations explored")]
    Unsolvable {
        /// Number of distinct configurations explored.
        configurations: usize,
    },
    /// The caller's time or expansion budget ran out before the search ended.
    #[error("search budget exhausted after {expansions} expansions in {elapsed:?}")]
    Timeout {
        /// Low-level expansions done (configuration generator calls).
        expansions: u64,
        /// Time spent.
        elapsed: Duration,
    },
}

impl MapfError {
    /// Whether the error proves that the instance has no solution.
    pub fn is_unsolvable(&self) -> bool {
        matches!(self, Self::Unsolvable { .. } | Self::GoalUnreachable { .. })
    }
}
