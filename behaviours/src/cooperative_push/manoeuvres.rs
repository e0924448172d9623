//! The manoeuvres: where the box is from the finder's sighting, the two slots beside it, the
//! drives there, the synchronised push and the backing onto the tape.

use super::*;

impl CooperativePush {
    pub(super) fn helper(&self) -> Option<u16> {
        self.bots
            .keys()
            .copied()
            .find(|id| Some(*id) != self.finder)
    }

    pub(super) fn enter(&mut self, phase: Phase, world: &WorldSnapshot) {
        tracing::debug!(?phase, t = world.time.as_secs_f64(), "cooperative_push");
        self.phase = phase;
        self.phase_since = world.time;
    }

    pub(super) fn fail(&mut self, why: String) -> Vec<Intent> {
        self.verdict = Some(
            Verdict::failure(why)
                .with("pushes", f64::from(self.pushes))
                .with("phase_reached", self.phase as u8 as f64),
        );
        Vec::new()
    }

    /// Every pusher's proximity reflex set to `power_level` (0 off).
    pub(super) fn reflexes(&self, power_level: u8) -> Vec<Intent> {
        self.bots
            .keys()
            .map(|&robot| Intent::Reflex { robot, power_level })
            .collect()
    }

    /// The route's moves, tagged with the phase they belong to.
    pub(super) fn send(&self, id: u16, route: Manoeuvre) -> Vec<Intent> {
        Intent::moves(id, route.moves, self.phase as u32)
    }

    /// Along-track distance to the nearest robot ahead of `me`, sensor to sensor.
    pub(super) fn gap_ahead(&self, me: &RobotView, world: &WorldSnapshot) -> f64 {
        world
            .robots
            .iter()
            .filter(|o| o.id != me.id)
            .filter_map(|o| self.track.gap(me, o, true))
            .fold(f64::INFINITY, f64::min)
    }

    /// Where the box must be, seen from the finder standing behind it.
    pub(super) fn locate(&self, finder: &RobotView) -> Site {
        // From where the finder first reported the box at the shortest reach, not from where it
        // stopped or where the model had it when the sighting arrived: both depend on the
        // link's latency, a few millimetres that decide whether each pusher still covers the
        // box's corner.
        let (p, gap) = match (self.sighted, finder.state.proximity.front_obstacle) {
            (Some(p), _) => (p, SIGHTED_GAP),
            (None, 1) => (finder.pose, 0.007),
            (None, 2) => (finder.pose, 0.022),
            (None, _) => (finder.pose, 0.03),
        };
        let heading = Vector2::new(p.theta.cos(), p.theta.sin());
        let along = heading;
        let centre = Point2::new(p.x, p.y) + along * (HALF_LEN + gap + self.box_half);
        // Pushed to the robot's left: on a counter-clockwise loop, into the loop's middle.
        let push = Vector2::new(-along.y, along.x);
        Site {
            centre,
            along,
            push,
        }
    }

    /// Distance of a pusher's centre from the box centre, across the track, when waiting.
    pub(super) fn lane(&self) -> f64 {
        -(self.box_half + LANE_GAP + HALF_LEN)
    }

    pub(super) fn slot(&self, id: u16) -> f64 {
        if self.bots.len() == 1 {
            0.0
        } else if Some(id) == self.finder {
            SLOT_OFFSET
        } else {
            -SLOT_OFFSET
        }
    }

    /// From `pose` on the tape behind the box: down to an approach lane below the slots, along it,
    /// then a quarter turn and straight up into the slot. Arriving sideways along the slots' line
    /// would swing the 48 mm body into the robot already waiting there. The first robot into
    /// the slots takes a shallower lane, and a robot farther back follows the tape's line up to
    /// where the finder left it first: off the tape nothing measures the heading, so the legs
    /// along the arena's edge are kept short and far from it. The robot's own reflex may end
    /// the last leg a little short of the box.
    pub(super) fn to_slot(&self, id: u16, pose: Pose, site: &Site, back_up: f64) -> Manoeuvre {
        let here = Vector2::new(pose.x, pose.y) - site.centre.coords;
        let along_now = here.dot(&site.along) - back_up;
        let leave = -(HALF_LEN + SIGHTED_GAP + self.box_half + TURN_BACK);
        let first = self.bots.len() == 1 || Some(id) == self.finder;
        let approach = self.lane() - if first { FIRST_BELOW } else { APPROACH_BELOW };
        let mut route = Manoeuvre::from(pose, MANOEUVRE_MPS).straight(-back_up);
        let mut along = along_now;
        if along_now < leave {
            let ahead = site.at(leave, here.dot(&site.push));
            route = route.to(ahead.x, ahead.y);
            along = leave;
        }
        let down = site.at(along, approach);
        let below = site.at(self.slot(id), approach);
        let slot = site.at(self.slot(id), self.lane());
        route
            .to(down.x, down.y)
            .to(below.x, below.y)
            .to(slot.x, slot.y)
    }

    /// Whether a robot whose reflex stopped its leg into the slot stands in the slot: at most
    /// [`SLOT_SHORT`] short of where the model puts the slot, across the track.
    pub(super) fn in_slot(&self, view: &RobotView, site: &Site) -> bool {
        let here = Vector2::new(view.pose.x, view.pose.y) - site.centre.coords;
        here.dot(&site.push) >= self.lane() - SLOT_SHORT
    }

    /// After the push: back up until the line sensor finds the tape. Odometry cannot say how far
    /// that is, because the wheels slipped while pushing; the tape can.
    pub(super) fn start_backing(&mut self, id: u16) -> Vec<Intent> {
        self.onto_tape(id, false)
    }

    /// Drive straight, backwards or `forwards`, until the line sensor crosses the tape.
    pub(super) fn onto_tape(&mut self, id: u16, forwards: bool) -> Vec<Intent> {
        let Some(bot) = self.bots.get_mut(&id) else {
            return Vec::new();
        };
        bot.backing = Some(Duration::ZERO);
        bot.backing_odometer_m = self.odometer.distance_m(id);
        bot.onto_forwards = forwards;
        let v = if forwards { BACK_MPS } else { -BACK_MPS };
        vec![Intent::WheelSpeeds {
            robot: id,
            left: v,
            right: v,
        }]
    }

    /// How far the robot has backed since it began to, by its encoders.
    pub(super) fn backed_m(&self, id: u16) -> f64 {
        let from = self.bots.get(&id).map_or(0.0, |b| b.backing_odometer_m);
        self.odometer.distance_m(id) - from
    }

    /// The sensor (16 mm ahead of the centre) has just crossed the tape: stop, and once the
    /// model has the sensor on the tape, bring the centre onto it and face along it.
    pub(super) fn on_tape(&mut self, id: u16, world: &WorldSnapshot) -> Vec<Intent> {
        if self.site.is_none() || world.robot(id).is_none() {
            return Vec::new();
        }
        if let Some(bot) = self.bots.get_mut(&id) {
            bot.backing = None;
            bot.rejoined = true;
            bot.align_holds = 0;
            bot.aligning = Some(Align {
                since: world.time,
                not_before: world.time,
            });
        }
        vec![Intent::Stop { robot: id }]
    }

    /// Robots stopped on the tape whose model now agrees (its line sensor on the tape), or that
    /// have waited [`ALIGN_WAIT`] for it: the straight onto the tape and the turn along it.
    ///
    /// The robot reports the crossing at once, but the state that shows its sensor on the tape
    /// follows up to a reflector period later: a route planned on the event alone starts from
    /// where the unmeasured slip under the box left the model, 50 mm beyond the tape, beside
    /// the other pusher, and was held (every run over 20 ms links).
    pub(super) fn align_on_tape(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let Some(site) = self.site else {
            return Vec::new();
        };
        let mut out = Vec::new();
        let waiting: Vec<(u16, Align)> = self
            .bots
            .iter()
            .filter_map(|(&id, b)| b.aligning.map(|a| (id, a)))
            .collect();
        for (id, align) in waiting {
            let Some(view) = world.robot(id) else {
                continue;
            };
            if world.time < align.not_before {
                continue;
            }
            let agrees = site.sensor_across(view.pose).abs() <= ALIGN_AGREE_M;
            if !agrees && world.time.saturating_sub(align.since) < ALIGN_WAIT {
                continue;
            }
            let overshoot = if self.bots.get(&id).is_some_and(|b| b.onto_forwards) {
                -BACK_OVERSHOOT
            } else {
                BACK_OVERSHOOT
            };
            if let Some(b) = self.bots.get_mut(&id) {
                b.aligning = None;
            }
            let route = Manoeuvre::from(view.pose, MANOEUVRE_MPS)
                .straight(SENSOR_AHEAD + overshoot)
                .turn_to(Site::heading(site.along));
            out.extend(self.send(id, route));
        }
        out
    }

    /// A move onto the tape or along it was held: the robot stands; try again a little later,
    /// at most [`ALIGN_HOLDS`] times, re-checked each time from where the model then has it.
    /// `false` once it has been held that often.
    pub(super) fn align_held(&mut self, id: u16, world: &WorldSnapshot) -> bool {
        let Some(b) = self.bots.get_mut(&id) else {
            return false;
        };
        b.align_holds += 1;
        if b.align_holds > ALIGN_HOLDS {
            return false;
        }
        b.aligning = Some(Align {
            since: world.time,
            not_before: world.time + ALIGN_RETRY,
        });
        true
    }

    pub(super) fn start_push(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        self.pushes += 1;
        self.push_started = world.time;
        self.enter(Phase::Push, world);
        let ids: Vec<u16> = self.bots.keys().copied().collect();
        for (&id, b) in self.bots.iter_mut() {
            b.push_odometer_m = self.odometer.distance_m(id);
            b.crossed_tape = false;
            b.rejoined = false;
        }
        // The reflexes go off before the push drives into the box: a setting written before a
        // move reaches the robot first on the same link. One command per robot in the same
        // reply: the supervisor sends them back to back.
        let mut out = self.reflexes(0);
        let push_heading = self.site.map(|s| Site::heading(s.push));
        let length = LANE_GAP + self.push_m;
        for id in ids {
            let Some(view) = world.robot(id) else {
                continue;
            };
            // A pusher facing a degree or two off the push direction drives a gentle arc that
            // ends along it: two pushers 16 mm apart that each face a degree towards the other
            // close in by 8 mm over a straight push, which the safety check rightly holds; the
            // arc halves that. A turn on the spot first (tried) changed how the box gave way.
            let off = push_heading.map_or(0.0, |h| wrap_angle(h - view.pose.theta));
            let command = if (ARC_MIN_RAD..ARC_MAX_RAD).contains(&off.abs()) {
                MoveCommand::Arc {
                    radius_m: (length / off.abs()) as f32,
                    angle_deg: off.to_degrees() as f32,
                    speed_mps: PUSH_MPS,
                }
            } else {
                MoveCommand::Straight {
                    distance_m: length as f32,
                    speed_mps: PUSH_MPS,
                }
            };
            out.extend(Intent::moves(id, [command], self.phase as u32));
        }
        out
    }

    /// A close reflection ahead with no robot there: the box.
    pub(super) fn found_box(&mut self, robot: u16, world: &WorldSnapshot) -> Vec<Intent> {
        let Some(view) = world.robot(robot) else {
            return Vec::new();
        };
        if self.gap_ahead(view, world) < 0.15 {
            return Vec::new();
        }
        match self.phase {
            Phase::Approach => {}
            Phase::Lapping => {
                if self.pushes >= MAX_PUSHES {
                    return self.fail(format!(
                        "robot {robot} still finds the box on the track after {} pushes",
                        self.pushes
                    ));
                }
                for b in self.bots.values_mut() {
                    b.lapped_m = 0.0;
                    b.last_s = None;
                    b.lap_odometer_m = None;
                }
            }
            _ => return Vec::new(),
        }
        self.finder = Some(robot);
        self.sighted = Some(view.front_close_at.unwrap_or(view.pose));
        self.enter(Phase::Gather, world);
        vec![Intent::FollowLine { robot, speed: None }]
    }
}
