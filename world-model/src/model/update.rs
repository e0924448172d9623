//! One state update taken into the model: the odometry step carried into the covariance, the
//! tape and the marks the line sensor sees matched against the track, and the robot found lost
//! when what it senses contradicts the model.

use super::*;

/// What one update says besides the pose: the odometry step and the line sensor's reading.
#[derive(Clone, Copy)]
struct Reading {
    /// Distance driven along the mean heading since the last update, metres.
    driven: f64,
    /// Heading turned since the last update, radians.
    turned: f64,
    sees_tape: bool,
    /// The firmware follows the tape it sees.
    following: bool,
    position_um: i16,
}

/// The odometry step since the last update, carried into the estimate: the corrected pose it
/// gives and the reading to correct it with.
fn predict(e: &mut Estimate, u: &StateUpdated) -> (Pose, Reading) {
    let (driven, turned) = e.last_odometry.map_or((0.0, 0.0), |p| {
        let turned = wrap_angle(u.pose.theta - p.theta);
        let mid = p.theta + turned / 2.0;
        let step = Vector2::new(u.pose.x - p.x, u.pose.y - p.y);
        (step.dot(&Vector2::new(mid.cos(), mid.sin())), turned)
    });
    if e.last_odometry.is_none() {
        // A robot may start on a mark: that is no mark's end.
        e.last_mark = u.state.line.mark;
    }
    e.last_odometry = Some(u.pose);
    let pose = e.correction.apply(u.pose);
    // The odometry step carries the covariance forward: the heading's uncertainty becomes
    // uncertainty across the path, and each step adds its own noise.
    let mid = pose.theta - turned / 2.0;
    let (s, c) = mid.sin_cos();
    let f = Matrix3::new(1.0, 0.0, -driven * s, 0.0, 1.0, driven * c, 0.0, 0.0, 1.0);
    let g = Vector3::new(c, s, 0.0);
    let q_heading = Q_HEADING_RAD2_PER_M * driven.abs() + Q_HEADING_RAD2_PER_RAD * turned.abs();
    e.cov = f * e.cov * f.transpose()
        + g * g.transpose() * (Q_ALONG_M2_PER_M * driven.abs())
        + Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, q_heading));
    let sees_tape = u.state.line.flags & LINE_LOST == 0;
    let following = sees_tape && u.state.line.flags & LINE_FOLLOWING != 0;
    let reading = Reading {
        driven,
        turned,
        sees_tape,
        following,
        position_um: u.state.line.position_um,
    };
    (pose, reading)
}

impl WorldModel {
    /// Takes one state update; says when the robot's localisation changed.
    pub fn apply(&self, u: &StateUpdated) -> Option<Transition> {
        let mut e = self
            .estimates
            .get(&u.robot_id)
            .map(|e| e.clone())
            .unwrap_or_default();
        let (mut pose, r) = predict(&mut e, u);
        let mut transition = None;
        let searching = e.lost.as_ref().is_some_and(|l| !l.fixed);
        if searching {
            if r.sees_tape {
                (pose, transition) = self.fix_lost(&mut e, u, &r, pose);
            }
        } else if r.sees_tape {
            (pose, transition) = self.correct_on_tape(&mut e, u, &r, pose);
            pose = self.correct_at_mark(&mut e, u, &r, pose);
        }
        if u.state.line.mark == e.last_mark {
            e.mark_held_m += r.driven.abs();
        } else {
            e.mark_held_m = 0.0;
        }
        e.last_mark = u.state.line.mark;
        let since_last = e.last_at.map_or(std::time::Duration::ZERO, |t| {
            u.at.saturating_duration_since(t)
        });
        e.last_at = Some(u.at);
        if e.lost.is_none() {
            let at_rest = (r.driven.abs() <= 1e-4 && r.turned.abs() <= 1e-3).then_some(since_last);
            let why =
                self.contradiction(&mut e, pose, r.sees_tape, r.position_um, r.driven, at_rest);
            // A contradiction may have been resolved by moving the estimate.
            pose = e.correction.apply(u.pose);
            if let Some(why) = why {
                lose(&mut e, u);
                transition = Some(Transition::Lost(why));
            }
        }
        e.saw_tape = r.sees_tape;
        e.was_following = r.following;
        let uptime = u.state.uptime_ms;
        while e
            .recent
            .front()
            .is_some_and(|&(t, _)| uptime.wrapping_sub(t) > RECENT_MS)
        {
            e.recent.pop_front();
        }
        e.recent.push_back((uptime, pose));
        self.publish(u, e, pose);
        transition
    }

    /// A lost robot that sees tape near its estimate: the position across that tape is fixed.
    fn fix_lost(
        &self,
        e: &mut Estimate,
        u: &StateUpdated,
        r: &Reading,
        pose: Pose,
    ) -> (Pose, Option<Transition>) {
        let Some((better, n)) = self.relocate(pose, r.position_um) else {
            return (pose, None);
        };
        e.correction = Correction::between(u.pose, better);
        let h = RowVector3::new(n.x, n.y, 0.0);
        e.cov = corrected(&e.cov, h, h.transpose(), R_LATERAL_M2);
        if let Some(l) = e.lost.as_mut() {
            l.fixed = true;
        }
        (better, Some(Transition::Fixed))
    }

    /// A tracked robot that sees tape: the reading matched to the track corrects the pose (a
    /// follower's through the match, one driving moves through the filter's gain); a lost robot
    /// whose reading matches is found.
    fn correct_on_tape(
        &self,
        e: &mut Estimate,
        u: &StateUpdated,
        r: &Reading,
        mut pose: Pose,
    ) -> (Pose, Option<Transition>) {
        let Reading {
            driven,
            turned,
            following,
            position_um,
            ..
        } = *r;
        let mut found = None;
        let sigma = sigmas(&e.cov);
        let (gate_m, gate_rad) = if following {
            // A follower is on some tape whatever the model says: the gates widen with the
            // distance it followed tape without a match.
            let widen = GATE_GROWTH_PER_M * e.unmatched_m;
            (
                (MATCH_M + widen)
                    .max(3.0 * sigma.position_m)
                    .min(MATCH_MAX_M),
                (ALIGNED_RAD + widen / MATCH_MAX_M * ALIGNED_RAD).min(ALIGNED_MAX_RAD),
            )
        } else {
            (
                MATCH_M.max(3.0 * sigma.position_m).min(MATCH_MAX_M),
                (ALIGNED_RAD + 3.0 * sigma.heading_rad).min(ALIGNED_MAX_RAD),
            )
        };
        // A robot driving moves is corrected by the filter's own gain, through which a
        // lateral offset that keeps growing as it drives also corrects its heading; one
        // standing still reads the same offset again and again, which is no new evidence.
        let moved = driven.abs() > 1e-4 || turned.abs() > 1e-3;
        let matched = if following {
            self.match_tape(pose, position_um, gate_m, gate_rad)
                .map(|m| {
                    let h = RowVector3::new(m.normal.x, m.normal.y, 0.0);
                    e.cov = corrected(&e.cov, h, h.transpose() * LATERAL_GAIN, R_LATERAL_M2);
                    if m.heading_gain > 0.0 {
                        let h = RowVector3::new(0.0, 0.0, 1.0);
                        e.cov =
                            corrected(&e.cov, h, h.transpose() * m.heading_gain, R_HEADING_RAD2);
                    }
                    m.pose
                })
        } else if moved {
            self.filter_tape(pose, &e.cov, position_um, gate_rad)
                .map(|(better, cov)| {
                    e.cov = cov;
                    better
                })
        } else {
            None
        };
        if let Some(better) = matched {
            pose = better;
            e.correction = Correction::between(u.pose, pose);
            e.unmatched_m = 0.0;
            if let Some(l) = e.lost.take() {
                e.stats.lost_time += u.at.saturating_duration_since(l.since);
                found = Some(Transition::Found);
            }
        } else if following {
            e.unmatched_m += driven.abs();
        }
        (pose, found)
    }

    /// A robot whose colour sensor crosses a mark's end: the pose along the tape is corrected to
    /// that end.
    fn correct_at_mark(&self, e: &mut Estimate, u: &StateUpdated, r: &Reading, pose: Pose) -> Pose {
        let Reading {
            driven,
            turned,
            following,
            ..
        } = *r;
        let mark = u.state.line.mark;
        // A robot driving moves counts a change of colour only after the old colour held for
        // a while: at a mark's edge its colour sensor flickers.
        // It must also be driving along, not turning on the spot (which sweeps the sensor
        // off a mark and back), and the end must be within what its uncertainty allows.
        let settled = following
            || (e.mark_held_m > MARK_SETTLED_M && driven.abs() > 1e-4 && turned.abs() < 0.01);
        // A follower's odometry slips by more than its covariance says, so its gate is wide;
        // but an estimate widened by a loss or a bump is honest about how far off it may be,
        // and a mark end beyond that is another mark's (one 56 mm off moved a robot just found
        // onto the wrong end and it drove into another).
        let sigma_m = sigmas(&e.cov).position_m;
        let gate_m = if following && sigma_m < WIDENED_SIGMA_M {
            MARK_GATE_M
        } else {
            (3.0 * sigma_m).clamp(MARK_GATE_MIN_M, MARK_GATE_M)
        };
        if mark == e.last_mark || !settled {
            return pose;
        }
        let colour = if mark != 0 { mark } else { e.last_mark };
        let entering = mark != 0;
        let Some((better, t)) = self.at_mark_end(pose, colour, entering, following, gate_m) else {
            return pose;
        };
        e.correction = Correction::between(u.pose, better);
        let h = RowVector3::new(t.x, t.y, 0.0);
        e.cov = corrected(&e.cov, h, h.transpose() * MARK_GAIN, R_MARK_M2);
        better
    }

    /// Stores the estimate and writes the robot's view: pose, state, place on the track,
    /// uncertainty and localisation.
    fn publish(&self, u: &StateUpdated, mut e: Estimate, pose: Pose) {
        let uncertainty = sigmas(&e.cov);
        e.stats.worst_uncertainty_m = e.stats.worst_uncertainty_m.max(uncertainty.position_m);
        let localisation = if e.lost.is_some() {
            Localisation::Lost
        } else {
            Localisation::Tracking
        };
        self.estimates.insert(u.robot_id, e);
        let (s, c) = pose.theta.sin_cos();
        let sensor = Point2::new(
            pose.x + LINE_SENSOR_AHEAD_M * c,
            pose.y + LINE_SENSOR_AHEAD_M * s,
        );
        // Only robots over tape are looked up: most of the floor is white.
        let on_track = if self.track.floor_at(sensor).ir_reflectance < 0.9 {
            self.track
                .nearest(sensor)
                .filter(|n| n.distance_m < ON_TRACK_M)
                .map(|n| behaviour_api::TrackPosition {
                    edge: n.edge,
                    along_m: n.offset_m,
                    offset_m: n.distance_m,
                })
        } else {
            None
        };
        // Noted before the map's write guard is taken: a snapshot holds the list's lock while it
        // reads the map, so the other order could deadlock across threads.
        self.changed(u.robot_id);
        if let Some(mut entry) = self.robots.get_mut(&u.robot_id) {
            let view = Arc::make_mut(&mut entry);
            view.connected = true;
            view.pose = pose;
            view.odometry = u.pose;
            view.state = u.state;
            view.front_close_at = if u.state.proximity.front_obstacle == 1 {
                view.front_close_at.or(Some(pose))
            } else {
                None
            };
            view.pending_moves = usize::from(u.state.locomotion.queue_len);
            view.on_track = on_track;
            view.uncertainty = uncertainty;
            view.localisation = localisation;
        }
    }
}

/// What a robot felt of a bump, as its `Bump` event says.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Felt {
    /// How far it was moved, metres (0 when only its wheels turning at rest gave it away).
    pub moved_m: f64,
    /// The move along its heading and to its left, metres.
    pub along_m: f64,
    /// See `along_m`.
    pub left_m: f64,
    /// When the jolt began, the robot's uptime in milliseconds.
    pub since_ms: u32,
}

impl WorldModel {
    /// Robot `id` felt itself moved by something other than its wheels from its uptime
    /// `since_ms` on, by about `moved_m` (the robot's own estimate). Where tape is within reach
    /// a jolt under 15 mm straight along the heading (the robot's own drive into something) is
    /// given back to the odometry and the robot stays tracked; any other goes to halfway between
    /// where the estimate stood before the jolt and the felt move's end, is widened to cover
    /// the move and a turn the accelerometer cannot feel, and the robot is lost until the tape
    /// fixes it again: a hand that shifts a robot also turns it, and a turn is what makes a
    /// confident model wrong by decimetres a few seconds later. Wheels turned while it stood on
    /// a plain stretch of tape are left to the line reading at rest, which sees a shift or turn there;
    /// at a junction or a tape's end it cannot, and the robot is lost. Where no tape is within
    /// reach it is only widened: nothing could fix it there. Returns why the robot is lost, for
    /// the supervisor to stop and re-localise it; `None` when it is not, or the model has no
    /// estimate of it yet.
    pub fn bumped(&self, id: u16, felt: Felt, at: tokio::time::Instant) -> Option<String> {
        let Felt {
            moved_m,
            along_m,
            left_m,
            since_ms,
        } = felt;
        // The robot's word is bounded by what a bump can be: a robot reporting metres (a broken
        // accelerometer, a lying peer) widens the estimate no farther than a credible bump.
        let moved_m = moved_m.clamp(0.0, BUMP_CREDIBLE_M);
        let mut e = self.estimates.get_mut(&id)?;
        // A robot that has not reported yet has no estimate to widen.
        let odometry = e.last_odometry?;
        let here = e.recent.back().map(|&(_, p)| p)?;
        let centre = Point2::new(here.x, here.y);
        let tape_near = self
            .track
            .nearest(centre)
            .is_some_and(|n| n.distance_m < RELOCATE_M + BUMP_MAX_M);
        let wheels_only = along_m == 0.0 && left_m == 0.0;
        if tape_near && wheels_only {
            let (s, c) = here.theta.sin_cos();
            let sensor = centre + Vector2::new(c, s) * LINE_SENSOR_AHEAD_M;
            let plain = !self.in_junction(sensor)
                && self
                    .track
                    .nearest(sensor)
                    .is_some_and(|n| self.clear_of_ends(&n, self.track.edge_length(n.edge)));
            // Only its wheels turned while it stood: the odometry counted them already, and on
            // a plain stretch of tape the line reading's own rule (`displaced_at_rest`) judges
            // the move.
            if plain {
                return None;
            }
        }
        if !tape_near {
            // It drives on, as uncertain as the move made it; the others keep that much
            // farther away.
            widen(
                &mut e.cov,
                (BUMP_MARGIN * moved_m).clamp(LOST_FLOOR_M, BUMP_MAX_M),
                BUMP_TURN_RAD,
            );
            drop(e);
            self.show_estimate(id, None, false);
            return None;
        }
        // A small jolt straight along the heading is what a robot's own drive into something
        // (an obstacle met, a slip under a load) feels: the odometry's error, given back, and
        // the robot stays tracked. Lost, the re-localiser's line follower would drive it on
        // into what stopped it.
        if !wheels_only
            && moved_m < BUMP_LOST_M
            && e.lost.is_none()
            && left_m.abs() <= ALONG_ONLY_M.max(along_m.abs() / 4.0)
        {
            let along_m = along_m.clamp(-BUMP_LOST_M, BUMP_LOST_M);
            let (s, c) = here.theta.sin_cos();
            let back = Pose {
                x: here.x + along_m * c,
                y: here.y + along_m * s,
                theta: here.theta,
            };
            e.correction = Correction::between(odometry, back);
            widen(&mut e.cov, BUMP_MARGIN * moved_m, SMALL_BUMP_TURN_RAD);
            drop(e);
            self.show_estimate(id, Some(back), false);
            return None;
        }
        if e.lost.is_none() {
            e.stats.lost_episodes += 1;
        }
        start_lost(&mut e, at);
        // From where the estimate stood before the jolt began (what the odometry counted since
        // is the dragged wheels', not travel) halfway along the felt move: the true move lies
        // between none and all of it.
        let mut pose = None;
        if let Some(&(_, before)) = e
            .recent
            .iter()
            .rev()
            .find(|&&(t, _)| t.wrapping_add(BUMP_BEFORE_MS) <= since_ms)
        {
            let (s, c) = before.theta.sin_cos();
            let half = |m: f64| m.clamp(-BUMP_CREDIBLE_M, BUMP_CREDIBLE_M) / 2.0;
            let half = (half(along_m), half(left_m));
            let mid = Pose {
                x: before.x + half.0 * c - half.1 * s,
                y: before.y + half.0 * s + half.1 * c,
                theta: before.theta,
            };
            e.correction = Correction::between(odometry, mid);
            pose = Some(mid);
        }
        // The felt move misses what the robot could not feel (a turn about its centre, the
        // start of the jolt), and along the heading it may be several times the true one. It
        // stays below the lost limit: once the tape fixes it across,
        // along the tape it stays this uncertain until a mark, and beyond the limit it would
        // be lost again at once.
        widen(
            &mut e.cov,
            (HALF_BUMP_MARGIN * moved_m + HALF_BUMP_SLACK_M).clamp(LOST_FLOOR_M, BUMP_MAX_M),
            BUMP_TURN_RAD,
        );
        drop(e);
        self.show_estimate(id, pose, true);
        Some(if wheels_only {
            "its wheels turned while it stood where its line sensor cannot tell a shift".into()
        } else {
            format!("it felt a bump that moved it about {:.0} mm", moved_m * 1e3)
        })
    }

    /// Robot `id` is taken over from an earlier host's record (`coordinator --resume`): before
    /// its first update, its estimate starts as uncertain as that record, widened for the gap,
    /// instead of as well known as a world file's start pose.
    pub fn resume(&self, id: u16, position_m: f64, heading_rad: f64) {
        let mut e = Estimate::default();
        widen(&mut e.cov, position_m, heading_rad);
        self.estimates.insert(id, e);
        self.show_estimate(id, None, false);
    }

    /// The search for lost robot `id` ended without finding it (no tape seen, or the tape it
    /// was put on did not match as it followed it): the next search starts afresh, its position
    /// across a tape not fixed (a fix the follow disproved would otherwise keep the next
    /// search's sightings from fixing it again) and as uncertain as a robot just found lost.
    pub fn search_afresh(&self, id: u16, at: tokio::time::Instant) {
        let Some(mut e) = self.estimates.get_mut(&id) else {
            return;
        };
        start_lost(&mut e, at);
        widen(&mut e.cov, LOST_FLOOR_M, LOST_FLOOR_RAD);
        drop(e);
        self.show_estimate(id, None, true);
    }

    /// Writes robot `id`'s estimate, changed outside a state update (a bump, a search begun
    /// afresh, a settled follow), into its view: its uncertainty, its pose when that moved, and
    /// lost when it is.
    pub(super) fn show_estimate(&self, id: u16, pose: Option<Pose>, lost: bool) {
        let Some(uncertainty) = self.estimates.get_mut(&id).map(|mut e| {
            let u = sigmas(&e.cov);
            e.stats.worst_uncertainty_m = e.stats.worst_uncertainty_m.max(u.position_m);
            u
        }) else {
            return;
        };
        // Noted before the map's write guard is taken, as `publish` does.
        self.changed(id);
        if let Some(mut entry) = self.robots.get_mut(&id) {
            let view = Arc::make_mut(&mut entry);
            view.uncertainty = uncertainty;
            if let Some(p) = pose {
                view.pose = p;
            }
            if lost {
                view.localisation = Localisation::Lost;
            }
        }
    }
}

/// Lost from `at` on, searching afresh: the evidence counters restart.
fn start_lost(e: &mut Estimate, at: tokio::time::Instant) {
    let since = e.lost.as_ref().map_or(at, |l| l.since);
    e.lost = Some(Lost {
        since,
        fixed: false,
    });
    e.no_tape_m = 0.0;
    e.no_tape_plain_m = 0.0;
    e.no_tape_plain_at_rest = std::time::Duration::ZERO;
    e.no_tape_at_rest = std::time::Duration::ZERO;
    e.stray_tape_m = 0.0;
    e.rest_line = None;
    e.displaced_reads = 0;
}

/// The robot is found lost: its evidence counters restart and its covariance is widened to what
/// the contradiction says the estimate may be off by.
fn lose(e: &mut Estimate, u: &StateUpdated) {
    start_lost(e, u.at);
    e.stats.lost_episodes += 1;
    // The contradiction says the estimate is off by at least what the line sensor
    // reaches either side; the safety check keeps everyone that much farther away.
    // The heading may be what is wrong (a turn that slipped): once the tape fixes
    // the position across it, driving along it measures the heading again.
    widen(&mut e.cov, LOST_FLOOR_M, LOST_FLOOR_RAD);
}
