//! Driving: a leg of the plan (one track edge) cut into segments that stay on the tape, sent as
//! moves with the next segment queued behind the running one, and a leg's end counted.

use super::*;

impl TrafficControl {
    pub(super) fn position(&self, node: u32) -> Point2<f64> {
        self.track.nodes()[node as usize].position
    }

    pub(super) fn name(&self, node: u32) -> &str {
        &self.track.nodes()[node as usize].id
    }

    /// The track edge between nodes `u` and `v`, and whether it runs from `u` to `v`.
    pub(super) fn edge_between(&self, u: u32, v: u32) -> Option<(usize, bool)> {
        let e = self
            .graph
            .graph
            .find_edge(NodeIndex::new(u as usize), NodeIndex::new(v as usize))
            .and_then(|e| self.graph.graph.edge_weight(e))?
            .edge;
        Some((e, self.track.edges()[e].from == u as usize))
    }

    /// The node a leg starts from.
    pub(super) fn leg_from(&self, leg: &EdgeDrive) -> u32 {
        let e = &self.track.edges()[leg.edge];
        if leg.forward {
            e.from as u32
        } else {
            e.to as u32
        }
    }

    /// The same edge driven back to the node it started from, outside the plan.
    pub(super) fn reversed(&self, leg: &EdgeDrive) -> EdgeDrive {
        EdgeDrive {
            index: None,
            edge: leg.edge,
            forward: !leg.forward,
            to: self.leg_from(leg),
            last: false,
            back: false,
        }
    }

    /// The next segment of `leg` from `pose`: a turn onto the tape if the robot faces away from
    /// it, then an arc (or straight) through a point `LOOKAHEAD` further along the tape, or the
    /// end node when that is nearer. Each segment is planned from the world model's pose, which
    /// the tape under the sensor keeps corrected, so errors of one segment are taken out by the
    /// next instead of adding up over a long curve.
    pub(super) fn segment(&self, pose: Pose, leg: &mut EdgeDrive) -> Manoeuvre {
        if leg.back {
            leg.last = true;
            let q = self.position(leg.to);
            let route = Manoeuvre::from(pose, DRIVE_MPS).back_to(q.x, q.y);
            return route;
        }
        let len = self.track.edge_length(leg.edge);
        let here = self.track.nearest_on(leg.edge, Point2::new(pose.x, pose.y));
        let done = if leg.forward {
            here.offset_m
        } else {
            len - here.offset_m
        };
        let remaining = (len - done).max(0.0);
        let ahead = (done + self.segment_m).min(len);
        leg.last = remaining <= self.segment_m + 0.01;
        let target_offset = if leg.last {
            if leg.forward {
                len
            } else {
                0.0
            }
        } else if leg.forward {
            ahead
        } else {
            len - ahead
        };
        let (q, _) = self.track.point_at(leg.edge, target_offset);
        let q = if leg.last { self.position(leg.to) } else { q };
        let mut route = Manoeuvre::from(pose, DRIVE_MPS);
        let (dx, dy) = (q.x - pose.x, q.y - pose.y);
        let d = dx.hypot(dy);
        if d < 0.003 {
            return route;
        }
        let mut alpha = wrap(dy.atan2(dx) - pose.theta);
        if alpha.abs() > MAX_BEND {
            // Facing away (at a node, before a new edge): turn to the tape's direction first.
            let (_, t) = self.track.point_at(leg.edge, here.offset_m);
            let dir = if leg.forward { t } else { -t };
            route = route.turn_to(dir.y.atan2(dir.x));
            alpha = wrap(dy.atan2(dx) - route.end.theta);
            if alpha.abs() > MAX_BEND {
                return route.to(q.x, q.y);
            }
        }
        if alpha.abs() < 1e-3 {
            return route.straight(d);
        }
        // The circle through the robot, tangent to its heading, through q.
        let radius = d / (2.0 * alpha.sin().abs());
        route.moves.push(MoveCommand::Arc {
            radius_m: radius as f32,
            angle_deg: (2.0 * alpha).to_degrees() as f32,
            speed_mps: DRIVE_MPS,
        });
        route.end = Pose {
            x: q.x,
            y: q.y,
            theta: route.end.theta + 2.0 * alpha,
        };
        route
    }

    /// Sends robot `k` the next segment of its leg. A leg whose end the robot already stands on
    /// needs no move: it is completed at the next step.
    pub(super) fn drive(&mut self, k: usize, world: &WorldSnapshot) -> Vec<Intent> {
        if self.bots[k].lost.is_some() || self.bots[k].making_room.is_some() {
            return Vec::new();
        }
        let (Some(mut leg), Some(view)) = (self.bots[k].driving, world.robot(self.bots[k].id))
        else {
            return Vec::new();
        };
        let mut route = self.segment(view.pose, &mut leg);
        if route.moves.is_empty() {
            leg.last = true;
            self.bots[k].driving = Some(leg);
            self.bots[k].at_end = true;
            return Vec::new();
        }
        self.bots[k].tail = None;
        if self.flow && !leg.last && !leg.back {
            // A route that turns on the spot first ends where the turn's coast leaves it (degrees
            // off): the segment after it is planned from rest, where the tape has corrected that.
            if let Some(end) = self.flowing_end(&route, &leg) {
                // Two segments queued from the start, so that the first joint flows too.
                let mut next_leg = leg;
                let next = self.segment(end, &mut next_leg);
                if self.flowing_end(&next, &next_leg).is_some() {
                    route.moves.extend(next.moves);
                    leg = next_leg;
                    self.bots[k].tail = (!leg.last).then_some((end, next.end));
                }
            }
        }
        self.bots[k].driving = Some(leg);
        self.send(k, route)
    }

    /// Robot `k` finished a segment and its tail runs: queues the segment after the tail,
    /// planned from where the tail will end (the tail's planned motion from the robot's pose
    /// now), when that is one forward move along the tape. Anything else (a turn first) waits
    /// for the robot to stop and is planned from where it then stands.
    pub(super) fn drive_ahead(&mut self, k: usize, world: &WorldSnapshot) -> Vec<Intent> {
        let (Some((from, to)), Some(mut leg), Some(view)) = (
            self.bots[k].tail.take(),
            self.bots[k].driving,
            world.robot(self.bots[k].id),
        ) else {
            return Vec::new();
        };
        // A tail is only kept for a leg that goes on after it (`drive`, `on_held`, `lose` and
        // `recover` clear it otherwise).
        let start = view.pose.compose(to.relative_to(from));
        let route = self.segment(start, &mut leg);
        // A queued segment that would end across the tape (a short last one from a start a few
        // millimetres aside bends hard) waits to be planned from rest.
        if self.flowing_end(&route, &leg).is_none() {
            return Vec::new();
        }
        self.bots[k].tail = (!leg.last).then_some((start, route.end));
        self.bots[k].driving = Some(leg);
        self.send(k, route)
    }

    /// Where `route` ends, when it is one move driving forward that ends heading along the tape
    /// of `leg`: a segment another can be queued behind, or that can itself be queued.
    pub(super) fn flowing_end(&self, route: &Manoeuvre, leg: &EdgeDrive) -> Option<Pose> {
        forward_move(route).filter(|&end| self.along_tape(leg, end))
    }

    /// Whether a segment ending at `end` leaves the robot heading along the tape of `leg`
    /// (within [`FLOW_ALIGN`]), so the next can follow at speed. A segment that ends across the
    /// tape (the arc from a pose with a heading error ends with the opposite error) is followed
    /// from rest: two such arcs flowed into each other at speed swing the robot from one bend
    /// into the opposite one, and in physics a robot doing that lost its pose.
    pub(super) fn along_tape(&self, leg: &EdgeDrive, end: Pose) -> bool {
        let here = self.track.nearest_on(leg.edge, Point2::new(end.x, end.y));
        let (_, tangent) = self.track.point_at(leg.edge, here.offset_m);
        let dir = if leg.forward { tangent } else { -tangent };
        wrap(end.theta - dir.y.atan2(dir.x)).abs() <= FLOW_ALIGN
    }

    pub(super) fn send(&mut self, k: usize, route: Manoeuvre) -> Vec<Intent> {
        self.bots[k].fresh_hold = true;
        Intent::moves(self.bots[k].id, route.moves, 0)
    }

    /// Robot `k` reached the end of `leg`.
    pub(super) fn complete_leg(
        &mut self,
        k: usize,
        leg: EdgeDrive,
        world: &WorldSnapshot,
    ) -> Result<(), String> {
        self.bots[k].node = leg.to;
        self.last_progress = world.time;
        let Some(index) = leg.index else {
            return Ok(());
        };
        self.bots[k].edges_m += self.track.edge_length(leg.edge);
        if let Some(adg) = self.adg.as_mut() {
            adg.complete(k, index)
                .map_err(|e| format!("robot {}: {e}", self.bots[k].id))?;
        }
        let b = &mut self.bots[k];
        if b.active && leg.to == b.goal {
            b.tasks_done += 1;
            b.reached = true;
            self.tasks += 1;
            self.recoveries = 0;
            if self.quota.is_some_and(|q| b.tasks_done >= q) {
                b.active = false;
            }
            // Every robot now finishes the edge it is on; then the team is planned again. With
            // the last task done, robots with a quota (scripted goals) run the plan to its end,
            // so that one pushed aside returns to its goal; lifelong tasks end once every robot
            // has finished its edge (running the plan to its end took minutes: LaCAM's paths for
            // robots far from their goals can be long).
            // With lifelong replanning, robots keep driving and the team is planned again at the
            // next snapshot, from where each robot stands or is driving to.
            if self.tasks < self.target_tasks && self.replan_mode == Replan::Lifelong {
                self.replan_due = true;
            } else if self.tasks < self.target_tasks || self.quota.is_none() {
                self.phase = Phase::Draining;
            }
        }
        if self.adg.as_ref().is_some_and(|a| a.is_done()) {
            self.phase = Phase::Draining;
        }
        Ok(())
    }
}

/// Where `route` ends, when it is a single move driving forward along a straight or an arc: a
/// move the firmware can flow into the next.
fn forward_move(route: &Manoeuvre) -> Option<Pose> {
    match route.moves.as_slice() {
        [MoveCommand::Straight { distance_m, .. }] if *distance_m > 0.0 => Some(route.end),
        [MoveCommand::Arc { .. }] => Some(route.end),
        _ => None,
    }
}
