//! A user's own experiment binary: the coordinator library with a registry that holds `led_wave`.

use std::time::Duration;

use behaviours::Registry;
use coordinator::{Plan, Transport};

fn main() -> anyhow::Result<()> {
    let mut registry = Registry::builtin();
    registry.register(
        "led_wave",
        "robots light up and spin in turn",
        "open",
        |cfg| Ok(Box::new(led_wave::LedWave::new(cfg))),
    );
    let plan = Plan {
        behaviour: "led_wave".into(),
        world: None,
        robots: Some(3),
        transport: Transport::Sim,
        seed: 1,
        realtime: false,
        duration: Duration::from_secs(60),
        params: Default::default(),
        faults: Vec::new(),
        body_faults: Vec::new(),
        kicks: Vec::new(),
    };
    let system = coordinator::actor_system(true);
    let report = system.block_on(coordinator::run(plan, &registry))?;
    println!("{report}");
    std::process::exit(if report.verdict.success { 0 } else { 1 });
}
