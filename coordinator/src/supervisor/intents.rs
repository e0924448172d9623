//! Intents carried out: each checked against every robot's swept footprint before it reaches its
//! robot, chained moves anchored where the robot is, and the control panel's commands and
//! emergency stop.

use super::*;

/// Spacing of the poses a searching follower's follow is taken to sweep: under half a body
/// length, so that no footprint fits between two of them.
const FOLLOW_SAMPLE_M: f64 = 0.02;

impl Supervisor {
    /// Carries out a reply's intents in order and tells the behaviour which were held.
    pub(super) fn carry_out_all(&mut self, intents: Vec<Intent>, ctx: &mut Context<Self>) {
        let world = self.snapshot_peek();
        // Once a robot's move is held, its later moves in the same reply are held too: they were
        // planned from where the held one would have left it.
        let mut held_robots: Vec<u16> = Vec::new();
        let before = self.held.len();
        for intent in intents {
            let id = intent.robot();
            if held_robots.contains(&id) && matches!(intent, Intent::Move { .. }) {
                self.held
                    .push((world.time, intent, "follows a held move".into()));
                continue;
            }
            if !self.carry_out(intent, &world) {
                held_robots.push(id);
            }
        }
        // The behaviour hears what did not reach its robots.
        if self.held.len() > before {
            if let Some(b) = self.behaviour.clone() {
                let held = self.held[before..]
                    .iter()
                    .map(|(_, i, why)| (*i, why.clone()))
                    .collect();
                let reply = b.send(Held { held, world });
                ctx.spawn(
                    reply
                        .into_actor(self)
                        .map(|r, act, ctx| act.on_reply(r, ctx)),
                );
            }
        }
    }

    /// The world as it is, without consuming the new encounters.
    pub(super) fn snapshot_peek(&self) -> WorldSnapshot {
        WorldSnapshot {
            time: Instant::now() - self.started_at,
            robots: behaviours::Robots(self.model.shared_views()),
            encounters: Vec::new(),
            arena: self.arena,
        }
    }

    /// Checks and sends one intent; `false` when it was held back (the robot is lost, or the
    /// safety check refused it).
    pub(super) fn carry_out(&mut self, intent: Intent, world: &WorldSnapshot) -> bool {
        let id = intent.robot();
        let drives = matches!(
            intent,
            Intent::Move { .. } | Intent::FollowLine { .. } | Intent::WheelSpeeds { .. }
        );
        if drives {
            // Driven by its behaviour, a robot moved aside for a lost one is its own again.
            self.making_room.remove(&id);
        }
        if drives && self.relocalising.contains_key(&id) {
            let reason = format!("robot {id} is lost: it is being re-localised");
            self.held.push((world.time, intent, reason));
            return false;
        }
        // The robot's watchdog has stopped it; a command would be lost, or (queued in a link
        // that comes back) carried out from a stale plan.
        if world.robot(id).is_some_and(|r| !r.connected) {
            let reason = format!("robot {id}'s link is lost");
            self.held.push((world.time, intent, reason));
            return false;
        }
        self.carry_out_checked(intent, world)
    }

    /// Passes one intent through the safety check and sends it.
    pub(super) fn carry_out_checked(&mut self, intent: Intent, world: &WorldSnapshot) -> bool {
        self.try_carry_out(intent, world).is_ok()
    }

    /// The safety check of `intent` against every robot, as [`Self::try_carry_out`] makes it,
    /// without carrying it out: where the mover starts from, or the robot it would touch.
    pub(super) fn check_only(
        &mut self,
        intent: &Intent,
        world: &WorldSnapshot,
    ) -> Result<Option<Pose>, Option<u16>> {
        let id = intent.robot();
        let now = Instant::now();
        let from = match self.planned.get(&id) {
            Some(plan) => Some(plan.end()),
            None => world.robot(id).and_then(|r| self.landing(r, now)),
        };
        let mut others: Vec<(u16, Pose)> = self
            .planned
            .iter()
            .filter(|(other, _)| **other != id)
            .map(|(other, plan)| (*other, plan.end()))
            .collect();
        others.extend(
            world
                .robots
                .iter()
                .filter(|o| o.id != id && !self.planned.contains_key(&o.id))
                .filter_map(|o| Some((o.id, self.landing(o, now)?))),
        );
        others.extend(self.search_follows(id, world));
        if let Err(refusal) = self.safety.check_planned(intent, world, from, &others) {
            warn!(?intent, reason = refusal.reason, "intent held back");
            self.held.push((world.time, *intent, refusal.reason));
            return Err(refusal.robot);
        }
        Ok(from)
    }

    /// As [`Self::carry_out_checked`]; a held intent names the robot it would have touched.
    pub(super) fn try_carry_out(
        &mut self,
        intent: Intent,
        world: &WorldSnapshot,
    ) -> Result<(), Option<u16>> {
        let id = intent.robot();
        let now = Instant::now();
        let from = self.check_only(&intent, world)?;
        match intent {
            Intent::Move { command, .. } => {
                let start = from
                    .or_else(|| world.robot(id).map(|r| r.pose))
                    .unwrap_or_default();
                let end = safety::end_pose(start, command);
                let plan = self.planned.entry(id).or_insert_with(|| Plan {
                    ends: Default::default(),
                    sent: now,
                });
                plan.ends.push_back((self.next_move, end));
                plan.sent = now;
            }
            Intent::Led { .. } | Intent::IrMessage { .. } | Intent::Reflex { .. } => {}
            _ => {
                self.planned.remove(&id);
            }
        }
        let Some(robot) = self.robot(intent.robot()) else {
            return Ok(());
        };
        let addr = robot.addr().clone();
        match intent {
            Intent::Move { command, tag, .. } => {
                let number = self.next_move;
                self.next_move = self.next_move.wrapping_add(1);
                self.move_tags.insert((id, number), tag);
                addr.do_send(Enqueue::tagged(command, number));
            }
            Intent::FollowLine { speed, .. } => addr.do_send(Command::FollowLine(speed)),
            Intent::WheelSpeeds { left, right, .. } => {
                addr.do_send(Command::WheelSpeeds(left, right))
            }
            Intent::ClearQueue { .. } => addr.do_send(Command::ClearQueue),
            Intent::Stop { .. } => addr.do_send(Command::Stop),
            Intent::Led { rgb, .. } => addr.do_send(Command::Led(rgb[0], rgb[1], rgb[2])),
            Intent::IrMessage { message, .. } => addr.do_send(Command::IrMessage(message)),
            Intent::Reflex { power_level, .. } => {
                let field = protocol::settings::Settings::field("reflex.power_level");
                if let Some((offset, _)) = field {
                    addr.do_send(robot_actor::WriteSettings {
                        offset,
                        bytes: vec![power_level],
                    });
                }
            }
        }
        Ok(())
    }

    /// Where the re-localiser's follows along the tape may take their robots (all but `id`):
    /// poses every [`FOLLOW_SAMPLE_M`] along the arc the follower's wheels drive, straight ahead
    /// before they turn. The follow is the robot's own line follower, which no move plans: a
    /// robot approved into the merge a searching follower was coming down to met it there
    /// (185035 `traffic_control`).
    fn search_follows(&self, id: u16, world: &WorldSnapshot) -> Vec<(u16, Pose)> {
        let search = f64::from(world_model::relocalise::SEARCH_MPS);
        let mut out = Vec::new();
        for (&fid, routine) in self.relocalising.iter().filter(|(&f, _)| f != id) {
            let (Some(reach), Some(v)) = (routine.follow_reach(), world.robot(fid)) else {
                continue;
            };
            let w = v.state.wheels;
            let (l, r) = (f64::from(w.left_mps), f64::from(w.right_mps));
            let wheels = if (l + r) / 2.0 > safety::AT_REST_MPS {
                (l, r)
            } else {
                (search, search)
            };
            let speed = (wheels.0 + wheels.1) / 2.0;
            let steps = (reach / FOLLOW_SAMPLE_M).ceil() as usize;
            out.extend((1..=steps).map(|k| {
                let d = (k as f64 * FOLLOW_SAMPLE_M).min(reach);
                (fid, safety::ahead(v.pose, wheels, d / speed))
            }));
        }
        out
    }

    /// Where a robot driving on its wheels will be when a command sent now reaches it
    /// ([`Safety::landing`]), from its link's longest recent round trip and its latest state's
    /// arrival.
    fn landing(&self, r: &behaviours::RobotView, now: Instant) -> Option<Pose> {
        let (rtt, state_at) = self.timing.get(&r.id)?;
        let late = now.saturating_duration_since(*state_at) + rtt.unwrap_or_default();
        self.safety.landing(r, late)
    }

    /// The move sent to `robot` under `number`, if one was, is not the behaviour's: its finish
    /// keeps no tag, and the behaviour does not hear of it.
    pub(super) fn disown_move(&mut self, robot: u16, number: u32) {
        self.move_tags.remove(&(robot, number));
    }
}

/// A command from the control panel: checked by the safety check like a behaviour's intent, then
/// sent; the error says why it was held. The behaviour does not hear a panel move's finish.
#[derive(Message)]
#[rtype(result = "Result<(), String>")]
pub struct PanelIntent(pub Intent);

impl Handler<PanelIntent> for Supervisor {
    type Result = Result<(), String>;
    fn handle(&mut self, msg: PanelIntent, _: &mut Context<Self>) -> Self::Result {
        let world = self.snapshot_peek();
        let intent = msg.0;
        let id = intent.robot();
        let number = self.next_move;
        if self.carry_out(intent, &world) {
            self.disown_move(id, number);
            Ok(())
        } else {
            Err(self.held.last().map(|h| h.2.clone()).unwrap_or_default())
        }
    }
}

/// The panel's emergency stop: every robot stops and the behaviour is over.
#[derive(Message)]
#[rtype(result = "()")]
pub struct EStop;

impl Handler<EStop> for Supervisor {
    type Result = ();
    fn handle(&mut self, _: EStop, ctx: &mut Context<Self>) {
        // Also when the behaviour is already over: the panel may have moved robots since.
        self.stop_all();
        let verdict = self.unfinished("emergency stop from the control panel".into());
        self.finish(verdict, ctx);
    }
}
