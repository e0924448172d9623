//! Carrying on after a disturbance: a pusher lost and found again, a move the safety check held or
//! an aborted manoeuvre while the team gathers at the box sends it back onto the tape behind the
//! box, one robot after the other, to find it and place itself again.

use super::*;

/// Regroups before the run gives up.
pub(super) const MAX_REGROUPS: u32 = 3;
/// Where the robot nearer the box waits on the tape behind it, from the box's near face to its
/// front, and how much farther back the other waits: more than the followers' stop gap, so that
/// both follow again at once.
const REGROUP_BEHIND: f64 = 0.06;
const REGROUP_SPACING: f64 = 0.15;
/// The regroup's lane runs this far below the slots: a robot backing down there keeps its rear
/// 25 mm from the push world's wall, beyond its reflex's reach, and one turning there clears the
/// other pusher still in its slot by 9 mm (no one passes another: the one farthest behind goes
/// first).
const REGROUP_BELOW: f64 = 0.045;
/// A robot whose heading is within about 35° of the push direction faces the box.
const FACING_BOX_COS: f64 = 0.8;
/// A robot whose centre is this close to the tape, heading within about 20° of it, stands on it.
const ON_TAPE_M: f64 = 0.01;
const ALONG_TAPE_COS: f64 = 0.94;
/// A route the safety check held is tried again this much later.
const REGROUP_RETRY: Duration = Duration::from_millis(1000);

impl CooperativePush {
    /// Something went wrong with the work around the box: stop every robot and send the team back
    /// onto the tape behind it, at most [`MAX_REGROUPS`] times; then the run fails with `why`.
    pub(super) fn regroup(
        &mut self,
        why: String,
        world: &WorldSnapshot,
        team: &Team,
    ) -> Vec<Intent> {
        // From the push on, the pushers' wheels have slipped under the box by an amount nothing
        // measures until their sensors find the tape again (a push the box did not give way to
        // leaves the model up to 15 cm ahead of them): a route planned from such a pose backed
        // robots into the wall. A held move or a stop there is a model that disagrees with
        // what stands around the robots, unseen (a pusher put down turned, which nothing
        // feels): driving on beside each other on it touched, and the run ends instead. A robot
        // lost (a felt bump) is searched for, and the team rejoins the tape ([`Self::rejoin`]).
        if self.after_push() {
            return self.fail(why);
        }
        self.regroups += 1;
        if self.regroups > MAX_REGROUPS {
            return self.fail(format!(
                "{why}; the team regrouped {MAX_REGROUPS} time(s) and gives up"
            ));
        }
        tracing::debug!(%why, regroups = self.regroups, "cooperative_push regroups");
        self.regroup_why = Some(why);
        self.routed.clear();
        self.retry_at = None;
        for b in self.bots.values_mut() {
            b.backing = None;
            b.aligning = None;
            b.crossed_tape = false;
            b.seeking = false;
        }
        self.enter(Phase::Regroup, world);
        self.stop_team(world, team)
    }

    /// Every tracked robot stopped (the supervisor stops lost ones itself), every reflex on.
    pub(super) fn stop_team(&self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let mut out: Vec<Intent> = team
            .ids()
            .filter(|&id| {
                world
                    .robot(id)
                    .is_some_and(|v| v.localisation == Localisation::Tracking)
            })
            .map(|robot| Intent::Stop { robot })
            .collect();
        out.extend(self.reflexes(REFLEX_ON));
        out
    }

    /// Whether `id` stands still with nothing to do: no move out, no follow, wheels at rest.
    pub(super) fn at_rest(id: u16, world: &WorldSnapshot, team: &Team) -> bool {
        world.robot(id).is_some_and(|v| {
            let w = v.state.wheels;
            team.idle(id)
                && team.following(id).is_none()
                && w.left_mps.abs() < 0.005
                && w.right_mps.abs() < 0.005
        })
    }

    /// The robot `id` is lost: its moves were dropped, and it is re-localised before it takes
    /// intents again. While following it resumes by itself once found; around the box the team
    /// regroups.
    pub(super) fn robot_lost(
        &mut self,
        id: u16,
        why: &str,
        world: &WorldSnapshot,
        team: &Team,
    ) -> Vec<Intent> {
        // Wherever it was, it is not on the tape as the team last knew it.
        if let Some(b) = self.bots.get_mut(&id) {
            b.rejoined = false;
        }
        match self.phase {
            Phase::Approach | Phase::Lapping => Vec::new(),
            // Already regrouping: its route, if it had one, is planned again once it is found.
            Phase::Regroup => {
                self.routed.retain(|r| *r != id);
                Vec::new()
            }
            // The team stops (the supervisor stopped those moving near it) and starts again.
            _ if self.after_push() => {
                self.rejoin(format!("robot {id} was lost ({why})"), world, team)
            }
            _ => self.regroup(format!("robot {id} was lost ({why})"), world, team),
        }
    }

    /// From the push on: the pushers' poses are off by their unmeasured slip.
    pub(super) fn after_push(&self) -> bool {
        matches!(
            self.phase,
            Phase::Push
                | Phase::FinderRejoins
                | Phase::HelperWaits
                | Phase::HelperRejoins
                | Phase::Rejoin
        )
    }

    /// One step of the regroup: once every robot is tracked and at rest, each in turn (the one
    /// farthest behind first) drives down to a lane below the slots, back along it and up onto
    /// the tape behind the box; once all stand there, they follow the tape again to find it.
    pub(super) fn regrouping(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        if self.retry_at.is_some_and(|t| world.time < t) {
            return Vec::new();
        }
        self.retry_at = None;
        let ready = |id: u16| {
            world
                .robot(id)
                .is_some_and(|v| v.localisation == Localisation::Tracking)
                && Self::at_rest(id, world, team)
        };
        let Some(site) = self.site else {
            // Lost before the box was placed: everyone is on the tape; follow it again.
            if team.ids().all(ready) {
                return self.follow_again(world, team);
            }
            return Vec::new();
        };
        // The robot farthest behind goes first, to the farther place: no one passes another in
        // the lane.
        let along = |id: u16| {
            world.robot(id).map_or(0.0, |v| {
                (Vector2::new(v.pose.x, v.pose.y) - site.centre.coords).dot(&site.along)
            })
        };
        let mut order: Vec<u16> = self.bots.keys().copied().collect();
        order.sort_by(|a, b| along(*a).total_cmp(&along(*b)));
        let n = order.len();
        for (rank, id) in order.iter().copied().enumerate() {
            if self.routed.contains(&id) {
                continue;
            }
            // One at a time, in order.
            if !ready(id) || !order[..rank].iter().all(|&o| ready(o)) {
                return Vec::new();
            }
            let Some(view) = world.robot(id) else {
                return Vec::new();
            };
            self.routed.push(id);
            let place = (n - 1 - rank) as f64;
            let behind = -(self.box_half + HALF_LEN + REGROUP_BEHIND + place * REGROUP_SPACING);
            return self.send(id, self.back_behind(view.pose, &site, behind));
        }
        if order.iter().all(|&id| ready(id)) {
            return self.follow_again(world, team);
        }
        Vec::new()
    }

    /// A regroup route was held: the robot stands where it is; plan it again a little later.
    pub(super) fn route_held(&mut self, id: u16, world: &WorldSnapshot) {
        self.routed.retain(|r| *r != id);
        self.retry_at = Some(world.time + REGROUP_RETRY);
    }

    /// From `pose` down to the approach lane, along it until clear of the box, up onto the tape
    /// there, facing the way the team follows it, and back along the tape to `behind` the box's
    /// centre. A robot facing the box (in its slot, or after a push) backs straight down: a turn
    /// there would sweep its corners into the other pusher standing 16 mm beside it.
    fn back_behind(&self, pose: Pose, site: &Site, behind: f64) -> Manoeuvre {
        let here = Vector2::new(pose.x, pose.y) - site.centre.coords;
        let along_now = here.dot(&site.along);
        let lane = self.lane() - REGROUP_BELOW;
        // Off the tape nothing measures the heading: the leg along the lane, beside the arena's
        // edge, ends as soon as the robot is clear of the box, and the rest is driven backwards
        // along the tape, where a heading off shows as the tape leaving the sensor.
        let clear = behind.max(-(self.box_half + HALF_LEN + REGROUP_BEHIND));
        let down = site.at(along_now, lane);
        let below = site.at(clear, lane);
        let on_tape = site.at(clear, 0.0);
        let heading = Vector2::new(pose.theta.cos(), pose.theta.sin());
        let start = Manoeuvre::from(pose, MANOEUVRE_MPS);
        // A robot already standing on the tape behind the box, along it (the helper that waited
        // there, one found again on it) drives along the tape to its place: the route through
        // the lane would bring it up onto the tape just behind the box, where the other robot
        // often stands, and the two would wait on each other for good.
        let across = here.dot(&site.push);
        let facing = heading.dot(&site.along);
        if across.abs() < ON_TAPE_M && facing.abs() > ALONG_TAPE_COS && along_now < -self.box_half {
            let route = start.straight((behind - along_now) * facing.signum());
            return if facing < 0.0 {
                route.turn_to(Site::heading(site.along))
            } else {
                route
            };
        }
        let start = if heading.dot(&site.push) > FACING_BOX_COS {
            start.back_to(down.x, down.y)
        } else {
            start.to(down.x, down.y)
        };
        start
            .to(below.x, below.y)
            .to(on_tape.x, on_tape.y)
            .turn_to(Site::heading(site.along))
            .straight(behind - clear)
    }

    /// Everyone stands on the tape: follow it again until someone finds the box, or, when a push
    /// the box gave way to was done already, lap.
    pub(super) fn follow_again(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        self.finder = None;
        self.site = None;
        self.sighted = None;
        self.routed.clear();
        // After a push, even one cut short, the laps find the box if it still stands on the
        // track.
        if self.pushes > 0 {
            for b in self.bots.values_mut() {
                b.lapped_m = 0.0;
                b.last_s = None;
                b.lap_odometer_m = None;
            }
            self.enter(Phase::Lapping, world);
        } else {
            self.enter(Phase::Approach, world);
        }
        team.ids()
            .map(|robot| Intent::FollowLine {
                robot,
                speed: Some(self.speed),
            })
            .collect()
    }
}
