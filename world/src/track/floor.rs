//! What the floor looks like at a point: the darkest tape covering it, found through one index
//! cell, and how far the answer holds around the point.

use nalgebra::Point2;

use super::index::CellTape;
use super::{Surface, Track};

/// Work done by one floor query, to check the spatial index without timing anything.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct QueryCost {
    /// Index cells looked at: 1 on the tape's bounding box, 0 outside it.
    pub cells_visited: usize,
    /// Edges whose exact geometry was tested.
    pub edges_tested: usize,
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

impl Track {
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
}
