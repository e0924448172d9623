//! Tape geometry: a graph of straight and circular-arc tape pieces laid on a white floor, with a
//! uniform-grid spatial index so the floor under a sensor spot is found by looking at one cell.

use std::collections::HashMap;
use std::f64::consts::{PI, TAU};

use nalgebra::{Point2, Vector2};
use serde::{Deserialize, Serialize};

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

/// A turn smaller than this is drawn as a straight line: the radius would overflow precision.
const STRAIGHT_TURN_DEG: f64 = 1e-6;

/// Largest angle of one index chord. Keeps the chord's sagitta below 0.1 % of the radius.
const INDEX_CHORD_RAD: f64 = 5.0 * PI / 180.0;

/// Colour mark of a whole edge. The firmware's colour sensor treats red as "slow down" and blue as
/// "speed up" (`protocol::packets::Mark`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mark {
    /// Red tape.
    Red,
    /// Blue tape.
    Blue,
}

/// What a downward-looking sensor sees at one point of the floor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surface {
    /// Fraction of infrared light reflected: white floor 1.0, black tape 0.08, coloured marks 0.35
    /// (darker than the floor, so the IR line sensor still sees them as line).
    pub ir_reflectance: f32,
    /// Visible colour as linear RGB in 0..=1, for the colour sensor and for drawing.
    pub rgb: [f32; 3],
}

impl Surface {
    /// Bare white floor.
    pub const WHITE: Surface = Surface {
        ir_reflectance: 1.0,
        rgb: [1.0, 1.0, 1.0],
    };
    /// Plain black tape.
    pub const BLACK: Surface = Surface {
        ir_reflectance: 0.08,
        rgb: [0.05, 0.05, 0.05],
    };
    /// Red mark.
    pub const RED: Surface = Surface {
        ir_reflectance: 0.35,
        rgb: [0.8, 0.1, 0.1],
    };
    /// Blue mark.
    pub const BLUE: Surface = Surface {
        ir_reflectance: 0.35,
        rgb: [0.1, 0.2, 0.8],
    };

    /// The tape surface of an edge with this mark.
    pub const fn of_tape(mark: Option<Mark>) -> Surface {
        match mark {
            None => Surface::BLACK,
            Some(Mark::Red) => Surface::RED,
            Some(Mark::Blue) => Surface::BLUE,
        }
    }
}

/// A named point of the track where edges start or end.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    /// Name used by edges, world files and the coordinator.
    pub id: String,
    /// Position on the floor in metres.
    pub position: Point2<f64>,
}

impl Node {
    /// A node called `id` at (`x`, `y`) metres.
    pub fn new(id: impl Into<String>, x: f64, y: f64) -> Self {
        Node {
            id: id.into(),
            position: Point2::new(x, y),
        }
    }
}

/// An edge as described by a user, naming its end nodes; [`Track::new`] resolves and checks it.
#[derive(Clone, Debug, PartialEq)]
pub struct EdgeSpec {
    /// Id of the start node.
    pub from: String,
    /// Id of the end node.
    pub to: String,
    /// Signed sweep of the arc from `from` to `to` in degrees, positive = turning left
    /// (counter-clockwise); 0 is a straight line. Must lie strictly between -360 and 360.
    pub turn_deg: f64,
    /// Tape width in metres.
    pub width_m: f64,
    /// Colour of the whole edge; `None` is black tape.
    pub mark: Option<Mark>,
}

impl EdgeSpec {
    /// A straight black edge of the default width.
    pub fn straight(from: impl Into<String>, to: impl Into<String>) -> Self {
        Self::arc(from, to, 0.0)
    }

    /// A black arc of the default width sweeping `turn_deg` (positive = left) from `from` to `to`.
    pub fn arc(from: impl Into<String>, to: impl Into<String>, turn_deg: f64) -> Self {
        EdgeSpec {
            from: from.into(),
            to: to.into(),
            turn_deg,
            width_m: DEFAULT_TAPE_WIDTH_M,
            mark: None,
        }
    }

    /// The same edge with a colour mark.
    pub fn with_mark(mut self, mark: Mark) -> Self {
        self.mark = Some(mark);
        self
    }
}

/// Which end of an edge a problem concerns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EdgeEnd {
    /// The `from` end.
    From,
    /// The `to` end.
    To,
}

/// Why a track description was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TrackError {
    /// Two nodes share an id.
    #[error("node {node} repeats the id \"{id}\" of an earlier node")]
    DuplicateNode {
        /// Index of the later node.
        node: usize,
        /// The repeated id.
        id: String,
    },
    /// A node position is NaN or infinite.
    #[error("node {node} (\"{id}\") has a position that is not a finite number")]
    NonFiniteNode {
        /// Index of the node.
        node: usize,
        /// Its id.
        id: String,
    },
    /// An edge names a node that does not exist.
    #[error("edge {edge} refers to unknown node \"{id}\"")]
    UnknownNode {
        /// Index of the edge.
        edge: usize,
        /// Which end names the node.
        end: EdgeEnd,
        /// The unknown id.
        id: String,
    },
    /// An edge's ends coincide, so it has no length and no direction.
    #[error("edge {edge} has zero length: its end nodes \"{from}\" and \"{to}\" coincide")]
    ZeroLength {
        /// Index of the edge.
        edge: usize,
        /// Id of its start node.
        from: String,
        /// Id of its end node.
        to: String,
    },
    /// An arc sweep outside (-360, 360) or not a number.
    #[error("edge {edge} has turn_deg = {turn_deg}; it must lie strictly between -360 and 360")]
    BadTurn {
        /// Index of the edge.
        edge: usize,
        /// The refused sweep.
        turn_deg: f64,
    },
    /// A tape width that is not positive, or wider than [`MAX_TAPE_WIDTH_M`].
    #[error("edge {edge} has width_m = {width_m}; it must be above 0 and at most {MAX_TAPE_WIDTH_M} (metres)")]
    BadWidth {
        /// Index of the edge.
        edge: usize,
        /// The refused width.
        width_m: f64,
    },
}

/// Exact shape of an edge, cached at construction.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Shape {
    Line {
        start: Point2<f64>,
        /// Unit direction from start to end.
        dir: Vector2<f64>,
        length: f64,
    },
    Arc {
        centre: Point2<f64>,
        radius: f64,
        /// Polar angle of the start point around the centre.
        start_angle: f64,
        /// Signed sweep in radians, positive = counter-clockwise.
        sweep: f64,
        /// Start and end points, as [`point_at`](Shape::point_at) gives them: the floor's tests
        /// need the arc's angular range without an arctangent per query.
        ends: [Point2<f64>; 2],
    },
}

impl Shape {
    fn new(a: Point2<f64>, b: Point2<f64>, turn_deg: f64) -> Shape {
        let chord = b - a;
        let c = chord.norm();
        if turn_deg.abs() < STRAIGHT_TURN_DEG {
            return Shape::Line {
                start: a,
                dir: chord / c,
                length: c,
            };
        }
        let sweep = turn_deg.to_radians();
        let radius = c / (2.0 * (sweep / 2.0).sin().abs());
        let left = Vector2::new(-chord.y, chord.x) / c;
        // Signed distance of the centre from the chord's midpoint along its left normal: a left
        // turn under 180° has its centre on the left, a larger one on the right, and a right turn
        // mirrors both.
        let centre = nalgebra::center(&a, &b) + left * (c / 2.0 / (sweep / 2.0).tan());
        let v = a - centre;
        let arc = |ends| Shape::Arc {
            centre,
            radius,
            start_angle: v.y.atan2(v.x),
            sweep,
            ends,
        };
        // The ends as the arc itself puts them, a few ulps from the nodes.
        let draft = arc([a, b]);
        arc([draft.point_at(0.0).0, draft.point_at(draft.length()).0])
    }

    fn length(&self) -> f64 {
        match *self {
            Shape::Line { length, .. } => length,
            Shape::Arc { radius, sweep, .. } => radius * sweep.abs(),
        }
    }

    /// Point and unit tangent at arc length `s` (already clamped) from the start.
    fn point_at(&self, s: f64) -> (Point2<f64>, Vector2<f64>) {
        match *self {
            Shape::Line { start, dir, .. } => (start + dir * s, dir),
            Shape::Arc {
                centre,
                radius,
                start_angle,
                sweep,
                ..
            } => {
                let sign = sweep.signum();
                let phi = start_angle + sign * s / radius;
                let (sin, cos) = phi.sin_cos();
                (
                    centre + Vector2::new(cos, sin) * radius,
                    Vector2::new(-sin, cos) * sign,
                )
            }
        }
    }

    /// Exact nearest point: (arc length from the start, distance, point).
    fn closest(&self, p: Point2<f64>) -> (f64, f64, Point2<f64>) {
        match *self {
            Shape::Line { start, dir, length } => {
                let s = (p - start).dot(&dir).clamp(0.0, length);
                let q = start + dir * s;
                (s, (p - q).norm(), q)
            }
            Shape::Arc {
                centre,
                radius,
                start_angle,
                sweep,
                ..
            } => {
                let v = p - centre;
                let r = v.norm();
                let length = radius * sweep.abs();
                if r > 0.0 {
                    let along = ((v.y.atan2(v.x) - start_angle) * sweep.signum()).rem_euclid(TAU);
                    if along <= sweep.abs() {
                        return (
                            along * radius,
                            (r - radius).abs(),
                            centre + v * (radius / r),
                        );
                    }
                }
                // Off the arc's angular range (or at the centre, where every arc point is equally
                // near): the nearer end point is the answer.
                let (a, _) = self.point_at(0.0);
                let (b, _) = self.point_at(length);
                let (da, db) = ((p - a).norm(), (p - b).norm());
                if da <= db {
                    (0.0, da, a)
                } else {
                    (length, db, b)
                }
            }
        }
    }

    /// Whether `p` lies within `half_width` of the centre line. Same answer as `closest`, but
    /// cheaper on the hot path: most probes fail the radial test before any trigonometry.
    fn covers(&self, p: Point2<f64>, half_width: f64) -> bool {
        match *self {
            Shape::Line { start, dir, length } => {
                let w = p - start;
                let s = w.dot(&dir).clamp(0.0, length);
                (w - dir * s).norm_squared() <= half_width * half_width
            }
            Shape::Arc { centre, radius, .. } => {
                if ((p - centre).norm() - radius).abs() > half_width {
                    return false;
                }
                self.distance(p) <= half_width
            }
        }
    }

    /// A radius around `p` within which [`covers`](Self::covers) keeps its answer: how far the
    /// distance to the centre line is from `half_width`, at most (the distance moves no faster
    /// than the point, so it cannot cross `half_width` sooner). Never more than the true margin.
    ///
    /// Returned with [`covers`](Self::covers)'s answer, worked out from the same distance.
    fn cover_margin(&self, p: Point2<f64>, half_width: f64) -> (bool, f64) {
        match *self {
            Shape::Line { start, dir, length } => {
                let w = p - start;
                let s = w.dot(&dir).clamp(0.0, length);
                let d2 = (w - dir * s).norm_squared();
                (
                    d2 <= half_width * half_width,
                    (d2.sqrt() - half_width).abs(),
                )
            }
            Shape::Arc { centre, radius, .. } => {
                // The whole circle is at least as near as the arc, so off its ring the arc is
                // farther still and no angle needs working out.
                let ring = ((p - centre).norm() - radius).abs();
                if ring > half_width {
                    return (false, ring - half_width);
                }
                let d = self.distance(p);
                (d <= half_width, (d - half_width).abs())
            }
        }
    }

    /// Distance from `p` to the centre line, as [`closest`](Self::closest) gives it, without the
    /// arc length and so without an arctangent: whether `p` lies in an arc's angular range is a
    /// matter of which side of its end radii it is on.
    fn distance(&self, p: Point2<f64>) -> f64 {
        match *self {
            Shape::Line { .. } => self.closest(p).1,
            Shape::Arc {
                centre,
                radius,
                sweep,
                ends: [a, b],
                ..
            } => {
                let v = p - centre;
                let r = v.norm();
                // Counter-clockwise from the start radius, and clockwise from the end radius,
                // in the arc's own sense of turning.
                let sign = sweep.signum();
                let (ua, ub) = (a - centre, b - centre);
                let after_start = (ua.x * v.y - ua.y * v.x) * sign >= 0.0;
                let before_end = (v.x * ub.y - v.y * ub.x) * sign >= 0.0;
                let within = if sweep.abs() <= PI {
                    after_start && before_end
                } else {
                    after_start || before_end
                };
                if r > 0.0 && within {
                    (r - radius).abs()
                } else {
                    (p - a).norm().min((p - b).norm())
                }
            }
        }
    }

    /// `n + 1` points splitting the edge into `n` equal pieces.
    fn samples(&self, n: usize) -> impl Iterator<Item = Point2<f64>> + '_ {
        let length = self.length();
        (0..=n).map(move |i| self.point_at(length * i as f64 / n as f64).0)
    }

    /// Number of index/drawing chords: none longer than `max_len`, none wider than
    /// [`INDEX_CHORD_RAD`] of arc.
    fn chord_count(&self, max_len: f64) -> usize {
        let by_length = (self.length() / max_len).ceil();
        let by_angle = match *self {
            Shape::Line { .. } => 1.0,
            Shape::Arc { sweep, .. } => (sweep.abs() / INDEX_CHORD_RAD).ceil(),
        };
        // Bounded so a tiny step can never ask for an absurd allocation.
        by_length.max(by_angle).clamp(1.0, 100_000.0) as usize
    }

    /// Largest distance between the arc and a chord of `n` equal pieces.
    fn sagitta(&self, n: usize) -> f64 {
        match *self {
            Shape::Line { .. } => 0.0,
            Shape::Arc { radius, sweep, .. } => {
                radius * (1.0 - (sweep.abs() / n as f64 / 2.0).cos())
            }
        }
    }
}

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

/// The point of a track nearest to a query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackPoint {
    /// Index of the edge in [`Track::edges`].
    pub edge: usize,
    /// Arc length from the edge's `from` node to `point`, in metres.
    pub offset_m: f64,
    /// Distance from the query point to `point`, in metres.
    pub distance_m: f64,
    /// The nearest point on the tape's centre line.
    pub point: Point2<f64>,
    /// Unit tangent at `point`, pointing from the edge's `from` node towards its `to` node.
    pub tangent: Vector2<f64>,
}

/// Work done by one floor query, to check the spatial index without timing anything.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct QueryCost {
    /// Index cells looked at: 1 on the tape's bounding box, 0 outside it.
    pub cells_visited: usize,
    /// Edges whose exact geometry was tested.
    pub edges_tested: usize,
}

/// Shape of the spatial index, for diagnostics and tests.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexStats {
    /// Side of one cell in metres.
    pub cell_m: f64,
    /// Cells along x.
    pub cols: usize,
    /// Cells along y.
    pub rows: usize,
    /// Most edges listed by any one cell.
    pub max_edges_per_cell: usize,
    /// Sum over cells of edges listed.
    pub entries: usize,
}

/// Uniform grid over the tape's bounding box. Each cell lists every edge whose tape can reach any
/// point of the cell, so a query needs exactly one cell and no neighbours.
#[derive(Clone, Debug, Default)]
struct GridIndex {
    origin: Point2<f64>,
    cell: f64,
    cols: usize,
    rows: usize,
    /// Cell `i` lists `items[starts[i]..starts[i + 1]]`.
    starts: Vec<u32>,
    items: Vec<u32>,
    /// The tape of each of `items`, side by side in cell order: a floor query reads one short
    /// run of memory instead of edges scattered over the whole track.
    tapes: Vec<CellTape>,
}

/// What a floor query needs of one edge listed in a cell.
#[derive(Clone, Copy, Debug, PartialEq)]
struct CellTape {
    shape: Shape,
    half_width_m: f64,
    surface: Surface,
}

impl GridIndex {
    fn build(edges: &[Edge]) -> GridIndex {
        let mut lo = Point2::new(f64::INFINITY, f64::INFINITY);
        let mut hi = Point2::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
        for e in edges {
            let reach = e.bound_radius + e.width_m / 2.0;
            lo = lo.inf(&(e.bound_centre - Vector2::repeat(reach)));
            hi = hi.sup(&(e.bound_centre + Vector2::repeat(reach)));
        }
        if edges.is_empty() || ![lo.x, lo.y, hi.x, hi.y].iter().all(|v| v.is_finite()) {
            return GridIndex::default();
        }
        let size = hi - lo;
        let mut cell = INDEX_CELL_M;
        // Doubling ends even for absurd extents: once the cell is infinite the product is NaN.
        while (size.x / cell + 2.0) * (size.y / cell + 2.0) > MAX_INDEX_CELLS as f64 {
            cell *= 2.0;
        }
        // Hand-made tracks put tapes on round coordinates. Cell borders halfway between
        // multiples of the cell size keep such a tape inside one row or column of cells instead
        // of straddling two, which halves the edges a typical cell lists.
        let snap = |v: f64| ((v / cell - 0.5).floor() + 0.5) * cell;
        let lo = Point2::new(snap(lo.x), snap(lo.y));
        let size = hi - lo;
        // Saturating casts: NaN gives 0, so an absurd track gets one cell rather than a panic.
        let cols = ((size.x / cell).floor() as usize).saturating_add(1);
        let rows = ((size.y / cell).floor() as usize).saturating_add(1);

        let mut pairs: Vec<(u32, u32)> = Vec::new();
        for (ei, e) in edges.iter().enumerate() {
            let n = e.shape.chord_count(cell);
            let reach = e.width_m / 2.0 + e.shape.sagitta(n) + 1e-9;
            let pts: Vec<Point2<f64>> = e.shape.samples(n).collect();
            for w in pts.windows(2) {
                let (a, b) = (w[0], w[1]);
                let c0 = ((a.x.min(b.x) - reach - lo.x) / cell).floor().max(0.0) as usize;
                let c1 = (((a.x.max(b.x) + reach - lo.x) / cell).floor() as usize).min(cols - 1);
                let r0 = ((a.y.min(b.y) - reach - lo.y) / cell).floor().max(0.0) as usize;
                let r1 = (((a.y.max(b.y) + reach - lo.y) / cell).floor() as usize).min(rows - 1);
                for row in r0..=r1 {
                    for col in c0..=c1 {
                        let min = lo + Vector2::new(col as f64 * cell, row as f64 * cell);
                        let max = min + Vector2::repeat(cell);
                        // Any point of the arc is within the sagitta of its chord, so this lists
                        // every cell the tape can reach, and few more.
                        if rect_segment_distance(min, max, a, b) <= reach {
                            pairs.push(((row * cols + col) as u32, ei as u32));
                        }
                    }
                }
            }
        }
        pairs.sort_unstable();
        pairs.dedup();
        let mut starts = vec![0u32; cols * rows + 1];
        for &(c, _) in &pairs {
            starts[c as usize + 1] += 1;
        }
        for i in 0..cols * rows {
            starts[i + 1] += starts[i];
        }
        let items: Vec<u32> = pairs.into_iter().map(|(_, e)| e).collect();
        let tapes = items
            .iter()
            .map(|&ei| {
                let e = &edges[ei as usize];
                CellTape {
                    shape: e.shape,
                    half_width_m: e.width_m / 2.0,
                    surface: e.surface(),
                }
            })
            .collect();
        GridIndex {
            origin: lo,
            cell,
            cols,
            rows,
            starts,
            items,
            tapes,
        }
    }

    /// The index cell holding `p`; `None` off the grid.
    fn cell_of(&self, p: Point2<f64>) -> Option<usize> {
        self.column_row_of(p)
            .map(|(col, row)| row * self.cols + col)
    }

    /// Column and row of the index cell holding `p`; `None` off the grid.
    fn column_row_of(&self, p: Point2<f64>) -> Option<(usize, usize)> {
        let fx = (p.x - self.origin.x) / self.cell;
        let fy = (p.y - self.origin.y) / self.cell;
        // Written so NaN also lands here: it fails every comparison.
        if !(fx >= 0.0 && fy >= 0.0 && fx < self.cols as f64 && fy < self.rows as f64) {
            return None;
        }
        Some((fx as usize, fy as usize))
    }

    /// Distance from `p` to the nearest side of the cell at `col`, `row`, which holds it.
    fn inside_margin(&self, (col, row): (usize, usize), p: Point2<f64>) -> f64 {
        let x0 = self.origin.x + col as f64 * self.cell;
        let y0 = self.origin.y + row as f64 * self.cell;
        (p.x - x0)
            .min(x0 + self.cell - p.x)
            .min(p.y - y0)
            .min(y0 + self.cell - p.y)
    }

    /// Distance from `p`, off the grid, to the grid (0 for NaN).
    fn outside_margin(&self, p: Point2<f64>) -> f64 {
        let min = self.origin;
        let max = min + Vector2::new(self.cols as f64, self.rows as f64) * self.cell;
        let d = (p - p.sup(&min).inf(&max)).norm();
        if d.is_nan() {
            0.0
        } else {
            d
        }
    }

    /// The tapes reaching into cell `i` (empty for a cell out of range).
    fn tapes_in(&self, i: usize) -> &[CellTape] {
        match (self.starts.get(i), self.starts.get(i + 1)) {
            (Some(&a), Some(&b)) => self.tapes.get(a as usize..b as usize).unwrap_or(&[]),
            _ => &[],
        }
    }
}

/// A margin made safe against rounding: the distances it came from and the tests it stands for
/// are each a few ulps of a coordinate off, far below a nanometre on any floor.
fn shrink(margin: f64) -> f64 {
    (margin - 1e-9).max(0.0)
}

/// The darkest of `tapes` covering `p` (white if none), counting the edges whose geometry it tested.
fn darkest_covering(tapes: &[CellTape], p: Point2<f64>, cost: &mut QueryCost) -> Surface {
    let mut best = Surface::WHITE;
    for t in tapes {
        let tape = t.surface;
        // Only a darker tape can change the answer, so skip the geometry otherwise.
        if tape.ir_reflectance >= best.ir_reflectance {
            continue;
        }
        cost.edges_tested += 1;
        if t.shape.covers(p, t.half_width_m) {
            best = tape;
            if best == Surface::BLACK {
                break;
            }
        }
    }
    best
}

/// Distance between the axis-aligned box from `min` to `max` and the segment a–b: zero if they meet,
/// else attained between a vertex of one and a side of the other.
fn rect_segment_distance(
    min: Point2<f64>,
    max: Point2<f64>,
    a: Point2<f64>,
    b: Point2<f64>,
) -> f64 {
    if segment_meets_rect(min, max, a, b) {
        return 0.0;
    }
    let to_rect = |p: Point2<f64>| (p - p.sup(&min).inf(&max)).norm();
    let corners = [
        min,
        Point2::new(max.x, min.y),
        max,
        Point2::new(min.x, max.y),
    ];
    corners
        .iter()
        .map(|&c| segment_distance(c, a, b))
        .fold(to_rect(a).min(to_rect(b)), f64::min)
}

/// Liang–Barsky clipping: whether any part of the segment a–b lies in the box.
fn segment_meets_rect(min: Point2<f64>, max: Point2<f64>, a: Point2<f64>, b: Point2<f64>) -> bool {
    let d = b - a;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [
        (-d.x, a.x - min.x),
        (d.x, max.x - a.x),
        (-d.y, a.y - min.y),
        (d.y, max.y - a.y),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return false;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
            if t0 > t1 {
                return false;
            }
        }
    }
    true
}

fn segment_distance(p: Point2<f64>, a: Point2<f64>, b: Point2<f64>) -> f64 {
    let ab = b - a;
    let len2 = ab.norm_squared();
    let t = if len2 > 0.0 {
        ((p - a).dot(&ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + ab * t)).norm()
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

    /// What the floor looks like at `p`. Where tapes overlap (forks, merges, crossings) the
    /// darkest one wins. Looks at one index cell.
    pub fn floor_at(&self, p: Point2<f64>) -> Surface {
        self.floor_at_counted(p).0
    }

    /// [`floor_at`](Self::floor_at) together with the work it did, for checking the index.
    pub fn floor_at_counted(&self, p: Point2<f64>) -> (Surface, QueryCost) {
        let mut cost = QueryCost::default();
        let Some(cell) = self.index.cell_of(p) else {
            return (Surface::WHITE, cost);
        };
        cost.cells_visited = 1;
        let best = darkest_covering(self.index.tapes_in(cell), p, &mut cost);
        (best, cost)
    }

    /// [`floor_at`](Self::floor_at) for each of `points`, with the same answers; points that share
    /// an index cell (a line sensor's spots, a few millimetres apart) share its lookup.
    pub fn floor_at_each<const N: usize>(&self, points: &[Point2<f64>; N]) -> [Surface; N] {
        let mut out = [Surface::WHITE; N];
        let mut cached: Option<(usize, &[CellTape])> = None;
        let mut cost = QueryCost::default();
        for (p, s) in points.iter().zip(&mut out) {
            let Some(cell) = self.index.cell_of(*p) else {
                continue;
            };
            let tapes = match cached {
                Some((c, t)) if c == cell => t,
                _ => {
                    let t = self.index.tapes_in(cell);
                    cached = Some((cell, t));
                    t
                }
            };
            *s = darkest_covering(tapes, *p, &mut cost);
        }
        out
    }

    /// [`floor_at`](Self::floor_at) and a radius around `p` within which every point has that
    /// same floor, so a sensor that moved less than the radius since it last looked need not look
    /// again. The radius is 0 where `p` is on a tape's border or nothing can be said.
    pub fn floor_at_within(&self, p: Point2<f64>) -> (Surface, f64) {
        let Some((col, row)) = self.index.column_row_of(p) else {
            // Off the grid every point is white, as far as the grid.
            return (Surface::WHITE, shrink(self.index.outside_margin(p)));
        };
        let tapes = self.index.tapes_in(row * self.index.cols + col);
        // Within the cell every point sees the same tapes; within each tape's margin each tape
        // covers it or not as it does `p`, so the darkest covering one is the same too. Chosen
        // as `darkest_covering` chooses, down to stopping at black.
        let mut margin = self.index.inside_margin((col, row), p);
        let mut best = Surface::WHITE;
        for t in tapes {
            let (covered, m) = t.shape.cover_margin(p, t.half_width_m);
            margin = margin.min(m);
            if covered && best != Surface::BLACK && t.surface.ir_reflectance < best.ir_reflectance {
                best = t.surface;
            }
        }
        (best, shrink(margin))
    }

    /// Nearest point of any edge's centre line to `p`; `None` for a track without edges. Where
    /// two edges are equally near, the one given first wins.
    ///
    /// Searches the index's cells in rings around `p` and stops once no unvisited cell can hold a
    /// nearer centre line, so a query near the tape looks at a few edges on any size of track.
    pub fn nearest(&self, p: Point2<f64>) -> Option<TrackPoint> {
        let idx = &self.index;
        let fx = (p.x - idx.origin.x) / idx.cell;
        let fy = (p.y - idx.origin.y) / idx.cell;
        // Off the grid (or NaN) there is no ring to start from: every edge is far anyway.
        if !(fx >= 0.0 && fy >= 0.0 && fx < idx.cols as f64 && fy < idx.rows as f64) {
            return self.nearest_scan(p);
        }
        let (cx, cy) = (fx as usize, fy as usize);
        let mut best: Option<TrackPoint> = None;
        for k in 0usize.. {
            let (c0, c1) = (cx.saturating_sub(k), (cx + k).min(idx.cols - 1));
            let (r0, r1) = (cy.saturating_sub(k), (cy + k).min(idx.rows - 1));
            for row in r0..=r1 {
                let on_ring_row = row + k == cy || row == cy + k;
                for col in c0..=c1 {
                    if !on_ring_row && col + k != cx && col != cx + k {
                        continue;
                    }
                    let i = row * idx.cols + col;
                    let (a, b) = (idx.starts[i] as usize, idx.starts[i + 1] as usize);
                    for &ei in &idx.items[a..b] {
                        self.consider(ei as usize, p, &mut best);
                    }
                }
            }
            // Every centre line point outside rings 0..=k is at least k cells from `p`.
            let bound = k as f64 * idx.cell;
            let whole_grid = c0 == 0 && r0 == 0 && c1 == idx.cols - 1 && r1 == idx.rows - 1;
            if whole_grid || best.as_ref().is_some_and(|b| b.distance_m < bound) {
                break;
            }
        }
        best
    }

    /// [`nearest`](Self::nearest) by testing every edge, pruned by bounding circles: the
    /// reference the index is checked and benchmarked against.
    pub fn nearest_scan(&self, p: Point2<f64>) -> Option<TrackPoint> {
        let mut best: Option<TrackPoint> = None;
        for i in 0..self.edges.len() {
            self.consider(i, p, &mut best);
        }
        best
    }

    /// Makes edge `i` the `best` if it is nearer to `p`, or as near and given earlier.
    fn consider(&self, i: usize, p: Point2<f64>, best: &mut Option<TrackPoint>) {
        let e = &self.edges[i];
        if let Some(b) = best {
            if (p - e.bound_centre).norm() - e.bound_radius > b.distance_m {
                return;
            }
        }
        let (offset_m, distance_m, point) = e.shape.closest(p);
        let better = best.as_ref().is_none_or(|b| {
            distance_m < b.distance_m || (distance_m == b.distance_m && i < b.edge)
        });
        if better {
            let (_, tangent) = e.shape.point_at(offset_m);
            *best = Some(TrackPoint {
                edge: i,
                offset_m,
                distance_m,
                point,
                tangent,
            });
        }
    }

    /// The point of edge `edge` nearest to `p` (like [`nearest`](Self::nearest), restricted to
    /// one edge), for following a chosen edge where several meet.
    ///
    /// # Panics
    /// If `edge` is not an index into [`edges`](Self::edges), like slice indexing.
    pub fn nearest_on(&self, edge: usize, p: Point2<f64>) -> TrackPoint {
        let e = &self.edges[edge];
        let (offset_m, distance_m, point) = e.shape.closest(p);
        let (_, tangent) = e.shape.point_at(offset_m);
        TrackPoint {
            edge,
            offset_m,
            distance_m,
            point,
            tangent,
        }
    }

    /// Length of edge `edge`'s centre line in metres.
    ///
    /// # Panics
    /// If `edge` is not an index into [`edges`](Self::edges), like slice indexing.
    pub fn edge_length(&self, edge: usize) -> f64 {
        self.edges[edge].length_m()
    }

    /// Point and unit tangent (towards the `to` node) at `offset_m` metres along edge `edge` from
    /// its `from` node; the offset is clamped to the edge.
    ///
    /// # Panics
    /// If `edge` is not an index into [`edges`](Self::edges), like slice indexing.
    pub fn point_at(&self, edge: usize, offset_m: f64) -> (Point2<f64>, Vector2<f64>) {
        let shape = &self.edges[edge].shape;
        // NaN clamps to NaN, so it is mapped to the start explicitly.
        let s = if offset_m.is_nan() {
            0.0
        } else {
            offset_m.clamp(0.0, shape.length())
        };
        shape.point_at(s)
    }

    /// Points along edge `edge` from its `from` to its `to` node, at most `max_step_m` apart and
    /// never more than 5° of arc apart, for drawing. A straight edge gives its two ends.
    ///
    /// # Panics
    /// If `edge` is not an index into [`edges`](Self::edges), like slice indexing.
    pub fn polyline(&self, edge: usize, max_step_m: f64) -> Vec<Point2<f64>> {
        let shape = &self.edges[edge].shape;
        let step = if max_step_m > 0.0 {
            max_step_m
        } else {
            f64::INFINITY
        };
        let n = match shape {
            Shape::Line { .. } => 1,
            Shape::Arc { .. } => shape.chord_count(step),
        };
        shape.samples(n).collect()
    }

    /// Shape of the spatial index.
    pub fn index_stats(&self) -> IndexStats {
        let idx = &self.index;
        let max_edges_per_cell = idx
            .starts
            .windows(2)
            .map(|w| (w[1] - w[0]) as usize)
            .max()
            .unwrap_or(0);
        IndexStats {
            cell_m: idx.cell,
            cols: idx.cols,
            rows: idx.rows,
            max_edges_per_cell,
            entries: idx.items.len(),
        }
    }
}

/// A circle holding the whole centre line: the box around the index chords, grown by the sagitta.
fn bounding_circle(shape: &Shape) -> (Point2<f64>, f64) {
    let n = shape.chord_count(f64::INFINITY);
    let mut lo = Point2::new(f64::INFINITY, f64::INFINITY);
    let mut hi = Point2::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in shape.samples(n) {
        lo = lo.inf(&p);
        hi = hi.sup(&p);
    }
    let centre = nalgebra::center(&lo, &hi);
    (centre, (hi - lo).norm() / 2.0 + shape.sagitta(n))
}

#[cfg(test)]
mod tests {
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
