//! `coordinator --behaviour NAME`: one supervised multi-robot experiment, on simulated robots by
//! default, ending with a report; the exit status says whether the behaviour succeeded.

/// Packets and state batches cross threads: mimalloc frees another thread's blocks cheaply.
#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use behaviours::Registry;
use clap::{Parser, ValueEnum};
use coordinator::instruments::panel::PanelOptions;
use coordinator::{Instruments, Plan, Transport};
use world::presets;

/// Run a supervised multi-robot experiment.
#[derive(Parser, Debug)]
#[command(
    version,
    subcommand_negates_reqs = true,
    after_help = "Examples:\n  coordinator --behaviour square_walk --robots 3\n  coordinator --behaviour cooperative_push --panel --record push.mcap\n  coordinator replay push.mcap --panel\n  coordinator sweep --behaviour line_follow --seeds 1..100 --param laps=1,2 --out laps\n  coordinator --behaviour square_walk --world my_world.toml --seed 7 --json-report out.json\n  coordinator --transport tcp --robots tcp://127.0.0.1:7001,tcp://127.0.0.1:7002 --behaviour square_walk\n  coordinator --list-behaviours"
)]
struct Args {
    /// The behaviour to run (see --list-behaviours).
    #[arg(long, required_unless_present_any = ["list_behaviours", "list_worlds", "resume"])]
    behaviour: Option<String>,
    /// Take over the run recorded in FILE.mcap whose coordinator died: its behaviour, world, seed
    /// and robot addresses come from the recording; the robots are adopted without a reboot,
    /// where its last world snapshot left them (carried on by their encoders), and the behaviour
    /// starts again from there, within what is left of the time limit.
    #[arg(long, value_name = "FILE.mcap", conflicts_with_all = ["behaviour", "world", "robots", "transport", "seed", "params", "kick", "fault"])]
    resume: Option<PathBuf>,
    /// Number of simulated robots, a comma-separated list of robot addresses, or with
    /// --transport zenoh the number of robots to wait for.
    #[arg(long)]
    robots: Option<String>,
    /// With --transport zenoh: the fleet's name, as its gateways were given it.
    #[arg(long)]
    fleet: Option<String>,
    /// With --transport zenoh: an endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable).
    #[arg(long = "zenoh-listen", value_name = "ENDPOINT")]
    zenoh_listen: Vec<String>,
    /// With --transport zenoh: a gateway's or peer's endpoint to connect to (repeatable).
    #[arg(long = "zenoh-connect", value_name = "ENDPOINT")]
    zenoh_connect: Vec<String>,
    /// With --transport zenoh: a zenoh JSON5 configuration file (TLS, authentication), applied
    /// first.
    #[arg(long = "zenoh-config", value_name = "FILE")]
    zenoh_config: Option<PathBuf>,
    /// A world preset, a world file, a generated lattice `grid:COLSxROWS:ROBOTS`, or a generated
    /// loop `serpentine:ROBOTS` (default: the behaviour's own).
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
    /// The simulated links' latency, loss and bandwidth: a profile (ideal, l2cap, bluetooth, poor)
    /// or a TOML file with a `[link]` table, replacing the world's `[link]`.
    #[arg(long = "link-profile", value_name = "NAME|FILE", value_parser = world::cli::parse_link_profile)]
    link_profile: Option<world::cli::LinkProfileArg>,
    /// Keep N threads busy beside the experiment, standing for other programs on a loaded host.
    #[arg(long = "host-load", value_name = "N", default_value_t = 0)]
    host_load: usize,
    /// Physics rate of simulated robots in Hz: 1000, 500, 250 or 200. Firmware deadlines, link
    /// packets and encoder edges keep the 1 kHz clock; below 1000 the bodies move in coarser steps
    /// and the line sensor sees the floor interpolated between them (faster, a little less exact).
    #[arg(long = "physics-hz", value_name = "HZ", default_value = "1000", value_parser = world::cli::parse_physics_hz)]
    physics_every: u32,
    /// Time limit in seconds (simulated time when simulating), more than 0 and at most 1000000.
    #[arg(long, default_value = "600", value_parser = world::cli::parse_duration, allow_negative_numbers = true)]
    duration: Duration,
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
    /// Serve the live control panel (default 127.0.0.1:7878); any address but loopback requires
    /// the token printed at start. Implies --realtime for simulated robots unless --fast.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = DEFAULT_PANEL)]
    panel: Option<SocketAddr>,
    /// With --panel: still run simulated time as fast as possible.
    #[arg(long)]
    fast: bool,
    /// Record every packet, the world snapshots and the robots' events to this MCAP file.
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
    /// Write the robots' trajectories over the track to this SVG file.
    #[arg(long, value_name = "FILE.svg")]
    plot: Option<PathBuf>,
    /// Kick simulated robot ID at SECONDS of experiment time by DX,DY metres and DEG degrees
    /// (repeatable). HOW is `teleport` (the default: the body moves at once and nothing on the
    /// robot feels it) or `shove[/MS]` (a hand pushes it over 50 ms or MS, 20–100: the wheels
    /// drag and the accelerometer feels it). `random[:HOW][:SECONDS]` draws per seed one robot,
    /// a time from 1 s to SECONDS (30), a shift of up to 3 cm and a turn of up to 20°, never
    /// into another body or a wall; a shove unless HOW says teleport.
    #[arg(long, value_name = "[HOW:]ID:SECONDS:DX,DY[,DEG] | random[:HOW][:SECONDS]", value_parser = world::cli::parse_kick)]
    kick: Vec<world::cli::KickSpec>,
    /// Inject a fault into simulated robot ID's link or firmware SECONDS into the experiment, for
    /// FOR_SECONDS (repeatable, beside the world file's `[[faults]]`). KIND is `cut` (nothing
    /// gets through), `loss`, `corrupt` (one byte of a packet replaced), `duplicate` or
    /// `reorder` (AMOUNT: the share of packets hit, default 1), `latency` (AMOUNT: seconds
    /// added, default 1, at most 2) or `reboot` (the firmware restarts; no FOR_SECONDS).
    /// `random:KIND[:FOR_SECONDS[:AMOUNT]]` draws the robot and a time from 1 to 30 s per seed,
    /// lasting 3 s unless given.
    #[arg(long, value_name = "KIND:ID:SECONDS[:FOR_SECONDS[:AMOUNT]] | random:KIND[:FOR_SECONDS[:AMOUNT]]", value_parser = world::faults::parse_fault)]
    fault: Vec<world::faults::FaultArg>,
    /// Write robot setting PATH (a field of the robot's settings, e.g. watchdog.timeout_ms) to
    /// VALUE on every robot before the experiment starts (repeatable); each robot gets it again
    /// after a reconnect. A value the robot refuses ends the run before it starts.
    #[arg(long = "setting", value_name = "PATH=VALUE")]
    settings: Vec<coordinator::SettingWrite>,
    #[command(subcommand)]
    command: Option<Sub>,
}

const DEFAULT_PANEL: &str = "127.0.0.1:7878";

#[derive(clap::Subcommand, Debug)]
enum Sub {
    /// Feed a recording's packets back through robot actors, the supervisor and its behaviour, and
    /// check that every recorded world snapshot comes out the same.
    Replay {
        /// The recording.
        file: PathBuf,
        /// Serve the control panel during the replay (paced to the wall clock).
        #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = DEFAULT_PANEL)]
        panel: Option<SocketAddr>,
        /// Write the replayed trajectories to this SVG file.
        #[arg(long, value_name = "FILE.svg")]
        plot: Option<PathBuf>,
    },
    /// Rewrite a recording whose recorder never finished (killed, or cut off mid-record) as a
    /// complete MCAP file with summary and indexes, keeping every whole chunk; reports what it
    /// kept and whether the tail was cut. The input is left as it is unless -o names it.
    Recover {
        /// The recording.
        file: PathBuf,
        /// Where to write the complete file (default: beside FILE, `run.mcap` gives
        /// `run.recovered.mcap`). It may be FILE itself: the new file replaces it only once whole.
        #[arg(short, long, value_name = "OUT.mcap")]
        output: Option<PathBuf>,
    },
    /// Run a behaviour over seeds and settings, each run its own experiment, and summarise the
    /// success rate and metrics (`coordinator sweep merge` combines shards).
    Sweep(Box<coordinator::instruments::sweep::SweepCommand>),
    /// Run every fault kind against every built-in over seeds (one sweep per behaviour) and
    /// write the table of verdicts, contacts and stops; the exit status says whether every rule
    /// held.
    Campaign(coordinator::instruments::campaign::CampaignArgs),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum TransportKind {
    /// Simulated robots in this process.
    Sim,
    /// Robots served over TCP (e.g. by pocketbot-sim or a serial bridge).
    Tcp,
    /// Robots on serial ports.
    Serial,
    /// Robots over Bluetooth L2CAP.
    #[value(help = BLUETOOTH_HELP)]
    Bluetooth,
    /// Robots behind pocketfleet-gateways on other hosts.
    #[value(help = ZENOH_HELP)]
    Zenoh,
}

/// `--transport zenoh`'s help, true to how this binary was built.
const ZENOH_HELP: &str = if cfg!(feature = "zenoh") {
    "Robots behind pocketfleet-gateways, over zenoh (--fleet, --robots N, --zenoh-connect)"
} else {
    "Robots behind pocketfleet-gateways: not in this binary; build it with --features zenoh"
};

/// `--transport bluetooth`'s help, true to how this binary was built.
const BLUETOOTH_HELP: &str = if cfg!(feature = "bluetooth") {
    "Robots over Bluetooth L2CAP, addressed bt://MAC (built into this binary)"
} else {
    "Robots over Bluetooth L2CAP: not in this binary; build it with --features bluetooth"
};

fn parse_param(s: &str) -> Result<(String, String), String> {
    s.split_once('=')
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .ok_or_else(|| format!("expected key=value, got {s:?}"))
}

/// Output files claimed before the run, so an unwritable path is found before any robot moves.
struct Outputs {
    /// Files this run created; removed again if the run ends in an error.
    created: Vec<PathBuf>,
}

impl Outputs {
    /// Opens every given path for writing, creating it if needed (an existing file keeps its
    /// content until the run writes it).
    fn claim(paths: &[(&str, Option<&std::path::Path>)]) -> Result<Self> {
        let mut outputs = Self {
            created: Vec::new(),
        };
        for (flag, path) in paths {
            let Some(path) = path else { continue };
            let existed = path.exists();
            let opened = std::fs::OpenOptions::new()
                .write(true)
                .create(true)
                .truncate(false)
                .open(path);
            if let Err(e) = opened {
                outputs.discard();
                bail!("{flag} {}: cannot write there: {e}", path.display());
            }
            if !existed {
                outputs.created.push(path.to_path_buf());
            }
        }
        Ok(outputs)
    }

    /// Removes the files this run created and left empty: an error leaves no empty output
    /// behind, but keeps whatever was written (a recording up to the error).
    fn discard(&self) {
        for path in &self.created {
            if std::fs::metadata(path).is_ok_and(|m| m.len() == 0) {
                let _ = std::fs::remove_file(path);
            }
        }
    }
}

#[cfg(feature = "zenoh")]
fn zenoh_transport(args: &Args) -> Result<Transport> {
    let fleet = args
        .fleet
        .clone()
        .context("--transport zenoh needs --fleet NAME")?;
    let robots = match &args.robots {
        None => 1,
        Some(s) => s.parse::<usize>().with_context(|| {
            format!("--robots {s:?}: with --transport zenoh give the number of robots to wait for")
        })?,
    };
    Ok(Transport::Zenoh {
        fleet,
        robots,
        options: robot_actor::link::zenoh::ZenohOptions {
            listen: args.zenoh_listen.clone(),
            connect: args.zenoh_connect.clone(),
            config_file: args.zenoh_config.clone(),
        },
    })
}

#[cfg(not(feature = "zenoh"))]
fn zenoh_transport(args: &Args) -> Result<Transport> {
    // Parsed in every build, so that --help lists them and a script reads the same everywhere.
    let _ = (
        &args.fleet,
        &args.zenoh_listen,
        &args.zenoh_connect,
        &args.zenoh_config,
    );
    anyhow::bail!(
        "--transport zenoh: this coordinator was built without it; build it with --features zenoh"
    )
}

fn plan(args: &Args) -> Result<Plan> {
    let behaviour = args.behaviour.clone().context("--behaviour is required")?;
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
        TransportKind::Zenoh => (zenoh_transport(args)?, None),
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
        world: args.world.clone(),
        robots,
        transport,
        seed: args.seed,
        // The panel is for watching: simulated time then runs at the wall clock's pace.
        realtime: args.realtime || (args.panel.is_some() && !args.fast),
        duration: args.duration,
        params: args.params.iter().cloned().collect(),
        kicks: args
            .kick
            .iter()
            .filter_map(|k| match *k {
                world::cli::KickSpec::Given(k) => Some(coordinator::Kick::from(k)),
                world::cli::KickSpec::Random(_) => None,
            })
            .collect(),
        random_kicks: args
            .kick
            .iter()
            .filter_map(|k| match *k {
                world::cli::KickSpec::Random(r) => Some(r),
                world::cli::KickSpec::Given(_) => None,
            })
            .collect(),
        faults: args
            .fault
            .iter()
            .filter_map(|f| match *f {
                world::faults::FaultArg::Given(f) => Some(f),
                world::faults::FaultArg::Random(_) => None,
            })
            .collect(),
        random_faults: args
            .fault
            .iter()
            .filter_map(|f| match *f {
                world::faults::FaultArg::Random(r) => Some(r),
                world::faults::FaultArg::Given(_) => None,
            })
            .collect(),
        settings: args.settings.clone(),
        physics_every: args.physics_every,
        link: args.link_profile.clone(),
        host_load: args.host_load,
        ..Plan::sim(behaviour)
    })
}

fn main() -> ExitCode {
    let args = Args::parse();
    world::cli::init_logging();
    let mut registry = Registry::builtin();
    coordinator::instruments::panel::register_teleop(&mut registry);
    if args.list_behaviours {
        for name in registry.names() {
            let e = registry.get(name).expect("listed");
            println!("{name:18} (world {:8}) {}", e.world, e.description);
            let params = e.params();
            if params.is_empty() {
                println!("{:20}no parameters", "");
            }
            for p in params {
                println!("{:20}--param {p}", "");
            }
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
    let result = match &args.command {
        Some(Sub::Replay { file, panel, plot }) => replay(file, *panel, plot.as_deref(), &registry),
        Some(Sub::Recover { file, output }) => recover(file, output.as_deref()),
        Some(Sub::Sweep(sweep)) => coordinator::instruments::sweep::main(sweep),
        Some(Sub::Campaign(c)) => coordinator::instruments::campaign::main(c),
        None => run(&args, &registry),
    };
    match result {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("coordinator: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run(args: &Args, registry: &Registry) -> Result<bool> {
    let plan = match &args.resume {
        Some(path) => {
            let (plan, resume) = coordinator::experiment::resume::Resume::load(path)?;
            Plan {
                settings: args.settings.clone(),
                resume: Some(std::sync::Arc::new(resume)),
                ..plan
            }
        }
        None => plan(args)?,
    };
    let outputs = Outputs::claim(&[
        ("--json-report", args.json_report.as_deref()),
        ("--plot", args.plot.as_deref()),
        ("--record", args.record.as_deref()),
    ])?;
    let result = run_plan(args, plan, registry);
    if result.is_err() {
        outputs.discard();
    }
    result
}

fn run_plan(args: &Args, plan: Plan, registry: &Registry) -> Result<bool> {
    // Loaded again for the plot only, after the run has checked the plan.
    let plot = args.plot.as_ref().map(|path| (path.clone(), plan.clone()));
    let instruments = Instruments {
        record: args.record.clone(),
        panel: args.panel.map(|addr| PanelOptions { addr, linger: true }),
        trails: args.plot.is_some(),
    };
    // Simulated experiments run on a paused clock: see `coordinator::actor_system`.
    let run = coordinator::run_blocking_with(plan, registry, instruments)?;
    let report = &run.report;
    println!("{report}");
    if let Some(path) = &args.json_report {
        std::fs::write(path, report.to_json())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    finish(&run, registry, plot)?;
    Ok(report.success())
}

/// The world a plan runs in, for the plot.
fn plan_world(plan: &Plan, registry: &Registry) -> Result<world::World> {
    let name = match &plan.world {
        Some(w) => w.clone(),
        None => registry
            .get(&plan.behaviour)
            .map(|e| e.world.to_string())
            .with_context(|| format!("unknown behaviour {:?}", plan.behaviour))?,
    };
    coordinator::load_world(&name)
}

fn finish(
    run: &coordinator::Run,
    registry: &Registry,
    plot: Option<(PathBuf, Plan)>,
) -> Result<()> {
    if let Some((path, stats)) = &run.recording {
        println!(
            "recording: {} ({} messages, {} packets, {} bytes)",
            path.display(),
            stats.messages,
            stats.packets,
            stats.bytes
        );
    }
    if let Some((path, plan)) = plot {
        let world = plan_world(&plan, registry)?;
        coordinator::instruments::plot::write_trajectories(
            &path,
            &world,
            &run.observed.trails,
            &run.observed.truth_trails,
        )?;
        println!("trajectories: {}", path.display());
    }
    Ok(())
}

fn recover(file: &std::path::Path, output: Option<&std::path::Path>) -> Result<bool> {
    let output = output.map_or_else(
        || coordinator::instruments::recover::default_output(file),
        std::path::Path::to_path_buf,
    );
    let kept = coordinator::instruments::recover::recover_file(file, &output)?;
    println!(
        "recovered {} into {}: {kept}",
        file.display(),
        output.display()
    );
    Ok(true)
}

fn replay(
    file: &std::path::Path,
    panel: Option<SocketAddr>,
    plot: Option<&std::path::Path>,
    registry: &Registry,
) -> Result<bool> {
    let outputs = Outputs::claim(&[("--plot", plot)])?;
    let result = replay_file(file, panel, plot, registry);
    if result.is_err() {
        outputs.discard();
    }
    result
}

fn replay_file(
    file: &std::path::Path,
    panel: Option<SocketAddr>,
    plot: Option<&std::path::Path>,
    registry: &Registry,
) -> Result<bool> {
    let recording = coordinator::instruments::replay::load(file)?;
    if let Some(why) = &recording.truncated {
        eprintln!("coordinator: the recording ends early ({why}); replaying what is there");
    }
    let info = &recording.info;
    let plan = Plan::sim(info.behaviour.clone())
        .world(info.world.clone())
        .robots(info.robots)
        .transport(Transport::Replay(file.to_path_buf()))
        .seed(info.seed)
        .realtime(panel.is_some())
        .duration(recording.end + Duration::from_secs(5))
        .params(info.params.clone());
    let plot = plot.map(|p| (p.to_path_buf(), plan.clone()));
    let instruments = Instruments {
        record: None,
        panel: panel.map(|addr| PanelOptions { addr, linger: true }),
        trails: plot.is_some(),
    };
    // Paused unless paced for the panel.
    let run = coordinator::run_blocking_with(plan, registry, instruments)?;
    let check = run
        .replay
        .clone()
        .context("the replay produced no comparison")?;
    println!("{check}");
    finish(&run, registry, plot)?;
    Ok(check.exact())
}
