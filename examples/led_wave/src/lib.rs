//! `led_wave`: a behaviour written as its own crate, to copy when writing yours.
//!
//! Robots take turns: the one whose turn it is lights its LED and spins once on the spot, then
//! passes the turn to the next. A spin the supervisor's safety check holds back is sent again
//! for up to 10 s. Success once every robot has had its turn and rests, each robot's encoders
//! having measured at least 90 % of a full turn. The crate depends only on the behaviour API;
//! `examples/led-wave.rs` runs it through the coordinator library with its own registry.

use std::time::Duration;

use behaviour_api::{
    Behaviour, BehaviourConfig, Event, HeldPolicy, Intent, MoveCommand, MoveOutcome, NoParams,
    Register, Team, Verdict, WorldSnapshot,
};

const LIT: [u8; 3] = [255, 120, 0];
/// How long a held spin is sent again before the run fails.
const PATIENCE: Duration = Duration::from_secs(10);
const SPIN: MoveCommand = MoveCommand::Rotate {
    angle_deg: 360.0,
    speed_mps: 0.15,
};

/// Whose turn it is: the robots in id order, and how many have spun.
#[derive(Debug, Default)]
pub struct LedWave {
    order: Vec<u16>,
    turn: usize,
}

impl LedWave {
    /// The robot whose turn it is lights up and spins; the spin is tagged with the turn.
    fn go(&self) -> Vec<Intent> {
        let Some(&robot) = self.order.get(self.turn) else {
            return Vec::new();
        };
        let spin = Intent::moves(robot, [SPIN], self.turn as u32);
        [vec![Intent::Led { robot, rgb: LIT }], spin].concat()
    }
}

impl Register for LedWave {
    // It takes no parameters: a `--param` of any key is refused by name.
    type Params = NoParams;

    fn build(_: NoParams, _: &BehaviourConfig) -> Result<Self, String> {
        Ok(Self::default())
    }
}

impl Behaviour for LedWave {
    fn start(&mut self, world: &WorldSnapshot, _: &mut Team) -> Vec<Intent> {
        self.order = world.robots.iter().map(|r| r.id).collect();
        self.go()
    }

    fn on_snapshot(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        let resting = world.robots.iter().all(|r| r.resting());
        if self.turn == self.order.len() && team.all_idle() && resting {
            let least = team.odometer().least_turn_deg(self.order.iter().copied());
            let summary = format!("{} spun, each {least:.0}° by encoders", self.turn);
            team.finish(Verdict::new(least >= 324.0, summary).with("least_turn_deg", least));
        }
        Vec::new()
    }

    fn on_event(&mut self, id: u16, e: &Event, _: &WorldSnapshot, team: &mut Team) -> Vec<Intent> {
        let Event::MoveFinished { tag, outcome } = *e else {
            return Vec::new();
        };
        if outcome != MoveOutcome::Completed || tag as usize != self.turn {
            team.fail(format!("robot {id}: spin {tag} ended {outcome:?}"));
            return Vec::new();
        }
        self.turn += 1;
        [
            vec![Intent::Led {
                robot: id,
                rgb: [0; 3],
            }],
            self.go(),
        ]
        .concat()
    }

    fn held_policy(&self) -> HeldPolicy {
        HeldPolicy::Retry { patience: PATIENCE }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use behaviour_api::testing::{world, Harness};

    #[test]
    fn robots_take_turns_and_the_verdict_needs_the_encoders_to_have_turned() {
        let mut h = Harness::new(LedWave::default());
        let still = world().robots([1, 2]).build();
        let first = h.start(&still);
        assert_eq!(first[0], Intent::Led { robot: 1, rgb: LIT });
        assert!(h.finish_move(2, 1, &still).is_empty(), "not robot 2's spin");
        let next = h.finish_move(1, 0, &still);
        assert_eq!(
            next[0],
            Intent::Led {
                robot: 1,
                rgb: [0; 3]
            }
        );
        assert_eq!(next[1], Intent::Led { robot: 2, rgb: LIT });
        assert_eq!(h.team().outstanding(2), 1);
        h.finish_move(2, 1, &still);
        // Nobody's encoders measured a turn: a failure.
        h.snapshot(&still);
        assert!(!h.verdict().expect("judged").success);

        let mut h = Harness::new(LedWave::default());
        h.start(&still);
        // Each robot's odometry heading goes round once, in quarter turns.
        for k in 1..=4 {
            let turned = k as f64 * 90.0;
            let w = world()
                .robot(1, 0.1, 0.5, turned)
                .robot(2, 0.2, 0.5, turned)
                .build();
            h.snapshot(&w);
        }
        h.finish_move(1, 0, &still);
        h.finish_move(2, 1, &still);
        let w = world()
            .robot(1, 0.1, 0.5, 360.0)
            .robot(2, 0.2, 0.5, 360.0)
            .build();
        h.snapshot(&w);
        assert!(h.verdict().expect("judged").success, "{:?}", h.verdict());
    }

    #[test]
    fn a_held_spin_is_sent_again_until_it_passes_or_waits_too_long() {
        let mut h = Harness::new(LedWave::default());
        let w = world().robots([1, 2]).build();
        let spin = h.start(&w)[1];
        assert!(h.hold(spin, "robot 2 is in the way", &w).is_empty());
        assert_eq!(h.team().outstanding(1), 1, "still robot 1's turn");
        assert_eq!(h.snapshot(&w.clone()), vec![spin], "sent again");
        // Held again and again for longer than its patience: the run fails saying why.
        h.hold(spin, "robot 2 is in the way", &w);
        let late = world().robots([1, 2]).at(11.0).build();
        h.hold(spin, "robot 2 is in the way", &late);
        let v = h.verdict().expect("failed");
        assert!(
            !v.success && v.summary.contains("robot 2 is in the way"),
            "{v:?}"
        );
    }
}
