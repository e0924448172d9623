//! The tape under the line sensor matched to the track: a follower's reading, a reading while
//! driving moves (through the filter's gain), a lost robot relocated, and a mark's end.

use super::*;

/// A follower that drives straight along a straight tape, centred on it, faces along it to
/// within its weave, and its centre is on the tape to within this: the variances
/// [`WorldModel::faces_along_tape`] leaves.
const SETTLED_HEADING_RAD2: f64 = (3.0 * PI / 180.0) * (3.0 * PI / 180.0);
const SETTLED_LATERAL_M2: f64 = 0.002 * 0.002;

impl WorldModel {
    /// Robot `id` has followed the tape and now drives straight along it, centred on it (the
    /// re-localiser saw it so): a measurement that its heading is the tape's and its centre on
    /// the tape, which replaces what the estimate had for both. The turns the follower made to
    /// get there are counted in the odometry, and with them any heading the robot was off by
    /// when it started to follow, which the tape's gentle heading gain takes seconds to undo.
    /// Only on a straight tape clear of junctions and ends, where a follower's heading is the
    /// tape's; returns whether the measurement was taken.
    pub fn faces_along_tape(&self, id: u16) -> bool {
        let Some(mut e) = self.estimates.get_mut(&id) else {
            return false;
        };
        let (Some(odometry), Some(&(_, pose))) = (e.last_odometry, e.recent.back()) else {
            return false;
        };
        let centre = Point2::new(pose.x, pose.y);
        let Some(n) = self.track.nearest(centre) else {
            return false;
        };
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let len = self.track.edge_length(n.edge);
        let plain = !self.track.edges()[n.edge].is_arc()
            && self.clear_of_ends(&n, len)
            && !self.in_junction(n.point)
            && n.distance_m < MATCH_MAX_M
            && n.tangent.dot(&heading).abs() > ALIGNED_MAX_RAD.cos();
        if !plain {
            return false;
        }
        let tape_dir = n.tangent * n.tangent.dot(&heading).signum();
        // Not a filter update: the follower's heading corrections (a fixed gain) leave the
        // heading's variance under a degree whatever the turn the follow made, so a gain
        // computed from it would hardly move the estimate. The measurement replaces the heading
        // and the position across the tape; along the tape the estimate stays as uncertain as
        // it was, and nothing it knew across or in heading is kept.
        let t = n.tangent;
        let normal = Vector2::new(-t.y, t.x);
        let along_var = sigma_along(&e.cov, t).powi(2);
        let xy = t * t.transpose() * along_var + normal * normal.transpose() * SETTLED_LATERAL_M2;
        let mut cov = Matrix3::zeros();
        cov.fixed_view_mut::<2, 2>(0, 0).copy_from(&xy);
        cov[(2, 2)] = SETTLED_HEADING_RAD2;
        // The tape's nearest point to the centre: the centre moved straight across onto it.
        let better = Pose {
            x: n.point.x,
            y: n.point.y,
            theta: tape_dir.y.atan2(tape_dir.x),
        };
        e.cov = cov;
        e.correction = Correction::between(odometry, better);
        if let Some(last) = e.recent.back_mut() {
            last.1 = better;
        }
        drop(e);
        self.show_estimate(id, Some(better), false);
        true
    }

    /// The tape nearest the line sensor at `sensor`, when the robot faces along it (facing
    /// `heading`) clear of tape ends and junctions, where the model expects the sensor to see it
    /// if near enough; `cov` gives the uncertainty across it.
    pub(super) fn tape_along(
        &self,
        cov: &Matrix3<f64>,
        sensor: Point2<f64>,
        heading: Vector2<f64>,
    ) -> Option<TapeAlong> {
        let n = self.track.nearest(sensor)?;
        let cos = n.tangent.dot(&heading).abs();
        let len = self.track.edge_length(n.edge);
        (cos > ALIGNED_RAD.cos() && self.clear_of_ends(&n, len) && !self.in_junction(n.point)).then(
            || TapeAlong {
                distance_m: n.distance_m,
                cos,
                sigma_m: sigma_along(cov, Vector2::new(-n.tangent.y, n.tangent.x)),
                width_m: self.track.edges()[n.edge].width_m,
            },
        )
    }

    /// An extended Kalman filter update from one sighting of a tape along the robot's heading:
    /// the offset across the tape is measured, and through the covariance's cross terms it moves
    /// the heading too. `None` when the sighting cannot be matched to one tape: near a junction,
    /// across the heading, or beyond three standard deviations of the expected offset.
    pub(super) fn filter_tape(
        &self,
        pose: Pose,
        cov: &Matrix3<f64>,
        position_um: i16,
        gate_rad: f64,
    ) -> Option<(Pose, Matrix3<f64>)> {
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let right = Vector2::new(heading.y, -heading.x);
        let centre = Point2::new(pose.x, pose.y);
        let arm = heading * LINE_SENSOR_AHEAD_M + right * (f64::from(position_um) * 1e-6);
        let seen = centre + arm;
        let at = self.track.nearest(seen)?;
        if self.in_junction(at.point) || at.tangent.dot(&heading).abs() < gate_rad.cos() {
            return None;
        }
        let normal = Vector2::new(-at.tangent.y, at.tangent.x);
        let innovation = normal.dot(&(at.point - seen));
        let s = (RowVector3::new(normal.x, normal.y, 0.0)
            * cov
            * Vector3::new(normal.x, normal.y, 0.0))[(0, 0)];
        if self.ambiguous(seen, &at, (3.0 * s.sqrt()).clamp(MATCH_M, MATCH_MAX_M)) {
            return None;
        }
        // d(seen)/dθ is the arm turned by 90°.
        let h = RowVector3::new(normal.x, normal.y, normal.dot(&Vector2::new(-arm.y, arm.x)));
        let s = (h * cov * h.transpose())[(0, 0)] + R_LATERAL_M2;
        if innovation.abs() > MATCH_MAX_M
            || innovation * innovation > 9.0 * s.max(MATCH_M * MATCH_M / 9.0)
        {
            return None;
        }
        let k = cov * h.transpose() / s;
        let dx = k * innovation;
        let cov = corrected(cov, h, k, R_LATERAL_M2);
        Some((
            Pose {
                x: pose.x + dx[0],
                y: pose.y + dx[1],
                theta: pose.theta + dx[2],
            },
            cov,
        ))
    }

    /// Whether a tape other than `nearest` (the one nearest the sighting `seen`) also lies within
    /// `gate_m` of it: then the sighting cannot say which one the sensor sees. Outside junction
    /// zones this happens only to an uncertain estimate whose gate spans two tapes, as beside a
    /// siding where it leaves the main line; taking the nearer there once moved an estimate
    /// 3 cm onto the wrong tape and left it confident.
    pub(super) fn ambiguous(
        &self,
        seen: Point2<f64>,
        nearest: &world::track::TrackPoint,
        gate_m: f64,
    ) -> bool {
        (0..self.track.edges().len())
            .filter(|&i| i != nearest.edge)
            .map(|i| self.track.nearest_on(i, seen))
            .any(|q| q.distance_m <= gate_m && (q.point - nearest.point).norm() > AMBIGUOUS_APART_M)
    }

    /// Whether a point on an edge `len` long is clear of where its tape ends or meets others:
    /// far enough from each end node, or that node only carries the tape on in line.
    pub(super) fn clear_of_ends(&self, n: &world::track::TrackPoint, len: f64) -> bool {
        let e = &self.track.edges()[n.edge];
        (n.offset_m > NODE_CLEAR_M || self.through[e.from])
            && (n.offset_m < len - NODE_CLEAR_M || self.through[e.to])
    }

    pub(super) fn in_junction(&self, p: Point2<f64>) -> bool {
        self.junctions.iter().any(|(j, r)| (j - p).norm() < *r)
    }

    /// While lost: the tape the sensor sees, taken to be the nearest one to where the model
    /// puts the sighting, and the pose moved across that tape to agree with it.
    pub(super) fn relocate(&self, pose: Pose, position_um: i16) -> Option<(Pose, Vector2<f64>)> {
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let right = Vector2::new(heading.y, -heading.x);
        let seen = Point2::new(pose.x, pose.y)
            + heading * LINE_SENSOR_AHEAD_M
            + right * (f64::from(position_um) * 1e-6);
        let n = self.track.nearest(seen)?;
        if n.distance_m > RELOCATE_M || self.in_junction(n.point) {
            return None;
        }
        let normal = Vector2::new(-n.tangent.y, n.tangent.x);
        let shift = normal * normal.dot(&(n.point - seen));
        Some((
            Pose {
                x: pose.x + shift.x,
                y: pose.y + shift.y,
                theta: pose.theta,
            },
            normal,
        ))
    }

    /// The pose moved part of the way towards agreeing with the tape the line sensor sees, or
    /// `None` when the sighting cannot be matched to one tape unambiguously.
    ///
    /// The sensor measures where the tape is across the robot (`position_um`, positive to the
    /// right); the track says where that tape is. Along the tape nothing is measured, so only the
    /// lateral offset and the heading are corrected.
    pub(super) fn match_tape(
        &self,
        pose: Pose,
        position_um: i16,
        gate_m: f64,
        gate_rad: f64,
    ) -> Option<TapeMatch> {
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let right = Vector2::new(heading.y, -heading.x);
        let centre = Point2::new(pose.x, pose.y);
        let sensor = centre + heading * LINE_SENSOR_AHEAD_M;
        let seen = sensor + right * (f64::from(position_um) * 1e-6);
        let at_seen = self.track.nearest(seen)?;
        if at_seen.distance_m > gate_m
            || self.in_junction(at_seen.point)
            || self.ambiguous(seen, &at_seen, gate_m)
        {
            return None;
        }
        let along = at_seen.tangent.dot(&heading);
        if along.abs() < gate_rad.cos() {
            return None;
        }
        let at_centre = self.track.nearest(centre)?;
        // Only the mismatch across the tape is measured, so the pose moves along the tape's
        // normal beside the robot's centre: any other direction (the normal under the sensor,
        // which on a curve is turned by the sensor's lead; the robot's own lateral axis, turned
        // by its heading error) has a component along the tape, and a steady bias in the
        // readings would then walk the estimate along the track lap after lap.
        let normal = Vector2::new(-at_centre.tangent.y, at_centre.tangent.x);
        let lateral = normal * normal.dot(&(at_seen.point - seen));
        // On a straight a follower weaves about the tape's direction, so that is its heading on
        // average. On a curve its heading depends on how it cuts the curve, which is not known
        // here; odometry carries the heading through the curve.
        let straight = !self.track.edges()[at_centre.edge].is_arc()
            && !self.track.edges()[at_seen.edge].is_arc();
        let tape_dir = at_centre.tangent * at_centre.tangent.dot(&heading).signum();
        let err = wrap_angle(tape_dir.y.atan2(tape_dir.x) - pose.theta);
        let (dtheta, heading_gain) = if straight {
            (HEADING_GAIN * err, HEADING_GAIN)
        } else {
            // Only the part beyond how a follower cuts a curve: a slip of the odometry on a curve
            // (16° was seen on a colour mark) would otherwise carry the estimate off the tape.
            let beyond = err - err.clamp(-CURVE_DEADBAND_RAD, CURVE_DEADBAND_RAD);
            (
                HEADING_GAIN * beyond,
                if beyond != 0.0 { HEADING_GAIN } else { 0.0 },
            )
        };
        Some(TapeMatch {
            pose: Pose {
                x: pose.x + LATERAL_GAIN * lateral.x,
                y: pose.y + LATERAL_GAIN * lateral.y,
                theta: pose.theta + dtheta,
            },
            normal,
            heading_gain,
        })
    }

    /// The pose moved along the tape so that the sensor sits on the nearest end of a mark of
    /// `colour` (a `protocol::packets::Mark` byte), or `None` when no such end is near.
    pub(super) fn at_mark_end(
        &self,
        pose: Pose,
        colour: u8,
        entering: bool,
        following: bool,
        gate_m: f64,
    ) -> Option<(Pose, Vector2<f64>)> {
        let wanted = match colour {
            1 => world::Mark::Red,
            2 => world::Mark::Blue,
            _ => return None,
        };
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let sensor = Point2::new(pose.x, pose.y) + heading * LINE_SENSOR_AHEAD_M;
        let nodes = self.track.nodes();
        let end = self
            .track
            .edges()
            .iter()
            .enumerate()
            .filter(|(_, e)| e.mark == Some(wanted))
            .flat_map(|(i, e)| {
                // Each end with the tape's direction into the mark from there.
                let len = self.track.edge_length(i);
                [
                    (nodes[e.from].position, self.track.point_at(i, 0.0).1),
                    (nodes[e.to].position, -self.track.point_at(i, len).1),
                ]
            })
            .filter(|(_, into)| {
                // A robot driving moves may pass a mark's end on another tape, or see a mark
                // flicker while it runs along its edge: only an end it drives into (or out of)
                // along the marked tape is where it is.
                following
                    || (into.dot(&heading) > ALIGNED_RAD.cos()) == entering
                        && into.dot(&heading).abs() > ALIGNED_RAD.cos()
            })
            .map(|(p, _)| (p, (p - sensor).norm()))
            .filter(|(_, d)| *d < gate_m)
            .min_by(|a, b| a.1.total_cmp(&b.1))?
            .0;
        let tangent = self.track.nearest(end)?.tangent;
        let shift = tangent * (tangent.dot(&(end - sensor)) * MARK_GAIN);
        Some((
            Pose {
                x: pose.x + shift.x,
                y: pose.y + shift.y,
                theta: pose.theta,
            },
            tangent,
        ))
    }
}
