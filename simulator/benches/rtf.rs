//! Real-time factor of the simulator with the firmware in the loop: 1, 10, 100 and 1,000 robots
//! line following, every robot connected and reflecting its state, on two worlds: `grid` (one
//! robot per edge of a lattice; they meet at junctions, collide and pile up) and `serpentine` (one
//! loop the robots follow spread out in the same direction, so every robot keeps driving).
//!
//! Runs each size with physics at 1 kHz (every clock step), 500 Hz and 200 Hz (`physics_every` 5:
//! contacts every 5 ms; motors, tyres, encoders, firmware and links still on the 1 kHz clock).
//! Prints simulated seconds per wall second, the cost per robot per millisecond of simulated
//! time, and that cost relative to the same size at 1 kHz measured in the same process; and what
//! the robots were doing at the end (how many still drove, how many robot–robot contacts there had
//! been), since the two worlds are not the same work.

/// The coordinator binary's allocator, so the bench measures what it runs.
#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

use std::time::{Duration, Instant};

use protocol::packets::{LineFollow, Ping};
use protocol::AnyPacket;
use simulator::world::{presets, World};
use simulator::{SimConfig, Simulation};

fn send(sim: &mut Simulation, i: usize, p: impl Into<AnyPacket>) {
    let mut buf = [0u8; protocol::MAX_PACKET];
    let n = p.into().encode(&mut buf).unwrap_or(0);
    sim.host_send(i, buf[..n].to_vec());
}

/// Simulated seconds per wall second, wall seconds per robot-millisecond, robots still driving at
/// the end, robot–robot contacts since the start.
fn measure(world: World, simulated: Duration, physics_every: u32) -> (f64, f64, usize, usize) {
    let robots = world.robots.len();
    let mut sim = Simulation::new(
        world,
        SimConfig {
            seed: Some(1),
            physics_every,
            ..SimConfig::default()
        },
    );
    for i in 0..robots {
        sim.connect(i);
        send(
            &mut sim,
            i,
            LineFollow {
                enable: 1,
                speed_mps: 0.15,
            },
        );
    }
    // Warm up a quarter of a second so every robot is moving.
    sim.run_for(Duration::from_millis(250));
    let start_sim = sim.now();
    let start = Instant::now();
    let mut next_ping = sim.now();
    while sim.now() - start_sim < simulated {
        if sim.now() >= next_ping {
            for i in 0..robots {
                send(
                    &mut sim,
                    i,
                    Ping {
                        seq: 0,
                        host_time_us: 0,
                    },
                );
            }
            next_ping += Duration::from_millis(100);
        }
        sim.step();
        for i in 0..robots {
            while sim.host_recv(i).is_some() {}
        }
    }
    let wall = start.elapsed().as_secs_f64();
    let sim_s = (sim.now() - start_sim).as_secs_f64();
    let steps = sim_s / sim.dt().as_secs_f64();
    // Faster than a creep on either wheel: moving, not stalled against another robot.
    let moving = sim
        .robots()
        .iter()
        .filter(|r| {
            r.wheel_speeds_mps(sim.spec())
                .iter()
                .any(|v| v.abs() > 0.02)
        })
        .count();
    (
        sim_s / wall,
        wall / (steps * robots as f64),
        moving,
        sim.robot_collisions(),
    )
}

/// A world for a number of robots.
type MakeWorld = fn(usize) -> World;

fn main() {
    // `cargo test --benches` runs this unoptimised: keep that a smoke run.
    let quick = std::env::args().any(|a| a == "--test" || a == "--bench") && cfg!(debug_assertions);
    println!(
        "world        robots  physics   sim s / wall s   wall per robot-ms   cost vs 1 kHz   moving at end   contacts"
    );
    // `RTF_ROBOTS=1000` measures one team size only, `RTF_HZ=200` one physics rate,
    // `RTF_WORLD=grid` one world, `RTF_SECS=60` a longer run (profiling).
    let only: Option<usize> = std::env::var("RTF_ROBOTS")
        .ok()
        .and_then(|v| v.parse().ok());
    let only_secs: Option<f64> = std::env::var("RTF_SECS").ok().and_then(|v| v.parse().ok());
    let only_hz: Option<u32> = std::env::var("RTF_HZ").ok().and_then(|v| v.parse().ok());
    let only_world = std::env::var("RTF_WORLD").ok();
    let worlds: [(&str, MakeWorld); 2] = [
        ("grid", |n| presets::grid(0, 0, n)),
        ("serpentine", presets::serpentine),
    ];
    for (name, make) in worlds {
        if only_world.as_deref().is_some_and(|w| w != name) {
            continue;
        }
        for robots in [1usize, 10, 100, 1000] {
            if only.is_some_and(|n| n != robots) {
                continue;
            }
            let secs = if let Some(s) = only_secs {
                s
            } else if quick {
                0.05
            } else if robots >= 1000 {
                2.0
            } else {
                5.0
            };
            let mut base = None;
            for (hz, every) in [(1000, 1), (500, 2), (200, 5)] {
                if only_hz.is_some_and(|h| h != hz) {
                    continue;
                }
                let (rtf, per, moving, contacts) =
                    measure(make(robots), Duration::from_secs_f64(secs), every);
                let ratio = per / *base.get_or_insert(per);
                println!(
                    "{name:11}  {robots:6}  {hz:4} Hz  {rtf:13.1}x  {:15.2} µs  {ratio:13.2}  {moving:7} of {robots:<5}  {contacts:8}",
                    per * 1e6
                );
            }
        }
    }
}
