//! Carrying on after a disturbance from the push on. The pushers' wheels have slipped under the box
//! by an amount nothing measures, so no route can be planned from their poses; only the tape can
//! take them back. The team stops, and each robot in turn, the one farthest along the track first,
//! gets onto the tape: a lost robot is put there by the supervisor's search, one beside it drives
//! straight until its sensor crosses it, and a robot already on it (first) faces along it. Whoever stands on the
//! tape where the next must come onto it first moves along. Then the team laps, which finds the box
//! again if it still stands on the track.

use super::*;

/// A robot already on the tape moves along it until it is this far ahead of the place where the
/// next robot comes onto it (sensor to centre), or this far behind it: clear of a 48 mm body with
/// a turn's corners, and of the uncertainty of both poses.
const CLEAR_BEHIND: f64 = 0.07;
/// A robot facing within about 25° of the track's direction needs no turn to follow it.
const ALONG_COS: f64 = 0.9;
/// A robot facing within 60° of straight across the tape drives straight onto it.
const FACING_ACROSS_COS: f64 = 0.5;

impl CooperativePush {
    /// A robot lost from the push on: stop the team and bring each robot back onto the tape in
    /// turn, at most [`regroup::MAX_REGROUPS`] times together with the regroups before the push.
    pub(super) fn rejoin(
        &mut self,
        why: String,
        world: &WorldSnapshot,
        team: &Team,
    ) -> Vec<Intent> {
        self.regroups += 1;
        if self.regroups > regroup::MAX_REGROUPS {
            return self.fail(format!(
                "{why}; the team regrouped {} time(s) and gives up",
                regroup::MAX_REGROUPS
            ));
        }
        tracing::debug!(%why, regroups = self.regroups, "cooperative_push rejoins the tape");
        if self.phase == Phase::Push {
            // A push cut short counts if it did its work: the box gave way to every pusher and
            // each drove its share. Otherwise the laps find the box still on the track.
            if self.push_evidence().is_ok() {
                self.push_time = Some(world.time.saturating_sub(self.push_started));
            }
        }
        self.regroup_why = Some(why);
        self.retry_at = None;
        for b in self.bots.values_mut() {
            b.backing = None;
            b.aligning = None;
            b.seeking = false;
        }
        self.enter(Phase::Rejoin, world);
        self.stop_team(world, team)
    }

    /// One step of the rejoin: while a robot is searched for, only those on the tape ahead of it
    /// move, away from it; then the next robot off the tape (or not yet facing along it), the
    /// one farthest along, gets onto it after those in its way have moved along; once all are on
    /// it, the team laps.
    pub(super) fn rejoining(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        if self.retry_at.is_some_and(|t| world.time < t) {
            return Vec::new();
        }
        self.retry_at = None;
        let Some(site) = self.site else {
            return self.fail("the team lost the box's place after the push".into());
        };
        let tracked = |id: u16| {
            world
                .robot(id)
                .is_some_and(|v| v.localisation == Localisation::Tracking)
        };
        let ids: Vec<u16> = self.bots.keys().copied().collect();
        let still = |id: u16| Self::at_rest(id, world, team);
        let along = |id: u16| {
            world.robot(id).map_or(0.0, |v| {
                (Vector2::new(v.pose.x, v.pose.y) - site.centre.coords).dot(&site.along)
            })
        };
        if ids.iter().any(|id| {
            self.bots
                .get(id)
                .is_some_and(|b| b.backing.is_some() || b.aligning.is_some())
        }) {
            return self.align_on_tape(world);
        }
        // Nobody drives beside a robot being searched for: the safety check sweeps a drive onto
        // the tape only at its start, and one backing beside a lost pusher touched it. Only a
        // robot already on the tape ahead of it follows the tape away, making room for it.
        let lost: Vec<u16> = ids.iter().copied().filter(|&id| !tracked(id)).collect();
        if !lost.is_empty() {
            let mut out = Vec::new();
            for &id in &ids {
                if lost.contains(&id)
                    || !team.idle(id)
                    || !self.bots.get(&id).is_some_and(|b| b.rejoined)
                {
                    continue;
                }
                let ahead = lost
                    .iter()
                    .map(|&l| along(id) - along(l))
                    .fold(f64::INFINITY, f64::min);
                let go = (0.0..REJOIN_GAP).contains(&ahead);
                if go != team.following(id).is_some() {
                    out.push(Intent::FollowLine {
                        robot: id,
                        speed: go.then_some(self.speed),
                    });
                }
            }
            return out;
        }
        // One the search put on the tape comes first: it may stand where another backs onto it,
        // and only once it faces along the tape can it move along out of the way.
        let on_tape =
            |id: u16| tracked(id) && world.robot(id).is_some_and(|v| v.on_track.is_some());
        let next = ids
            .iter()
            .copied()
            .filter(|id| self.bots.get(id).is_some_and(|b| !b.rejoined))
            .max_by(|a, b| {
                (on_tape(*a), along(*a))
                    .partial_cmp(&(on_tape(*b), along(*b)))
                    .unwrap_or(std::cmp::Ordering::Equal)
            });
        let Some(n) = next else {
            if ids.iter().all(|&id| still(id)) {
                return self.follow_again(world, team);
            }
            return ids
                .iter()
                .filter(|&&id| team.following(id).is_some())
                .map(|&robot| Intent::FollowLine { robot, speed: None })
                .collect();
        };
        // Those on the tape where `n` comes onto it move along it first: ahead of it forwards,
        // just behind it backwards.
        let mut out = Vec::new();
        let mut busy = false;
        for &id in &ids {
            if id == n || !self.bots.get(&id).is_some_and(|b| b.rejoined) {
                continue;
            }
            let d = along(id) - along(n);
            let following = team.following(id).is_some();
            if !team.idle(id) {
                // Its turn to face along the tape is not done: a follow now would drive it on
                // the way it faces.
                busy = true;
            } else if (0.0..REJOIN_GAP).contains(&d) {
                busy = true;
                if !following {
                    out.push(Intent::FollowLine {
                        robot: id,
                        speed: Some(self.speed),
                    });
                }
            } else if following {
                busy = true;
                out.push(Intent::FollowLine {
                    robot: id,
                    speed: None,
                });
            } else if !still(id) {
                busy = true;
            } else if d > -CLEAR_BEHIND && d < 0.0 {
                busy = true;
                if let Some(v) = world.robot(id) {
                    let route =
                        Manoeuvre::from(v.pose, MANOEUVRE_MPS).straight(-(CLEAR_BEHIND + d));
                    out.extend(self.send(id, route));
                }
            }
        }
        if busy || !still(n) {
            return out;
        }
        let Some(view) = world.robot(n) else {
            return out;
        };
        let heading = Vector2::new(view.pose.theta.cos(), view.pose.theta.sin());
        let across = site.sensor_across(view.pose);
        tracing::debug!(
            robot = n,
            across,
            on_track = view.on_track.is_some(),
            "rejoin: next"
        );
        if view.on_track.is_some() {
            // On the tape already (a search put it there): face along it.
            if let Some(b) = self.bots.get_mut(&n) {
                b.rejoined = true;
            }
            if heading.dot(&site.along) < ALONG_COS {
                let route =
                    Manoeuvre::from(view.pose, MANOEUVRE_MPS).turn_to(Site::heading(site.along));
                out.extend(self.send(n, route));
            }
        } else if heading.dot(&site.push).abs() > FACING_ACROSS_COS {
            // Beside the tape, facing across it: straight towards it until the sensor crosses
            // it, backwards from beyond where the box stood, forwards from short of it.
            let forwards = across * heading.dot(&site.push) < 0.0;
            out.extend(self.onto_tape(n, forwards));
        } else {
            return self.fail(format!(
                "robot {n} stands off the tape, facing along it, where driving straight cannot \
                 take it back ({})",
                self.regroup_why.as_deref().unwrap_or("a disturbance")
            ));
        }
        out
    }

    /// A move or a drive of the rejoin was held: the robot is not back on the tape; try again a
    /// little later.
    pub(super) fn rejoin_held(&mut self, id: u16, world: &WorldSnapshot) {
        if let Some(b) = self.bots.get_mut(&id) {
            b.rejoined = false;
            b.backing = None;
            b.aligning = None;
        }
        self.retry_at = Some(world.time + Duration::from_millis(1000));
    }
}
