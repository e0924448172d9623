//! `led_wave`: a behaviour written as its own crate, to copy when writing yours.
//!
//! Robots take turns: the one whose turn it is lights its LED and spins once on the spot, then
//! passes the turn to the next. Success when every robot has spun a full turn, judged by odometry.
//! The crate depends only on the behaviour API; `src/bin/led-wave.rs` runs it through the
//! coordinator library with its own registry.

use behaviours::{
    Behaviour, BehaviourConfig, Intent, MoveCommand, RobotEventKind, Verdict, WorldSnapshot,
};

const LIT: [u8; 3] = [255, 120, 0];
const DARK: [u8; 3] = [0, 0, 0];

/// The behaviour's state: whose turn it is and how far each robot turned.
#[derive(Debug, Default)]
pub struct LedWave {
    order: Vec<u16>,
    turn: usize,
    start_heading: Vec<f64>,
    turned: Vec<f64>,
    waiting: bool,
    /// Every robot had its turn and stands still again: the headings are final.
    settled: bool,
}

impl LedWave {
    /// Builds it for the robots in `cfg`.
    pub fn new(cfg: &BehaviourConfig) -> Self {
        Self {
            order: cfg.robots.clone(),
            ..Self::default()
        }
    }

    fn go(&mut self, k: usize) -> Vec<Intent> {
        self.waiting = true;
        let robot = self.order[k];
        vec![
            Intent::Led { robot, rgb: LIT },
            Intent::Move {
                robot,
                command: MoveCommand::Rotate {
                    angle_deg: 360.0,
                    speed_mps: 0.15,
                },
            },
        ]
    }
}

impl Behaviour for LedWave {
    fn start(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        if self.order.is_empty() {
            self.order = world.robots.iter().map(|r| r.id).collect();
        }
        self.start_heading = self
            .order
            .iter()
            .map(|id| world.robot(*id).map_or(0.0, |r| r.pose.theta))
            .collect();
        self.turned = vec![0.0; self.order.len()];
        if self.order.is_empty() {
            return Vec::new();
        }
        self.go(0)
    }

    fn on_snapshot(&mut self, world: &WorldSnapshot) -> Vec<Intent> {
        let all_done = self.turn >= self.order.len();
        let still = self
            .order
            .iter()
            .all(|id| world.robot(*id).is_some_and(|r| r.pending_moves == 0));
        if all_done && still && !self.settled {
            // Judge on the next snapshot after the last turn, once the robots stand still.
            for (k, id) in self.order.iter().enumerate() {
                if let Some(r) = world.robot(*id) {
                    self.turned[k] = r.pose.theta - self.start_heading[k];
                }
            }
            self.settled = true;
        }
        Vec::new()
    }

    fn on_event(&mut self, robot: u16, event: &RobotEventKind, _: &WorldSnapshot) -> Vec<Intent> {
        let current = self.order.get(self.turn).copied();
        if !(self.waiting
            && Some(robot) == current
            && matches!(event, RobotEventKind::MoveFinished { .. }))
        {
            return Vec::new();
        }
        self.waiting = false;
        let mut intents = vec![Intent::Led { robot, rgb: DARK }];
        self.turn += 1;
        if self.turn < self.order.len() {
            intents.extend(self.go(self.turn));
        }
        intents
    }

    fn verdict(&self) -> Option<Verdict> {
        if self.order.is_empty() || !self.settled {
            return None;
        }
        let worst = self
            .turned
            .iter()
            .map(|t| (t.to_degrees() - 360.0).abs())
            .fold(0.0, f64::max);
        let summary = format!(
            "{} robots spun in turn; worst turn error {worst:.1}°",
            self.order.len()
        );
        let v = if worst < 10.0 {
            Verdict::success(summary)
        } else {
            Verdict::failure(summary)
        };
        Some(v.with("worst_turn_error_deg", worst))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use behaviours::{Pose, RobotView};

    fn world(turned: f64) -> WorldSnapshot {
        WorldSnapshot {
            time: Default::default(),
            robots: [1u16, 2]
                .iter()
                .map(|&id| RobotView {
                    id,
                    connected: true,
                    pose: Pose {
                        x: 0.0,
                        y: 0.0,
                        theta: turned,
                    },
                    odometry: Default::default(),
                    state: Default::default(),
                    pending_moves: 0,
                    on_track: None,
                    ..Default::default()
                })
                .collect(),
            encounters: Vec::new(),
            arena: (1.0, 1.0),
        }
    }

    #[test]
    fn robots_take_turns_and_the_verdict_follows_the_headings() {
        let cfg = BehaviourConfig {
            robots: vec![1, 2],
            ..Default::default()
        };
        let mut b = LedWave::new(&cfg);
        let first = b.start(&world(0.0));
        assert_eq!(first[0], Intent::Led { robot: 1, rgb: LIT });
        let done = RobotEventKind::MoveFinished {
            id: 1,
            outcome: behaviours::MoveOutcome::Completed,
        };
        let next = b.on_event(2, &done, &world(0.0));
        assert!(next.is_empty(), "not robot 2's turn yet");
        let next = b.on_event(1, &done, &world(0.0));
        assert_eq!(
            next[0],
            Intent::Led {
                robot: 1,
                rgb: DARK
            }
        );
        assert_eq!(next[1], Intent::Led { robot: 2, rgb: LIT });
        assert!(b.verdict().is_none());
        b.on_event(2, &done, &world(0.0));
        b.on_snapshot(&world(std::f64::consts::TAU));
        assert!(b.verdict().unwrap().success);
    }
}
