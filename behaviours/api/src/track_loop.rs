//! A closed loop of tape as one coordinate: the arc length from the loop's start, in the direction
//! its edges run. Behaviours on a round track use it for laps and for the gap to the robot ahead.

use world::Track;

/// A track that is one closed loop, its edges in driving order.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackLoop {
    /// Arc length at which each track edge starts, indexed by track edge.
    start_of: Vec<f64>,
    /// Total length, metres.
    length_m: f64,
}

impl TrackLoop {
    /// The loop formed by `track`'s edges, each running from its `from` node to its `to` node.
    ///
    /// # Errors
    /// When the edges are not one closed chain (a fork, a dead end, several loops, no tape).
    pub fn new(track: &Track) -> Result<Self, String> {
        let edges = track.edges();
        if edges.is_empty() {
            return Err("the world has no track".into());
        }
        let mut next = vec![None; track.nodes().len()];
        for (i, e) in edges.iter().enumerate() {
            if next[e.from].replace(i).is_some() {
                return Err(format!(
                    "track node {:?} starts two edges: not a single loop",
                    track.nodes()[e.from].id
                ));
            }
        }
        let mut start_of = vec![f64::NAN; edges.len()];
        let (mut edge, mut s) = (0usize, 0.0);
        for _ in 0..edges.len() {
            if !start_of[edge].is_nan() {
                break;
            }
            start_of[edge] = s;
            s += track.edge_length(edge);
            edge = next[edges[edge].to].ok_or_else(|| {
                format!(
                    "the tape ends at node {:?}: not a closed loop",
                    track.nodes()[edges[edge].to].id
                )
            })?;
        }
        if edge != 0 || start_of.iter().any(|s| s.is_nan()) {
            return Err("the track is not one closed loop through every edge".into());
        }
        Ok(Self {
            start_of,
            length_m: s,
        })
    }

    /// Length of the loop, metres.
    pub fn length_m(&self) -> f64 {
        self.length_m
    }

    /// Loop coordinate of a point `offset_m` along track edge `edge`.
    pub fn coordinate(&self, edge: usize, offset_m: f64) -> f64 {
        (self.start_of.get(edge).copied().unwrap_or(0.0) + offset_m).rem_euclid(self.length_m)
    }

    /// How far `to` is ahead of `from` along the driving direction, in `[0, length)`.
    pub fn ahead(&self, from: f64, to: f64) -> f64 {
        (to - from).rem_euclid(self.length_m)
    }

    /// Distance driven forwards from `before` to `after`; `None` for a step backwards or a jump
    /// of half the loop or more, which is a mismatch rather than progress.
    pub fn forward(&self, before: f64, after: f64) -> Option<f64> {
        let d = self.ahead(before, after);
        (d < 0.5 * self.length_m).then_some(d)
    }

    /// Signed progress from `before` to `after` (the shorter way round), for lap counting.
    pub fn progress(&self, before: f64, after: f64) -> f64 {
        let d = self.ahead(before, after);
        if d > 0.5 * self.length_m {
            d - self.length_m
        } else {
            d
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use world::presets;

    #[test]
    fn oval_is_a_loop_whose_coordinate_runs_with_its_edges() {
        let w = presets::preset("oval").unwrap();
        let l = TrackLoop::new(&w.track).unwrap();
        assert!((l.length_m() - (1.0 + 0.3 * std::f64::consts::PI)).abs() < 1e-4);
        let a = w.track.nearest(nalgebra::Point2::new(0.35, 0.15)).unwrap();
        let b = w.track.nearest(nalgebra::Point2::new(0.45, 0.15)).unwrap();
        let (sa, sb) = (
            l.coordinate(a.edge, a.offset_m),
            l.coordinate(b.edge, b.offset_m),
        );
        assert!((l.ahead(sa, sb) - 0.1).abs() < 1e-9);
        assert!((l.progress(sb, sa) + 0.1).abs() < 1e-9);
        assert!((l.ahead(sb, sa) - (l.length_m() - 0.1)).abs() < 1e-9);
    }

    #[test]
    fn forks_and_open_floors_are_refused() {
        for name in ["junction", "open", "grid"] {
            let w = presets::preset(name).unwrap();
            assert!(TrackLoop::new(&w.track).is_err(), "{name}");
        }
    }
}
