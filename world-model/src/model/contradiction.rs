//! When what a robot senses contradicts the model: tape missing where the model puts it squarely
//! on one, tape where the model has none, or a reading that moves while the robot stands.

use super::*;

/// Where the line sensor is and what it read, for the contradiction rules.
#[derive(Clone, Copy)]
struct Sight {
    pose: Pose,
    heading: Vector2<f64>,
    sensor: Point2<f64>,
    position_um: i16,
    driven: f64,
    at_rest: Option<std::time::Duration>,
}

impl WorldModel {
    /// Why what the robot senses contradicts the model, once it has for long enough; `at_rest`
    /// is the time since the last update when the robot did not move in it.
    pub(super) fn contradiction(
        &self,
        e: &mut Estimate,
        pose: Pose,
        sees_tape: bool,
        position_um: i16,
        driven: f64,
        at_rest: Option<std::time::Duration>,
    ) -> Option<String> {
        let sigma = sigmas(&e.cov);
        // Where no tape is within reach nothing could find the robot again: it drives on as
        // uncertain as it is (the safety check gives such a robot its whole region).
        let findable = self
            .track
            .nearest(Point2::new(pose.x, pose.y))
            .is_some_and(|n| n.distance_m < RELOCATE_M + sigma.position_m);
        if sigma.position_m > LOST_SIGMA_M && findable {
            return Some(format!(
                "its position is uncertain by {:.0} mm (1σ), beyond {:.0} mm",
                sigma.position_m * 1e3,
                LOST_SIGMA_M * 1e3
            ));
        }
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let sensor = Point2::new(pose.x, pose.y) + heading * LINE_SENSOR_AHEAD_M;
        if at_rest.is_none() {
            e.rest_line = None;
            e.displaced_reads = 0;
        }
        let seen = Sight {
            pose,
            heading,
            sensor,
            position_um,
            driven,
            at_rest,
        };
        if sees_tape {
            self.stray_tape(e, &seen, sigma)
        } else {
            self.missing_tape(e, &seen)
        }
    }

    /// The sensor sees tape: a reading moved while standing widens the estimate, and tape seen
    /// where the model has none moves the estimate onto it when it can be only one tape, or
    /// contradicts the model once it was seen for long enough.
    fn stray_tape(&self, e: &mut Estimate, seen: &Sight, sigma: PoseUncertainty) -> Option<String> {
        let Sight {
            pose,
            heading,
            sensor,
            position_um,
            driven,
            at_rest,
        } = *seen;
        if let Some(moved_m) = self.displaced_at_rest(e, sensor, position_um, at_rest) {
            // Moved while standing, still on the tape: the sensor moved across the tape by
            // `moved_m`, by a shift or a turn about the robot's centre, and a reading at rest
            // cannot tell the two apart, nor see a shift along the tape. A robot that drove off
            // on such a turn met a wall 3 cm from where its model had it: it is lost, and the
            // re-localiser's follow along the tape measures its heading again.
            return Some(format!(
                "its line reading moved {:.1} mm while it stood",
                moved_m * 1e3
            ));
        }
        e.no_tape_m = 0.0;
        e.no_tape_plain_m = 0.0;
        e.no_tape_plain_at_rest = std::time::Duration::ZERO;
        e.no_tape_at_rest = std::time::Duration::ZERO;
        let right = Vector2::new(heading.y, -heading.x);
        let seen = sensor + right * (f64::from(position_um) * 1e-6);
        let far = self
            .track
            .nearest(seen)
            .is_none_or(|n| n.distance_m > STRAY_M.max(3.0 * sigma.position_m));
        e.stray_tape_m = if far {
            e.stray_tape_m + driven.abs()
        } else {
            0.0
        };
        // Crossing a tape, the sensor sees it for no more than its width, never the 25 mm
        // the rule below waits for; but the moment it comes onto a tape is as good a fix
        // across that tape.
        let crosses = far
            && !e.saw_tape
            && self
                .track
                .nearest(seen)
                .is_some_and(|n| n.tangent.dot(&heading).abs() < CROSSING_RAD.cos());
        if e.stray_tape_m > CONTRADICTION_M || crosses {
            // The tape the sensor follows is evidence of where the robot is: when it can be
            // only one tape near the estimate, the estimate moves across onto it (a pusher
            // whose wheels slipped under the load, backing up onto the track) and the robot
            // is not lost.
            if let Some((better, n)) = self.relocate(pose, position_um) {
                e.stray_tape_m = 0.0;
                e.correction = Correction::between(e.last_odometry.unwrap_or(pose), better);
                let h = RowVector3::new(n.x, n.y, 0.0);
                e.cov = corrected(&e.cov, h, h.transpose(), R_LATERAL_M2);
                e.stats.reassociations += 1;
                return None;
            }
            // A crossing that matches no tape unambiguously is no evidence either way; only
            // tape seen for longer contradicts the model.
            if e.stray_tape_m <= CONTRADICTION_M {
                return None;
            }
            return Some(format!(
                "its line sensor saw tape for {:.0} mm where the model has none",
                e.stray_tape_m * 1e3
            ));
        }
        None
    }

    /// The sensor sees no tape: where the model puts it squarely on one, for a distance driven,
    /// a time standing, or a follower that lost it, the model is contradicted.
    fn missing_tape(&self, e: &mut Estimate, seen: &Sight) -> Option<String> {
        let Sight {
            heading,
            sensor,
            driven,
            at_rest,
            ..
        } = *seen;
        e.stray_tape_m = 0.0;
        let tape = self.tape_along(&e.cov, sensor, heading);
        let squarely = tape.is_some_and(|t| t.distance_m + 2.0 * t.sigma_m < SQUARELY_M);
        e.no_tape_m = if squarely {
            e.no_tape_m + driven.abs()
        } else {
            0.0
        };
        // An estimate grown uncertain is never squarely on a tape, and so could drive on
        // unchallenged however long its sensor sees nothing: where its mean has the sensor
        // within half that of a tape's centre, the spots reach far enough either side that
        // seeing none over a longer run means the mean is off by more than a centimetre.
        // In a junction zone, where the tape along the heading is not told apart from its
        // neighbours, any tape plainly under the sensor's middle will do: robots wait on the
        // nodes there.
        let plainly = match tape {
            Some(t) => t.distance_m < SQUARELY_M / 2.0,
            None => {
                self.in_junction(sensor)
                    && self.track.nearest(sensor).is_some_and(|n| {
                        n.distance_m < SQUARELY_M / 2.0 && n.tangent.dot(&heading).abs() > 0.5
                    })
            }
        };
        e.no_tape_plain_m = if plainly {
            e.no_tape_plain_m + driven.abs()
        } else {
            0.0
        };
        e.no_tape_plain_at_rest = match at_rest {
            Some(dt) if plainly => e.no_tape_plain_at_rest + dt,
            _ => std::time::Duration::ZERO,
        };
        if e.no_tape_plain_m > PLAIN_CONTRADICTION_M {
            return Some(format!(
                "its line sensor saw no tape for {:.0} mm where the model's estimate has it on one",
                e.no_tape_plain_m * 1e3
            ));
        }
        if e.no_tape_plain_at_rest > 2 * CONTRADICTION_AT_REST {
            return Some(format!(
                "its line sensor saw no tape for {:.1} s standing where the model's estimate has \
                 it on one",
                e.no_tape_plain_at_rest.as_secs_f64()
            ));
        }
        // Time counts only while the robot stands: one that drives is judged by distance.
        // The row of spots stands across the heading: along it the tape is farther than across
        // the tape by 1/cos. One spot must be over the tape by a margin.
        let under_a_spot = tape.is_some_and(|t| {
            t.distance_m / t.cos + 2.0 * t.sigma_m < SPOTS_REACH_M + t.width_m / 2.0 - SPOT_MARGIN_M
        });
        e.no_tape_at_rest = match at_rest {
            Some(dt) if under_a_spot => e.no_tape_at_rest + dt,
            _ => std::time::Duration::ZERO,
        };
        if e.no_tape_m > CONTRADICTION_M {
            return Some(format!(
                "its line sensor saw no tape for {:.0} mm where the model puts it on one",
                e.no_tape_m * 1e3
            ));
        }
        // A follower loses its tape only by leaving it: where the model has it squarely on
        // one, the model is wrong (it was knocked aside, or slid off in a bend).
        if e.was_following && squarely {
            return Some("its follower lost the tape where the model puts it on one".into());
        }
        if e.no_tape_at_rest > CONTRADICTION_AT_REST {
            return Some(format!(
                "its line sensor saw no tape for {:.1} s standing where the model puts it on one",
                e.no_tape_at_rest.as_secs_f64()
            ));
        }
        None
    }

    /// How far the line reading of a robot standing still on a tape moved while its wheels did
    /// not, once it has for long enough: the robot was moved. Such a kick can turn the robot or
    /// shift it across its tape by centimetres while the sensor still sees the tape, and a
    /// sighting at rest is no evidence for the filter; the robot then drives off on a heading the
    /// model does not have, and by the time its sensor loses the tape it is far from where the
    /// model puts it. Junctions and tape ends are left out: there a spot can see another tape's
    /// edge come and go.
    pub(super) fn displaced_at_rest(
        &self,
        e: &mut Estimate,
        sensor: Point2<f64>,
        position_um: i16,
        at_rest: Option<std::time::Duration>,
    ) -> Option<f64> {
        at_rest?;
        let clear = !self.in_junction(sensor)
            && self
                .track
                .nearest(sensor)
                .is_some_and(|n| self.clear_of_ends(&n, self.track.edge_length(n.edge)));
        if !clear {
            e.rest_line = None;
            e.displaced_reads = 0;
            return None;
        }
        let first = *e.rest_line.get_or_insert(position_um);
        let moved_um = (i32::from(position_um) - i32::from(first)).abs();
        if moved_um <= DISPLACED_AT_REST_UM {
            e.displaced_reads = 0;
            return None;
        }
        e.displaced_reads += 1;
        if e.displaced_reads < DISPLACED_READS {
            return None;
        }
        // Where it stands now is the new reference: the move is counted once.
        e.rest_line = Some(position_um);
        e.displaced_reads = 0;
        Some(f64::from(moved_um) * 1e-6)
    }
}
