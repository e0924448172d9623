//! The template works in physics: three simulated robots, the unmodified firmware driving them,
//! spin in turn through the coordinator, judged by the report with its ground truth.

use std::time::Duration;

use behaviours::{Entry, Registry};
use coordinator::Plan;

#[test]
fn three_robots_spin_in_turn_without_contact() {
    let mut registry = Registry::builtin();
    registry.add(Entry::of::<led_wave::LedWave>(
        "led_wave",
        "robots spin in turn",
        "open",
    ));
    let plan = Plan::sim("led_wave")
        .robots(3)
        .duration(Duration::from_secs(60));
    let report = coordinator::run_blocking(plan, &registry).expect("the experiment runs");
    assert!(report.success(), "{report}");
    // Three spins of a full turn at 0.15 m/s on a 30 mm-odd wheel base take seconds, not the
    // minute allowed: a run that only timed out has not spun.
    assert!(report.experiment_time < Duration::from_secs(30), "{report}");
}
