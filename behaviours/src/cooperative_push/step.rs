//! One step of the team on every snapshot and event: the run's time limits, spacing while
//! following, and the work of each phase from gathering behind the box to lapping after it.

use super::*;

impl CooperativePush {
    /// One step of the team: the run's time limits, spacing while following, a box found, and
    /// the work of the current phase.
    pub(super) fn step(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        self.odometer.observe(world);
        if let Some(why) = self.overdue(world) {
            return self.fail(why);
        }
        if let Some(id) = self.aborted(world, team) {
            return self.regroup(format!("robot {id}: a manoeuvre was aborted"), world, team);
        }
        let mut out = self.spacing(world, team);
        if matches!(self.phase, Phase::Approach | Phase::Lapping) {
            let found = world.robots.iter().find(|v| {
                v.state.proximity.front_obstacle == 1
                    && self.bots.contains_key(&v.id)
                    && self.gap_ahead(v, world) > 0.15
            });
            if let Some(id) = found.map(|v| v.id) {
                out.extend(self.found_box(id, world));
                return out;
            }
        }
        let next = match self.phase {
            Phase::Approach => Ok(Vec::new()),
            Phase::FinderRejoins | Phase::HelperRejoins => Ok(self.align_on_tape(world)),
            Phase::Gather => self.gather(world, team),
            Phase::FinderToSlot => Ok(self.finder_to_slot(world, team)),
            Phase::HelperToSlot => Ok(self.helper_to_slot(world, team)),
            Phase::Push => self.pushed(world, team),
            Phase::HelperWaits => Ok(self.helper_waits(world)),
            Phase::Regroup => Ok(self.regrouping(world, team)),
            Phase::Rejoin => Ok(self.rejoining(world, team)),
            // The verdict ends the run: the spacing intents of this step are not sent.
            Phase::Lapping => match self.lapping(world) {
                Ok(true) => return Vec::new(),
                other => other.map(|_| Vec::new()),
            },
        };
        match next {
            Err(why) => self.fail(why),
            Ok(intents) => {
                out.extend(intents);
                out
            }
        }
    }

    /// Why the run must stop: a stalled wheel, a phase over its time limit, a robot backing up
    /// for too long, a regroup that does not end.
    pub(super) fn overdue(&mut self, world: &WorldSnapshot) -> Option<String> {
        if let Some(stall) = self.odometer.stall() {
            return Some(stall.to_string());
        }
        if matches!(self.phase, Phase::Regroup | Phase::Rejoin) {
            // A regroup has its own reason, which the phase limit's message would hide.
            if world.time.saturating_sub(self.phase_since) > REGROUP_LIMIT {
                return Some(format!(
                    "the team did not regroup within {:.0} s after: {}",
                    REGROUP_LIMIT.as_secs_f64(),
                    self.regroup_why.as_deref().unwrap_or("a disturbance")
                ));
            }
        }
        let limit = match self.phase {
            // Following is slowed by spacing; three times the lap time at full speed is plenty.
            Phase::Approach | Phase::Lapping => PHASE_LIMIT.max(Duration::from_secs_f64(
                3.0 * self.laps * self.track.length_m() / f64::from(self.speed),
            )),
            Phase::Regroup | Phase::Rejoin => REGROUP_LIMIT,
            _ => PHASE_LIMIT,
        };
        if world.time.saturating_sub(self.phase_since) > limit {
            return Some(format!(
                "{:?} took longer than {:.0} s",
                self.phase,
                limit.as_secs_f64()
            ));
        }
        let backing_limit = Duration::from_secs_f64((self.push_m + 0.1) / f64::from(BACK_MPS));
        for b in self.bots.values_mut() {
            if let Some(since) = b.backing.as_mut() {
                if *since == Duration::ZERO {
                    *since = world.time.max(Duration::from_nanos(1));
                }
            }
        }
        if let Some((id, _)) = self.bots.iter().find(|(_, b)| {
            b.backing
                .is_some_and(|since| world.time.saturating_sub(since) > backing_limit)
        }) {
            return Some(format!("robot {id} backed up without finding the tape"));
        }
        None
    }

    /// A robot whose move was aborted (a stop, a lost link, a lost robot, its reflex short of
    /// something other than the box) since the last step, outside a regroup, which stops robots
    /// itself.
    pub(super) fn aborted(&mut self, world: &WorldSnapshot, team: &Team) -> Option<u16> {
        let mut found = None;
        for id in team.ids() {
            let now = (team.interrupted(id), team.blocked(id));
            let seen = self.interrupts_seen.entry(id).or_insert((0, 0));
            let (interrupted, blocked) = (now.0 > seen.0, now.1 > seen.1);
            *seen = now;
            // A regroup stops robots itself; a rejoin's own stops interrupt moves too, but its
            // reflexes are on again, and one that stops a robot is a new disturbance.
            // A route along the tape stopped because a move of it was held is tried again.
            let realigning = self.bots.get(&id).is_some_and(|b| b.aligning.is_some());
            if self.phase == Phase::Regroup
                || !(interrupted || blocked)
                || (self.phase == Phase::Rejoin && !blocked)
                || (realigning && !blocked)
            {
                continue;
            }
            // The reflex ends the leg up into the slot at the box: that is the leg's end.
            let at_box = !interrupted
                && self.bots.get(&id).is_some_and(|b| b.seeking)
                && self
                    .site
                    .zip(world.robot(id))
                    .is_some_and(|(site, view)| self.in_slot(view, &site));
            if !at_box {
                found = found.or(Some(id));
            }
        }
        found
    }

    /// Spacing while following: never run into the robot ahead.
    pub(super) fn spacing(&self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let mut out = Vec::new();
        if matches!(self.phase, Phase::Approach | Phase::Gather | Phase::Lapping) {
            for view in &world.robots {
                if !self.bots.contains_key(&view.id) {
                    continue;
                }
                let following = team.following(view.id);
                if Some(view.id) == self.finder && self.phase == Phase::Gather {
                    continue;
                }
                let gap = self.gap_ahead(view, world);
                let mut want = if gap < STOP_GAP {
                    None
                } else if gap > GO_GAP || following.is_some() {
                    Some(self.speed)
                } else {
                    following
                };
                // Something close ahead that is not a robot: creep, so that the first sighting
                // at the shortest reach (15 mm) places it to within a few millimetres.
                let level = view.state.proximity.front_obstacle;
                if gap > 0.15 && (2..=3).contains(&level) {
                    want = want.map(|v| v.min(CREEP_MPS));
                }
                out.push(Intent::FollowLine {
                    robot: view.id,
                    speed: want,
                });
            }
        }
        out
    }

    /// Gathered behind the box: once both rest, the box is placed from the finder's sighting and
    /// the finder sets off for its slot.
    pub(super) fn gather(
        &mut self,
        world: &WorldSnapshot,
        team: &Team,
    ) -> Result<Vec<Intent>, String> {
        let mut out = Vec::new();
        let settled = world.robots.iter().all(|r| {
            let w = r.state.wheels;
            let (l, rr) = (w.left_mps, w.right_mps);
            team.following(r.id).is_none() && l.abs() < 0.005 && rr.abs() < 0.005
        });
        if settled && world.time.saturating_sub(self.phase_since) > Duration::from_millis(300) {
            let Some(finder) = self.finder.and_then(|f| world.robot(f)) else {
                return Err("the robot that found the box is gone".into());
            };
            let site = self.locate(finder);
            tracing::debug!(x = site.centre.x, y = site.centre.y, "box located");
            self.site = Some(site);
            let route = self.to_slot(finder.id, finder.pose, &site, 0.015);
            let id = finder.id;
            out.extend(self.send(id, route));
            self.seek(id);
            self.enter(Phase::FinderToSlot, world);
        }
        Ok(out)
    }

    /// The finder in its slot: the helper sets off for its own, or, alone, the push starts.
    pub(super) fn finder_to_slot(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let mut out = Vec::new();
        let Some(f) = self.finder else {
            return out;
        };
        if !self.in_place(f, team) {
            return out;
        }
        match (self.helper(), self.site) {
            (Some(h), Some(site)) => {
                if let Some(view) = world.robot(h) {
                    let route = self.to_slot(h, view.pose, &site, 0.0);
                    out.extend(self.send(h, route));
                    self.seek(h);
                }
                self.enter(Phase::HelperToSlot, world);
            }
            _ => out.extend(self.start_push(world)),
        }
        out
    }

    /// The helper in its slot: the push starts.
    pub(super) fn helper_to_slot(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let mut out = Vec::new();
        if let Some(h) = self.helper() {
            if self.in_place(h, team) {
                out.extend(self.start_push(world));
            }
        }
        out
    }

    /// `id` is on its way into its slot.
    fn seek(&mut self, id: u16) {
        if let Some(b) = self.bots.get_mut(&id) {
            b.seeking = true;
        }
    }

    /// Whether `id` stands in its slot (its route there is done).
    fn in_place(&mut self, id: u16, team: &Team) -> bool {
        let done = team.idle(id);
        if done {
            if let Some(b) = self.bots.get_mut(&id) {
                b.seeking = false;
            }
        }
        done
    }

    /// The push ended: it counts only if the box gave way and each pusher drove its share; then
    /// the finder backs onto the tape first.
    pub(super) fn pushed(
        &mut self,
        world: &WorldSnapshot,
        team: &Team,
    ) -> Result<Vec<Intent>, String> {
        let mut out = Vec::new();
        if team.all_idle() {
            self.push_evidence()?;
            self.push_time = Some(world.time.saturating_sub(self.push_started));
            // Backing onto the tape drives away from the box: the rear reflexes guard it.
            out.extend(self.reflexes(REFLEX_ON));
            if let Some(f) = self.finder {
                out.extend(self.start_backing(f));
            }
            self.enter(Phase::FinderRejoins, world);
        }
        Ok(out)
    }

    /// Whether the push did its work: the box gave way to every pusher, and each drove its
    /// share of the push; the error says what is missing.
    pub(super) fn push_evidence(&self) -> Result<(), String> {
        // A box that gave way let the pushers' sensors, 8 mm behind their fronts, run over the
        // tape it stood on; wheels that only slipped did not.
        if let Some((id, _)) = self.bots.iter().find(|(_, b)| !b.crossed_tape) {
            return Err(format!(
                "the box did not give way: robot {id} never reached the tape behind it \
                 ({} robot(s) pushing)",
                self.bots.len()
            ));
        }
        // The box can give way to one robot's push while the other only stood beside it: each
        // must have driven its share.
        let sent = LANE_GAP + self.push_m;
        let odometer = &self.odometer;
        let short = self.bots.iter().find_map(|(&id, b)| {
            let driven = odometer.distance_m(id) - b.push_odometer_m;
            (driven < EVIDENCE_SHARE * sent).then_some((id, driven))
        });
        if let Some((id, driven)) = short {
            return Err(format!(
                "robot {id} did not push: its encoders measured {:.0} mm of the {:.0} mm push \
                 it was sent (at least {:.0} mm needed)",
                driven * 1e3,
                sent * 1e3,
                EVIDENCE_SHARE * sent * 1e3
            ));
        }
        Ok(())
    }

    /// The helper backs onto the tape once the finder has left it room.
    pub(super) fn helper_waits(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let mut out = Vec::new();
        let room = match (self.finder.and_then(|f| world.robot(f)), self.site) {
            (Some(f), Some(site)) => {
                let p = Vector2::new(f.pose.x, f.pose.y) - site.centre.coords;
                p.dot(&site.along) > REJOIN_GAP
            }
            _ => true,
        };
        if room {
            if let Some(h) = self.helper() {
                out.extend(self.start_backing(h));
            }
            self.enter(Phase::HelperRejoins, world);
        }
        out
    }

    /// Lapping after the push: each robot's laps along the tape, checked against its encoders;
    /// the verdict once all have lapped (`true` then).
    pub(super) fn lapping(&mut self, world: &WorldSnapshot) -> Result<bool, String> {
        let length = self.track.length_m();
        for view in &world.robots {
            let odometer_m = self.odometer.distance_m(view.id);
            let Some(bot) = self.bots.get_mut(&view.id) else {
                continue;
            };
            bot.lap_odometer_m.get_or_insert(odometer_m);
            let s = self.track.position(view);
            if let (Some(before), Some(after)) = (bot.last_s, s) {
                bot.lapped_m += self.track.forward(before, after).unwrap_or(0.0);
            }
            if s.is_some() {
                bot.last_s = s;
            }
        }
        if self.bots.values().all(|b| b.lapped_m >= self.laps * length) {
            if self.push_time.is_none() {
                return Err(format!(
                    "the box is off the track, but the push that moved it was cut short \
                     before it did its work ({})",
                    self.regroup_why.as_deref().unwrap_or("a disturbance")
                ));
            }
            let claimed = self.laps * length;
            let lapped = |id: u16| {
                let from = self.bots.get(&id).and_then(|b| b.lap_odometer_m);
                self.odometer.distance_m(id) - from.unwrap_or(0.0)
            };
            let short = self
                .bots
                .keys()
                .map(|&id| (id, lapped(id)))
                .find(|(_, m)| *m < EVIDENCE_SHARE * claimed);
            let least = self
                .bots
                .keys()
                .map(|&id| lapped(id))
                .fold(f64::INFINITY, f64::min);
            if let Some((id, measured)) = short {
                return Err(format!(
                    "robot {id}: its place on the tape went {} lap(s) after the push but \
                     its encoders measured {measured:.2} m, short of the {:.2} m driving \
                     them takes",
                    self.laps,
                    EVIDENCE_SHARE * claimed
                ));
            }
            let mut v = Verdict::success(format!(
                "the box gave way to {} robots pushing together ({:.0} mm of drive) and \
                 the team has lapped {} more time(s) without finding it on the track, \
                 each robot at least {least:.2} m by its encoders",
                self.bots.len(),
                self.push_m * 1e3,
                self.laps
            ))
            .with("pushes", f64::from(self.pushes))
            .with("least_encoder_lap_m", least);
            if let Some(t) = self.push_time {
                v = v.with("push_time_s", t.as_secs_f64());
            }
            self.verdict = Some(v);
            return Ok(true);
        }
        Ok(false)
    }
}

impl Behaviour for CooperativePush {
    fn start(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        self.phase_since = world.time;
        self.step(world, team)
    }

    fn on_snapshot(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        self.step(world, team)
    }

    fn on_event(
        &mut self,
        robot: u16,
        event: &Event,
        world: &WorldSnapshot,
        team: &mut Team,
    ) -> Vec<Intent> {
        match event {
            Event::Obstacle(o) if o.side == Side::Front && o.is_close() => {
                self.found_box(robot, world)
            }
            // Finishing a rejoin hands the robot back to the tape; a route along it that was
            // stopped for a hold is still to come.
            Event::MoveFinished { .. }
                if team.idle(robot)
                    && self.bots.get(&robot).is_none_or(|b| b.aligning.is_none()) =>
            {
                let follow = vec![Intent::FollowLine {
                    robot,
                    speed: Some(self.speed),
                }];
                match self.phase {
                    Phase::FinderRejoins if Some(robot) == self.finder => {
                        let mut out = follow;
                        let next = if self.helper().is_some() {
                            Phase::HelperWaits
                        } else {
                            out.extend(self.reflexes(REFLEX_ON));
                            Phase::Lapping
                        };
                        self.enter(next, world);
                        out
                    }
                    // Both back on the tape: their reflexes are on again for the laps.
                    Phase::HelperRejoins if Some(robot) == self.helper() => {
                        self.enter(Phase::Lapping, world);
                        let mut out = follow;
                        out.extend(self.reflexes(REFLEX_ON));
                        out
                    }
                    _ => Vec::new(),
                }
            }
            Event::LineFound if self.bots.get(&robot).is_some_and(|b| b.backing.is_some()) => {
                let forwards = self.bots.get(&robot).is_some_and(|b| b.onto_forwards);
                if forwards || self.backed_m(robot) >= MIN_BACK_M {
                    self.on_tape(robot, world)
                } else {
                    Vec::new()
                }
            }
            Event::LineFound if self.phase == Phase::Push => {
                if let Some(b) = self.bots.get_mut(&robot) {
                    b.crossed_tape = true;
                }
                Vec::new()
            }
            // On its way onto the tape, the robot met something close: stopped there, it cannot
            // find the tape that way.
            Event::Reflexed { .. }
                if self.bots.get(&robot).is_some_and(|b| b.backing.is_some()) =>
            {
                if let Some(b) = self.bots.get_mut(&robot) {
                    b.backing = None;
                }
                self.regroup(
                    format!("robot {robot}'s reflex stopped it on its way onto the tape"),
                    world,
                    team,
                )
            }
            // Felt off the tape while the team gathers at the box, where the model only widens
            // it (no tape could fix it there) and its queued route would take it on at a
            // heading up to 20° off, along the arena's edge: the team stops, and the run ends.
            // A regroup from there drove the same unknown heading along the lane and touched.
            Event::Bumped { moved_m }
                if matches!(
                    self.phase,
                    Phase::Gather | Phase::FinderToSlot | Phase::HelperToSlot
                ) && world.robot(robot).is_some_and(|v| {
                    v.localisation == Localisation::Tracking && v.on_track.is_none()
                }) =>
            {
                let mut out = self.stop_team(world, team);
                out.extend(self.fail(format!(
                    "robot {robot} felt a bump of about {:.0} mm off the tape, where nothing \
                     measures its heading: the team stopped",
                    moved_m * 1e3
                )));
                out
            }
            // Following the tape, a robot whose link is lost is stopped by its watchdog and
            // follows on once the robot actor has it back; the others keep their distance on the
            // tape as from any robot standing there. Around the box the team regroups behind it,
            // and after the push each robot gets back onto the tape in turn, as after a robot
            // lost; either waits for the robot to be back. During the push itself the run ends:
            // a pusher cut off mid-push stands wherever its slip left it, and backing it onto
            // the tape from there met the wall (188304).
            Event::LinkLost => match self.phase {
                Phase::Approach | Phase::Lapping => {
                    self.link_down.insert(robot);
                    Vec::new()
                }
                Phase::Regroup | Phase::Rejoin => Vec::new(),
                Phase::Push => self.fail(format!("robot {robot} lost its link while pushing")),
                _ if self.after_push() => {
                    self.rejoin(format!("robot {robot} lost its link"), world, team)
                }
                _ => {
                    let mut out = self.stop_team(world, team);
                    out.extend(self.regroup(format!("robot {robot} lost its link"), world, team));
                    out
                }
            },
            Event::Connected if self.link_down.remove(&robot) => {
                if matches!(self.phase, Phase::Approach | Phase::Lapping) {
                    vec![Intent::FollowLine {
                        robot,
                        speed: Some(self.speed),
                    }]
                } else {
                    Vec::new()
                }
            }
            _ => Vec::new(),
        }
    }

    /// A manoeuvre planned around the box is not improvised when the supervisor refuses a step
    /// of it: the team regroups behind the box and plans it again from where the robots stand.
    fn held_policy(&self) -> HeldPolicy {
        HeldPolicy::Tell
    }

    fn on_held(
        &mut self,
        intent: &Intent,
        reason: &str,
        world: &WorldSnapshot,
        team: &mut Team,
    ) -> Vec<Intent> {
        let robot = match *intent {
            Intent::Move { robot, .. } => robot,
            Intent::WheelSpeeds { robot, .. } if self.phase == Phase::Rejoin => {
                self.rejoin_held(robot, world);
                return Vec::new();
            }
            _ => return Vec::new(),
        };
        // The rest of the manoeuvre may have been approved: the robot must not drive it alone.
        let stop = vec![Intent::Stop { robot }];
        if self.phase == Phase::Rejoin {
            self.rejoin_held(robot, world);
            return stop;
        }
        if self.phase == Phase::Regroup {
            self.route_held(robot, world);
            return stop;
        }
        // The centre onto the tape and the turn along it, after the push: the robot stands where
        // its sensor found the tape, and the same route is planned again from where the model
        // has it a little later.
        if matches!(self.phase, Phase::FinderRejoins | Phase::HelperRejoins)
            && self.align_held(robot, world)
        {
            return stop;
        }
        let mut out = stop;
        out.extend(self.regroup(
            format!("robot {robot}: the supervisor held back a move: {reason}"),
            world,
            team,
        ));
        out
    }

    fn on_localisation(
        &mut self,
        robot: u16,
        event: &LocalisationEvent,
        world: &WorldSnapshot,
        team: &mut Team,
    ) -> Vec<Intent> {
        match event {
            LocalisationEvent::Lost { why } => self.robot_lost(robot, why, world, team),
            LocalisationEvent::Found => Vec::new(),
        }
    }

    fn verdict(&self) -> Option<Verdict> {
        self.verdict.clone()
    }

    fn progress(&self) -> Vec<(String, f64)> {
        vec![("pushes".into(), f64::from(self.pushes))]
    }
}
