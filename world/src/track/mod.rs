//! Tape geometry: a graph of straight and circular-arc tape pieces laid on a white floor, with a
//! uniform-grid spatial index so the floor under a sensor spot is found by looking at one cell.

mod description;
mod floor;
mod index;
mod points;
mod shape;
mod surface;

use std::collections::HashMap;

use nalgebra::Point2;

use index::GridIndex;
use shape::{bounding_circle, Shape};

pub use description::{EdgeEnd, EdgeSpec, Node, TrackError};
pub use floor::QueryCost;
pub use index::IndexStats;
pub use points::TrackPoint;
pub use surface::{Mark, Surface};

/// Width of plain black tape when an edge does not give its own: a few millimetres of tape.
pub const DEFAULT_TAPE_WIDTH_M: f64 = 0.006;

/// Widest tape accepted. Anything wider is almost certainly a value given in millimetres.
pub const MAX_TAPE_WIDTH_M: f64 = 0.1;

/// Side of one spatial-index cell. Smaller than the track spacing of every preset, so a cell
/// usually holds at most the few edges meeting at one node.
pub const INDEX_CELL_M: f64 = 0.05;

/// Cap on index cells: a track spread over a huge area gets coarser cells instead of an
/// allocation that could fail.
const MAX_INDEX_CELLS: usize = 1 << 22;

/// Shorter edges are refused: their direction, and an arc's centre, are numerically meaningless.
pub const MIN_EDGE_LENGTH_M: f64 = 1e-6;

/// One edge of a built track.
#[derive(Clone, Debug, PartialEq)]
pub struct Edge {
    /// Index of the start node in [`Track::nodes`].
    pub from: usize,
    /// Index of the end node in [`Track::nodes`].
    pub to: usize,
    /// Signed sweep in degrees, positive = left; 0 for a straight edge.
    pub turn_deg: f64,
    /// Tape width in metres.
    pub width_m: f64,
    /// Colour of the edge; `None` is black tape.
    pub mark: Option<Mark>,
    shape: Shape,
    /// Centre and radius of a circle holding the whole centre line, for pruning `nearest`.
    bound_centre: Point2<f64>,
    bound_radius: f64,
}

impl Edge {
    /// Length of the centre line in metres.
    pub fn length_m(&self) -> f64 {
        self.shape.length()
    }

    /// Whether the edge is a circular arc rather than a straight line.
    pub fn is_arc(&self) -> bool {
        matches!(self.shape, Shape::Arc { .. })
    }

    /// What the tape of this edge looks like.
    pub fn surface(&self) -> Surface {
        Surface::of_tape(self.mark)
    }
}

/// A validated tape layout with its spatial index. The default is a bare floor without tape.
#[derive(Clone, Debug, Default)]
pub struct Track {
    nodes: Vec<Node>,
    edges: Vec<Edge>,
    by_id: HashMap<String, usize>,
    index: GridIndex,
}

impl Track {
    /// Checks the description and builds the geometry and spatial index.
    ///
    /// Refuses duplicate or non-finite nodes, edges naming unknown nodes, zero-length edges,
    /// sweeps outside (-360°, 360°) (a full circle needs two edges) and bad tape widths.
    pub fn new(nodes: Vec<Node>, specs: Vec<EdgeSpec>) -> Result<Track, TrackError> {
        let mut by_id = HashMap::with_capacity(nodes.len());
        for (i, n) in nodes.iter().enumerate() {
            if !(n.position.x.is_finite() && n.position.y.is_finite()) {
                return Err(TrackError::NonFiniteNode {
                    node: i,
                    id: n.id.clone(),
                });
            }
            if by_id.insert(n.id.clone(), i).is_some() {
                return Err(TrackError::DuplicateNode {
                    node: i,
                    id: n.id.clone(),
                });
            }
        }
        let mut edges = Vec::with_capacity(specs.len());
        for (i, spec) in specs.into_iter().enumerate() {
            let lookup = |id: &String, end| {
                by_id.get(id).copied().ok_or(TrackError::UnknownNode {
                    edge: i,
                    end,
                    id: id.clone(),
                })
            };
            let from = lookup(&spec.from, EdgeEnd::From)?;
            let to = lookup(&spec.to, EdgeEnd::To)?;
            if !(spec.turn_deg.is_finite() && spec.turn_deg.abs() < 360.0) {
                return Err(TrackError::BadTurn {
                    edge: i,
                    turn_deg: spec.turn_deg,
                });
            }
            if !(spec.width_m > 0.0 && spec.width_m <= MAX_TAPE_WIDTH_M) {
                return Err(TrackError::BadWidth {
                    edge: i,
                    width_m: spec.width_m,
                });
            }
            let (a, b) = (nodes[from].position, nodes[to].position);
            let shape = Shape::new(a, b, spec.turn_deg);
            if (b - a).norm() < MIN_EDGE_LENGTH_M || !shape.length().is_finite() {
                return Err(TrackError::ZeroLength {
                    edge: i,
                    from: spec.from,
                    to: spec.to,
                });
            }
            let (bound_centre, bound_radius) = bounding_circle(&shape);
            edges.push(Edge {
                from,
                to,
                turn_deg: spec.turn_deg,
                width_m: spec.width_m,
                mark: spec.mark,
                shape,
                bound_centre,
                bound_radius,
            });
        }
        let index = GridIndex::build(&edges);
        Ok(Track {
            nodes,
            edges,
            by_id,
            index,
        })
    }

    /// All nodes, in the order given.
    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }

    /// All edges, in the order given.
    pub fn edges(&self) -> &[Edge] {
        &self.edges
    }

    /// Index of the node called `id`.
    pub fn node_index(&self, id: &str) -> Option<usize> {
        self.by_id.get(id).copied()
    }
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use nalgebra::Vector2;

    use super::index::rect_segment_distance;
    use super::*;

    const EPS: f64 = 1e-9;

    fn p(x: f64, y: f64) -> Point2<f64> {
        Point2::new(x, y)
    }

    /// A straight edge a→b along x, and a left quarter arc b→c of radius 0.2 about (1.0, 0.2).
    fn sample() -> Track {
        Track::new(
            vec![
                Node::new("a", 0.0, 0.0),
                Node::new("b", 1.0, 0.0),
                Node::new("c", 1.2, 0.2),
            ],
            vec![EdgeSpec::straight("a", "b"), EdgeSpec::arc("b", "c", 90.0)],
        )
        .expect("valid sample track")
    }

    #[test]
    fn floor_black_on_tape_centre_and_white_5mm_beside_6mm_tape() {
        let t = sample();
        assert_eq!(t.floor_at(p(0.5, 0.0)), Surface::BLACK);
        assert_eq!(t.floor_at(p(0.5, 0.0029)), Surface::BLACK);
        assert_eq!(t.floor_at(p(0.5, 0.005)), Surface::WHITE);
        assert_eq!(t.floor_at(p(0.5, -0.005)), Surface::WHITE);
        assert_eq!(t.floor_at(p(-5.0, 3.0)), Surface::WHITE);
        assert_eq!(t.floor_at(p(f64::NAN, 0.0)), Surface::WHITE);
    }

    #[test]
    fn floor_follows_the_arc_exactly() {
        let t = sample();
        let centre = p(1.0, 0.2);
        for deg in [-80.0f64, -45.0, -10.0] {
            let u = Vector2::new(deg.to_radians().cos(), deg.to_radians().sin());
            assert_eq!(
                t.floor_at(centre + u * 0.2),
                Surface::BLACK,
                "on arc at {deg}°"
            );
            assert_eq!(
                t.floor_at(centre + u * 0.2028),
                Surface::BLACK,
                "inside tape {deg}°"
            );
            assert_eq!(
                t.floor_at(centre + u * 0.205),
                Surface::WHITE,
                "outside {deg}°"
            );
            assert_eq!(
                t.floor_at(centre + u * 0.195),
                Surface::WHITE,
                "inside {deg}°"
            );
        }
        // Past the arc's end the circle continues on the floor but not on the tape.
        let on_circle =
            centre + Vector2::new(30f64.to_radians().cos(), 30f64.to_radians().sin()) * 0.2;
        assert_eq!(t.floor_at(on_circle), Surface::WHITE);
    }

    #[test]
    fn right_turn_bulges_left_of_its_chord() {
        // A right-turning semicircle from (0, 0) to (0, 1) starts heading -x and swings round
        // through (-0.5, 0.5), like a car turning right out of a westward street.
        let t = Track::new(
            vec![Node::new("a", 0.0, 0.0), Node::new("b", 0.0, 1.0)],
            vec![EdgeSpec::arc("a", "b", -180.0)],
        )
        .expect("valid");
        assert_eq!(t.floor_at(p(-0.5, 0.5)), Surface::BLACK);
        assert_eq!(t.floor_at(p(0.5, 0.5)), Surface::WHITE);
        let (_, tangent) = t.point_at(0, 0.0);
        assert!((tangent - Vector2::new(-1.0, 0.0)).norm() < EPS);
        let (_, tangent) = t.point_at(0, t.edge_length(0));
        assert!((tangent - Vector2::new(1.0, 0.0)).norm() < EPS);
        assert!((t.edge_length(0) - PI * 0.5).abs() < EPS);
    }

    #[test]
    fn an_arcs_distance_without_its_angle_is_the_nearest_points_distance() {
        for turn in [30.0, 90.0, 179.0, 181.0, 270.0, 350.0] {
            for sign in [1.0, -1.0] {
                let shape = Shape::new(p(0.1, 0.2), p(0.3, 0.25), sign * turn);
                for i in 0..4000u32 {
                    let q = p(
                        f64::from(i % 61) / 61.0 * 0.8 - 0.2,
                        f64::from(i % 67) / 67.0 * 0.8 - 0.2,
                    );
                    let (d, reference) = (shape.distance(q), shape.closest(q).1);
                    assert!(
                        (d - reference).abs() < 1e-12,
                        "{turn}° at {q:?}: {d} vs {reference}"
                    );
                }
            }
        }
    }

    #[test]
    fn rect_segment_distance_cases() {
        let (lo, hi) = (p(0.0, 0.0), p(1.0, 1.0));
        assert_eq!(
            rect_segment_distance(lo, hi, p(-1.0, 0.5), p(2.0, 0.5)),
            0.0
        );
        assert_eq!(rect_segment_distance(lo, hi, p(0.5, 0.5), p(0.6, 0.6)), 0.0);
        assert!((rect_segment_distance(lo, hi, p(-1.0, 1.5), p(2.0, 1.5)) - 0.5).abs() < EPS);
        assert!((rect_segment_distance(lo, hi, p(2.0, 0.0), p(0.0, 2.0)) - 0.0).abs() < EPS);
        let d = rect_segment_distance(lo, hi, p(3.0, 0.0), p(0.0, 3.0));
        assert!((d - 0.5f64.sqrt()).abs() < EPS, "{d}");
        assert!(
            (rect_segment_distance(lo, hi, p(3.0, 3.0), p(3.0, 3.0)) - 8f64.sqrt()).abs() < EPS
        );
    }

    #[test]
    fn nearest_and_point_at_round_trip_on_line_and_arc() {
        let t = sample();
        for (edge, offset) in [(0, 0.0), (0, 0.37), (0, 1.0), (1, 0.01), (1, 0.2), (1, 0.3)] {
            let (q, tangent) = t.point_at(edge, offset);
            assert!((tangent.norm() - 1.0).abs() < EPS);
            let normal = Vector2::new(-tangent.y, tangent.x);
            for side in [0.0, 0.004, -0.004] {
                let np = t.nearest(q + normal * side).expect("track has edges");
                assert_eq!(np.edge, edge, "edge at {edge}/{offset}/{side}");
                assert!((np.offset_m - offset).abs() < 1e-9, "offset {np:?}");
                assert!((np.distance_m - side.abs()).abs() < 1e-9, "distance {np:?}");
                assert!((np.point - q).norm() < 1e-9);
                assert!((np.tangent - tangent).norm() < 1e-9);
            }
        }
        assert!((t.edge_length(1) - 0.2 * PI / 2.0).abs() < EPS);
        // Offsets past the end clamp to it.
        assert!((t.point_at(1, 9.0).0 - p(1.2, 0.2)).norm() < EPS);
    }

    #[test]
    fn nearest_off_the_arc_range_is_an_end_point() {
        let t = Track::new(
            vec![Node::new("a", 0.0, 0.0), Node::new("b", 0.2, 0.2)],
            vec![EdgeSpec::arc("a", "b", 90.0)],
        )
        .expect("valid");
        // Below the start point, outside the arc's angular range.
        let np = t.nearest(p(-0.05, -0.1)).expect("edge");
        assert_eq!(np.offset_m, 0.0);
        assert!((np.distance_m - (0.05f64.hypot(0.1))).abs() < EPS);
    }

    #[test]
    fn fork_point_is_dark_and_darkest_tape_wins() {
        let t = Track::new(
            vec![
                Node::new("f", 0.0, 0.0),
                Node::new("main", 0.5, 0.0),
                Node::new("branch", 0.3, 0.1),
                Node::new("r", 0.0, 0.3),
                Node::new("s", 0.5, 0.3),
            ],
            vec![
                EdgeSpec::straight("f", "main").with_mark(Mark::Blue),
                EdgeSpec::arc("f", "branch", 30.0),
                EdgeSpec::straight("r", "s").with_mark(Mark::Red),
            ],
        )
        .expect("valid");
        assert_eq!(t.floor_at(p(0.0, 0.0)), Surface::BLACK);
        assert_eq!(t.floor_at(p(0.01, 0.0)), Surface::BLACK);
        assert_eq!(t.floor_at(p(0.4, 0.0)), Surface::BLUE);
        assert_eq!(t.floor_at(p(0.25, 0.3)), Surface::RED);
    }

    #[test]
    fn bad_edges_are_refused() {
        let nodes = || vec![Node::new("a", 0.0, 0.0), Node::new("b", 1.0, 0.0)];
        let err = |spec| Track::new(nodes(), vec![spec]).unwrap_err();
        assert!(matches!(
            err(EdgeSpec::straight("a", "c")),
            TrackError::UnknownNode {
                edge: 0,
                end: EdgeEnd::To,
                ..
            }
        ));
        assert!(matches!(
            err(EdgeSpec::straight("a", "a")),
            TrackError::ZeroLength { .. }
        ));
        assert!(matches!(
            err(EdgeSpec::arc("a", "b", 360.0)),
            TrackError::BadTurn { .. }
        ));
        assert!(matches!(
            err(EdgeSpec::arc("a", "b", f64::NAN)),
            TrackError::BadTurn { .. }
        ));
        let mut wide = EdgeSpec::straight("a", "b");
        wide.width_m = 6.0;
        assert!(matches!(err(wide), TrackError::BadWidth { .. }));
        let dup = Track::new(
            vec![Node::new("a", 0.0, 0.0), Node::new("a", 1.0, 0.0)],
            vec![],
        );
        assert!(matches!(
            dup,
            Err(TrackError::DuplicateNode { node: 1, .. })
        ));
    }

    #[test]
    fn huge_tracks_get_coarser_cells_without_failing() {
        let t = Track::new(
            vec![Node::new("a", 0.0, 0.0), Node::new("b", 1e5, 0.0)],
            vec![EdgeSpec::straight("a", "b")],
        )
        .expect("valid");
        let stats = t.index_stats();
        assert!(stats.cols * stats.rows <= MAX_INDEX_CELLS, "{stats:?}");
        assert_eq!(t.floor_at(p(5e4, 0.001)), Surface::BLACK);
        assert_eq!(t.floor_at(p(5e4, 0.004)), Surface::WHITE);
        for far in [1e300, f64::MAX] {
            let t = Track::new(
                vec![Node::new("a", -far, 0.0), Node::new("b", far, 1.0)],
                vec![EdgeSpec::arc("a", "b", 10.0)],
            );
            if let Ok(t) = t {
                let _ = t.floor_at(p(0.0, 0.0));
                let _ = t.nearest(p(0.0, 0.0));
            }
        }
    }

    #[test]
    fn polyline_of_arc_stays_on_the_arc() {
        let t = sample();
        let pts = t.polyline(1, 0.01);
        assert!(pts.len() >= 33, "0.314 m at 1 cm steps");
        assert!((pts[0] - p(1.0, 0.0)).norm() < EPS);
        assert!((pts[pts.len() - 1] - p(1.2, 0.2)).norm() < EPS);
        for q in &pts {
            assert!(((q - p(1.0, 0.2)).norm() - 0.2).abs() < EPS);
        }
        assert_eq!(t.polyline(0, 0.01).len(), 2);
        assert!(t.polyline(1, -1.0).len() >= 2);
    }

    /// The darkest tape at `q` found by testing every edge exactly, without the index.
    fn brute_force_floor(t: &Track, q: Point2<f64>) -> Surface {
        t.edges
            .iter()
            .filter(|e| e.shape.closest(q).1 <= e.width_m / 2.0)
            .map(Edge::surface)
            .fold(Surface::WHITE, |a, b| {
                if b.ir_reflectance < a.ir_reflectance {
                    b
                } else {
                    a
                }
            })
    }

    #[test]
    fn index_agrees_with_brute_force_on_every_preset() {
        // The grid preset is left out to keep the test quick: its straight edges take the
        // same path as the straights here.
        for name in ["oval", "push", "junction"] {
            let w = crate::presets::preset(name).expect("preset parses");
            let mut x = 0.0;
            while x < w.arena.width_m {
                let mut y = 0.0;
                while y < w.arena.height_m {
                    let q = p(x, y);
                    let (s, cost) = w.track.floor_at_counted(q);
                    assert_eq!(s, brute_force_floor(&w.track, q), "{name} at {q}");
                    assert!(cost.cells_visited <= 1);
                    y += 0.0009;
                }
                x += 0.0023;
            }
        }
    }

    #[test]
    fn index_covers_every_tape_point_from_one_cell() {
        // Compare the indexed answer with a brute-force exact test on a dense lattice.
        let t = sample();
        let mut x = -0.02;
        while x < 1.25 {
            let mut y = -0.02;
            while y < 0.25 {
                let q = p(x, y);
                let brute = t
                    .edges
                    .iter()
                    .any(|e| e.shape.closest(q).1 <= e.width_m / 2.0);
                let (s, cost) = t.floor_at_counted(q);
                assert_eq!(s == Surface::BLACK, brute, "at {q}");
                assert!(cost.cells_visited <= 1);
                y += 0.0007;
            }
            x += 0.0013;
        }
    }

    #[test]
    fn indexed_nearest_agrees_with_the_scan_on_every_preset() {
        for name in ["oval", "push", "junction", "grid"] {
            let w = crate::presets::preset(name).expect("preset parses");
            let mut x = -0.1;
            while x < w.arena.width_m + 0.1 {
                let mut y = -0.1;
                while y < w.arena.height_m + 0.1 {
                    let q = p(x, y);
                    let (a, b) = (w.track.nearest(q), w.track.nearest_scan(q));
                    let key = |t: Option<TrackPoint>| t.map(|t| (t.edge, t.offset_m, t.distance_m));
                    assert_eq!(key(a), key(b), "{name} at {q}");
                    y += 0.0071;
                }
                x += 0.0093;
            }
        }
    }
}
