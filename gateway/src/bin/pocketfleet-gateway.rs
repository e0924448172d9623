//! `pocketfleet-gateway --fleet NAME --robots ADDR[,ADDR...]`: bridges these robots onto zenoh
//! for a coordinator elsewhere (`coordinator --transport zenoh --fleet NAME`).

use std::path::PathBuf;

use clap::Parser;
use gateway::{Gateway, GatewayConfig};
use robot_actor::link::zenoh::ZenohOptions;

/// Bridges robot links onto zenoh for a coordinator on another host.
#[derive(Parser, Debug)]
#[command(
    version,
    after_help = "Example, with the coordinator on 192.0.2.10:\n  \
    pocketfleet-gateway --fleet lab --robots bt://AA:BB:CC:DD:EE:FF,serial:///dev/ttyUSB0 \
    --zenoh-connect tcp/192.0.2.10:7447"
)]
struct Args {
    /// The fleet's name (one word); the coordinator uses the same.
    #[arg(long)]
    fleet: String,
    /// The robots this gateway owns: tcp://, serial://, bt://, unix://, seqpacket:// addresses.
    #[arg(long, value_delimiter = ',', required = true)]
    robots: Vec<String>,
    /// This gateway's name in the fleet (default: gateway-PID).
    #[arg(long)]
    name: Option<String>,
    /// A zenoh endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable).
    #[arg(long = "zenoh-listen")]
    listen: Vec<String>,
    /// A peer's zenoh endpoint to connect to, e.g. tcp/192.0.2.10:7447 (repeatable).
    #[arg(long = "zenoh-connect")]
    connect: Vec<String>,
    /// A zenoh JSON5 configuration file (TLS, authentication, scouting), applied first.
    #[arg(long = "zenoh-config")]
    config: Option<PathBuf>,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "info,zenoh=warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let args = Args::parse();
    let config = GatewayConfig {
        fleet: args.fleet,
        name: args
            .name
            .unwrap_or_else(|| format!("gateway-{}", std::process::id())),
        robots: args.robots,
        zenoh: ZenohOptions {
            listen: args.listen,
            connect: args.connect,
            config_file: args.config,
        },
    };
    let gateway = Gateway::start(config).await?;
    tokio::signal::ctrl_c().await?;
    drop(gateway);
    Ok(())
}
