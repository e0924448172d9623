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
    /// The links' latency, loss and bandwidth: a profile (ideal, l2cap, bluetooth, poor) or a
    /// TOML file with a `[link]` table, replacing the world's `[link]`.
    #[arg(long = "link-profile", value_name = "NAME|FILE", value_parser = simulator::cli::parse_link_profile)]
    link_profile: Option<simulator::cli::LinkProfileArg>,
    /// Seed of noise and link jitter (defaults to the world's).
    #[arg(long)]
    seed: Option<u64>,
    /// Run faster than real time instead of pacing to the wall clock.
    #[arg(long)]
    fast: bool,
    /// Simulated seconds per wall-clock second (more than 0, at most 100; default 1): below 1
    /// the robots live slower than the host, so its reaction times shrink in the robots' time.
    #[arg(long, value_parser = parse_rate, conflicts_with = "fast")]
    rate: Option<f64>,
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
    /// Kick robot ID at SECONDS of simulated time by DX,DY metres and DEG degrees (repeatable).
    /// HOW is `teleport` (the default: the body moves at once and its odometry never learns of
    /// it) or `shove[/MS]` (a hand pushes it over 50 ms or MS: wheels and accelerometer feel it).
    #[arg(long, value_name = "[HOW:]ID:SECONDS:DX,DY[,DEG]", value_parser = simulator::cli::parse_kick)]
    kick: Vec<simulator::cli::KickSpec>,
    /// Write the ground truth (true poses, boxes, contacts, wheel speeds, host silences) as JSON
    /// to FILE every second and at exit, so another process can judge what happened.
    #[arg(long, value_name = "FILE")]
    truth: Option<std::path::PathBuf>,
}

fn parse_rate(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(r) if r > 0.0 && r <= 100.0 => Ok(r),
        _ => Err(format!("{s:?}: give a number above 0 and at most 100")),
    }
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
async fn main() -> std::process::ExitCode {
    let args = Args::parse();
    // Link buffer overflows are reported as warnings (at most one a second per robot).
    simulator::cli::init_logging();
    if args.list_worlds {
        for name in presets::preset_names() {
            if let Some(w) = presets::preset(name) {
                println!("{name:10} {} robots  {}", w.robots.len(), w.description);
            }
        }
        return std::process::ExitCode::SUCCESS;
    }
    // A world, fault or kick the simulator cannot take is a usage error, as a bad flag is.
    let (sim, kicks) = match prepare(&args) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("pocketbot-sim: {e:#}");
            return std::process::ExitCode::from(2);
        }
    };
    match run(&args, sim, kicks).await {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("pocketbot-sim: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// A kick to land, on the robot at this index.
type Kick = (usize, simulator::cli::KickArg);

/// The simulation the flags describe, and the kicks to land in it.
fn prepare(args: &Args) -> Result<(Simulation, Vec<Kick>)> {
    let mut world = load_world(&args.world)?;
    if let Some(link) = &args.link_profile {
        world.link = link.model;
    }
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
        let simulator::cli::KickSpec::Given(k) = k else {
            anyhow::bail!("--kick random: kicks drawn per seed are the coordinator's to draw");
        };
        let i = sim
            .robot_index(k.robot)
            .with_context(|| format!("--kick {}: no robot {} in the world", k.robot, k.robot))?;
        kicks.push((i, *k));
    }
    Ok((sim, kicks))
}

/// Serves the robots until the duration ends or the process is told to stop.
async fn run(args: &Args, sim: Simulation, kicks: Vec<Kick>) -> Result<()> {
    let pace = match (args.fast, args.rate) {
        (true, _) => Pace::Unpaced,
        (false, Some(rate)) => Pace::Scaled(rate),
        (false, None) => Pace::WallClock,
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
        handle.kick_at(k.at, i, [k.dx_m, k.dy_m, k.dtheta_rad], k.how);
    }
    let mut terminate = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    let mut written: Option<std::time::Instant> = None;
    loop {
        let t = handle.truth().await.context("simulation stopped")?;
        let end = args.duration.is_some_and(|end| t.now >= end);
        if let Some(path) = &args.truth {
            if end || written.is_none_or(|w| w.elapsed() >= Duration::from_secs(1)) {
                write_truth(path, &t, &addrs)?;
                written = Some(std::time::Instant::now());
            }
        }
        if end {
            break;
        }
        tokio::select! {
            _ = tokio::time::sleep(Duration::from_millis(50)) => {}
            _ = tokio::signal::ctrl_c() => break,
            _ = terminate.recv() => break,
        }
    }
    if let Some(path) = &args.truth {
        let t = handle.truth().await.context("simulation stopped")?;
        write_truth(path, &t, &addrs)?;
    }
    handle.stop();
    let _ = task.await;
    Ok(())
}

/// Writes the ground truth to `path` whole: to a file beside it, then renamed over it, so a
/// reader never sees half a file.
fn write_truth(
    path: &std::path::Path,
    t: &simulator::runtime::Truth,
    addrs: &[(u16, std::net::SocketAddr)],
) -> Result<()> {
    use serde_json::json;
    let robots: Vec<_> = t
        .robots
        .iter()
        .enumerate()
        .map(|(i, (id, p))| {
            let silences: Vec<_> = t.host_silences[i]
                .iter()
                .map(|s| {
                    json!({
                        "last_packet_s": s.last_packet_s,
                        "resumed_s": s.resumed_s,
                        "wheels_stopped_s": s.wheels_stopped_s,
                    })
                })
                .collect();
            json!({
                "id": id,
                "address": addrs.get(i).map(|(_, a)| format!("tcp://{a}")),
                "pose": { "x": p.x, "y": p.y, "theta": p.theta },
                "distance_m": t.distances_m[i],
                "wheel_speeds_mps": t.wheel_speeds_mps[i],
                "last_host_packet_s": t.last_host_packet_s[i],
                "host_silences": silences,
                "settings_updates_received": t.settings_updates[i],
                "watchdog_timeout_ms": t.watchdog_ms[i],
            })
        })
        .collect();
    let boxes: Vec<_> = t
        .obstacles
        .iter()
        .zip(&t.obstacle_displacements_m)
        .map(|(p, d)| json!({ "pose": { "x": p.x, "y": p.y, "theta": p.theta }, "displacement_m": d }))
        .collect();
    let contacts: Vec<_> = t
        .collision_log
        .iter()
        .map(|(at, a, b)| json!({ "at_s": at, "robots": [a, b] }))
        .collect();
    let walls: Vec<_> = t
        .wall_contact_log
        .iter()
        .map(|(at, id)| json!({ "at_s": at, "robot": id }))
        .collect();
    let doc = json!({
        "time_s": t.now.as_secs_f64(),
        "robots": robots,
        "boxes": boxes,
        "robot_contacts": contacts,
        "wall_contacts": walls,
    });
    let tmp = path.with_extension("json.part");
    std::fs::write(&tmp, serde_json::to_vec_pretty(&doc)?)
        .with_context(|| format!("--truth {}: cannot write", path.display()))?;
    std::fs::rename(&tmp, path)
        .with_context(|| format!("--truth {}: cannot write", path.display()))?;
    Ok(())
}
