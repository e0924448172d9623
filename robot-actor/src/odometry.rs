//! Odometry from encoder totals (thesis 9.8): the heading from the exact integer formula
//! θ = θ₀ + 2πr / (l·T) · (N₂ − N₁), position integrated per update along the mean heading.
//!
//! Totals are kept in `i64` from wrapping `i32` deltas, so a robot that drives past the counters'
//! range keeps an exact heading.

use std::f64::consts::TAU;

/// Position and heading in the plane: the world crate's, so odometry, the world model and the
/// simulator's ground truth are one type.
pub use world::Pose;

/// Wheel geometry the formula needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Geometry {
    /// Wheel radius r, metres.
    pub wheel_radius_m: f64,
    /// Wheel gauge l, metres.
    pub gauge_m: f64,
    /// Pulses per revolution T.
    pub ticks_per_rev: f64,
}

impl Geometry {
    /// From the robot's settings.
    pub fn from_settings(s: &protocol::Settings) -> Self {
        let g = s.geometry;
        Self {
            wheel_radius_m: f64::from(g.wheel_diameter_m) * 0.5,
            gauge_m: f64::from(g.wheel_gauge_m),
            ticks_per_rev: f64::from(g.ticks_per_rev.max(1)),
        }
    }

    /// Metres per pulse, 2πr / T.
    pub fn tick_m(&self) -> f64 {
        TAU * self.wheel_radius_m / self.ticks_per_rev
    }
}

/// Dead reckoning from encoder totals.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Odometry {
    geometry: Geometry,
    origin: Pose,
    last: Option<(i32, i32)>,
    totals: (i64, i64),
    pose: Pose,
}

impl Odometry {
    /// Starts at `origin`; the first update only records the counters.
    pub fn new(geometry: Geometry, origin: Pose) -> Self {
        Self {
            geometry,
            origin,
            last: None,
            totals: (0, 0),
            pose: origin,
        }
    }

    /// Starts again at `origin` from the next update's counters.
    pub fn reset(&mut self, origin: Pose) {
        *self = Self::new(self.geometry, origin);
    }

    /// Carries on at `pose` from counters the robot reported earlier (`counters`): the next update
    /// counts every pulse since them, so travel while nobody was listening is not lost.
    pub fn continue_from(&mut self, pose: Pose, counters: (i32, i32)) {
        *self = Self::new(self.geometry, pose);
        self.last = Some(counters);
    }

    /// The robot's counters start again (it restarted): the next update only records them, and
    /// the pose stays where it is.
    pub fn rebase(&mut self) {
        self.last = None;
    }

    /// The wheels it counts with.
    pub fn geometry(&self) -> Geometry {
        self.geometry
    }

    /// Pulses counted since the origin, left and right.
    pub fn totals(&self) -> (i64, i64) {
        self.totals
    }

    /// The current estimate.
    pub fn pose(&self) -> Pose {
        self.pose
    }

    /// The heading from the totals alone: θ₀ + 2πr/(l·T)·(N₂ − N₁).
    pub fn heading(&self) -> f64 {
        let g = &self.geometry;
        let (n1, n2) = self.totals;
        self.origin.theta
            + TAU * g.wheel_radius_m / (g.gauge_m * g.ticks_per_rev) * (n2 - n1) as f64
    }

    /// Takes new encoder totals as reported by the robot (wrapping `i32`).
    pub fn update(&mut self, left: i32, right: i32) -> Pose {
        self.advance(left, right, false)
    }

    /// Takes totals after a long gap as one arc of constant curvature: its chord, not its
    /// length, along the mean heading, which is exact for an arc (a robot following a curve) where
    /// [`Odometry::update`]'s short steps need no such care.
    pub fn update_across_gap(&mut self, left: i32, right: i32) -> Pose {
        self.advance(left, right, true)
    }

    fn advance(&mut self, left: i32, right: i32, chord: bool) -> Pose {
        let Some((l0, r0)) = self.last.replace((left, right)) else {
            return self.pose;
        };
        let dl = i64::from(left.wrapping_sub(l0));
        let dr = i64::from(right.wrapping_sub(r0));
        if dl == 0 && dr == 0 {
            return self.pose;
        }
        let before = self.pose.theta;
        self.totals.0 += dl;
        self.totals.1 += dr;
        let after = self.heading();
        let mut d = self.geometry.tick_m() * (dl + dr) as f64 * 0.5;
        let half = 0.5 * (after - before);
        if chord && half.abs() > 1e-9 {
            d *= half.sin() / half;
        }
        let mid = 0.5 * (before + after);
        self.pose = Pose {
            x: self.pose.x + d * mid.cos(),
            y: self.pose.y + d * mid.sin(),
            theta: after,
        };
        self.pose
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geometry() -> Geometry {
        Geometry {
            wheel_radius_m: 0.0045,
            gauge_m: 0.026,
            ticks_per_rev: 40.0,
        }
    }

    #[test]
    fn straight_then_quarter_turn() {
        let g = geometry();
        let mut o = Odometry::new(g, Pose::default());
        o.update(0, 0);
        let n = (0.1 / g.tick_m()).round() as i32;
        for k in 1..=n {
            o.update(k, k);
        }
        assert!((o.pose().x - n as f64 * g.tick_m()).abs() < 1e-12);
        assert_eq!(o.pose().theta, 0.0);
        // A quarter turn in place: each wheel 0.25·π·l / 2.
        let q = (std::f64::consts::FRAC_PI_2 * g.gauge_m * 0.5 / g.tick_m()).round() as i32;
        o.update(n - q, n + q);
        let expected = TAU * g.wheel_radius_m / (g.gauge_m * g.ticks_per_rev) * (2 * q) as f64;
        assert_eq!(o.pose().theta, expected);
        assert!((expected - std::f64::consts::FRAC_PI_2).abs() < 0.03);
    }

    #[test]
    fn an_arc_taken_across_a_gap_lands_on_the_arc() {
        // A line follower on the oval's curve (radius 0.15 m) for a third of a turn, counted in
        // one step after its host died.
        let g = geometry();
        let (radius, angle) = (0.15, TAU / 3.0);
        let outer = ((radius + g.gauge_m / 2.0) * angle / g.tick_m()).round() as i32;
        let inner = ((radius - g.gauge_m / 2.0) * angle / g.tick_m()).round() as i32;
        let (x, y) = (radius * angle.sin(), radius * (1.0 - angle.cos()));
        let mut gap = Odometry::new(g, Pose::default());
        gap.continue_from(Pose::default(), (0, 0));
        let p = gap.update_across_gap(inner, outer);
        // Within what a tick's rounding moves the end (about 2 mm of travel a wheel).
        assert!((p.x - x).hypot(p.y - y) < 0.002, "{p:?}");
        // Taken as a straight step, the same counts land past the arc's end.
        let mut straight = Odometry::new(g, Pose::default());
        straight.continue_from(Pose::default(), (0, 0));
        let q = straight.update(inner, outer);
        assert!((q.x - x).hypot(q.y - y) > 0.01, "{q:?}");
    }

    #[test]
    fn heading_is_exact_however_the_updates_are_split() {
        let mut a = Odometry::new(geometry(), Pose::default());
        let mut b = Odometry::new(geometry(), Pose::default());
        a.update(0, 0);
        b.update(0, 0);
        let mut l = 0;
        let mut r = 0;
        for k in 0..1000 {
            l += k % 3;
            r += k % 5;
            a.update(l, r);
        }
        b.update(l, r);
        assert_eq!(a.heading(), b.heading());
        assert_eq!(a.pose().theta, b.pose().theta);
    }

    #[test]
    fn counter_wrap_is_a_small_step() {
        let mut o = Odometry::new(geometry(), Pose::default());
        o.update(i32::MAX - 1, i32::MAX - 1);
        o.update(i32::MIN + 1, i32::MIN + 1);
        assert_eq!(o.totals(), (3, 3));
        assert!(o.pose().x > 0.0 && o.pose().x < 0.003);
    }
}
