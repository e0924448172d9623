//! The track as a routing graph for the coordinator: junctions, ends and waypoints joined by
//! edges weighted with their tape length.
//!
//! The graph is undirected (`UnGraph`): tape has no direction of its own. A PocketBot2 can follow
//! an edge either way and turn on the spot, and a single-lane section is used both ways; which way
//! traffic may go is a rule the coordinator imposes, not a property of the floor.

use std::collections::HashMap;

use nalgebra::Point2;
use petgraph::algo::astar;
use petgraph::graph::{EdgeIndex, NodeIndex, UnGraph};

use super::track::{Mark, Track};

/// Role of a node, from how many tape edges meet there.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum NodeKind {
    /// Three or more edges: a fork, merge or crossing where a robot must choose.
    Junction,
    /// At most one edge: the tape ends here.
    End,
    /// Exactly two edges: the tape just goes on.
    Waypoint,
}

/// Node weight of a [`TrackGraph`].
#[derive(Clone, Debug, PartialEq)]
pub struct GraphNode {
    /// The track node's id.
    pub id: String,
    /// Its position in metres.
    pub position: Point2<f64>,
    /// Its role.
    pub kind: NodeKind,
}

/// Edge weight of a [`TrackGraph`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GraphEdge {
    /// Index of the edge in [`Track::edges`].
    pub edge: usize,
    /// Length of its tape in metres.
    pub length_m: f64,
    /// Its colour mark.
    pub mark: Option<Mark>,
}

/// A shortest route between two nodes.
#[derive(Clone, Debug, PartialEq)]
pub struct Route {
    /// Total tape length in metres.
    pub length_m: f64,
    /// Nodes passed, first and last included.
    pub nodes: Vec<NodeIndex>,
    /// Track edge indices driven, one fewer than `nodes`.
    pub edges: Vec<usize>,
}

/// Routing view of a [`Track`]. Node `i` of the graph is node `i` of the track, and graph edge
/// `i` is track edge `i`, so indices can be used on either.
#[derive(Clone, Debug)]
pub struct TrackGraph {
    /// The graph itself, for any petgraph algorithm.
    pub graph: UnGraph<GraphNode, GraphEdge>,
    by_id: HashMap<String, NodeIndex>,
}

impl TrackGraph {
    /// Builds the graph of `track`.
    pub fn new(track: &Track) -> TrackGraph {
        let mut degree = vec![0usize; track.nodes().len()];
        for e in track.edges() {
            degree[e.from] += 1;
            degree[e.to] += 1;
        }
        let mut graph = UnGraph::with_capacity(track.nodes().len(), track.edges().len());
        let mut by_id = HashMap::with_capacity(track.nodes().len());
        for (n, d) in track.nodes().iter().zip(degree) {
            let kind = match d {
                0 | 1 => NodeKind::End,
                2 => NodeKind::Waypoint,
                _ => NodeKind::Junction,
            };
            let ix = graph.add_node(GraphNode {
                id: n.id.clone(),
                position: n.position,
                kind,
            });
            by_id.insert(n.id.clone(), ix);
        }
        for (i, e) in track.edges().iter().enumerate() {
            graph.add_edge(
                NodeIndex::new(e.from),
                NodeIndex::new(e.to),
                GraphEdge {
                    edge: i,
                    length_m: e.length_m(),
                    mark: e.mark,
                },
            );
        }
        TrackGraph { graph, by_id }
    }

    /// The node called `id`.
    pub fn node(&self, id: &str) -> Option<NodeIndex> {
        self.by_id.get(id).copied()
    }

    /// The weight of node `ix`, if it exists.
    pub fn node_weight(&self, ix: NodeIndex) -> Option<&GraphNode> {
        self.graph.node_weight(ix)
    }

    /// Track edges meeting at node `ix`.
    pub fn edges_at(&self, ix: NodeIndex) -> impl Iterator<Item = usize> + '_ {
        self.graph.edges(ix).map(|e| e.weight().edge)
    }

    /// Shortest route by tape length between the nodes called `from` and `to` (A*, with the
    /// straight-line distance as estimate: tape is never shorter than the chord). `None` if
    /// either id is unknown or no tape connects them.
    pub fn shortest_path(&self, from: &str, to: &str) -> Option<Route> {
        let (start, goal) = (self.node(from)?, self.node(to)?);
        let goal_pos = self.graph.node_weight(goal)?.position;
        let (length_m, nodes) = astar(
            &self.graph,
            start,
            |n| n == goal,
            |e| e.weight().length_m,
            |n| {
                self.graph
                    .node_weight(n)
                    .map_or(0.0, |w| (w.position - goal_pos).norm())
            },
        )?;
        // Between two nodes joined by parallel edges (two halves of a loop), A* took the shorter.
        let edges = nodes
            .windows(2)
            .map(|w| {
                self.graph
                    .edges_connecting(w[0], w[1])
                    .map(|e| *e.weight())
                    .min_by(|a, b| a.length_m.total_cmp(&b.length_m))
                    .map(|e| e.edge)
            })
            .collect::<Option<Vec<usize>>>()?;
        Some(Route {
            length_m,
            nodes,
            edges,
        })
    }

    /// The graph edge for track edge `edge`.
    pub fn edge_index(&self, edge: usize) -> Option<EdgeIndex> {
        (edge < self.graph.edge_count()).then(|| EdgeIndex::new(edge))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::{EdgeSpec, Node};

    /// A loop a–b–c–d–a of four 1 m sides with a 0.5 m spur b–e.
    fn square() -> Track {
        Track::new(
            vec![
                Node::new("a", 0.0, 0.0),
                Node::new("b", 1.0, 0.0),
                Node::new("c", 1.0, 1.0),
                Node::new("d", 0.0, 1.0),
                Node::new("e", 1.5, 0.0),
                Node::new("lonely", 3.0, 3.0),
            ],
            vec![
                EdgeSpec::straight("a", "b"),
                EdgeSpec::straight("b", "c"),
                EdgeSpec::straight("c", "d"),
                EdgeSpec::straight("d", "a"),
                EdgeSpec::straight("b", "e"),
            ],
        )
        .expect("valid")
    }

    #[test]
    fn kinds_follow_degree() {
        let g = TrackGraph::new(&square());
        let kind = |id| g.node(id).and_then(|n| g.node_weight(n)).map(|w| w.kind);
        assert_eq!(kind("b"), Some(NodeKind::Junction));
        assert_eq!(kind("a"), Some(NodeKind::Waypoint));
        assert_eq!(kind("e"), Some(NodeKind::End));
        assert_eq!(kind("lonely"), Some(NodeKind::End));
        assert_eq!(kind("zz"), None);
    }

    #[test]
    fn shortest_path_takes_the_short_way_round() {
        let g = TrackGraph::new(&square());
        let r = g.shortest_path("e", "d").expect("connected");
        assert!((r.length_m - 2.5).abs() < 1e-12);
        assert_eq!(r.edges.len(), 3);
        assert_eq!(r.edges[0], 4);
        assert!(g.shortest_path("a", "lonely").is_none());
        assert!(g.shortest_path("a", "nowhere").is_none());
        let same = g.shortest_path("c", "c").expect("trivial");
        assert_eq!(same.length_m, 0.0);
        assert!(same.edges.is_empty());
    }

    #[test]
    fn parallel_edges_pick_the_shorter() {
        // Two arcs between the same nodes: a semicircle (π·0.5 m) and a 270° arc.
        let t = Track::new(
            vec![Node::new("a", 0.0, 0.0), Node::new("b", 1.0, 0.0)],
            vec![
                EdgeSpec::arc("a", "b", -270.0),
                EdgeSpec::arc("a", "b", 180.0),
            ],
        )
        .expect("valid");
        let g = TrackGraph::new(&t);
        let r = g.shortest_path("a", "b").expect("connected");
        assert_eq!(r.edges, vec![1]);
        assert!((r.length_m - std::f64::consts::PI * 0.5).abs() < 1e-12);
    }
}
