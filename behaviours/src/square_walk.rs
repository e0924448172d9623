//! `square_walk`: every robot walks a 0.1 m square (thesis A.1) and must end where it began.
//!
//! The square is four corners in the world frame. If a robot's link drops mid-walk (its watchdog
//! then stops it and clears its queue), the walk is planned again from where the robot stands to
//! the next corner once it is back. Success when every robot finished its moves, its odometry
//! closes within 10 mm and 5° of its start, and its encoders measured the walk: a path of at
//! least 90 % of the square's perimeter (0.36 m for the default 0.1 m side) and turns adding up
//! to at least 90 % of a full turn (324°). A robot that stands still closes perfectly; the
//! encoders tell it apart. A robot whose wheels are driven for 3 s without an encoder pulse fails
//! the walk at once (see [`behaviour_api::evidence`]). The coordinator's report adds the ground truth.

use std::collections::BTreeMap;
use std::f64::consts::FRAC_PI_2;

use behaviour_api::{MoveCommand, Pose};
use protocol::packets::MoveOutcome;

use behaviour_api::event::Event;
use behaviour_api::evidence::{Odometer, EVIDENCE_SHARE};
use behaviour_api::moves::wrap;
use behaviour_api::team::Team;
use behaviour_api::{params, Behaviour, BehaviourConfig, Intent, Register, Verdict, WorldSnapshot};

const SIDE_M: f32 = 0.1;
const SPEED_MPS: f32 = 0.2;

params! {
    /// Parameters of `square_walk`.
    pub struct SquareWalkParams {
        /// Side of the square, metres.
        side: f32 = SIDE_M, 0.001 => 10.0;
    }
}

/// Less than this by the encoders is no motion at all.
const NO_MOTION_M: f64 = 0.005;
/// Per-robot progress.
#[derive(Clone, Debug)]
struct Walker {
    start: Pose,
    /// Moves finished, in plan order: leg `k` is a straight to corner `k + 1` then a quarter turn.
    /// Each move's tag is its place in the current plan.
    done: usize,
    /// Moves the current plan expects in all.
    expected: usize,
    /// The link dropped; the queue on the robot is gone until a new plan is sent.
    interrupted: bool,
    failed: bool,
    end: Option<Pose>,
}

/// The square walk behaviour.
#[derive(Clone, Debug, Default)]
pub struct SquareWalk {
    side_m: f32,
    walkers: BTreeMap<u16, Walker>,
    odometer: Odometer,
}

impl Register for SquareWalk {
    type Params = SquareWalkParams;

    fn build(p: SquareWalkParams, _: &BehaviourConfig) -> Result<Self, String> {
        Ok(Self {
            side_m: p.side,
            walkers: BTreeMap::new(),
            odometer: Odometer::new(),
        })
    }
}

impl SquareWalk {
    /// Corner `c` (1..=4; 4 is the start) and the heading after turning there.
    fn corner(&self, start: Pose, c: usize) -> ((f64, f64), f64) {
        let side = f64::from(self.side_m);
        let mut p = (start.x, start.y);
        for k in 0..c {
            let h = start.theta + FRAC_PI_2 * k as f64;
            p = (p.0 + side * h.cos(), p.1 + side * h.sin());
        }
        (p, start.theta + FRAC_PI_2 * c as f64)
    }

    fn moves(robot: u16, commands: Vec<MoveCommand>) -> Vec<Intent> {
        (0..)
            .zip(commands)
            .map(|(tag, command)| Intent::Move {
                robot,
                command,
                tag,
            })
            .collect()
    }

    /// The rest of the square from `pose`, for a walker that finished `done` moves of its plan.
    fn replan(&self, w: &Walker, pose: Pose) -> Vec<MoveCommand> {
        let legs_done = w.done / 2;
        let mut plan = Vec::new();
        let rotate = |a: f64| MoveCommand::Rotate {
            angle_deg: wrap(a).to_degrees() as f32,
            speed_mps: SPEED_MPS,
        };
        let mut heading = pose.theta;
        let first = legs_done + 1;
        if first <= 4 {
            let ((x, y), turn_to) = self.corner(w.start, first);
            if w.done % 2 == 0 {
                let (dx, dy) = (x - pose.x, y - pose.y);
                let bearing = dy.atan2(dx);
                plan.push(rotate(bearing - heading));
                plan.push(MoveCommand::Straight {
                    distance_m: dx.hypot(dy) as f32,
                    speed_mps: SPEED_MPS,
                });
                heading = bearing;
            }
            plan.push(rotate(turn_to - heading));
        }
        for _ in first + 1..=4 {
            plan.push(MoveCommand::Straight {
                distance_m: self.side_m,
                speed_mps: SPEED_MPS,
            });
            plan.push(rotate(FRAC_PI_2));
        }
        plan
    }
}

impl Behaviour for SquareWalk {
    fn start(&mut self, world: &WorldSnapshot, _: &mut Team) -> Vec<Intent> {
        self.odometer.observe(world);
        let mut intents = Vec::new();
        for r in &world.robots {
            let mut plan = Vec::new();
            for _ in 0..4 {
                plan.push(MoveCommand::Straight {
                    distance_m: self.side_m,
                    speed_mps: SPEED_MPS,
                });
                plan.push(MoveCommand::Rotate {
                    angle_deg: 90.0,
                    speed_mps: SPEED_MPS,
                });
            }
            self.walkers.insert(
                r.id,
                Walker {
                    start: r.pose,
                    done: 0,
                    expected: plan.len(),
                    interrupted: false,
                    failed: false,
                    end: None,
                },
            );
            intents.extend(Self::moves(r.id, plan));
        }
        intents
    }

    fn on_snapshot(&mut self, world: &WorldSnapshot, _: &mut Team) -> Vec<Intent> {
        self.odometer.observe(world);
        for r in &world.robots {
            if let Some(w) = self.walkers.get_mut(&r.id) {
                // The last turn is reported finished a coast early and coasts onto its heading
                // (about 20° at this speed), so the closure is judged once the wheels rest.
                let resting = r.state.wheels.left_mps == 0.0 && r.state.wheels.right_mps == 0.0;
                if w.done == w.expected && w.end.is_none() && r.pending_moves == 0 && resting {
                    w.end = Some(r.pose);
                }
            }
        }
        Vec::new()
    }

    fn on_event(
        &mut self,
        robot: u16,
        event: &Event,
        world: &WorldSnapshot,
        _: &mut Team,
    ) -> Vec<Intent> {
        let Some(w) = self.walkers.get(&robot).cloned() else {
            return Vec::new();
        };
        match event {
            Event::MoveFinished { tag, outcome } => {
                let w = self.walkers.get_mut(&robot).expect("present");
                match outcome {
                    MoveOutcome::Completed => w.done = *tag as usize + 1,
                    _ => w.failed = true,
                }
                Vec::new()
            }
            Event::LinkLost => {
                if let Some(w) = self.walkers.get_mut(&robot) {
                    w.interrupted = w.done < w.expected;
                }
                Vec::new()
            }
            Event::Connected if w.interrupted => {
                let Some(pose) = world.robot(robot).map(|r| r.pose) else {
                    return Vec::new();
                };
                let plan = self.replan(&w, pose);
                let w = self.walkers.get_mut(&robot).expect("present");
                // The new plan counts from zero: its legs are the remaining corners.
                w.done = 0;
                w.expected = plan.len();
                w.interrupted = false;
                Self::moves(robot, plan)
            }
            _ => Vec::new(),
        }
    }

    fn verdict(&self) -> Option<Verdict> {
        if self.walkers.is_empty() {
            return None;
        }
        if let Some((&id, _)) = self.walkers.iter().find(|(_, w)| w.failed) {
            // A robot whose encoders count nothing drives on at full duty until something stops
            // it (its reflex at a wall, before the stall is long enough to name): say so.
            let measured = self.odometer.distance_m(id);
            let why = if measured < NO_MOTION_M {
                format!(
                    "robot {id}: a move was aborted; its encoders had measured {:.1} mm by then",
                    measured * 1e3
                )
            } else {
                format!("robot {id}: a move was aborted")
            };
            return Some(Verdict::failure(why));
        }
        if let Some(stall) = self.odometer.stall() {
            return Some(Verdict::failure(stall.to_string()));
        }
        if self.walkers.values().any(|w| w.end.is_none()) {
            return None;
        }
        let ids = self.walkers.keys().copied();
        let least_m = self.odometer.least_m(ids.clone());
        let least_deg = ids
            .clone()
            .map(|id| self.odometer.turned_rad(id).to_degrees())
            .fold(f64::INFINITY, f64::min);
        let perimeter = 4.0 * f64::from(self.side_m);
        let evidence = |v: Verdict| {
            v.with("least_encoder_distance_m", least_m)
                .with("least_encoder_turn_deg", least_deg)
        };
        if let Some((id, measured, _)) = self.odometer.short_of(ids.clone(), |_| perimeter) {
            return Some(evidence(Verdict::failure(format!(
                "robot {id}: its encoders measured a path of {:.0} mm, short of the {:.0} mm the \
                 square needs ({:.0} % of its perimeter): it did not walk the square",
                measured * 1e3,
                EVIDENCE_SHARE * perimeter * 1e3,
                EVIDENCE_SHARE * 100.0
            ))));
        }
        let full_turn = 360.0;
        if let Some(id) = ids
            .clone()
            .find(|id| self.odometer.turned_rad(*id).to_degrees() < EVIDENCE_SHARE * full_turn)
        {
            return Some(evidence(Verdict::failure(format!(
                "robot {id}: its encoders measured {:.0}° of turning, short of the {:.0}° the \
                 square's four corners need",
                self.odometer.turned_rad(id).to_degrees(),
                EVIDENCE_SHARE * full_turn
            ))));
        }
        let mut worst_mm: f64 = 0.0;
        let mut worst_deg: f64 = 0.0;
        for w in self.walkers.values() {
            let Some(e) = w.end else { continue };
            let s = w.start;
            worst_mm = worst_mm.max((e.x - s.x).hypot(e.y - s.y) * 1e3);
            worst_deg = worst_deg.max(wrap(e.theta - s.theta).to_degrees().abs());
        }
        let ok = worst_mm < 10.0 && worst_deg < 5.0;
        let summary = format!(
            "{} squares walked; worst closure {worst_mm:.1} mm and {worst_deg:.1}° by odometry; \
             each robot's encoders measured at least {:.0} mm and {least_deg:.0}° (needed {:.0} mm \
             and {:.0}°)",
            self.walkers.len(),
            least_m * 1e3,
            EVIDENCE_SHARE * perimeter * 1e3,
            EVIDENCE_SHARE * full_turn
        );
        let v = if ok {
            Verdict::success(summary)
        } else {
            Verdict::failure(summary)
        };
        Some(evidence(
            v.with("worst_closure_mm", worst_mm)
                .with("worst_heading_error_deg", worst_deg),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use behaviour_api::testing::{world as snapshot, Harness};
    use std::f64::consts::{PI, TAU};

    fn world(poses: &[(u16, Pose)], pending: usize) -> WorldSnapshot {
        poses
            .iter()
            .fold(snapshot(), |w, &(id, p)| {
                w.robot(id, p.x, p.y, p.theta.to_degrees())
                    .with(id, |r| r.pending_moves = pending)
            })
            .build()
    }

    fn walk_of(robots: &[u16]) -> Harness<SquareWalk> {
        let mut h = Harness::new(SquareWalk::from_config(&BehaviourConfig::default()).unwrap());
        let poses: Vec<(u16, Pose)> = robots.iter().map(|&id| (id, START)).collect();
        h.start(&world(&poses, 0));
        h
    }

    /// Where the test robot starts its square.
    const START: Pose = Pose {
        x: 0.3,
        y: 0.3,
        theta: 0.0,
    };

    /// Every move of the square (tags 0 to 7) completes.
    fn finish_all(h: &mut Harness<SquareWalk>, id: u16) {
        for tag in 0..8 {
            h.finish_move(id, tag, &world(&[], 0));
        }
    }

    /// Snapshots of robots 1 and 2 walking the square from `start`, corner by corner.
    fn walk(h: &mut Harness<SquareWalk>, start: Pose) {
        let mut p = start;
        for k in 0..4 {
            let dir = FRAC_PI_2 * f64::from(k);
            p.x += 0.1 * dir.cos();
            p.y += 0.1 * dir.sin();
            h.snapshot(&world(&[(1, p), (2, p)], 1));
            p.theta += FRAC_PI_2;
            h.snapshot(&world(&[(1, p), (2, p)], 1));
        }
    }

    #[test]
    fn queues_eight_moves_per_robot_and_judges_the_closure() {
        let mut h = Harness::new(SquareWalk::from_config(&BehaviourConfig::default()).unwrap());
        let intents = h.start(&world(&[(1, START), (2, START)], 0));
        assert_eq!(intents.len(), 16);
        assert_eq!(h.team().outstanding(2), 8);
        assert!(h.verdict().is_none());
        walk(&mut h, START);
        finish_all(&mut h, 1);
        finish_all(&mut h, 2);
        assert!(h.team().all_idle());
        let end = Pose {
            x: 0.303,
            y: 0.3,
            theta: TAU,
        };
        h.snapshot(&world(&[(1, end), (2, end)], 0));
        let v = h.verdict().unwrap();
        assert!(v.success, "{v:?}");
        let mut far = walk_of(&[1]);
        finish_all(&mut far, 1);
        far.snapshot(&world(&[(1, Pose { x: 0.32, ..end })], 0));
        assert!(!far.verdict().unwrap().success);
    }

    #[test]
    fn a_robot_that_reports_its_moves_done_without_moving_fails() {
        let mut h = walk_of(&[1]);
        finish_all(&mut h, 1);
        h.snapshot(&world(&[(1, START)], 0));
        let v = h.verdict().unwrap();
        assert!(!v.success, "{v:?}");
        assert!(
            v.summary.contains("robot 1") && v.summary.contains("encoders"),
            "{v:?}"
        );
    }

    #[test]
    fn a_walk_without_its_turns_fails() {
        let mut h = walk_of(&[1]);
        // 0.4 m of path straight out and back, with a single half turn.
        let out = Pose { x: 0.5, ..START };
        h.snapshot(&world(&[(1, out)], 1));
        let back = Pose { theta: PI, ..out };
        h.snapshot(&world(&[(1, back)], 1));
        finish_all(&mut h, 1);
        h.snapshot(&world(&[(1, Pose { theta: PI, ..START })], 0));
        let v = h.verdict().unwrap();
        assert!(!v.success && v.summary.contains("turning"), "{v:?}");
    }

    #[test]
    fn an_aborted_move_fails_the_walk_and_nothing_is_asked_after_it() {
        let mut h = walk_of(&[1]);
        let stopped = Event::MoveFinished {
            tag: 0,
            outcome: MoveOutcome::Stopped,
        };
        h.event(1, stopped, &world(&[], 0));
        assert!(!h.verdict().unwrap().success);
        assert!(h.snapshot(&world(&[(1, START)], 0)).is_empty());
    }

    #[test]
    fn a_walk_cut_mid_leg_is_planned_again_to_the_next_corner() {
        let mut h = walk_of(&[1]);
        // First leg done (straight + turn), then the link drops 4 cm into the second straight.
        h.finish_move(1, 0, &world(&[], 0));
        h.finish_move(1, 1, &world(&[], 0));
        h.event(1, Event::LinkLost, &world(&[], 0));
        assert!(h.team().idle(1), "the queue went with the link");
        let here = Pose {
            x: 0.4,
            y: 0.34,
            theta: FRAC_PI_2,
        };
        let plan = h.event(1, Event::Connected, &world(&[(1, here)], 0));
        let cmds: Vec<MoveCommand> = plan
            .iter()
            .map(|i| match i {
                Intent::Move { command, .. } => *command,
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(
            cmds.len(),
            7,
            "turn, straight, turn to the corner heading, then two legs"
        );
        match cmds[1] {
            MoveCommand::Straight { distance_m, .. } => assert!((distance_m - 0.06).abs() < 1e-4),
            other => panic!("{other:?}"),
        }
        match cmds[2] {
            MoveCommand::Rotate { angle_deg, .. } => assert!((angle_deg - 90.0).abs() < 1e-3),
            other => panic!("{other:?}"),
        }
    }
}
