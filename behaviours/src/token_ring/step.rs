//! One step of the ring on every snapshot and event: its limits, the team turning round, and
//! each robot following, detouring or trying a held move again; and the behaviour's hooks.

use super::*;

impl TokenRing {
    /// One step of the team: the run's limits, the team turning round, and each robot's
    /// following, detour or held move.
    pub(super) fn step(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        self.odometer.observe(world);
        if let Some(stall) = self.odometer.stall() {
            return self.fail(stall.to_string());
        }
        if let Some(why) = self.overdue(world, team) {
            return self.fail(why);
        }
        if let Some(out) = self.turn_round(world, team) {
            return out;
        }
        let mut out = Vec::new();
        for (k, id) in self.order.clone().into_iter().enumerate() {
            self.drive(k, id, world, team, &mut out);
        }
        out
    }

    /// Why the run must stop: no token pass for too long, or an aborted manoeuvre. Notes which
    /// robots stand still.
    pub(super) fn overdue(&mut self, world: &WorldSnapshot, team: &Team) -> Option<String> {
        for view in &world.robots {
            if let Some(bot) = self.bots.get_mut(&view.id) {
                let w = view.state.wheels;
                bot.still_since = if w.left_mps == 0.0 && w.right_mps == 0.0 {
                    bot.still_since.or(Some(world.time))
                } else {
                    None
                };
            }
        }
        if world.time.saturating_sub(self.last_pass) > PASS_LIMIT {
            return Some(format!(
                "no token pass for {} s after {} passes",
                PASS_LIMIT.as_secs(),
                self.passes
            ));
        }
        let forgiving = world.time <= self.forgive_until;
        for id in team.ids() {
            let Some(bot) = self.bots.get_mut(&id) else {
                continue;
            };
            let interrupted = team.interrupted(id);
            if interrupted > bot.forgiven {
                if !forgiving {
                    return Some(format!("robot {id}: a manoeuvre was aborted"));
                }
                bot.forgiven = interrupted;
            }
        }
        None
    }

    /// The whole team turning round: once the token has been round and nobody is mid-detour,
    /// every robot faces about; while it turns, only its moves go out.
    pub(super) fn turn_round(&mut self, world: &WorldSnapshot, team: &Team) -> Option<Vec<Intent>> {
        let mut out = Vec::new();
        if self.turning {
            if self.order.iter().all(|id| !self.busy(*id, team)) {
                self.turning = false;
                self.direction = -self.direction;
                self.reversals += 1;
            } else {
                for id in self.order.clone() {
                    out.extend(self.pump(id, world, team));
                }
                return Some(out);
            }
        }
        // Turn the whole team round once the token has been round, when nobody is mid-detour.
        if self.passes >= self.reverse_at && self.order.iter().all(|id| !self.busy(*id, team)) {
            self.reverse_at += self.order.len() as u32;
            self.turning = true;
            for id in self.order.clone() {
                if let Some(view) = world.robot(id) {
                    out.push(Intent::Stop { robot: id });
                    out.extend(self.send(id, &[Leg::Face(view.pose.theta + PI)], world, team));
                }
            }
            return Some(out);
        }
        None
    }

    /// Robot `id` (the `k`-th in the ring): a held move tried again, its staggered start, a
    /// detour round an unknown obstacle, or its following speed kept to the gap ahead. `out`
    /// holds what this step has sent so far.
    pub(super) fn drive(
        &mut self,
        k: usize,
        id: u16,
        world: &WorldSnapshot,
        team: &Team,
        out: &mut Vec<Intent>,
    ) {
        let Some(view) = world.robot(id) else {
            return;
        };
        let Some(bot) = self.bots.get(&id) else {
            return;
        };
        if !team.idle(id) {
            return;
        }
        if !bot.legs.is_empty() {
            // A held move: try it again.
            out.extend(self.pump(id, world, team));
            return;
        }
        if !bot.started {
            if world.time < START_STAGGER * k as u32 {
                return;
            }
            if let Some(b) = self.bots.get_mut(&id) {
                b.started = true;
            }
        }
        let ahead = self.ahead(view, world);
        let gap = ahead
            .map_or(f64::INFINITY, |(_, d)| d)
            .min(self.sighted_gap(id, world.time));
        let level = view.state.proximity.front_obstacle;
        let unknown = level > 0 && !self.reflection_explained(view, world, level);
        if level == 1 && unknown {
            out.push(Intent::FollowLine {
                robot: id,
                speed: None,
            });
            // One detour at a time: the box's surroundings hold one robot off the tape. A
            // move sent in this same step counts too (the team's books see it once this
            // step returns).
            let moving = |o: u16| {
                out.iter()
                    .any(|i| matches!(i, Intent::Move { robot, .. } if *robot == o))
            };
            let someone_detouring = self
                .order
                .iter()
                .any(|o| *o != id && (self.busy(*o, team) || moving(*o)));
            // The tape past the box, where the detour comes back, must be free.
            let (s, c) = view.pose.theta.sin_cos();
            let rejoin = (view.pose.x + 0.12 * c, view.pose.y + 0.12 * s);
            let rejoin_clear = world
                .robots
                .iter()
                .filter(|r| r.id != id)
                .all(|r| (r.pose.x - rejoin.0).hypot(r.pose.y - rejoin.1) > REJOIN_CLEAR);
            if !someone_detouring && rejoin_clear {
                out.push(Intent::Stop { robot: id });
                out.extend(self.detour(view, world, team));
            }
            return;
        }
        let current = team.following(id);
        let mut want = if gap < STOP_GAP {
            None
        } else if gap > GO_GAP || current.is_some() {
            Some(self.speed_of(id))
        } else {
            current
        };
        if unknown && (2..=3).contains(&level) {
            want = want.map(|v| v.min(CREEP_MPS));
        }
        out.push(Intent::FollowLine {
            robot: id,
            speed: want,
        });
    }
}

impl TokenRing {
    /// A move of `id` was held: a robot standing close behind it backs away a little. A robot
    /// backing out of a box's reach, or turning there, needs room behind it that a follower
    /// stopped at the follow gap leaves only while both models are sure along the tape; after a
    /// robot was lost and found, its uncertainty along the tape widens it past that gap, and
    /// neither would ever move again. The back-off is checked like any move; held in turn, it
    /// makes room behind itself the same way.
    fn make_room(&mut self, id: u16, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let Some(me) = world.robot(id) else {
            return Vec::new();
        };
        let heading = (me.pose.theta.cos(), me.pose.theta.sin());
        let behind = world.robots.iter().find(|o| {
            let (dx, dy) = (o.pose.x - me.pose.x, o.pose.y - me.pose.y);
            let w = o.state.wheels;
            let (c, s) = (o.pose.theta.cos(), o.pose.theta.sin());
            o.id != id
                && self.bots.contains_key(&o.id)
                && dx * heading.0 + dy * heading.1 < 0.0
                // It backs away from this one: two standing back to back would each back into
                // the other, held in turn for ever.
                && dx * c + dy * s < 0.0
                && self
                    .room_made
                    .get(&o.id)
                    .is_none_or(|&t| world.time >= t + ROOM_EVERY)
                && dx.hypot(dy) < ROOM_NEAR
                && w.left_mps.abs() < 0.005
                && w.right_mps.abs() < 0.005
                && team.idle(o.id)
                && team.following(o.id).is_none_or(|v| v == 0.0)
        });
        let Some(id) = behind.map(|o| o.id) else {
            return Vec::new();
        };
        tracing::debug!(robot = id, "backs away to make room");
        self.room_made.insert(id, world.time);
        // Its own held legs (a turn round beside this one) follow the back-off.
        match self.bots.get_mut(&id) {
            Some(bot) if !bot.legs.is_empty() => {
                bot.legs.push_front(Leg::Straight(-ROOM_BACK));
                self.pump(id, world, team).into_iter().collect()
            }
            _ => self.send(id, &[Leg::Straight(-ROOM_BACK)], world, team),
        }
    }
}

/// A robot whose move is held makes the robot behind it back away when their centres are closer
/// than this (a follower stopped at the follow gap stands 110 mm behind, centre to centre), by
/// this much.
const ROOM_NEAR: f64 = 0.1;
const ROOM_BACK: f64 = 0.03;
/// A robot backs away to make room at most this often: a held back-off makes room behind itself
/// in the same instant, and a chain of them must end.
const ROOM_EVERY: Duration = Duration::from_secs(1);

/// How long after a robot is found lost the moves interrupted are the supervisor's stops.
const LOST_STOPS: Duration = Duration::from_secs(2);

impl Behaviour for TokenRing {
    fn start(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        self.last_pass = world.time;
        let mut out = self.leds();
        out.extend(self.step(world, team));
        out
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
        if let (Event::Sighting(e), Some(b)) = (event, self.bots.get_mut(&robot)) {
            if let Some(front) = FrontSighting::of(e, world.time) {
                b.front_sighting = Some(front);
            }
        }
        match event {
            // The carrier's front receiver identified the robot ahead of it.
            Event::Sighting(e)
                if robot == self.holder
                    && e.side == Side::Front
                    && !self.turning
                    && !self.lost.contains(&robot)
                    && !self.lost.contains(&e.robot)
                    && !self.link_down.contains(&robot)
                    && !self.link_down.contains(&e.robot) =>
            {
                let Some(view) = world.robot(robot) else {
                    return Vec::new();
                };
                let seen = e.robot;
                match self.ahead(view, world) {
                    Some((next, d)) if next == seen && d < PASS_RANGE => {}
                    _ => return Vec::new(),
                }
                self.holder = seen;
                self.passes += 1;
                self.last_pass = world.time;
                tracing::debug!(
                    from = robot,
                    to = seen,
                    passes = self.passes,
                    "token passed"
                );
                let mut out = self.leds();
                // New speeds at once: the new carrier pulls away, the old one falls back.
                for id in [robot, seen] {
                    if team.following(id).is_some() {
                        out.push(Intent::FollowLine {
                            robot: id,
                            speed: Some(self.speed_of(id)),
                        });
                    }
                }
                if self.passes >= self.rounds * self.order.len() as u32 {
                    out.extend(self.finish(world));
                }
                out
            }
            Event::MoveFinished { .. } => self.pump(robot, world, team).into_iter().collect(),
            // Its watchdog stops it and the robot actor reconnects; the robots behind it stop at
            // it on the tape, as behind a robot lost. Back, it follows on with the others.
            Event::LinkLost => {
                self.forgive_until = world.time + LOST_STOPS;
                self.link_down.insert(robot);
                Vec::new()
            }
            Event::Connected => {
                self.link_down.remove(&robot);
                self.forgive_until = world.time + LOST_STOPS;
                Vec::new()
            }
            _ => Vec::new(),
        }
    }

    /// A robot found lost: the supervisor stopped it and the robots moving near it, dropping
    /// their moves; each detour or turn goes on leg by leg from where its robot stands, the lost
    /// one's once it is found (its intents are held until then).
    fn on_localisation(
        &mut self,
        robot: u16,
        event: &LocalisationEvent,
        world: &WorldSnapshot,
        _team: &mut Team,
    ) -> Vec<Intent> {
        match event {
            LocalisationEvent::Lost { .. } => {
                self.forgive_until = world.time + LOST_STOPS;
                self.lost.insert(robot);
            }
            LocalisationEvent::Found => {
                self.lost.remove(&robot);
            }
        }
        Vec::new()
    }

    // It re-plans a held move itself at once (a detour, a robot behind backing away): a
    // retry would only wait.
    fn held_policy(&self) -> behaviour_api::team::HeldPolicy {
        behaviour_api::team::HeldPolicy::Tell
    }

    fn on_held(
        &mut self,
        intent: &Intent,
        _reason: &str,
        world: &WorldSnapshot,
        team: &mut Team,
    ) -> Vec<Intent> {
        // A held move never ran: the leg stays, and the next snapshot tries it again.
        let Intent::Move { robot, .. } = *intent else {
            return Vec::new();
        };
        if let Some(bot) = self.bots.get_mut(&robot) {
            bot.legs.held();
        }
        self.make_room(robot, world, team)
    }

    fn verdict(&self) -> Option<Verdict> {
        self.verdict.clone()
    }

    fn progress(&self) -> Vec<(String, f64)> {
        vec![("passes".into(), f64::from(self.passes))]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use behaviour_api::testing::{world as snapshot, Harness};
    use behaviour_api::{MoveCommand, Register};
    use std::sync::Arc;
    use world::presets;

    /// Robot 1 stands on the oval's lower straight facing +x, robot 2 8 cm behind it facing
    /// `heading2`; both still, neither following.
    fn standing(heading2: f64) -> (Harness<TokenRing>, WorldSnapshot) {
        let cfg = BehaviourConfig {
            robots: vec![1, 2],
            track: Arc::new(presets::preset("oval").unwrap().track),
            ..Default::default()
        };
        let ring = TokenRing::build(Default::default(), &cfg).unwrap();
        let on = |x: f64| cfg.track.nearest(nalgebra::Point2::new(x, 0.15)).unwrap();
        let (a, b) = (on(0.40), on(0.32));
        let at = |t: f64| {
            snapshot()
                .arena(1.0, 0.6)
                .robot(1, 0.40, 0.15, 0.0)
                .robot(2, 0.32, 0.15, heading2)
                .on_track(1, a.edge, a.offset_m)
                .on_track(2, b.edge, b.offset_m)
                .at(t)
                .build()
        };
        let mut h = Harness::new(ring);
        h.start(&at(0.0));
        for id in [1, 2] {
            h.event(id, Event::WatchdogStop, &at(0.0));
        }
        // Standing still long enough to have settled.
        h.snapshot(&at(0.1));
        let world = at(2.0);
        h.snapshot(&world);
        (h, world)
    }

    fn held_step(robot: u16) -> Intent {
        Intent::Move {
            robot,
            command: MoveCommand::Straight {
                distance_m: -0.02,
                speed_mps: 0.05,
            },
            tag: 0,
        }
    }

    fn backs_away(intents: &[Intent], robot: u16) -> bool {
        intents.iter().any(|i| {
            matches!(i, Intent::Move { robot: r, command: MoveCommand::Straight { distance_m, .. }, .. }
                if *r == robot && *distance_m < 0.0)
        })
    }

    /// A held move makes the robot standing close behind back away, once in a while.
    #[test]
    fn a_held_move_makes_the_robot_behind_back_away() {
        let (mut h, world) = standing(0.0);
        let out = h.hold(held_step(1), "in the way", &world);
        assert!(backs_away(&out, 2), "{out:?}");
        let again = h.hold(held_step(1), "in the way", &world);
        assert!(
            !backs_away(&again, 2),
            "backs away again at once: {again:?}"
        );
    }

    /// Two robots back to back: backing away would drive each into the other, and each held
    /// back-off made room for the other's in the same instant, for ever.
    #[test]
    fn a_robot_behind_facing_away_does_not_back_into_the_held_one() {
        let (mut h, world) = standing(180.0);
        let out = h.hold(held_step(1), "in the way", &world);
        assert!(!backs_away(&out, 2), "{out:?}");
    }

    /// A lost robot's search turns it about, and what its front receiver then sees (the robot
    /// beside or behind it) is no pass of the token: a pass waits until it is found.
    #[test]
    fn a_lost_carrier_passes_no_token() {
        let (mut h, world) = standing(0.0);
        // Robot 1 carries the token; robot 2 stands behind it, facing it.
        let seen = Event::Sighting(behaviour_api::Sighting {
            robot: 2,
            side: Side::Front,
            relative_heading_deg: 180,
            range_mm: 60,
            message: 0,
        });
        let turned = snapshot()
            .arena(1.0, 0.6)
            .robot(1, 0.40, 0.15, 180.0)
            .robot(2, 0.32, 0.15, 0.0)
            .at(2.5)
            .build();
        h.localise(
            1,
            LocalisationEvent::Lost {
                why: "bumped".into(),
            },
            &world,
        );
        h.event(1, seen, &turned);
        assert_eq!(h.behaviour().passes, 0);
        assert_eq!(h.behaviour().holder, 1);
        // Found again, the same sighting passes it.
        h.localise(1, LocalisationEvent::Found, &turned);
        h.event(1, seen, &turned);
        assert_eq!(h.behaviour().passes, 1);
        assert_eq!(h.behaviour().holder, 2);
    }
}
