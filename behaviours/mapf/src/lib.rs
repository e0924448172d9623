//! Multi-agent path finding for PocketFleet's traffic control.
//!
//! Robots follow tape, so where they may be is a graph: junctions and waypoints are vertices and
//! tape segments are edges. Traffic control needs every robot to reach its goal vertex without
//! two robots ever sharing a vertex or passing each other on a segment. This crate plans that
//! (multi-agent path finding, MAPF) and turns the plan into something robots of uneven speed can
//! execute.
//!
//! - [`Graph`]: the graph in compressed sparse row form (`u32` vertex ids), built from an edge
//!   list, a petgraph graph or as a grid, with breadth-first distance tables to goals computed on
//!   first use and cached per goal.
//! - [`pibt`]: *Priority Inheritance with Backtracking* (Okumura et al., IJCAI 2019; AIJ 2022),
//!   which plans one synchronous step for all agents in time linear in their number, with the
//!   swap operation of LaCAM3 so that agents meeting head-on in a corridor back out to let each
//!   other pass. On its own it is fast but incomplete: agents can chase each other round in
//!   circles.
//! - [`lacam`]: *LaCAM*, lazy constraints addition search (Okumura, AAAI 2023; LaCAM*, IJCAI
//!   2023), a depth-first search over joint configurations that uses PIBT to generate successors
//!   under gradually added constraints. It is complete: it finds a plan whenever one exists and
//!   otherwise reports [`MapfError::Unsolvable`] after exhausting the reachable configurations,
//!   unless the caller's budget ends it first with [`MapfError::Timeout`].
//! - [`movingai`]: the MovingAI benchmark's `.map` and `.scen` files, and random instances on
//!   their maps.
//! - [`Solution`] and [`validate`]: the synchronous plan (`paths[agent][step]`, all of one length,
//!   agents that arrive early wait and may be pushed aside later) and its checker.
//! - [`Adg`]: the *action dependency graph* of Hönig et al. ("Persistent and Robust Execution of
//!   MAPF Schedules in Warehouses", RA-L 2019), which lets each robot start its next move as
//!   soon as the robots it must follow have completed theirs, without a shared clock.
//!
//! Conflicts ruled out everywhere: two agents on one vertex; two agents crossing one edge in
//! opposite directions (a swap); and, stricter than textbook MAPF, three or more agents moving
//! round a cycle in lockstep (a rotation). Robots enter a vertex only once it is vacated, so a
//! rotation could never start; forbidding it keeps every plan executable through the ADG.
//!
//! ```
//! use mapf::{lacam, validate, Adg, Graph};
//!
//! // A corridor 0-1-2-3-4 with a siding 5 off vertex 2: the two robots swap ends.
//! let graph = Graph::from_edges(6, [(0, 1), (1, 2), (2, 3), (3, 4), (2, 5)])?;
//! let (starts, goals) = ([0, 4], [4, 0]);
//! let plan = lacam::solve(&graph, &starts, &goals, &lacam::Options::default())?;
//! validate(&graph, &plan, &starts, &goals)?;
//!
//! let mut adg = Adg::new(&plan)?;
//! while !adg.is_done() {
//!     for robot in 0..2 {
//!         if let Some(action) = adg.ready(robot) {
//!             // ... drive from action.from to action.to, then:
//!             adg.complete(robot, action.index)?;
//!         }
//!     }
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![warn(missing_docs)]

pub mod adg;
pub mod error;
pub mod graph;
pub mod lacam;
pub mod movingai;
pub mod pibt;
pub mod plan;
pub mod scenario;

pub use adg::{Action, Adg, AdgError};
pub use error::MapfError;
pub use graph::{DistanceTable, Graph, GraphError};
pub use movingai::{GridMap, MovingAiError};
pub use pibt::Pibt;
pub use plan::{validate, Conflict, Solution};
pub use scenario::Scenario;
