//! The spatial index: a uniform grid over the tape's bounding box whose cells list every tape that
//! can reach into them, so the floor at a point is found by looking at one cell.

use nalgebra::{Point2, Vector2};

use super::shape::Shape;
use super::{Edge, Surface, Track, INDEX_CELL_M, MAX_INDEX_CELLS};

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
pub(super) struct GridIndex {
    pub(super) origin: Point2<f64>,
    pub(super) cell: f64,
    pub(super) cols: usize,
    pub(super) rows: usize,
    /// Cell `i` lists `items[starts[i]..starts[i + 1]]`.
    pub(super) starts: Vec<u32>,
    pub(super) items: Vec<u32>,
    /// The tape of each of `items`, side by side in cell order: a floor query reads one short
    /// run of memory instead of edges scattered over the whole track.
    tapes: Vec<CellTape>,
}

/// What a floor query needs of one edge listed in a cell.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct CellTape {
    pub(super) shape: Shape,
    pub(super) half_width_m: f64,
    pub(super) surface: Surface,
}

impl GridIndex {
    pub(super) fn build(edges: &[Edge]) -> GridIndex {
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

        let mut pairs = cell_pairs(edges, lo, cell, cols, rows);
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
    pub(super) fn cell_of(&self, p: Point2<f64>) -> Option<usize> {
        self.column_row_of(p)
            .map(|(col, row)| row * self.cols + col)
    }

    /// Column and row of the index cell holding `p`; `None` off the grid.
    pub(super) fn column_row_of(&self, p: Point2<f64>) -> Option<(usize, usize)> {
        let fx = (p.x - self.origin.x) / self.cell;
        let fy = (p.y - self.origin.y) / self.cell;
        // Written so NaN also lands here: it fails every comparison.
        if !(fx >= 0.0 && fy >= 0.0 && fx < self.cols as f64 && fy < self.rows as f64) {
            return None;
        }
        Some((fx as usize, fy as usize))
    }

    /// Distance from `p` to the nearest side of the cell at `col`, `row`, which holds it.
    pub(super) fn inside_margin(&self, (col, row): (usize, usize), p: Point2<f64>) -> f64 {
        let x0 = self.origin.x + col as f64 * self.cell;
        let y0 = self.origin.y + row as f64 * self.cell;
        (p.x - x0)
            .min(x0 + self.cell - p.x)
            .min(p.y - y0)
            .min(y0 + self.cell - p.y)
    }

    /// Distance from `p`, off the grid, to the grid (0 for NaN).
    pub(super) fn outside_margin(&self, p: Point2<f64>) -> f64 {
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
    pub(super) fn tapes_in(&self, i: usize) -> &[CellTape] {
        match (self.starts.get(i), self.starts.get(i + 1)) {
            (Some(&a), Some(&b)) => self.tapes.get(a as usize..b as usize).unwrap_or(&[]),
            _ => &[],
        }
    }
}

/// (cell, edge) for every cell of the grid from `lo` with `cols` by `rows` cells of side `cell`
/// that an edge's tape can reach, unsorted and with repeats.
fn cell_pairs(
    edges: &[Edge],
    lo: Point2<f64>,
    cell: f64,
    cols: usize,
    rows: usize,
) -> Vec<(u32, u32)> {
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
    pairs
}

/// Distance between the axis-aligned box from `min` to `max` and the segment a–b: zero if they meet,
/// else attained between a vertex of one and a side of the other.
pub(super) fn rect_segment_distance(
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

impl Track {
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
