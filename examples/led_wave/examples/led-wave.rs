//! A user's own experiment binary: the coordinator library with a registry that holds `led_wave`.
//! Run it with `cargo run --release -p led-wave --example led-wave`.

use std::time::Duration;

use behaviours::{Entry, Registry};
use coordinator::Plan;

fn main() -> anyhow::Result<()> {
    let mut registry = Registry::builtin();
    registry.add(Entry::of::<led_wave::LedWave>(
        "led_wave",
        "robots light up and spin in turn",
        "open",
    ));
    let plan = Plan::sim("led_wave")
        .robots(3)
        .duration(Duration::from_secs(60));
    let report = coordinator::run_blocking(plan, &registry)?;
    println!("{report}");
    std::process::exit(if report.success() { 0 } else { 1 });
}
