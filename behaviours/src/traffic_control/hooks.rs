//! The behaviour's hooks: one step of the team on every snapshot and event, the verdict and the
//! figures of the work.

use super::*;

/// Why a robot whose link was lost waits, as [`TrafficControl::explain`] says it.
const LINK_LOST: &str = "its link was lost; it waits to reconnect";

impl TrafficControl {
    pub(super) fn finish(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let minutes = world.time.saturating_sub(self.started).as_secs_f64() / 60.0;
        self.odometer.observe(world);
        // A robot stands within a couple of centimetres of its node, so a robot that drove a
        // single short edge may have been that much short of it; the slack is given once.
        let claimed = |id: u16| {
            let edges_m = self
                .bots
                .iter()
                .find(|b| b.id == id)
                .map_or(0.0, |b| b.edges_m);
            (edges_m - NODE_SLACK_M / EVIDENCE_SHARE).max(0.0)
        };
        let ids = self.bots.iter().map(|b| b.id);
        if let Some((id, measured, claim)) = self.odometer.short_of(ids, claimed) {
            return self.fail(format!(
                "robot {id}: its encoders measured {measured:.2} m, short of the {:.2} m that the \
                 edges it reported driving take ({:.0} % of their tape, less {:.0} cm)",
                EVIDENCE_SHARE * claim,
                EVIDENCE_SHARE * 100.0,
                NODE_SLACK_M * 100.0
            ));
        }
        let driven: f64 = self
            .bots
            .iter()
            .map(|b| self.odometer.distance_m(b.id))
            .sum();
        self.verdict = Some(
            Verdict::success(format!(
                "{} tasks done by {} robots, {:.1} per minute, {} plans, {} recoveries; \
                 {driven:.1} m driven by the encoders",
                self.tasks,
                self.bots.len(),
                f64::from(self.tasks) / minutes.max(1e-9),
                self.replans,
                self.recoveries_total
            ))
            .with("tasks", f64::from(self.tasks))
            .with("encoder_distance_m", driven)
            .with(
                "tasks_per_minute",
                f64::from(self.tasks) / minutes.max(1e-9),
            )
            .with("plans", f64::from(self.replans))
            .with("live_plans", f64::from(self.replans_live))
            .with("recoveries", f64::from(self.recoveries_total))
            .with("held_segments", f64::from(self.held))
            .with("plan_time_max_ms", self.plan_time_max.as_secs_f64() * 1e3),
        );
        Vec::new()
    }

    /// One round: arrivals, recovery, replanning and dispatch. Lifelong plans are made only at
    /// a `snapshot`, so that all robots reaching their goals since the last one share a plan.
    /// Robot `k` is back (found, or its link up again): its leg goes on from where it stands.
    fn found(&mut self, k: usize, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        self.bots[k].lost = None;
        self.last_progress = world.time;
        let mut out = Vec::new();
        if self.bots[k].driving.is_some() && team.idle(self.bots[k].id) {
            out.extend(self.drive(k, world));
        }
        out.extend(self.step(world, team, false));
        out
    }

    pub(super) fn step(
        &mut self,
        world: &WorldSnapshot,
        team: &Team,
        snapshot: bool,
    ) -> Vec<Intent> {
        self.now = world.time;
        self.odometer.observe(world);
        if let Some(stall) = self.odometer.stall() {
            return self.fail(stall.to_string());
        }
        for k in 0..self.bots.len() {
            if !std::mem::take(&mut self.bots[k].at_end) {
                continue;
            }
            if let Some(leg) = self.bots[k].driving.take() {
                if let Err(e) = self.complete_leg(k, leg, world) {
                    return self.fail(e);
                }
            }
        }
        // A lost robot is the supervisor's to bring back: the wait is not a deadlock.
        if self.bots.iter().any(|b| b.lost.is_some()) {
            self.last_progress = world.time;
        }
        let mut out = Vec::new();
        let held_long = self.bots.iter().find(|b| {
            b.lost.is_none()
                && b.held_since
                    .is_some_and(|t| world.time.saturating_sub(t) >= HOLD_LIMIT)
        });
        if let Some(b) = held_long {
            let why = format!(
                "robot {}'s segment was held back for {} s ({})",
                b.id,
                HOLD_LIMIT.as_secs(),
                b.held_why
            );
            out.extend(self.recover(world, why, team));
        } else if world.time.saturating_sub(self.last_progress) > STALL_LIMIT {
            let why = format!("no robot finished an edge for {} s", STALL_LIMIT.as_secs());
            out.extend(self.recover(world, why, team));
        }
        if self.verdict.is_some() {
            return out;
        }
        out.extend(self.make_room(world, team));
        for k in 0..self.bots.len() {
            let b = &self.bots[k];
            if b.retry && team.idle(b.id) && b.lost.is_none() && b.making_room.is_none() {
                self.bots[k].retry = false;
                out.extend(self.drive(k, world));
            }
        }
        let all_still = self.bots.iter().all(|b| {
            team.idle(b.id) && b.driving.is_none() && b.lost.is_none() && b.making_room.is_none()
        });
        if self.phase == Phase::Placing && all_still {
            self.phase = Phase::Draining;
        }
        if self.phase == Phase::Draining && all_still {
            if self.tasks >= self.target_tasks {
                return self.finish(world);
            }
            if let Err(e) = self.replan() {
                return self.fail(e);
            }
            if self.tasks >= self.target_tasks {
                return self.finish(world);
            }
            self.phase = Phase::Running;
        } else if self.phase == Phase::Running && self.replan_due && snapshot {
            if let Err(e) = self.replan_lifelong() {
                return self.fail(e);
            }
        }
        out.extend(self.dispatch(world, team));
        out
    }
}

impl Behaviour for TrafficControl {
    fn start(&mut self, world: &WorldSnapshot, _: &mut Team) -> Vec<Intent> {
        self.started = world.time;
        self.last_progress = world.time;
        match self.place(world) {
            Ok(out) => out,
            Err(e) => self.fail(e),
        }
    }

    fn on_snapshot(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        self.step(world, team, true)
    }

    fn on_event(
        &mut self,
        robot: u16,
        event: &Event,
        world: &WorldSnapshot,
        team: &mut Team,
    ) -> Vec<Intent> {
        let Some(k) = self.bots.iter().position(|b| b.id == robot) else {
            return Vec::new();
        };
        match event {
            Event::MoveFinished { outcome, .. } => {
                if self.bots[k].lost.is_some() {
                    return Vec::new();
                }
                if let Some(m) = self.bots[k].making_room {
                    // Backed away: it waits. Back where it stood (or stopped on the way): its
                    // leg goes on from there.
                    if m.returning && team.idle(robot) {
                        self.bots[k].making_room = None;
                        if self.bots[k].driving.is_some() {
                            return self.drive(k, world);
                        }
                        return self.step(world, team, false);
                    }
                    return Vec::new();
                }
                if *outcome != MoveOutcome::Completed {
                    // The supervisor may stop a robot it lost before telling us so.
                    if world
                        .robot(robot)
                        .is_some_and(|v| v.localisation == Localisation::Lost)
                    {
                        self.lose(k, "the world model lost it".into());
                        return Vec::new();
                    }
                    // Stopped by the supervisor beside a robot it lost: the leg goes on from
                    // where it stands, held by the safety check until the way is clear. Not
                    // after its own reflex stopped it: something the model does not know of
                    // stands close, and driving the leg again touched it.
                    if *outcome == MoveOutcome::Stopped {
                        if !team.idle(robot) {
                            return Vec::new();
                        }
                        if self.bots[k].driving.is_some() {
                            return self.drive(k, world);
                        }
                        return self.step(world, team, false);
                    }
                    return self.fail(format!("robot {robot}: a move ended {outcome:?}"));
                }
                self.bots[k].held_since = None;
                if team.outstanding(robot) == 1 && self.bots[k].tail.is_some() {
                    return self.drive_ahead(k, world);
                }
                if team.idle(robot) {
                    match self.bots[k].driving {
                        Some(leg) if leg.last => {
                            self.bots[k].driving = None;
                            if let Err(e) = self.complete_leg(k, leg, world) {
                                return self.fail(e);
                            }
                            return self.step(world, team, false);
                        }
                        Some(_) => return self.drive(k, world),
                        None => return self.step(world, team, false),
                    }
                }
                Vec::new()
            }
            // Its watchdog stops it where it is and the robot actor reconnects: the team treats it
            // as a lost robot (the others wait for it, or make room) until it is back.
            Event::LinkLost => {
                if self.bots[k].lost.is_none() {
                    self.lose(k, LINK_LOST.into());
                }
                Vec::new()
            }
            Event::Connected if self.bots[k].lost.as_deref() == Some(LINK_LOST) => {
                self.found(k, world, team)
            }
            _ => Vec::new(),
        }
    }

    // It re-plans a held move itself at once (a detour, a robot behind backing away): a
    // retry would only wait.
    fn held_policy(&self) -> behaviour_api::team::HeldPolicy {
        behaviour_api::team::HeldPolicy::Tell
    }

    fn on_held(
        &mut self,
        intent: &Intent,
        reason: &str,
        world: &WorldSnapshot,
        team: &mut Team,
    ) -> Vec<Intent> {
        // The plan keeps robots apart by construction; a held segment means the world model saw
        // a robot closer than the plan assumed (a pose error). The segment is planned again from
        // the robot's pose at the next snapshot; held for `HOLD_LIMIT`, the team is replanned.
        if let Intent::Move { robot, .. } = intent {
            if let Some(bot) = self.bots.iter_mut().find(|b| b.id == *robot) {
                // Held while backing away (something behind): it waits where it stands, and is
                // not asked again. Held coming back (the found robot still near): its leg is
                // planned from where it stands.
                if let Some(m) = bot.making_room {
                    if m.returning {
                        bot.making_room = None;
                        if bot.driving.is_some() {
                            bot.retry = true;
                        }
                    }
                    self.held += 1;
                    return Vec::new();
                }
                // The segment did not reach the node even if earlier moves of it are driven.
                if let Some(leg) = bot.driving.as_mut() {
                    leg.last = false;
                }
                bot.tail = None;
                if bot.lost.is_none() {
                    bot.held_since.get_or_insert(world.time);
                    // The first held move of a batch says why; the rest only follow it.
                    if std::mem::take(&mut bot.fresh_hold) {
                        bot.held_why = reason.to_owned();
                    }
                    if team.idle(bot.id) && bot.driving.is_some() {
                        bot.retry = true;
                    }
                }
            }
            self.held += 1;
        }
        Vec::new()
    }

    fn on_localisation(
        &mut self,
        robot: u16,
        event: &LocalisationEvent,
        world: &WorldSnapshot,
        team: &mut Team,
    ) -> Vec<Intent> {
        let Some(k) = self.bots.iter().position(|b| b.id == robot) else {
            return Vec::new();
        };
        match event {
            LocalisationEvent::Lost { why } => {
                self.lose(k, why.clone());
                Vec::new()
            }
            LocalisationEvent::Found => self.found(k, world, team),
        }
    }

    fn verdict(&self) -> Option<Verdict> {
        self.verdict.clone()
    }

    fn progress(&self) -> Vec<(String, f64)> {
        let minutes = self.now.saturating_sub(self.started).as_secs_f64() / 60.0;
        vec![
            ("tasks".into(), f64::from(self.tasks)),
            (
                "tasks_per_minute".into(),
                f64::from(self.tasks) / minutes.max(1e-9),
            ),
            ("plans".into(), f64::from(self.replans)),
            ("recoveries".into(), f64::from(self.recoveries_total)),
        ]
    }
}
