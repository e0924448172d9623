//! What each robot makes of what it senses and what it is sent: the robot ahead, a reflection
//! the model explains, the moves of a detour, the token's LEDs, and the verdict.

use super::*;

impl TokenRing {
    pub(super) fn speed_of(&self, id: u16) -> f32 {
        if id == self.holder {
            self.speed
        } else {
            self.speed * 0.5
        }
    }

    /// The nearest robot ahead of `me` in the direction of travel and its distance (along the
    /// tape when both are on it, straight-line within a cone ahead otherwise).
    pub(super) fn ahead(&self, me: &RobotView, world: &WorldSnapshot) -> Option<(u16, f64)> {
        let mut best: Option<(u16, f64)> = None;
        for other in world.robots.iter().filter(|o| o.id != me.id) {
            let d = self
                .track
                .gap(me, other, self.direction > 0.0)
                .unwrap_or(f64::INFINITY);
            // Off the tape (detouring) or close by, a robot in front counts by straight-line
            // distance: anywhere in the front half within `NEAR`, within the cone farther out.
            let (off, straight) = me.bearing_to(other);
            let d = if (off < FRAC_PI_2 && straight < NEAR) || off < AHEAD_CONE {
                d.min(straight)
            } else {
                d
            };
            if !d.is_finite() {
                continue;
            }
            if best.is_none_or(|(_, b)| d < b) {
                best = Some((other.id, d));
            }
        }
        best
    }

    /// The most a fresh front sighting lets the gap to the robot in front be, sensor to sensor. A
    /// follower whose model is off along the tape (odometry cannot see a shove along it, and the
    /// line sensor cannot either) still stops short of the robot its receiver sees.
    pub(super) fn sighted_gap(&self, id: u16, now: Duration) -> f64 {
        self.bots
            .get(&id)
            .and_then(|b| b.front_sighting)
            .map_or(f64::INFINITY, |s| s.gap_bound(now, SIGHTING_FRESH))
    }

    /// Whether a body the world model knows (another robot, an arena wall) can account for a
    /// reflection the front receiver sees at power `level`. One that none can is an unknown
    /// obstacle, however close the next robot along the tape is: a robot beside the box, or
    /// just past it, must not make a follower drive into the box.
    pub(super) fn reflection_explained(
        &self,
        me: &RobotView,
        world: &WorldSnapshot,
        level: u8,
    ) -> bool {
        let Some(reach) = REFLECT_REACH_M.get(usize::from(level).wrapping_sub(1)) else {
            return true;
        };
        let reach = reach + MODEL_SLACK_M;
        let (s, c) = me.pose.theta.sin_cos();
        let front = (me.pose.x + HALF_LEN * c, me.pose.y + HALF_LEN * s);
        let robot_there = world.robots.iter().filter(|o| o.id != me.id).any(|o| {
            let (dx, dy) = (o.pose.x - front.0, o.pose.y - front.1);
            dx * c + dy * s > -HALF_LEN && dx.hypot(dy) - HALF_LEN < reach
        });
        // Distance along the heading from the front to the arena's walls.
        let (w, h) = world.arena;
        let to_wall = |p: f64, d: f64, far: f64| {
            if d > 1e-9 {
                (far - p) / d
            } else if d < -1e-9 {
                -p / d
            } else {
                f64::INFINITY
            }
        };
        let wall = to_wall(front.0, c, w).min(to_wall(front.1, s, h));
        robot_there || wall < reach
    }

    /// Starts a manoeuvre; its moves go out one at a time, each from the robot's pose when the
    /// last has finished, so a move the safety check holds is simply tried again later instead
    /// of leaving the robot halfway.
    pub(super) fn send(
        &mut self,
        id: u16,
        legs: &[Leg],
        world: &WorldSnapshot,
        team: &Team,
    ) -> Vec<Intent> {
        if let Some(bot) = self.bots.get_mut(&id) {
            bot.legs = Legs::new(MANOEUVRE_MPS);
            for leg in legs {
                bot.legs.push(*leg);
            }
        }
        self.pump(id, world, team).into_iter().collect()
    }

    /// The robot's next manoeuvre move, if none is running and the robot has settled: a turn
    /// is reported finished while the wheels still coast, and a leg planned from that pose would
    /// be off by the rest of the coast.
    pub(super) fn pump(&mut self, id: u16, world: &WorldSnapshot, team: &Team) -> Option<Intent> {
        let pose = world.robot(id)?.pose;
        let bot = self.bots.get_mut(&id)?;
        let settled = bot
            .still_since
            .is_some_and(|t| world.time.saturating_sub(t) >= SETTLE);
        if !team.idle(id) || !settled {
            return None;
        }
        let command = bot.legs.next(pose)?;
        tracing::debug!(robot = id, ?command, ?pose, "manoeuvre move");
        Some(Intent::Move {
            robot: id,
            command,
            tag: 0,
        })
    }

    /// Whether the robot is on a manoeuvre: a move out or legs still to drive.
    pub(super) fn busy(&self, id: u16, team: &Team) -> bool {
        !team.idle(id) || self.bots.get(&id).is_some_and(|b| !b.legs.is_empty())
    }

    pub(super) fn leds(&self) -> Vec<Intent> {
        self.order
            .iter()
            .map(|&robot| Intent::Led {
                robot,
                rgb: if robot == self.holder {
                    TOKEN_RGB
                } else {
                    PLAIN_RGB
                },
            })
            .collect()
    }

    /// Around the box on the robot's right: back off a little, step aside, pass, step back onto
    /// the tape where it continues past the box, face along it.
    pub(super) fn detour(
        &mut self,
        view: &RobotView,
        world: &WorldSnapshot,
        team: &Team,
    ) -> Vec<Intent> {
        let p = view.pose;
        let (s, c) = p.theta.sin_cos();
        let (rx, ry) = (s, -c);
        let ahead = nalgebra::Point2::new(p.x + DETOUR_ALONG * c, p.y + DETOUR_ALONG * s);
        // Rejoin on the tape itself where it is near, so the line sensor finds it under its
        // centre; facing along it in the direction of travel.
        let (rejoin, heading) = match self.tape.nearest(ahead) {
            Some(n) if n.distance_m < 0.03 => {
                let t = n.tangent * n.tangent.dot(&nalgebra::Vector2::new(c, s)).signum();
                (n.point, t.y.atan2(t.x))
            }
            _ => (ahead, p.theta),
        };
        let legs = [
            Leg::Straight(-DETOUR_BACK),
            Leg::To {
                x: p.x + DETOUR_SIDE * rx,
                y: p.y + DETOUR_SIDE * ry,
            },
            Leg::To {
                x: rejoin.x + DETOUR_SIDE * rx,
                y: rejoin.y + DETOUR_SIDE * ry,
            },
            Leg::To {
                x: rejoin.x,
                y: rejoin.y,
            },
            Leg::Face(heading),
        ];
        self.detours += 1;
        self.send(view.id, &legs, world, team)
    }

    pub(super) fn finish(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let n = self.order.len() as f64;
        self.odometer.observe(world);
        let needed = LOOP_SHARE_PER_ROUND * f64::from(self.rounds) * self.track.length_m();
        let ids = self.order.iter().copied();
        let least_m = self.odometer.least_m(ids.clone());
        if let Some(id) = ids
            .clone()
            .find(|id| self.odometer.distance_m(*id) < needed)
        {
            let measured = self.odometer.distance_m(id);
            return self.fail(format!(
                "robot {id}: the token went round {} times but its encoders measured \
                 {measured:.2} m, short of the {needed:.2} m (half a loop per round) that \
                 carrying and following it takes",
                self.rounds
            ));
        }
        self.verdict = Some(
            Verdict::success(format!(
                "the token went round {} robots {} times ({} passes, {} reversals, {} detours), \
                 each robot at least {least_m:.2} m by its encoders",
                self.order.len(),
                self.rounds,
                self.passes,
                self.reversals,
                self.detours
            ))
            .with("passes", f64::from(self.passes))
            .with("least_encoder_distance_m", least_m)
            .with("reversals", f64::from(self.reversals))
            .with("detours", f64::from(self.detours))
            .with(
                "seconds_per_round",
                world.time.as_secs_f64() / (f64::from(self.passes) / n),
            ),
        );
        Vec::new()
    }

    pub(super) fn fail(&mut self, why: String) -> Vec<Intent> {
        let least_m = self.odometer.least_m(self.order.iter().copied());
        self.verdict = Some(
            Verdict::failure(why)
                .with("passes", f64::from(self.passes))
                .with("least_encoder_distance_m", least_m),
        );
        Vec::new()
    }
}
