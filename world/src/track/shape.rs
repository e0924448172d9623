//! The exact shape of one edge's centre line, a straight line or a circular arc: points along it,
//! the nearest point and distance to it, and the chords the index and drawings use.

use std::f64::consts::{PI, TAU};

use nalgebra::{Point2, Vector2};

/// A turn smaller than this is drawn as a straight line: the radius would overflow precision.
const STRAIGHT_TURN_DEG: f64 = 1e-6;

/// Largest angle of one index chord. Keeps the chord's sagitta below 0.1 % of the radius.
const INDEX_CHORD_RAD: f64 = 5.0 * PI / 180.0;

/// Exact shape of an edge, cached at construction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Shape {
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
    pub(super) fn new(a: Point2<f64>, b: Point2<f64>, turn_deg: f64) -> Shape {
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

    pub(super) fn length(&self) -> f64 {
        match *self {
            Shape::Line { length, .. } => length,
            Shape::Arc { radius, sweep, .. } => radius * sweep.abs(),
        }
    }

    /// Point and unit tangent at arc length `s` (already clamped) from the start.
    pub(super) fn point_at(&self, s: f64) -> (Point2<f64>, Vector2<f64>) {
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
    pub(super) fn closest(&self, p: Point2<f64>) -> (f64, f64, Point2<f64>) {
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
    pub(super) fn covers(&self, p: Point2<f64>, half_width: f64) -> bool {
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
    pub(super) fn cover_margin(&self, p: Point2<f64>, half_width: f64) -> (bool, f64) {
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
    pub(super) fn distance(&self, p: Point2<f64>) -> f64 {
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
    pub(super) fn samples(&self, n: usize) -> impl Iterator<Item = Point2<f64>> + '_ {
        let length = self.length();
        (0..=n).map(move |i| self.point_at(length * i as f64 / n as f64).0)
    }

    /// Number of index/drawing chords: none longer than `max_len`, none wider than
    /// [`INDEX_CHORD_RAD`] of arc.
    pub(super) fn chord_count(&self, max_len: f64) -> usize {
        let by_length = (self.length() / max_len).ceil();
        let by_angle = match *self {
            Shape::Line { .. } => 1.0,
            Shape::Arc { sweep, .. } => (sweep.abs() / INDEX_CHORD_RAD).ceil(),
        };
        // Bounded so a tiny step can never ask for an absurd allocation.
        by_length.max(by_angle).clamp(1.0, 100_000.0) as usize
    }

    /// Largest distance between the arc and a chord of `n` equal pieces.
    pub(super) fn sagitta(&self, n: usize) -> f64 {
        match *self {
            Shape::Line { .. } => 0.0,
            Shape::Arc { radius, sweep, .. } => {
                radius * (1.0 - (sweep.abs() / n as f64 / 2.0).cos())
            }
        }
    }
}

/// A circle holding the whole centre line: the box around the index chords, grown by the sagitta.
pub(super) fn bounding_circle(shape: &Shape) -> (Point2<f64>, f64) {
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
