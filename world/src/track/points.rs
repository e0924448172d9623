//! Points of the track: the nearest to a query point (through the index's rings of cells, or by a
//! scan), and points and tangents along an edge.

use nalgebra::{Point2, Vector2};

use super::shape::Shape;
use super::Track;

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

impl Track {
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
}
