//! A robot found lost: stopped, its behaviour told, and driven by the relocaliser until the tape
//! fixes its pose again.

use super::*;

use behaviours::MoveCommand;
use protocol::packets::DriveMode;

/// A robot that stands in a lost robot's search moves this far along its heading, at this speed,
/// at most this far in all, and back once the lost robot is found.
const ROOM_STEP_M: f64 = 0.04;
const ROOM_MPS: f32 = 0.04;
const ROOM_MOST_M: f64 = 0.12;
/// Wheels slower than this are at rest (the safety check's measure, in the state's units).
const AT_REST_MPS: f32 = world_model::safety::AT_REST_MPS as f32;

/// Whether a robot's wheels turn.
fn wheels_turn(v: &behaviours::RobotView) -> bool {
    let w = v.state.wheels;
    w.left_mps.abs() > AT_REST_MPS || w.right_mps.abs() > AT_REST_MPS
}

/// A robot moved aside for a lost robot's search.
#[derive(Clone, Copy, Debug)]
pub(super) struct Room {
    /// The lost robot.
    lost: u16,
    /// Where it stood, and how far it has been moved so far.
    from: Pose,
    moved_m: f64,
}

impl Supervisor {
    /// A robot's sensing contradicted the model: stop it and every robot moving within its
    /// reach, hold its intents, tell the behaviour, and start re-localising it.
    pub(super) fn on_lost(&mut self, id: u16, why: String, ctx: &mut Context<Self>) {
        let world = self.snapshot_peek();
        let Some(view) = world.robot(id).cloned() else {
            return;
        };
        warn!(
            robot = id,
            why, "robot lost: stopping it and re-localising it"
        );
        // The sweep stays where the safety check lets the lost robot's footprint go: its
        // circumscribed circle, the margin and its uncertainty (1σ against the walls, with room
        // for it to grow a little on the way) inside the arena.
        let clear = (self.safety.length_m / 2.0).hypot(self.safety.width_m / 2.0)
            + self.safety.margin_m
            + safety::UNCERTAINTY_SIGMAS * (view.uncertainty.position_m + SWEEP_SIGMA_GROWTH_M);
        let (w, h) = self.arena;
        let room = ([clear, clear], [w - clear, h - clear]);
        let (routine, first) = Relocaliser::start(
            &view,
            self.model.track(),
            self.model.junctions(),
            room,
            Instant::now(),
        );
        self.relocalising.insert(id, routine);
        self.routine_from.insert(id, self.next_move);
        self.act(id, first, &world);
        let reach = LOST_REACH_M + self.safety.reach(&view);
        let near: Vec<u16> = world
            .robots
            .iter()
            .filter(|o| o.id != id && !self.relocalising.contains_key(&o.id))
            .filter(|o| {
                let moving = o.pending_moves > 0 || wheels_turn(o);
                let planned = self.planned.get(&o.id).map_or(o.pose, Plan::end);
                let within = |p: Pose| (p.x - view.pose.x).hypot(p.y - view.pose.y) < reach;
                moving && (within(o.pose) || within(planned))
            })
            .map(|o| o.id)
            .collect();
        for other in near {
            info!(robot = other, lost = id, "stopping a robot near a lost one");
            self.planned.remove(&other);
            if let Some(r) = self.robot(other) {
                r.addr().do_send(Command::Stop);
            }
        }
        self.tell(id, LocalisationEvent::Lost { why }, ctx);
    }

    pub(super) fn tell(&mut self, id: u16, event: LocalisationEvent, ctx: &mut Context<Self>) {
        if let Some(b) = self.behaviour.clone() {
            let reply = b.send(Localised {
                robot: id,
                event,
                world: self.snapshot_peek(),
            });
            ctx.spawn(
                reply
                    .into_actor(self)
                    .map(|r, act, ctx| act.on_reply(r, ctx)),
            );
        }
    }

    /// Carries out one step of a re-localisation routine.
    pub(super) fn act(&mut self, id: u16, action: Action, world: &WorldSnapshot) {
        match action {
            Action::Stop => {
                self.planned.remove(&id);
                if let Some(r) = self.robot(id) {
                    r.addr().do_send(Command::Stop);
                }
            }
            Action::Follow(speed) => {
                // The follow is the robot's own line follower: checked before it starts as the
                // drive straight ahead it may make, and held like a search leg.
                let sweep = Intent::Move {
                    robot: id,
                    command: MoveCommand::Straight {
                        distance_m: FOLLOW_MOST_M as f32,
                        speed_mps: speed,
                    },
                    tag: RELOCALISATION_TAG,
                };
                if let Err(blocker) = self.check_only(&sweep, world) {
                    if let Some(other) = blocker {
                        self.make_room(other, id, world);
                    }
                    if let Some(r) = self.relocalising.get_mut(&id) {
                        r.follow_held(Instant::now());
                    }
                    return;
                }
                tracing::debug!(robot = id, speed, "re-localisation follows the tape");
                if let Some(r) = self.robot(id) {
                    r.addr().do_send(Command::FollowLine(Some(speed)));
                }
            }
            Action::Moves(moves) => {
                tracing::debug!(robot = id, ?moves, "re-localisation moves");
                let mut held = Vec::new();
                for command in moves {
                    if !held.is_empty() {
                        held.push(command);
                        continue;
                    }
                    if let Err(blocker) = self.own_move(id, command, world) {
                        held.push(command);
                        if let Some(other) = blocker {
                            self.make_room(other, id, world);
                        }
                    }
                }
                if !held.is_empty() {
                    if let Some(r) = self.relocalising.get_mut(&id) {
                        r.held(held, Instant::now());
                    }
                }
            }
        }
    }

    /// Advances the routine of a lost robot after a state update or a transition.
    pub(super) fn relocalise(
        &mut self,
        id: u16,
        transition: Option<Transition>,
        ctx: &mut Context<Self>,
    ) {
        let now = Instant::now();
        let world = self.snapshot_peek();
        let Some(view) = world.robot(id).cloned() else {
            return;
        };
        let track = Arc::clone(self.model.track());
        let Some(routine) = self.relocalising.get_mut(&id) else {
            return;
        };
        let action = match transition {
            Some(Transition::Fixed) => {
                info!(robot = id, "lost robot found a tape: aligning it");
                Some(routine.fixed(now))
            }
            _ => routine.poll(&view, &track, now),
        };
        if routine.aligned() {
            if view.localisation == behaviours::Localisation::Tracking {
                let settled = routine.settled() && self.model.faces_along_tape(id);
                info!(robot = id, settled, "robot re-localised");
                self.relocalising.remove(&id);
                // A follow that ended unsettled may have matched the wrong tape: its robot can
                // stand centimetres from where the model puts it, and a neighbour driving back
                // beside it met it (165025 `token_ring`). The neighbours then stay where they
                // made room, and their behaviours go on from there.
                if settled {
                    self.give_room_back(id, &world);
                } else {
                    self.making_room.retain(|_, r| r.lost != id);
                }
                // The routine's last word stops its follow along the tape: the robot waits for
                // its behaviour, which hears it was found, rather than follow on unasked.
                if let Some(action) = action {
                    self.act(id, action, &world);
                }
                self.tell(id, LocalisationEvent::Found, ctx);
                return;
            }
            warn!(robot = id, "back on the tape, but it does not match");
            routine.give_up();
        }
        if routine.gave_up() {
            self.search_again(id, ctx);
            return;
        }
        if let Some(action) = action {
            self.act(id, action, &world);
        }
    }

    /// The routine of lost robot `id` found no tape that matches: it starts again from where the
    /// robot stands, with the model's widened pose, at most [`SEARCHES`] times in all; then the
    /// run ends, the robot stopped where it is, rather than hang or drive on a guess.
    fn search_again(&mut self, id: u16, ctx: &mut Context<Self>) {
        self.relocalising.remove(&id);
        let searches = self.searches.entry(id).or_insert(0);
        *searches += 1;
        if *searches >= SEARCHES {
            warn!(robot = id, "robot lost and not found: ending the run");
            let verdict = self.unfinished(format!("robot {id} lost and not found"));
            self.finish(verdict, ctx);
            return;
        }
        warn!(
            robot = id,
            searches = *searches,
            "robot not found: searching again"
        );
        self.model.search_afresh(id, Instant::now());
        self.on_lost(id, "its search found no tape that matches".into(), ctx);
    }

    /// A lost robot's search move was held because it would touch `other`: a robot standing
    /// idle and tracked there moves [`ROOM_STEP_M`] along its heading (checked like any move),
    /// up to [`ROOM_MOST_M`] in all. Without it the two wait on each other for good: the lost
    /// robot's whole uncertainty region is an exclusion zone, and the other's behaviour waits
    /// for the lost one to be found (record 0034).
    fn make_room(&mut self, other: u16, lost: u16, world: &WorldSnapshot) {
        let (Some(o), Some(l)) = (world.robot(other), world.robot(lost)) else {
            return;
        };
        let idle = o.connected
            && o.localisation == behaviours::Localisation::Tracking
            && o.pending_moves == 0
            && o.state.locomotion.mode == DriveMode::Idle as u8
            && !wheels_turn(o)
            && !self.planned.contains_key(&other)
            && !self.relocalising.contains_key(&other);
        if !idle {
            return;
        }
        let room = *self.making_room.entry(other).or_insert(Room {
            lost,
            from: o.pose,
            moved_m: 0.0,
        });
        if room.lost != lost || room.moved_m + ROOM_STEP_M > ROOM_MOST_M + 1e-9 {
            return;
        }
        // Backwards, unless the lost robot stands clearly behind: a robot faces what it drove
        // up to (a box it pushes beside the lost one, a robot it queues behind), and came from
        // behind.
        let (s, c) = o.pose.theta.sin_cos();
        let behind = (o.pose.x - l.pose.x) * c + (o.pose.y - l.pose.y) * s;
        let way = if behind > world::robot::LENGTH_M / 2.0 {
            1.0
        } else {
            -1.0
        };
        let command = MoveCommand::Straight {
            distance_m: (ROOM_STEP_M * way) as f32,
            speed_mps: ROOM_MPS,
        };
        if self.own_move(other, command, world).is_ok() {
            info!(
                robot = other,
                lost, "moving aside for a lost robot's search"
            );
            if let Some(r) = self.making_room.get_mut(&other) {
                r.moved_m += ROOM_STEP_M;
            }
        }
    }

    /// Lost robot `lost` is found: the robots moved aside for it go back where they stood, where
    /// their behaviour left them (one it has driven since is its own again); a move back that
    /// the safety check holds is not made, and the robot's behaviour goes on from where it is.
    fn give_room_back(&mut self, lost: u16, world: &WorldSnapshot) {
        let movers: Vec<(u16, Room)> = self
            .making_room
            .iter()
            .filter(|(_, r)| r.lost == lost)
            .map(|(id, r)| (*id, *r))
            .collect();
        for (id, room) in movers {
            self.making_room.remove(&id);
            let Some(o) = world.robot(id) else { continue };
            if room.moved_m == 0.0 || o.pending_moves > 0 || self.planned.contains_key(&id) {
                continue;
            }
            let (s, c) = o.pose.theta.sin_cos();
            let back = (room.from.x - o.pose.x) * c + (room.from.y - o.pose.y) * s;
            if back.abs() < 0.003 {
                continue;
            }
            let command = MoveCommand::Straight {
                distance_m: back as f32,
                speed_mps: ROOM_MPS,
            };
            if self.own_move(id, command, world).is_ok() {
                info!(robot = id, lost, "back where it stood before it made room");
            }
        }
    }

    /// Sends a move of the supervisor's own (the re-localiser's, or one making room for it)
    /// through the safety check; the behaviour does not hear of its end. A held one names the
    /// robot it would have touched.
    fn own_move(
        &mut self,
        robot: u16,
        command: MoveCommand,
        world: &WorldSnapshot,
    ) -> Result<(), Option<u16>> {
        let number = self.next_move;
        let intent = Intent::Move {
            robot,
            command,
            tag: RELOCALISATION_TAG,
        };
        self.try_carry_out(intent, world)?;
        self.disown_move(robot, number);
        Ok(())
    }
}
