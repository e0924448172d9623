//! The behaviour supervised: built and started (again after a panic), its replies carried out,
//! the robots' events passed on to it.

use super::*;

impl Supervisor {
    pub(super) fn start_behaviour(&mut self, ctx: &mut Context<Self>) {
        if self.done.is_none() {
            return;
        }
        let behaviour = match self.behaviour_entry.build(&self.config) {
            Ok(b) => BehaviourActor::new(b).start(),
            Err(why) => {
                self.finish(Verdict::failure(format!("behaviour not built: {why}")), ctx);
                return;
            }
        };
        self.behaviour = Some(behaviour.clone());
        let world = self.snapshot();
        let reply = behaviour.send(Start(world));
        ctx.spawn(
            reply
                .into_actor(self)
                .map(|r, act, ctx| act.on_reply(r, ctx)),
        );
    }

    pub(super) fn on_reply(
        &mut self,
        reply: Result<Result<Reply, Panicked>, MailboxError>,
        ctx: &mut Context<Self>,
    ) {
        if self.done.is_none() {
            // The experiment is over: late intents must not move a stopped robot.
            return;
        }
        match reply {
            Ok(Ok(reply)) => {
                if !reply.progress.is_empty() {
                    self.progress = reply.progress;
                }
                // Most replies to events carry no intent: the snapshot (a pointer per robot) is
                // taken only for one that does.
                if !reply.intents.is_empty() {
                    self.carry_out_all(reply.intents, ctx);
                }
                if let Some(verdict) = reply.verdict {
                    self.finish(verdict, ctx);
                }
            }
            Ok(Err(Panicked(why))) => {
                warn!(why, "behaviour panicked: stopping every robot");
                self.stop_all();
                self.restarts += 1;
                if self.restarts > MAX_RESTARTS {
                    self.finish(
                        Verdict::failure(format!(
                            "behaviour panicked {} times: {why}",
                            self.restarts
                        )),
                        ctx,
                    );
                } else {
                    // Restart only once the stop has reached every robot and its last events
                    // (the aborted moves) have gone by: they belong to the old instance.
                    self.behaviour = None;
                    ctx.run_later(RESTART_DELAY, |act, ctx| act.start_behaviour(ctx));
                }
            }
            Err(e) => warn!(error = %e, "behaviour unreachable"),
        }
    }

    pub(super) fn tell_behaviour(&mut self, e: RobotEvent, ctx: &mut Context<Self>) {
        if let Some(b) = &self.behaviour {
            let msg = FromRobot {
                robot: e.robot_id,
                kind: e.kind,
                world: self.snapshot_peek(),
            };
            let reply = b.send(msg);
            ctx.spawn(
                reply
                    .into_actor(self)
                    .map(|r, act, ctx| act.on_reply(r, ctx)),
            );
        }
    }
}

impl Handler<RobotEvent> for Supervisor {
    type Result = ();
    fn handle(&mut self, mut e: RobotEvent, ctx: &mut Context<Self>) {
        // A finished move that is not the behaviour's (the panel's, the re-localisation's, or
        // one queued before a link was lost) has no tag here and is not its news: under any tag
        // it could stand for one of the behaviour's own moves.
        let mut foreign = false;
        if let RobotEventKind::MoveFinished { tag, .. } = &mut e.kind {
            let number = *tag;
            let at = self.model.robots().get(&e.robot_id).map(|v| v.pose);
            if let (Some(plan), Some(at)) = (self.planned.get_mut(&e.robot_id), at) {
                if !plan.finished(number, at) {
                    self.planned.remove(&e.robot_id);
                }
            }
            // The behaviour hears of its move under its own tag.
            match self.move_tags.remove(&(e.robot_id, number)) {
                Some(behaviours_tag) => *tag = behaviours_tag,
                None => foreign = true,
            }
        }
        match &e.kind {
            RobotEventKind::Encounter(enc) => {
                let encounter = Encounter {
                    observer: e.robot_id,
                    seen: enc.robot_id,
                    side: behaviours::Side::try_from(enc.side).unwrap_or(behaviours::Side::Front),
                    relative_heading_deg: enc.relative_heading_deg,
                    range_mm: enc.range_mm,
                    at: e.at - self.started_at,
                };
                self.encounters.push(encounter);
                self.encounters_new.push(encounter);
            }
            RobotEventKind::LinkLost => {
                // Its moves in flight fail without finishing.
                self.move_tags.retain(|&(robot, _), _| robot != e.robot_id);
                // A link lost again before its first report: the behaviour hears of the loss
                // only, not of a connection it never could use.
                self.reconnected.remove(&e.robot_id);
                self.model.lost(e.robot_id);
                self.note_link(e.robot_id, "lost");
                warn!(robot = e.robot_id, "link lost; the robot actor reconnects");
            }
            RobotEventKind::Bump(b) => {
                // Its pose is widened and it is stopped at once, whatever the behaviour makes
                // of the news; it is held until the tape localises it again.
                let moved_m = f64::from(b.moved_mm) * 1e-3;
                warn!(
                    robot = e.robot_id,
                    moved_m,
                    along_mm = { b.along_mm },
                    left_mm = { b.left_mm },
                    peak_mg = { b.peak_mg },
                    "robot bumped"
                );
                if self.started && self.done.is_some() {
                    let felt = world_model::Felt {
                        moved_m,
                        along_m: f64::from(b.along_mm) * 1e-3,
                        left_m: f64::from(b.left_mm) * 1e-3,
                        since_ms: b.at_ms,
                    };
                    if let Some(why) = self.model.bumped(e.robot_id, felt, e.at) {
                        self.on_lost(e.robot_id, why, ctx);
                    }
                }
            }
            RobotEventKind::Reflex(r) => {
                // The robot stopped itself: what it drives next is planned again from its pose.
                self.planned.remove(&e.robot_id);
                self.reflexes += 1;
                warn!(
                    robot = e.robot_id,
                    side = { r.side },
                    power_level = { r.power_level },
                    "the proximity reflex stopped the robot"
                );
            }
            RobotEventKind::Connected(_) => {
                self.note_link(e.robot_id, "connected");
                if self
                    .model
                    .robots()
                    .get(&e.robot_id)
                    .is_some_and(|v| !v.connected)
                {
                    self.reconnected.insert(e.robot_id, e);
                    return;
                }
            }
            _ => {}
        }
        // While a robot is re-localised its moves are the routine's (or ones the stop dropped):
        // the behaviour does not hear of them.
        if let Some(routine) = self.relocalising.get_mut(&e.robot_id) {
            match &e.kind {
                RobotEventKind::MoveFinished { outcome, tag, .. } => {
                    // A move sent before this routine began (the behaviour's, or an earlier
                    // search's) that a stop dropped: its end is not the routine's. Counted, it
                    // ended searches as they began (165089 `token_ring`: three searches in
                    // 0.34 s).
                    let from = self.routine_from.get(&e.robot_id).copied().unwrap_or(0);
                    if (tag.wrapping_sub(from) as i32) < 0 {
                        return;
                    }
                    if *outcome == MoveOutcome::Blocked {
                        routine.blocked(tokio::time::Instant::now());
                    } else {
                        routine.move_finished(*outcome == MoveOutcome::Completed);
                    }
                    self.relocalise(e.robot_id, None, ctx);
                    return;
                }
                RobotEventKind::QueueEmpty => return,
                _ => {}
            }
        }
        if foreign {
            debug!(robot = e.robot_id, ?e.kind, "a move the supervisor did not send ended");
            return;
        }
        self.tell_behaviour(e, ctx);
    }
}
