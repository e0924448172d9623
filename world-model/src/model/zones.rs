//! Places on a track where the tape alone says little: junctions whose tapes run too close to
//! tell apart, and nodes where two tapes run on in line.

use super::*;

/// Per node of `track`: whether exactly two edges end there and their tapes run on in line
/// (within 10°), as where an oval's bend meets its straight; there a sensor sees tape on both
/// sides of the node.
pub(super) fn through_nodes(track: &Track) -> Vec<bool> {
    let mut ends: Vec<Vec<Vector2<f64>>> = vec![Vec::new(); track.nodes().len()];
    for (i, e) in track.edges().iter().enumerate() {
        let len = track.edge_length(i);
        ends[e.from].push(track.point_at(i, 0.0).1);
        ends[e.to].push(track.point_at(i, len).1);
    }
    ends.iter()
        .map(|t| t.len() == 2 && t[0].dot(&t[1]).abs() > 10f64.to_radians().cos())
        .collect()
}

/// Every junction and the radius around it in which its tapes run too close together to be told
/// apart: a fork whose branch leaves tangentially on a 0.15 m arc needs about 8 cm, a crossing
/// only the minimum.
pub(super) fn junction_zones(track: &Track) -> Vec<(Point2<f64>, f64)> {
    let mut at: Vec<Vec<(usize, bool)>> = vec![Vec::new(); track.nodes().len()];
    for (i, e) in track.edges().iter().enumerate() {
        at[e.from].push((i, true));
        at[e.to].push((i, false));
    }
    let along = |(edge, from_start): (usize, bool), s: f64| {
        let len = track.edge_length(edge);
        track.point_at(edge, if from_start { s } else { len - s }).0
    };
    at.iter()
        .enumerate()
        .filter(|(_, edges)| edges.len() >= 3)
        .map(|(n, edges)| {
            let mut radius = JUNCTION_CLEAR_M;
            for (k, a) in edges.iter().enumerate() {
                for b in &edges[k + 1..] {
                    let limit = track.edge_length(a.0).min(track.edge_length(b.0));
                    let mut s = 0.0;
                    while s < limit && (along(*a, s) - along(*b, s)).norm() < BRANCHES_APART_M {
                        s += 0.005;
                    }
                    radius = radius.max(s + 0.01);
                }
            }
            (track.nodes()[n].position, radius)
        })
        .collect()
}
