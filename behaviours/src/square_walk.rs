//! `square_walk`: every robot walks a 0.1 m square (thesis A.1) and must end where it began.
//!
//! Success when every robot completed all eight moves and its odometry closes within 10 mm and 5°
//! of its start; the coordinator's report adds the ground truth.

use std::collections::BTreeMap;

use protocol::packets::MoveOutcome;
use robot_actor::{MoveCommand, Pose, RobotEventKind};

use crate::api::{Behaviour, BehaviourConfig, Intent, Verdict, WorldSnapshot};

const SIDE_M: f32 = 0.1;
const SPEED_MPS: f32 = 0.2;
const MOVES: usize = 8;

/// Per-robot progress.
#[derive(Clone, Debug, Default)]
struct Walker {
    start: Option<Pose>,
    completed: usize,
    failed: bool,
    end: Option<Pose>,
}

/// The square walk behaviour.
#[derive(Clone, Debug, Default)]
pub struct SquareWalk {
    side_m: f32,
    walkers: BTreeMap<u16, Walker>,
}

impl SquareWalk {
    /// Builds it; `--param side=0.15` changes the side length.
    pub fn new(cfg: &BehaviourConfig) -> Self {
        let side_m = cfg
            .params
            .get("side")
            .and_then(|s| s.parse().ok())
            .unwrap_or(SIDE_M);
        Self {
            side_m,
            walkers: BTreeMap::new(),
        }
    }
}

impl Behaviour for SquareWalk {
    fn start(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let mut intents = Vec::new();
        for r in &world.robots {
            self.walkers.insert(
                r.id,
                Walker {
                    start: Some(r.pose),
                    ..Walker::default()
                },
            );
            for _ in 0..4 {
                intents.push(Intent::Move {
                    robot: r.id,
                    command: MoveCommand::Straight {
                        distance_m: self.side_m,
                        speed_mps: SPEED_MPS,
                    },
                });
                intents.push(Intent::Move {
                    robot: r.id,
                    command: MoveCommand::Rotate {
                        angle_deg: 90.0,
                        speed_mps: SPEED_MPS,
                    },
                });
            }
        }
        intents
    }

    fn on_snapshot(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        for r in &world.robots {
            if let Some(w) = self.walkers.get_mut(&r.id) {
                if w.completed == MOVES && w.end.is_none() && r.pending_moves == 0 {
                    w.end = Some(r.pose);
                }
            }
        }
        Vec::new()
    }

    fn on_event(&mut self, robot: u16, event: &RobotEventKind, _: &WorldSnapshot) -> Vec<Intent> {
        if let (Some(w), RobotEventKind::MoveFinished { outcome, .. }) =
            (self.walkers.get_mut(&robot), event)
        {
            match outcome {
                MoveOutcome::Completed => w.completed += 1,
                _ => w.failed = true,
            }
        }
        Vec::new()
    }

    fn verdict(&self) -> Option<Verdict> {
        if self.walkers.is_empty() {
            return None;
        }
        if let Some((id, _)) = self.walkers.iter().find(|(_, w)| w.failed) {
            return Some(Verdict::failure(format!("robot {id}: a move was aborted")));
        }
        if self.walkers.values().any(|w| w.end.is_none()) {
            return None;
        }
        let mut worst_mm: f64 = 0.0;
        let mut worst_deg: f64 = 0.0;
        for w in self.walkers.values() {
            let (Some(s), Some(e)) = (w.start, w.end) else {
                continue;
            };
            worst_mm = worst_mm.max((e.x - s.x).hypot(e.y - s.y) * 1e3);
            let turned = (e.theta - s.theta).to_degrees();
            worst_deg = worst_deg.max((turned - 360.0).abs());
        }
        let ok = worst_mm < 10.0 && worst_deg < 5.0;
        let summary = format!(
            "{} squares walked; worst closure {worst_mm:.1} mm and {worst_deg:.1}° by odometry",
            self.walkers.len()
        );
        let v = if ok {
            Verdict::success(summary)
        } else {
            Verdict::failure(summary)
        };
        Some(
            v.with("worst_closure_mm", worst_mm)
                .with("worst_heading_error_deg", worst_deg),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::api::RobotView;

    fn world(poses: &[(u16, Pose)], pending: usize) -> WorldSnapshot {
        WorldSnapshot {
            time: std::time::Duration::ZERO,
            robots: poses
                .iter()
                .map(|&(id, pose)| RobotView {
                    id,
                    connected: true,
                    pose,
                    state: Default::default(),
                    pending_moves: pending,
                    on_track: None,
                })
                .collect(),
            encounters: Vec::new(),
            arena: (1.0, 1.0),
        }
    }

    #[test]
    fn queues_eight_moves_per_robot_and_judges_the_closure() {
        let start = Pose {
            x: 0.3,
            y: 0.3,
            theta: 0.0,
        };
        let mut b = SquareWalk::new(&BehaviourConfig::default());
        let intents = b.start(&world(&[(1, start), (2, start)], 0));
        assert_eq!(intents.len(), 16);
        assert!(b.verdict().is_none());
        let done = RobotEventKind::MoveFinished {
            id: 1,
            outcome: MoveOutcome::Completed,
        };
        for id in [1, 2] {
            for _ in 0..MOVES {
                b.on_event(id, &done, &world(&[], 0));
            }
        }
        let end = Pose {
            x: 0.303,
            y: 0.3,
            theta: std::f64::consts::TAU,
        };
        b.on_snapshot(&world(&[(1, end), (2, end)], 0));
        let v = b.verdict().unwrap();
        assert!(v.success, "{v:?}");
        let mut far = SquareWalk::new(&BehaviourConfig::default());
        far.start(&world(&[(1, start)], 0));
        for _ in 0..MOVES {
            far.on_event(1, &done, &world(&[], 0));
        }
        far.on_snapshot(&world(&[(1, Pose { x: 0.32, ..end })], 0));
        assert!(!far.verdict().unwrap().success);
    }

    #[test]
    fn an_aborted_move_fails_the_walk() {
        let mut b = SquareWalk::new(&BehaviourConfig::default());
        b.start(&world(&[(1, Pose::default())], 0));
        let stopped = RobotEventKind::MoveFinished {
            id: 1,
            outcome: MoveOutcome::Stopped,
        };
        b.on_event(1, &stopped, &world(&[], 0));
        assert!(!b.verdict().unwrap().success);
    }
}
