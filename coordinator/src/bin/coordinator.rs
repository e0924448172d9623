//! `coordinator --behaviour NAME`: one supervised multi-robot experiment, on simulated robots by
//! default, ending with a report; the exit status says whether the behaviour succeeded.

use std::collections::BTreeMap;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use behaviours::Registry;
use clap::{Parser, ValueEnum};
use coordinator::{Plan, Transport};
use simulator::world::presets;

/// Run a supervised multi-robot experiment.
#[derive(Parser, Debug)]
#[command(
    version,
    after_help = "Examples:\n  coordinator --behaviour square_walk --robots 3\n  coordinator --behaviour square_walk --world my_world.toml --seed 7 --json-report out.json\n  coordinator --transport tcp --robots tcp://127.0.0.1:7001,tcp://127.0.0.1:7002 --behaviour square_walk\n  coordinator --list-behaviours"
)]
struct Args {
    /// The behaviour to run (see --list-behaviours).
    #[arg(long, required_unless_present_any = ["list_behaviours", "list_worlds"])]
    behaviour: Option<String>,
    /// Number of simulated robots, or a comma-separated list of robot addresses.
    #[arg(long)]
    robots: Option<String>,
    /// A world preset or world file (default: the behaviour's own).
    #[arg(long)]
    world: Option<String>,
    /// Where the robots are.
    #[arg(long, value_enum, default_value_t = TransportKind::Sim)]
    transport: TransportKind,
    /// Seed of the simulation's noise and the behaviour's choices.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Pace the simulation to the wall clock instead of running it as fast as possible.
    #[arg(long)]
    realtime: bool,
    /// Time limit in seconds (simulated time when simulating).
    #[arg(long, default_value_t = 120.0)]
    duration: f64,
    /// Also write the report as JSON to this file.
    #[arg(long)]
    json_report: Option<std::path::PathBuf>,
    /// A behaviour parameter, key=value (repeatable).
    #[arg(long = "param", value_parser = parse_param)]
    params: Vec<(String, String)>,
    /// List the behaviours and exit.
    #[arg(long)]
    list_behaviours: bool,
    /// List the built-in worlds and exit.
    #[arg(long)]
    list_worlds: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum TransportKind {
    /// Simulated robots in this process.
    Sim,
    /// Robots served over TCP (e.g. by pocketbot-sim or a serial bridge).
    Tcp,
    /// Robots on serial ports.
    Serial,
    /// Robots over Bluetooth L2CAP (build with --features bluetooth).
    Bluetooth,
}

fn parse_param(s: &str) -> Result<(String, String), String> {
    s.split_once('=')
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .ok_or_else(|| format!("expected key=value, got {s:?}"))
}

fn plan(args: &Args) -> Result<Plan> {
    let behaviour = args.behaviour.clone().context("--behaviour is required")?;
    if !args.duration.is_finite() || args.duration <= 0.0 {
        bail!("--duration must be a positive number of seconds");
    }
    let (transport, robots) = match args.transport {
        TransportKind::Sim => {
            let n = match &args.robots {
                None => None,
                Some(s) => Some(s.parse::<usize>().with_context(|| {
                    format!("--robots {s:?}: with --transport sim give a number of robots")
                })?),
            };
            (Transport::Sim, n)
        }
        kind => {
            let list = args
                .robots
                .as_deref()
                .with_context(|| format!("--transport {kind:?} needs --robots ADDR[,ADDR…]"))?;
            let addrs: Vec<String> = list.split(',').map(|a| a.trim().to_string()).collect();
            (Transport::Addresses(addrs), None)
        }
    };
    Ok(Plan {
        behaviour,
        world: args.world.clone(),
        robots,
        transport,
        seed: args.seed,
        realtime: args.realtime,
        duration: Duration::from_secs_f64(args.duration),
        params: args.params.iter().cloned().collect::<BTreeMap<_, _>>(),
        faults: Vec::new(),
    })
}

fn main() -> ExitCode {
    let args = Args::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let registry = Registry::builtin();
    if args.list_behaviours {
        for name in registry.names() {
            let e = registry.get(name).expect("listed");
            println!("{name:18} (world {:8}) {}", e.world, e.description);
        }
        return ExitCode::SUCCESS;
    }
    if args.list_worlds {
        for name in presets::preset_names() {
            if let Some(w) = presets::preset(name) {
                println!("{name:10} {:3} robots  {}", w.robots.len(), w.description);
            }
        }
        return ExitCode::SUCCESS;
    }
    match run(&args, &registry) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("coordinator: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run(args: &Args, registry: &Registry) -> Result<bool> {
    let plan = plan(args)?;
    let simulated = plan.transport == Transport::Sim;
    // Simulated experiments run on a paused clock: see `coordinator::actor_system`.
    let system = coordinator::actor_system(simulated && !plan.realtime);
    let report = system.block_on(coordinator::run(plan, registry))?;
    println!("{report}");
    if let Some(path) = &args.json_report {
        std::fs::write(path, report.to_json())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(report.verdict.success)
}
