//! Two simulated PocketBot2s follow the `oval` track for three laps: the host side sends protocol
//! packets over the simulated links and reads back the reflected state; the robots are the
//! unmodified firmware driving bodies in the physics world.

use std::time::{Duration, Instant};

use protocol::packets::{LineFollow, Ping, ReflectorConfig, ReflectorMode};
use protocol::AnyPacket;
use simulator::world::presets;
use simulator::{SimConfig, Simulation};

fn send(sim: &mut Simulation, i: usize, p: impl Into<AnyPacket>) {
    let mut buf = [0u8; protocol::MAX_PACKET];
    let n = p.into().encode(&mut buf).expect("packet fits");
    sim.host_send(i, buf[..n].to_vec());
}

fn main() {
    let world = presets::preset("oval").expect("built-in preset");
    println!("{}: {}", world.name, world.description);
    let mut sim = Simulation::new(world, SimConfig::default());
    for i in 0..sim.robots().len() {
        sim.connect(i);
        send(
            &mut sim,
            i,
            ReflectorConfig {
                mode: ReflectorMode::Full as u8,
                period_ms: 100,
            },
        );
        send(
            &mut sim,
            i,
            LineFollow {
                enable: 1,
                speed_mps: 0.2,
            },
        );
    }
    let wall = Instant::now();
    let centre = (0.5, 0.3);
    let angle = |x: f64, y: f64| (y - centre.1).atan2(x - centre.0);
    let mut turned: Vec<f64> = sim
        .robots()
        .iter()
        .map(|r| angle(r.pose().x, r.pose().y))
        .collect();
    let start = turned.clone();
    let mut latest = vec![None; sim.robots().len()];
    println!(" t [s]  robot  x [mm]  y [mm]  line [µm]  left/right [m/s]  battery [mV]  laps");
    while sim.now() < Duration::from_secs(40) {
        let now_us = sim.now().as_micros() as u64;
        for i in 0..sim.robots().len() {
            send(
                &mut sim,
                i,
                Ping {
                    seq: 0,
                    host_time_us: now_us,
                },
            );
        }
        for _ in 0..100 {
            sim.step();
            for (i, slot) in latest.iter_mut().enumerate() {
                while let Some(bytes) = sim.host_recv(i) {
                    if let Ok(AnyPacket::State(s)) = protocol::decode(&bytes) {
                        *slot = Some(s);
                    }
                }
                let p = sim.robots()[i].pose();
                let a = angle(p.x, p.y);
                turned[i] +=
                    simulator::world::wrap_angle(a - turned[i].rem_euclid(std::f64::consts::TAU));
            }
        }
        if sim.now().as_millis() % 2000 == 0 {
            for (i, r) in sim.robots().iter().enumerate() {
                let Some(s) = latest[i] else { continue };
                let p = r.pose();
                println!(
                    "{:6.1}  {:5}  {:6.0}  {:6.0}  {:9}  {:7.3}/{:<7.3}  {:12}  {:4.2}",
                    sim.now().as_secs_f64(),
                    r.id(),
                    p.x * 1e3,
                    p.y * 1e3,
                    { s.line.position_um },
                    { s.wheels.left_mps },
                    { s.wheels.right_mps },
                    { s.power.battery_mv },
                    (turned[i] - start[i]) / std::f64::consts::TAU
                );
            }
        }
        if turned
            .iter()
            .zip(&start)
            .all(|(t, s)| t - s >= 3.0 * std::f64::consts::TAU)
        {
            break;
        }
    }
    println!(
        "3 laps each in {:.1} s simulated ({:.2} s wall, {:.0}x real time); robot-robot collisions: {}",
        sim.now().as_secs_f64(),
        wall.elapsed().as_secs_f64(),
        sim.now().as_secs_f64() / wall.elapsed().as_secs_f64(),
        sim.robot_collisions()
    );
}
