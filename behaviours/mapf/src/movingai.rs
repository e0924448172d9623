//! The MovingAI grid benchmark formats (Sturtevant, "Benchmarks for Grid-Based Pathfinding",
//! 2012; Stern et al., "Multi-Agent Pathfinding: Definitions, Variants, and Benchmarks", 2019).
//!
//! A `.map` file is a header (`type octile`, `height H`, `width W`, `map`) and `H` rows of `W`
//! cells: `.`, `G` and `S` are passable, `@`, `O`, `T` and `W` are not. A `.scen` file is
//! `version 1` and one agent a line: bucket, map, width, height, start x, start y, goal x, goal
//! y, optimal length; its first `N` lines are the `N`-agent instance.
//!
//! Only passable cells become vertices of the [`Graph`] (4-connected): distance tables, which
//! the planners need one of per goal, then cover no walls. [`GridMap`] translates between cells
//! and vertices.

use std::path::Path;

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use thiserror::Error;

use crate::graph::Graph;
use crate::pibt::NONE;
use crate::scenario::{largest_component, Scenario};

/// Why a MovingAI file or instance could not be used. Line numbers count from 1.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
pub enum MovingAiError {
    /// The file could not be read.
    #[error("cannot read {path}: {reason}")]
    Io {
        /// The file.
        path: String,
        /// What the operating system said.
        reason: String,
    },
    /// A line is malformed.
    #[error("line {line}: {reason}")]
    Syntax {
        /// The offending line.
        line: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// The file ended before the header or all rows were read.
    #[error("unexpected end of file after line {line}: expected {expected}")]
    Truncated {
        /// Last line read.
        line: usize,
        /// What was still missing.
        expected: String,
    },
    /// An instance asks for more agents than the scenario file lists.
    #[error("{wanted} agents wanted, the scenario has {available}")]
    TooFewAgents {
        /// Agents asked for.
        wanted: usize,
        /// Lines in the scenario.
        available: usize,
    },
    /// A random instance asks for more agents than the largest connected region has cells.
    #[error("{agents} agents do not fit the largest region of {cells} cells")]
    TooFewCells {
        /// Agents asked for.
        agents: usize,
        /// Cells in the largest connected region.
        cells: usize,
    },
}

fn syntax(line: usize, reason: impl Into<String>) -> MovingAiError {
    MovingAiError::Syntax {
        line,
        reason: reason.into(),
    }
}

fn read(path: &Path) -> Result<String, MovingAiError> {
    std::fs::read_to_string(path).map_err(|e| MovingAiError::Io {
        path: path.display().to_string(),
        reason: e.to_string(),
    })
}

/// A grid map: its size, its passable cells as the vertices of a [`Graph`], and the translation
/// between cells `(x, y)` (column, row from the top) and vertices.
#[derive(Clone, Debug)]
pub struct GridMap {
    width: u32,
    height: u32,
    graph: Graph,
    /// Vertex of each cell in row-major order, [`NONE`] where blocked.
    vertex_of: Vec<u32>,
    /// Row-major cell index of each vertex.
    cell_of: Vec<u32>,
}

/// One row of a `.map` file's cells: a vertex for each passable cell, none for an obstacle.
fn parse_row(
    line: usize,
    row: &str,
    width: u32,
    vertex_of: &mut Vec<u32>,
    cell_of: &mut Vec<u32>,
) -> Result<(), MovingAiError> {
    if row.chars().count() != width as usize {
        return Err(syntax(
            line,
            format!("row has {} cells, expected {width}", row.chars().count()),
        ));
    }
    for (column, c) in row.chars().enumerate() {
        match c {
            '.' | 'G' | 'S' => {
                vertex_of.push(cell_of.len() as u32);
                cell_of.push(vertex_of.len() as u32 - 1);
            }
            '@' | 'O' | 'T' | 'W' => vertex_of.push(NONE),
            _ => {
                return Err(syntax(
                    line,
                    format!("unknown cell `{c}` in column {}", column + 1),
                ))
            }
        }
    }
    Ok(())
}

/// The grid's edges: each passable cell to its passable right and lower neighbours.
fn grid_edges(width: u32, height: u32, vertex_of: &[u32], cell_of: &[u32]) -> Vec<(u32, u32)> {
    let mut edges = Vec::with_capacity(cell_of.len() * 2);
    for (v, &cell) in cell_of.iter().enumerate() {
        let (x, y) = (cell % width, cell / width);
        let right = (x + 1 < width).then(|| vertex_of[cell as usize + 1]);
        let down = (y + 1 < height).then(|| vertex_of[(cell + width) as usize]);
        for u in [right, down].into_iter().flatten().filter(|&u| u != NONE) {
            edges.push((v as u32, u));
        }
    }
    edges
}

impl GridMap {
    /// Reads a `.map` file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, MovingAiError> {
        Self::parse(&read(path.as_ref())?)
    }

    /// Parses the text of a `.map` file.
    pub fn parse(text: &str) -> Result<Self, MovingAiError> {
        let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim_end()));
        let line_count = text.lines().count();
        let mut header = |expected: &str| {
            lines.next().ok_or_else(|| MovingAiError::Truncated {
                line: line_count,
                expected: expected.to_owned(),
            })
        };
        let (line, kind) = header("`type octile`")?;
        if kind.split_whitespace().collect::<Vec<_>>() != ["type", "octile"] {
            return Err(syntax(
                line,
                format!("expected `type octile`, found `{kind}`"),
            ));
        }
        let (mut width, mut height) = (None, None);
        for _ in 0..2 {
            let (line, text) = header("`height H` and `width W`")?;
            let mut words = text.split_whitespace();
            let slot = match words.next() {
                Some("height") => &mut height,
                Some("width") => &mut width,
                _ => {
                    return Err(syntax(
                        line,
                        format!("expected `height H` or `width W`, found `{text}`"),
                    ))
                }
            };
            let value = match (words.next().map(str::parse::<u32>), words.next()) {
                (Some(Ok(v)), None) if v > 0 => v,
                _ => {
                    return Err(syntax(
                        line,
                        format!("expected a positive size, found `{text}`"),
                    ))
                }
            };
            if slot.replace(value).is_some() {
                return Err(syntax(line, "size given twice"));
            }
        }
        let (Some(width), Some(height)) = (width, height) else {
            return Err(syntax(3, "expected both `height H` and `width W`"));
        };
        let (line, marker) = header("`map`")?;
        if marker.trim() != "map" {
            return Err(syntax(line, format!("expected `map`, found `{marker}`")));
        }
        let cells = (width as usize)
            .checked_mul(height as usize)
            .filter(|&c| c < NONE as usize)
            .ok_or_else(|| syntax(3, "map too large"))?;

        let mut vertex_of = Vec::with_capacity(cells);
        let mut cell_of = Vec::new();
        let mut last = line;
        for _ in 0..height {
            let (line, row) = lines.next().ok_or_else(|| MovingAiError::Truncated {
                line: last,
                expected: format!("{height} rows"),
            })?;
            last = line;
            parse_row(line, row, width, &mut vertex_of, &mut cell_of)?;
        }
        if let Some((line, extra)) = lines.find(|(_, l)| !l.is_empty()) {
            return Err(syntax(line, format!("text after the last row: `{extra}`")));
        }

        let edges = grid_edges(width, height, &vertex_of, &cell_of);
        let graph =
            Graph::from_edges(cell_of.len(), edges).map_err(|e| syntax(3, e.to_string()))?;
        Ok(Self {
            width,
            height,
            graph,
            vertex_of,
            cell_of,
        })
    }

    /// Width in cells.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in cells.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The graph of passable cells.
    pub fn graph(&self) -> &Graph {
        &self.graph
    }

    /// The vertex of cell `(x, y)`, or `None` if it is blocked or off the map.
    pub fn vertex(&self, x: u32, y: u32) -> Option<u32> {
        if x >= self.width || y >= self.height {
            return None;
        }
        Some(self.vertex_of[(y * self.width + x) as usize]).filter(|&v| v != NONE)
    }

    /// The cell `(x, y)` of vertex `v`, or `None` if it is not a vertex.
    pub fn cell(&self, v: u32) -> Option<(u32, u32)> {
        let cell = *self.cell_of.get(v as usize)?;
        Some((cell % self.width, cell / self.width))
    }

    /// The instance of the first `agents` lines of `scen`, on a copy of this map's graph.
    pub fn instance(&self, scen: &[ScenAgent], agents: usize) -> Result<Scenario, MovingAiError> {
        if scen.len() < agents {
            return Err(MovingAiError::TooFewAgents {
                wanted: agents,
                available: scen.len(),
            });
        }
        let vertex = |a: &ScenAgent, (x, y): (u32, u32), what: &str| {
            if (a.width, a.height) != (self.width, self.height) {
                return Err(syntax(
                    a.line,
                    format!(
                        "scenario is for a {} x {} map, this one is {} x {}",
                        a.width, a.height, self.width, self.height
                    ),
                ));
            }
            self.vertex(x, y).ok_or_else(|| {
                syntax(
                    a.line,
                    format!("{what} ({x}, {y}) is blocked or off the map"),
                )
            })
        };
        let mut starts = Vec::with_capacity(agents);
        let mut goals = Vec::with_capacity(agents);
        for a in &scen[..agents] {
            starts.push(vertex(a, a.start, "start")?);
            goals.push(vertex(a, a.goal, "goal")?);
        }
        Ok(Scenario {
            graph: self.fresh_graph(),
            starts,
            goals,
        })
    }

    /// A random instance of `agents` distinct starts and distinct goals in the largest connected
    /// region, on a copy of this map's graph. Equal seeds give equal instances.
    pub fn random_instance(&self, agents: usize, seed: u64) -> Result<Scenario, MovingAiError> {
        let region = largest_component(&self.graph);
        if region.len() < agents {
            return Err(MovingAiError::TooFewCells {
                agents,
                cells: region.len(),
            });
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut pick = || {
            let mut r = region.clone();
            r.shuffle(&mut rng);
            r.truncate(agents);
            r
        };
        let starts = pick();
        let goals = pick();
        Ok(Scenario {
            graph: self.fresh_graph(),
            starts,
            goals,
        })
    }

    /// A copy of the graph without cached distance tables, so that each instance pays for its
    /// own, as a planner run from scratch would.
    fn fresh_graph(&self) -> Graph {
        let mut graph = self.graph.clone();
        graph.clear_distance_cache();
        graph
    }
}

/// One line of a `.scen` file.
#[derive(Clone, Debug, PartialEq)]
pub struct ScenAgent {
    /// Line in the file, for error messages.
    pub line: usize,
    /// Width of the map the line was made for.
    pub width: u32,
    /// Height of the map the line was made for.
    pub height: u32,
    /// Start cell `(x, y)`.
    pub start: (u32, u32),
    /// Goal cell `(x, y)`.
    pub goal: (u32, u32),
    /// Length of an optimal single-agent path (octile, as the file gives it).
    pub optimal_length: f64,
}

/// Reads a `.scen` file.
pub fn load_scen(path: impl AsRef<Path>) -> Result<Vec<ScenAgent>, MovingAiError> {
    parse_scen(&read(path.as_ref())?)
}

/// Parses the text of a `.scen` file.
pub fn parse_scen(text: &str) -> Result<Vec<ScenAgent>, MovingAiError> {
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim_end()));
    match lines.next() {
        Some((_, l)) if l.split_whitespace().eq(["version", "1"]) => {}
        Some((_, l)) => return Err(syntax(1, format!("expected `version 1`, found `{l}`"))),
        None => {
            return Err(MovingAiError::Truncated {
                line: 0,
                expected: "`version 1`".to_owned(),
            })
        }
    }
    let mut agents = Vec::new();
    for (line, text) in lines.filter(|(_, l)| !l.is_empty()) {
        // Fields are tab-separated so that map names may hold spaces; accept plain whitespace too.
        let fields: Vec<&str> = if text.contains('\t') {
            text.split('\t').map(str::trim).collect()
        } else {
            text.split_whitespace().collect()
        };
        if fields.len() != 9 {
            return Err(syntax(
                line,
                format!("expected 9 fields, found {}", fields.len()),
            ));
        }
        let int = |i: usize, name: &str| {
            fields[i].parse::<u32>().map_err(|_| {
                syntax(
                    line,
                    format!("{name} `{}` is not a whole number", fields[i]),
                )
            })
        };
        let optimal_length = fields[8]
            .parse::<f64>()
            .ok()
            .filter(|l| l.is_finite() && *l >= 0.0)
            .ok_or_else(|| {
                syntax(
                    line,
                    format!("optimal length `{}` is not a length", fields[8]),
                )
            })?;
        agents.push(ScenAgent {
            line,
            width: int(2, "width")?,
            height: int(3, "height")?,
            start: (int(4, "start x")?, int(5, "start y")?),
            goal: (int(6, "goal x")?, int(7, "goal y")?),
            optimal_length,
        });
    }
    Ok(agents)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MAP: &str = "type octile\nheight 3\nwidth 4\nmap\n.W@.\nG.T.\nS...\n";

    fn line_of(e: MovingAiError) -> usize {
        match e {
            MovingAiError::Syntax { line, .. } => line,
            other => panic!("expected a syntax error, got {other:?}"),
        }
    }

    #[test]
    fn map_cells_become_vertices_in_row_major_order() {
        let m = GridMap::parse(MAP).unwrap();
        assert_eq!((m.width(), m.height()), (4, 3));
        assert_eq!(m.graph().num_vertices(), 9);
        assert_eq!(m.vertex(0, 0), Some(0));
        assert_eq!(m.vertex(1, 0), None);
        assert_eq!(m.vertex(2, 0), None);
        assert_eq!(m.vertex(3, 0), Some(1));
        assert_eq!(m.vertex(4, 0), None);
        assert_eq!(m.cell(1), Some((3, 0)));
        assert_eq!(m.cell(9), None);
        // (3, 0) reaches the rest only through (3, 1): a dead end.
        assert_eq!(m.graph().neighbors(1), &[m.vertex(3, 1).unwrap()]);
        assert_eq!(m.graph().distance(0, m.vertex(3, 0).unwrap()), Some(7));
        // CRLF line ends and trailing blank lines are fine.
        assert!(GridMap::parse(&MAP.replace('\n', "\r\n")).is_ok());
        assert!(GridMap::parse(&format!("{MAP}\n\n")).is_ok());
    }

    #[test]
    fn bad_maps_name_the_line() {
        let bad = |from: &str, to: &str| GridMap::parse(&MAP.replacen(from, to, 1)).unwrap_err();
        assert_eq!(line_of(bad("type octile", "type hex")), 1);
        assert_eq!(line_of(bad("height 3", "height three")), 2);
        assert_eq!(line_of(bad("width 4", "width 0")), 3);
        assert_eq!(line_of(bad("width 4", "height 4")), 3);
        assert_eq!(line_of(bad("map\n", "mop\n")), 4);
        assert_eq!(line_of(bad("G.T.", "G.T")), 6);
        assert_eq!(line_of(bad("G.T.", "G.X.")), 6);
        assert_eq!(
            line_of(GridMap::parse(&format!("{MAP}....\n")).unwrap_err()),
            8
        );
        assert_eq!(
            GridMap::parse("type octile\nheight 3\nwidth 4\nmap\n....\n").unwrap_err(),
            MovingAiError::Truncated {
                line: 5,
                expected: "3 rows".to_owned()
            }
        );
        assert!(matches!(
            GridMap::parse("type octile\n"),
            Err(MovingAiError::Truncated { .. })
        ));
        assert!(matches!(
            GridMap::load("/nonexistent/x.map"),
            Err(MovingAiError::Io { .. })
        ));
    }

    #[test]
    fn scenario_lines_give_instances() {
        let m = GridMap::parse(MAP).unwrap();
        let scen =
            parse_scen("version 1\n0\tm.map\t4\t3\t0\t0\t3\t0\t7\n0 m.map 4 3 1 2 0 0 3.0\n\n")
                .unwrap();
        assert_eq!(scen.len(), 2);
        assert_eq!(scen[1].line, 3);
        assert_eq!(scen[1].start, (1, 2));
        let s = m.instance(&scen, 2).unwrap();
        assert_eq!(s.starts, vec![0, m.vertex(1, 2).unwrap()]);
        assert_eq!(s.goals, vec![1, 0]);
        assert_eq!(s.graph.cached_distance_tables(), 0);
        assert_eq!(
            m.instance(&scen, 3).unwrap_err(),
            MovingAiError::TooFewAgents {
                wanted: 3,
                available: 2
            }
        );
    }

    #[test]
    fn bad_scenarios_name_the_line() {
        let m = GridMap::parse(MAP).unwrap();
        let ok = "0\tm.map\t4\t3\t0\t0\t3\t0\t7";
        let bad = |line: &str| parse_scen(&format!("version 1\n{ok}\n{line}\n")).unwrap_err();
        assert_eq!(line_of(parse_scen("version 2\n").unwrap_err()), 1);
        assert_eq!(line_of(bad("0\tm.map\t4\t3\t0\t0\t3\t0")), 3);
        assert_eq!(line_of(bad("0\tm.map\t4\t3\t-1\t0\t3\t0\t7")), 3);
        assert_eq!(line_of(bad("0\tm.map\t4\t3\t0\t0\t3\t0\tfar")), 3);
        let blocked =
            parse_scen(&format!("version 1\n{ok}\n0\tm.map\t4\t3\t2\t0\t3\t0\t1\n")).unwrap();
        assert_eq!(line_of(m.instance(&blocked, 2).unwrap_err()), 3);
        let other_map = parse_scen("version 1\n0\tm.map\t5\t3\t0\t0\t3\t0\t7\n").unwrap();
        assert_eq!(line_of(m.instance(&other_map, 1).unwrap_err()), 2);
    }

    #[test]
    fn random_instances_are_distinct_connected_and_reproducible() {
        // Two regions; the isolated cell (0, 2) must never be used.
        let m = GridMap::parse("type octile\nheight 3\nwidth 3\nmap\n...\n@@.\n.@.\n").unwrap();
        let a = m.random_instance(5, 7).unwrap();
        let b = m.random_instance(5, 7).unwrap();
        assert_eq!((&a.starts, &a.goals), (&b.starts, &b.goals));
        let lonely = m.vertex(0, 2).unwrap();
        for set in [&a.starts, &a.goals] {
            let mut s = set.clone();
            s.sort_unstable();
            s.dedup();
            assert_eq!(s.len(), 5);
            assert!(!s.contains(&lonely));
        }
        assert_eq!(
            m.random_instance(6, 0).unwrap_err(),
            MovingAiError::TooFewCells {
                agents: 6,
                cells: 5
            }
        );
    }
}
