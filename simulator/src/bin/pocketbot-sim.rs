//! `pocketbot-sim`: serves every robot of a simulated world on its own TCP port with SLIP framing,
//! so any client can connect to it as to a robot on a serial line.

use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::Parser;
use simulator::runtime::Pace;
use simulator::serve::serve;
use simulator::world::{file, presets};
use simulator::{SimConfig, Simulation};

/// Serve simulated PocketBot2 robots over TCP (SLIP-framed protocol packets).
#[derive(Parser, Debug)]
#[command(
    version,
    after_help = "Examples:\n  pocketbot-sim --world push\n  pocketbot-sim --world worlds/my.toml --port-base 7101\n  pocketbot-sim --port-base 0   # ephemeral ports, printed one robot per line"
)]
struct Args {
    /// A preset name or a world file (.toml).
    #[arg(long, default_value = "oval")]
    world: String,
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1")]
    bind: String,
    /// Port of the first robot; the next robots take the following ports. 0 picks free ports.
    #[arg(long, default_value_t = 7001)]
    port_base: u16,
    /// Seed of noise and link jitter (defaults to the world's).
    #[arg(long)]
    seed: Option<u64>,
    /// Run faster than real time instead of pacing to the wall clock.
    #[arg(long)]
    fast: bool,
    /// Stop after this many simulated seconds (more than 0, at most 1e6).
    #[arg(long, value_parser = simulator::cli::parse_duration, allow_negative_numbers = true)]
    duration: Option<Duration>,
    /// List the built-in worlds and exit.
    #[arg(long)]
    list_worlds: bool,
    /// Break robot ID's body, as ID:jammed-wheels or ID:dead-encoders (repeatable): its firmware
    /// still runs and answers, but it cannot move, or cannot measure that it does.
    #[arg(long, value_name = "ID:FAULT", value_parser = parse_body_fault)]
    body_fault: Vec<(u16, simulator::BodyFault)>,
    /// Kick robot ID at SECONDS of simulated time by DX,DY metres and DEG degrees (repeatable):
    /// its body moves at once and its odometry never learns of it.
    #[arg(long, value_name = "ID:SECONDS:DX,DY[,DEG]", value_parser = simulator::cli::parse_kick)]
    kick: Vec<simulator::cli::KickArg>,
}

fn parse_body_fault(s: &str) -> Result<(u16, simulator::BodyFault), String> {
    let (id, fault) = s
        .split_once(':')
        .ok_or_else(|| format!("{s:?}: expected ID:FAULT, e.g. 2:jammed-wheels"))?;
    let id = id
        .parse()
        .map_err(|_| format!("{s:?}: robot id {id:?} is not a number from 0 to 65535"))?;
    Ok((id, fault.parse()?))
}

fn load_world(name: &str) -> Result<simulator::World> {
    if let Some(w) = presets::preset(name) {
        return Ok(w);
    }
    if name.ends_with(".toml") || std::path::Path::new(name).exists() {
        return file::load(name).map_err(|e| anyhow::anyhow!("{e}"));
    }
    bail!(
        "unknown world {name:?}: not a preset ({}) nor a .toml file",
        presets::preset_names().join(", ")
    )
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<()> {
    let args = Args::parse();
    // Link buffer overflows are reported as warnings (at most one a second per robot).
    simulator::cli::init_logging();
    if args.list_worlds {
        for name in presets::preset_names() {
            let w = presets::preset(name).context("preset")?;
            println!("{name:10} {} robots  {}", w.robots.len(), w.description);
        }
        return Ok(());
    }
    let world = load_world(&args.world)?;
    let mut sim = Simulation::new(
        world,
        SimConfig {
            seed: args.seed,
            ..SimConfig::default()
        },
    );
    for &(id, fault) in &args.body_fault {
        let i = sim
            .robot_index(id)
            .with_context(|| format!("--body-fault {id}: no robot {id} in the world"))?;
        sim.set_body_fault(i, Some(fault));
    }
    let mut kicks = Vec::new();
    for k in &args.kick {
        let i = sim
            .robot_index(k.robot)
            .with_context(|| format!("--kick {}: no robot {} in the world", k.robot, k.robot))?;
        kicks.push((i, *k));
    }
    let pace = if args.fast {
        Pace::Unpaced
    } else {
        Pace::WallClock
    };
    let (addrs, handle, task) = serve(sim, &args.bind, args.port_base, pace)
        .await
        .with_context(|| {
            format!(
                "binding robots on {} from port {}",
                args.bind, args.port_base
            )
        })?;
    for (id, addr) in &addrs {
        println!("robot {id} tcp://{addr}");
    }
    println!("serving {} robots", addrs.len());
    for (i, k) in kicks {
        handle.displace_at(k.at, i, k.dx_m, k.dy_m, k.dtheta_rad);
    }
    match args.duration {
        Some(end) => loop {
            let t = handle.truth().await.context("simulation stopped")?;
            if t.now >= end {
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        },
        None => {
            tokio::signal::ctrl_c().await?;
        }
    }
    handle.stop();
    let _ = task.await;
    Ok(())
}
