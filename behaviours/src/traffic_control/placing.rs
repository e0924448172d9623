//! Placing: where each robot stands when the experiment starts (on a node, or on an edge with a
//! free end to drive to), before the first plan.

use super::*;

impl TrafficControl {
    /// Puts every robot on a node of its own. A robot within `NODE_SLACK_M` of a node stands on
    /// it; any other drives along its nearest edge to an end node no other robot holds (the one
    /// ahead first, else the one behind, backing on a straight). Two robots on one edge each take
    /// the end on their side, so they never cross. A robot farther than `REACH_M` from the tape,
    /// or with no free end to go to, is refused with where it is.
    pub(super) fn place(&mut self, world: &WorldSnapshot) -> Result<Vec<Intent>, String> {
        let starts = self.start_places(world)?;
        let (mut owner, placed) = self.claim_nodes(&starts);
        let mut out = Vec::new();
        for k in 0..self.bots.len() {
            if placed[k] {
                continue;
            }
            let id = self.bots[k].id;
            let near = &starts[k].1;
            let edge = &self.track.edges()[near.edge];
            let to = edge.to as u32;
            let (target, towards_to) = self.end_to_drive_to(k, &starts, &placed, &owner)?;
            owner[target as usize] = Some(id);
            self.bots[k].node = target;
            let forward = target == to;
            let facing = forward == towards_to;
            self.bots[k].driving = Some(EdgeDrive {
                index: None,
                edge: near.edge,
                forward,
                to: target,
                last: false,
                back: !facing && !edge.is_arc(),
            });
            out.extend(self.drive(k, world));
        }
        Ok(out)
    }

    /// Each robot's pose, its nearest place on the tape, and the node it stands on, if any; a
    /// robot too far from the tape is refused with where it is.
    fn start_places(&self, world: &WorldSnapshot) -> Result<Vec<Start>, String> {
        let nodes = self.track.nodes();
        let mut starts = Vec::with_capacity(self.bots.len());
        for b in &self.bots {
            let id = b.id;
            let view = world
                .robot(id)
                .ok_or_else(|| format!("robot {id} is not in the world"))?;
            let p = view.pose;
            let at = Point2::new(p.x, p.y);
            let near = self.track.nearest(at).ok_or("the track is empty")?;
            if near.distance_m > REACH_M {
                let e = &self.track.edges()[near.edge];
                return Err(format!(
                    "robot {id} starts at ({:.3}, {:.3}) m, {:.1} cm from the nearest tape (edge \
                     {}-{}); traffic control drives a robot onto the track only from within {:.0} \
                     cm of it: place the robot on a node or an edge",
                    p.x,
                    p.y,
                    near.distance_m * 100.0,
                    nodes[e.from].id,
                    nodes[e.to].id,
                    REACH_M * 100.0
                ));
            }
            let on_node = (0..nodes.len())
                .map(|v| (v, (nodes[v].position - at).norm()))
                .filter(|(_, d)| *d <= NODE_SLACK_M)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(v, _)| v as u32);
            starts.push((p, near, on_node));
        }
        Ok(starts)
    }

    /// The robots standing on a node take it, first come first served: which robot owns each
    /// node, and which robots are placed.
    fn claim_nodes(&mut self, starts: &[Start]) -> (Vec<Option<u16>>, Vec<bool>) {
        let nodes = self.track.nodes();
        let mut owner: Vec<Option<u16>> = vec![None; nodes.len()];
        let mut placed = vec![false; self.bots.len()];
        for (k, (_, _, on_node)) in starts.iter().enumerate() {
            if let Some(v) = *on_node {
                if owner[v as usize].is_none() {
                    owner[v as usize] = Some(self.bots[k].id);
                    self.bots[k].node = v;
                    placed[k] = true;
                }
            }
        }
        (owner, placed)
    }

    /// The end of its edge robot `k` drives to (the one ahead first, else the one behind; the one
    /// on its side when it shares the edge), and whether it faces the edge's end; refused when
    /// no end is free.
    fn end_to_drive_to(
        &self,
        k: usize,
        starts: &[Start],
        placed: &[bool],
        owner: &[Option<u16>],
    ) -> Result<(u32, bool), String> {
        let id = self.bots[k].id;
        let (p, near, _) = &starts[k];
        let edge = &self.track.edges()[near.edge];
        let (from, to) = (edge.from as u32, edge.to as u32);
        let heading = Vector2::new(p.theta.cos(), p.theta.sin());
        let towards_to = near.tangent.dot(&heading) >= 0.0;
        let sharing: Vec<(u16, f64)> = (0..self.bots.len())
            .filter(|&j| j != k && !placed[j] && starts[j].1.edge == near.edge)
            .map(|j| (self.bots[j].id, starts[j].1.offset_m))
            .collect();
        let before = sharing.iter().any(|(_, o)| *o < near.offset_m);
        let after = sharing.iter().any(|(_, o)| *o >= near.offset_m);
        let candidates: Vec<u32> = match (before, after) {
            (false, false) if towards_to => vec![to, from],
            (false, false) => vec![from, to],
            (false, true) => vec![from],
            (true, false) => vec![to],
            (true, true) => {
                return Err(format!(
                    "robot {id} starts at ({:.3}, {:.3}) m between robots {} on edge {}-{}: \
                     neither end is free to drive to without passing another robot",
                    p.x,
                    p.y,
                    sharing
                        .iter()
                        .map(|(j, _)| j.to_string())
                        .collect::<Vec<_>>()
                        .join(" and "),
                    self.name(from),
                    self.name(to)
                ))
            }
        };
        let Some(&target) = candidates.iter().find(|v| owner[**v as usize].is_none()) else {
            let held = candidates
                .iter()
                .map(|v| {
                    format!(
                        "{} by robot {}",
                        self.name(*v),
                        owner[*v as usize].unwrap_or_default()
                    )
                })
                .collect::<Vec<_>>()
                .join(", ");
            return Err(format!(
                "robot {id} starts at ({:.3}, {:.3}) m on edge {}-{}, and the nodes it could \
                 drive to are taken ({held}): move it to a free node or edge",
                p.x,
                p.y,
                self.name(from),
                self.name(to)
            ));
        };
        Ok((target, towards_to))
    }
}

/// Where a robot starts: its pose, its nearest place on the tape, and the node it stands on.
type Start = (Pose, world::track::TrackPoint, Option<u32>);
