//! Recovery: what the team does when it stops making progress, when a robot is lost, and when a
//! robot waits just behind a lost one (it makes room); and how a failure is explained.

use super::*;

impl TrafficControl {
    /// What each robot is doing or waiting for, for a verdict that explains a stop.
    pub(super) fn explain(&self) -> String {
        let mut lines = Vec::new();
        for (k, b) in self.bots.iter().enumerate() {
            let line = if let Some(why) = &b.lost {
                format!("robot {} is lost ({why})", b.id)
            } else if let Some(m) = b.making_room {
                format!("robot {} keeps out of lost robot {}'s way", b.id, m.lost)
            } else if let Some(leg) = b.driving {
                let route = format!("{}->{}", self.name(self.leg_from(&leg)), self.name(leg.to));
                if b.held_since.is_some() {
                    format!(
                        "robot {} on {route}: its segment is held back ({})",
                        b.id, b.held_why
                    )
                } else {
                    format!("robot {} is driving {route}", b.id)
                }
            } else if let Some(adg) = self.adg.as_ref().filter(|_| self.phase == Phase::Running) {
                let next = adg.completed(k);
                match adg.actions(k).get(next) {
                    None => format!(
                        "robot {} stands on {}, its plan done",
                        b.id,
                        self.name(b.node)
                    ),
                    Some(a) => match adg.dependency(k, next) {
                        Some((j, i)) if adg.completed(j) <= i => {
                            let d = adg.actions(j)[i];
                            format!(
                                "robot {} on {} waits to enter {} until robot {} has driven {}->{}",
                                b.id,
                                self.name(b.node),
                                self.name(a.to),
                                self.bots[j].id,
                                self.name(d.from),
                                self.name(d.to)
                            )
                        }
                        _ => format!(
                            "robot {} on {} is free to drive to {}",
                            b.id,
                            self.name(b.node),
                            self.name(a.to)
                        ),
                    },
                }
            } else {
                format!("robot {} stands on {}", b.id, self.name(b.node))
            };
            lines.push(line);
        }
        lines.join("; ")
    }

    /// No progress: stop starting actions, bring every robot to a node (a robot whose segment
    /// is held, or every driving robot from the second recovery on, drives back to the node it
    /// came from; the others finish their edges) and plan the team again from there. Fails
    /// once `MAX_RECOVERIES` recoveries in a row brought no task done.
    pub(super) fn recover(
        &mut self,
        world: &WorldSnapshot,
        why: String,
        team: &Team,
    ) -> Vec<Intent> {
        self.recoveries += 1;
        if self.recoveries > MAX_RECOVERIES {
            let summary = format!(
                "deadlock: {why}, after {MAX_RECOVERIES} replans from where the robots stood \
                 without a task done ({} tasks done): {}",
                self.tasks,
                self.explain()
            );
            return self.fail(summary);
        }
        self.recoveries_total += 1;
        tracing::info!(
            t = world.time.as_secs_f64(),
            recovery = self.recoveries,
            %why,
            state = %self.explain(),
            "traffic control recovers"
        );
        self.last_progress = world.time;
        self.phase = Phase::Draining;
        let mut out = Vec::new();
        for k in 0..self.bots.len() {
            let b = &self.bots[k];
            let Some(leg) = b.driving else { continue };
            if b.lost.is_some() || !(b.held_since.is_some() || self.recoveries > 1) {
                continue;
            }
            let back = self.reversed(&leg);
            let b = &mut self.bots[k];
            b.driving = Some(back);
            b.tail = None;
            b.held_since = None;
            b.at_end = false;
            if team.idle(b.id) {
                b.retry = false;
                out.extend(self.drive(k, world));
            }
        }
        out
    }

    pub(super) fn fail(&mut self, why: String) -> Vec<Intent> {
        self.verdict = Some(
            Verdict::failure(why)
                .with("tasks", f64::from(self.tasks))
                .with("plans", f64::from(self.replans))
                .with("recoveries", f64::from(self.recoveries_total)),
        );
        Vec::new()
    }

    /// Robot `k` is lost: its queued moves are dropped by the supervisor (the team forgets
    /// them), so their ends are not progress nor failure; its leg is kept for when it is found.
    pub(super) fn lose(&mut self, k: usize, why: String) {
        let b = &mut self.bots[k];
        b.retry = false;
        b.held_since = None;
        if let Some(leg) = b.driving.as_mut() {
            leg.last = false;
        }
        b.tail = None;
        b.making_room = None;
        b.lost = Some(why);
    }

    /// Robots waiting just behind a lost one back away from it, and come back once it is found.
    ///
    /// Only a robot with no move under way is asked, and its leg (if any) is planned again from
    /// where it stands when it is back; the safety check still judges every move.
    pub(super) fn make_room(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let mut out = Vec::new();
        for k in 0..self.bots.len() {
            let id = self.bots[k].id;
            if self.bots[k].lost.is_some() || !team.idle(id) {
                continue;
            }
            let Some(me) = world.robot(id) else { continue };
            if let Some(m) = self.bots[k].making_room {
                let still_lost = self.bots.iter().any(|b| b.id == m.lost && b.lost.is_some());
                if m.returning || still_lost {
                    continue;
                }
                let back = Vector2::new(m.from.x - me.pose.x, m.from.y - me.pose.y).norm();
                if back < 0.003 {
                    self.bots[k].making_room = None;
                    if self.bots[k].driving.is_some() {
                        out.extend(self.drive(k, world));
                    }
                    continue;
                }
                self.bots[k].making_room = Some(MakeRoom {
                    returning: true,
                    ..m
                });
                out.push(Intent::Move {
                    robot: id,
                    command: MoveCommand::Straight {
                        distance_m: back as f32,
                        speed_mps: MAKE_ROOM_MPS,
                    },
                    tag: MAKE_ROOM_TAG,
                });
                continue;
            }
            let lost_ahead = self.bots.iter().filter(|b| b.lost.is_some()).find_map(|b| {
                let (off, distance) = me.bearing_to(world.robot(b.id)?);
                (distance < MAKE_ROOM_NEAR_M && off < FRAC_PI_2).then_some(b.id)
            });
            let Some(lost) = lost_ahead else { continue };
            let b = &mut self.bots[k];
            tracing::debug!(robot = id, lost, "makes room for a lost robot");
            b.making_room = Some(MakeRoom {
                lost,
                from: me.pose,
                returning: false,
            });
            b.retry = false;
            b.held_since = None;
            b.tail = None;
            if let Some(leg) = b.driving.as_mut() {
                leg.last = false;
            }
            out.push(Intent::Move {
                robot: id,
                command: MoveCommand::Straight {
                    distance_m: -MAKE_ROOM_M,
                    speed_mps: MAKE_ROOM_MPS,
                },
                tag: MAKE_ROOM_TAG,
            });
        }
        out
    }
}
