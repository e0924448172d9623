//! The planning graph: an undirected graph in compressed sparse row form with lazily computed,
//! cached breadth-first distance tables.

use std::fmt;
use std::sync::OnceLock;

use petgraph::graph::IndexType;
use petgraph::EdgeType;
use thiserror::Error;

/// Why a [`Graph`] could not be built.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
pub enum GraphError {
    /// An edge names a vertex that is not below the vertex count.
    #[error("edge endpoint {vertex} is not a vertex (the graph has {num_vertices})")]
    VertexOutOfRange {
        /// The offending endpoint.
        vertex: u32,
        /// Number of vertices of the graph being built.
        num_vertices: usize,
    },
    /// The graph does not fit `u32` vertex ids and adjacency offsets.
    #[error("the graph is too large for u32 vertex ids and offsets")]
    TooLarge,
    /// The obstacle mask of a grid does not have one entry per cell.
    #[error("grid mask has {found} cells, expected {expected}")]
    MaskLength {
        /// `width * height`.
        expected: usize,
        /// Length of the mask given.
        found: usize,
    },
}

/// Hop distances from every vertex to one goal vertex.
///
/// Stored as `u16` when the graph has fewer than 65,535 vertices (no distance can then exceed
/// `u16::MAX - 1`), which halves the memory of the per-goal cache on track-sized graphs.
#[derive(Clone)]
pub struct DistanceTable(Storage);

#[derive(Clone)]
enum Storage {
    Narrow(Box<[u16]>),
    Wide(Box<[u32]>),
}

/// Internal marker for "no path"; kept at `u32::MAX` so that it sorts after every real distance.
pub(crate) const UNREACHABLE: u32 = u32::MAX;

impl fmt::Debug for DistanceTable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // The entries themselves would drown any log they appear in.
        f.debug_struct("DistanceTable")
            .field("len", &self.len())
            .field("heap_bytes", &self.heap_bytes())
            .finish()
    }
}

impl DistanceTable {
    /// Hops from `v` to the goal, or `None` when the goal is in another component.
    pub fn get(&self, v: u32) -> Option<u32> {
        match self.raw(v) {
            UNREACHABLE => None,
            d => Some(d),
        }
    }

    /// Like [`get`](Self::get), with [`UNREACHABLE`] for no path, for the planners' hot loops.
    #[inline]
    pub(crate) fn raw(&self, v: u32) -> u32 {
        match &self.0 {
            Storage::Narrow(d) => match d[v as usize] {
                u16::MAX => UNREACHABLE,
                x => u32::from(x),
            },
            Storage::Wide(d) => d[v as usize],
        }
    }

    /// Number of vertices covered (the graph's vertex count).
    pub fn len(&self) -> usize {
        match &self.0 {
            Storage::Narrow(d) => d.len(),
            Storage::Wide(d) => d.len(),
        }
    }

    /// Whether the table covers no vertex (the graph is empty).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Heap bytes held by the table.
    pub fn heap_bytes(&self) -> usize {
        match &self.0 {
            Storage::Narrow(d) => d.len() * 2,
            Storage::Wide(d) => d.len() * 4,
        }
    }
}

/// An undirected graph with `u32` vertex ids `0..num_vertices()`, in compressed sparse row form.
///
/// Neighbour lists are sorted and free of duplicates and self-loops (waiting is always allowed
/// by the planners, so a self-loop carries no information). Distance tables to goal vertices are
/// computed by breadth-first search the first time a goal is asked for and kept until
/// [`clear_distance_cache`](Self::clear_distance_cache); only goals actually used cost memory.
/// The cache is thread-safe, so one `Graph` can serve planners on several threads.
#[derive(Clone)]
pub struct Graph {
    offsets: Vec<u32>,
    adjacency: Vec<u32>,
    distances: Box<[OnceLock<DistanceTable>]>,
}

impl fmt::Debug for Graph {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Graph")
            .field("vertices", &self.num_vertices())
            .field("edges", &self.num_edges())
            .field("cached_distance_tables", &self.cached_distance_tables())
            .finish()
    }
}

impl Graph {
    /// Builds a graph on `num_vertices` vertices from undirected edges; duplicates (in either
    /// direction) and self-loops are dropped.
    pub fn from_edges<I>(num_vertices: usize, edges: I) -> Result<Self, GraphError>
    where
        I: IntoIterator<Item = (u32, u32)>,
    {
        if num_vertices >= u32::MAX as usize {
            return Err(GraphError::TooLarge);
        }
        let mut arcs = Vec::new();
        for (u, v) in edges {
            for x in [u, v] {
                if x as usize >= num_vertices {
                    return Err(GraphError::VertexOutOfRange {
                        vertex: x,
                        num_vertices,
                    });
                }
            }
            if u != v {
                arcs.push((u, v));
                arcs.push((v, u));
            }
        }
        arcs.sort_unstable();
        arcs.dedup();
        if arcs.len() >= u32::MAX as usize {
            return Err(GraphError::TooLarge);
        }
        let mut offsets = vec![0u32; num_vertices + 1];
        for &(u, _) in &arcs {
            offsets[u as usize + 1] += 1;
        }
        for i in 0..num_vertices {
            offsets[i + 1] += offsets[i];
        }
        let adjacency = arcs.into_iter().map(|(_, v)| v).collect();
        Ok(Self {
            offsets,
            adjacency,
            distances: (0..num_vertices).map(|_| OnceLock::new()).collect(),
        })
    }

    /// Builds a graph from a petgraph [`petgraph::Graph`] (e.g. an `UnGraph`), ignoring weights:
    /// vertex `i` is `NodeIndex::new(i)`. Directed edges are taken as undirected, since robots
    /// may drive a tape segment both ways.
    pub fn from_petgraph<N, E, Ty, Ix>(
        graph: &petgraph::Graph<N, E, Ty, Ix>,
    ) -> Result<Self, GraphError>
    where
        Ty: EdgeType,
        Ix: IndexType,
    {
        let to_u32 = |i: usize| u32::try_from(i).map_err(|_| GraphError::TooLarge);
        let edges = graph
            .raw_edges()
            .iter()
            .map(|e| Ok((to_u32(e.source().index())?, to_u32(e.target().index())?)))
            .collect::<Result<Vec<_>, GraphError>>()?;
        Self::from_edges(graph.node_count(), edges)
    }

    /// A `width` × `height` 4-connected grid; cell `(x, y)` is vertex `y * width + x`.
    ///
    /// Blocked cells (`blocked[y * width + x] == true`) stay vertices, so ids remain row-major,
    /// but have no edges.
    pub fn grid(width: u32, height: u32, blocked: Option<&[bool]>) -> Result<Self, GraphError> {
        let cells = (width as usize)
            .checked_mul(height as usize)
            .ok_or(GraphError::TooLarge)?;
        if let Some(mask) = blocked {
            if mask.len() != cells {
                return Err(GraphError::MaskLength {
                    expected: cells,
                    found: mask.len(),
                });
            }
        }
        let free = |i: u32| blocked.is_none_or(|m| !m[i as usize]);
        let mut edges = Vec::with_capacity(cells * 2);
        for y in 0..height {
            for x in 0..width {
                let v = y * width + x;
                if !free(v) {
                    continue;
                }
                if x + 1 < width && free(v + 1) {
                    edges.push((v, v + 1));
                }
                if y + 1 < height && free(v + width) {
                    edges.push((v, v + width));
                }
            }
        }
        Self::from_edges(cells, edges)
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Number of undirected edges.
    pub fn num_edges(&self) -> usize {
        self.adjacency.len() / 2
    }

    /// Sorted neighbours of `v`.
    ///
    /// # Panics
    /// If `v` is not a vertex.
    #[inline]
    pub fn neighbors(&self, v: u32) -> &[u32] {
        let v = v as usize;
        &self.adjacency[self.offsets[v] as usize..self.offsets[v + 1] as usize]
    }

    /// Number of neighbours of `v`.
    pub fn degree(&self, v: u32) -> usize {
        self.neighbors(v).len()
    }

    /// Whether `u` and `v` are joined by an edge (false if either is not a vertex).
    pub fn has_edge(&self, u: u32, v: u32) -> bool {
        (u as usize) < self.num_vertices()
            && (v as usize) < self.num_vertices()
            && self.neighbors(u).binary_search(&v).is_ok()
    }

    /// Whether `v` is a vertex of the graph.
    pub fn contains(&self, v: u32) -> bool {
        (v as usize) < self.num_vertices()
    }

    /// Distances from every vertex to `goal`, computed on first use and cached.
    ///
    /// # Panics
    /// If `goal` is not a vertex.
    pub fn distances(&self, goal: u32) -> &DistanceTable {
        self.distances[goal as usize].get_or_init(|| self.bfs(goal))
    }

    /// Hops from `from` to `goal`, or `None` when they are not connected. Caches the table of
    /// `goal`, so ask with the goal that will be asked for again.
    ///
    /// # Panics
    /// If either is not a vertex.
    pub fn distance(&self, from: u32, goal: u32) -> Option<u32> {
        self.distances(goal).get(from)
    }

    /// Number of goals whose distance table is cached.
    pub fn cached_distance_tables(&self) -> usize {
        self.distances.iter().filter(|c| c.get().is_some()).count()
    }

    /// Heap bytes held by cached distance tables.
    pub fn distance_cache_bytes(&self) -> usize {
        self.distances
            .iter()
            .filter_map(|c| c.get().map(DistanceTable::heap_bytes))
            .sum()
    }

    /// Drops every cached distance table (e.g. when the set of goals in use has changed).
    pub fn clear_distance_cache(&mut self) {
        for c in self.distances.iter_mut() {
            c.take();
        }
    }

    fn bfs(&self, goal: u32) -> DistanceTable {
        let n = self.num_vertices();
        let mut dist = vec![UNREACHABLE; n];
        let mut queue = Vec::with_capacity(n);
        dist[goal as usize] = 0;
        queue.push(goal);
        let mut head = 0;
        while let Some(&v) = queue.get(head) {
            head += 1;
            let d = dist[v as usize] + 1;
            for &u in self.neighbors(v) {
                if dist[u as usize] == UNREACHABLE {
                    dist[u as usize] = d;
                    queue.push(u);
                }
            }
        }
        if n < u16::MAX as usize {
            DistanceTable(Storage::Narrow(
                dist.into_iter()
                    .map(|d| u16::try_from(d).unwrap_or(u16::MAX))
                    .collect(),
            ))
        } else {
            DistanceTable(Storage::Wide(dist.into_boxed_slice()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edges_are_deduplicated_and_symmetric() {
        let g = Graph::from_edges(4, [(0, 1), (1, 0), (1, 2), (2, 2), (3, 1)]).unwrap();
        assert_eq!(g.num_edges(), 3);
        assert_eq!(g.neighbors(1), &[0, 2, 3]);
        assert_eq!(g.neighbors(2), &[1]);
        assert!(g.has_edge(3, 1) && g.has_edge(1, 3));
        assert!(!g.has_edge(0, 2));
        assert!(!g.has_edge(0, 9));
    }

    #[test]
    fn out_of_range_edge_is_rejected() {
        assert_eq!(
            Graph::from_edges(2, [(0, 2)]).unwrap_err(),
            GraphError::VertexOutOfRange {
                vertex: 2,
                num_vertices: 2
            }
        );
    }

    #[test]
    fn grid_has_row_major_ids_and_blocked_cells_are_isolated() {
        // 3 x 2 with the middle of the top row blocked.
        let blocked = [false, true, false, false, false, false];
        let g = Graph::grid(3, 2, Some(&blocked)).unwrap();
        assert_eq!(g.num_vertices(), 6);
        assert_eq!(g.neighbors(1), &[] as &[u32]);
        assert_eq!(g.neighbors(0), &[3]);
        assert_eq!(g.neighbors(4), &[3, 5]);
        assert_eq!(g.distance(0, 2), Some(4));
        assert_eq!(g.distance(1, 2), None);
        assert!(Graph::grid(3, 2, Some(&blocked[..5])).is_err());
    }

    #[test]
    fn distance_tables_are_cached_per_goal_and_clearable() {
        let mut g = Graph::grid(10, 10, None).unwrap();
        assert_eq!(g.cached_distance_tables(), 0);
        assert_eq!(g.distance(0, 99), Some(18));
        assert_eq!(g.distance(5, 99), Some(13));
        assert_eq!(g.cached_distance_tables(), 1);
        assert_eq!(g.distance_cache_bytes(), 200);
        g.distance(99, 0);
        assert_eq!(g.cached_distance_tables(), 2);
        g.clear_distance_cache();
        assert_eq!(g.cached_distance_tables(), 0);
    }

    #[test]
    fn from_petgraph_keeps_node_indices() {
        let mut pg = petgraph::graph::UnGraph::<&str, f32>::new_undirected();
        let a = pg.add_node("a");
        let b = pg.add_node("b");
        let c = pg.add_node("c");
        pg.add_edge(a, b, 1.0);
        pg.add_edge(c, b, 2.0);
        let g = Graph::from_petgraph(&pg).unwrap();
        assert_eq!(g.num_vertices(), 3);
        assert_eq!(g.neighbors(b.index() as u32), &[0, 2]);
        let mut dg = petgraph::graph::DiGraph::<(), ()>::new();
        let x = dg.add_node(());
        let y = dg.add_node(());
        dg.add_edge(x, y, ());
        assert!(Graph::from_petgraph(&dg).unwrap().has_edge(1, 0));
    }
}
