//! A minimal host for simulator tests: sends packets, keeps the watchdog fed, decodes what comes back.

#![allow(dead_code)]

use std::time::Duration;

use protocol::packets::Ping;
use protocol::AnyPacket;
use simulator::world::{file, World};
use simulator::{SimConfig, Simulation};

/// A world from TOML text (panics with the parse error: a test's own world must be valid).
pub fn world(text: &str) -> World {
    file::parse(text, "test.toml").unwrap_or_else(|e| panic!("{e}"))
}

/// A simulation of `world` with every robot connected.
pub fn connected(world: World, seed: u64) -> Simulation {
    connected_with(world, seed, 1)
}

/// [`connected`] with physics every `physics_every` clock steps.
pub fn connected_with(world: World, seed: u64, physics_every: u32) -> Simulation {
    let mut sim = Simulation::new(
        world,
        SimConfig {
            seed: Some(seed),
            physics_every,
            ..SimConfig::default()
        },
    );
    for i in 0..sim.robots().len() {
        sim.connect(i);
    }
    sim
}

/// Sends a packet from the host to robot `i`.
pub fn send(sim: &mut Simulation, i: usize, p: impl Into<AnyPacket>) {
    let mut buf = [0u8; protocol::MAX_PACKET];
    let n = p.into().encode(&mut buf).expect("encodable");
    sim.host_send(i, buf[..n].to_vec());
}

/// Runs for `d`, pinging every robot every 100 ms, handing each arriving packet to `f` with the
/// robot index; stops early when `f` returns true and returns the simulated time then.
pub fn run(
    sim: &mut Simulation,
    d: Duration,
    mut f: impl FnMut(usize, AnyPacket) -> bool,
) -> Option<Duration> {
    let end = sim.now() + d;
    let mut next_ping = sim.now();
    while sim.now() < end {
        if sim.now() >= next_ping {
            for i in 0..sim.robots().len() {
                if sim.robots()[i].link_up() {
                    send(
                        sim,
                        i,
                        Ping {
                            seq: 0,
                            host_time_us: sim.now().as_micros() as u64,
                        },
                    );
                }
            }
            next_ping += Duration::from_millis(100);
        }
        sim.step();
        for i in 0..sim.robots().len() {
            while let Some(bytes) = sim.host_recv(i) {
                if let Ok(p) = protocol::decode(&bytes) {
                    if f(i, p) {
                        return Some(sim.now());
                    }
                }
            }
        }
    }
    None
}
