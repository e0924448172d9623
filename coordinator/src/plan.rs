//! What an experiment is asked to be: the [`Plan`] (behaviour, world, robots, seed, limits, faults,
//! kicks, transport) and how a world is found by name.

use std::time::Duration;

use crate::twin::BodyFault;
use anyhow::{anyhow, bail, Result};
pub use world::cli::{KickHow, RandomKick};
pub use world::faults::{FaultKind, FaultSpec, RandomFault};
use world::{file, presets, World};

/// Where the robots come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Transport {
    /// Simulated robots in this process (the default).
    Sim,
    /// Robots at the given addresses (`tcp://…`, `serial://…`, `bt://…`).
    Addresses(Vec<String>),
    /// The robots of an MCAP recording, played back (see `coordinator replay`).
    Replay(std::path::PathBuf),
    /// Robots behind `pocketfleet-gateway`s on zenoh (feature `zenoh`).
    #[cfg(feature = "zenoh")]
    Zenoh {
        /// The fleet's name.
        fleet: String,
        /// How many robots to wait for before the experiment starts.
        robots: usize,
        /// Endpoints and configuration.
        options: robot_actor::link::zenoh::ZenohOptions,
    },
}

/// What to run.
#[derive(Clone, Debug)]
pub struct Plan {
    /// Behaviour name.
    pub behaviour: String,
    /// World preset name or file; `None` takes the behaviour's preferred world.
    pub world: Option<String>,
    /// How many simulated robots (the world's first N); `None` takes them all.
    pub robots: Option<usize>,
    /// Robot source.
    pub transport: Transport,
    /// Seed.
    pub seed: u64,
    /// Pace the simulation to the wall clock.
    pub realtime: bool,
    /// Time limit (simulated when simulating).
    pub duration: Duration,
    /// Behaviour parameters.
    pub params: std::collections::BTreeMap<String, String>,
    /// Faults of simulated robots' links and firmware (beside the world's own `[[faults]]`).
    pub faults: Vec<FaultSpec>,
    /// Faults drawn per seed (`--fault random:KIND`).
    pub random_faults: Vec<RandomFault>,
    /// Body faults of simulated robots, by robot id, present from the start (a robot that
    /// cannot move, or cannot measure that it does, to prove that verdicts need the work done).
    pub body_faults: Vec<(u16, BodyFault)>,
    /// Kicks of simulated robots: bodies moved without their odometry knowing, or shoved.
    pub kicks: Vec<Kick>,
    /// Kicks drawn per seed (`--kick random`).
    pub random_kicks: Vec<RandomKick>,
    /// Settings written to every robot before the experiment starts.
    pub settings: Vec<SettingWrite>,
    /// Clock steps (1 ms) per physics step of simulated robots: 1 is physics at 1 kHz.
    pub physics_every: u32,
    /// The simulated links' model, replacing the world's `[link]` (`--link-profile`): the
    /// name or file given, and the model.
    pub link: Option<world::cli::LinkProfileArg>,
    /// Threads kept busy beside the experiment, standing for other programs on the host.
    pub host_load: usize,
    /// A killed run taken over (`--resume`): its robots adopted where its recording left them.
    pub resume: Option<std::sync::Arc<crate::experiment::resume::Resume>>,
}

/// One robot setting the coordinator writes to every robot before the experiment starts,
/// confirmed by read-back; each robot actor writes it again after a reconnect or reboot.
/// Parsed from `PATH=VALUE`, e.g. `watchdog.timeout_ms=400` (`docs/protocol.md` lists the paths).
#[derive(Clone, Debug, PartialEq)]
pub struct SettingWrite {
    /// The field's dotted path.
    pub path: String,
    /// Its byte offset in the settings.
    pub offset: usize,
    /// The value's bytes, little-endian as on the wire.
    pub bytes: Vec<u8>,
}

impl std::str::FromStr for SettingWrite {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        use protocol::layout::Layout;
        let (path, value) = s
            .split_once('=')
            .ok_or_else(|| format!("{s:?}: expected PATH=VALUE, e.g. watchdog.timeout_ms=400"))?;
        let (path, value) = (path.trim(), value.trim());
        let (offset, ty) = protocol::Settings::LAYOUT
            .field_type(path)
            .ok_or_else(|| format!("{path:?} is not a robot setting (see docs/protocol.md)"))?;
        let bad = |e: &dyn std::fmt::Display| format!("{path} is a {}: {value:?}: {e}", ty.name);
        macro_rules! number {
            ($t:ty) => {
                value
                    .parse::<$t>()
                    .map_err(|e| bad(&e))?
                    .to_le_bytes()
                    .to_vec()
            };
        }
        let bytes = match ty.name {
            "u8" => number!(u8),
            "u16" => number!(u16),
            "u32" => number!(u32),
            "i8" => number!(i8),
            "i16" => number!(i16),
            "i32" => number!(i32),
            "f32" => number!(f32),
            "f64" => number!(f64),
            other if ty.fields.is_empty() && ty.array.is_none() => {
                return Err(format!("{path} is a {other}, which --setting cannot write"))
            }
            _ => {
                return Err(format!(
                    "{path} is a group of settings: name one of its fields"
                ))
            }
        };
        Ok(SettingWrite {
            path: path.to_string(),
            offset,
            bytes,
        })
    }
}

impl Plan {
    /// The default time limit, the CLI's `--duration` default.
    pub const DEFAULT_DURATION: Duration = Duration::from_secs(600);

    /// The simulated robots' physics rate, Hz.
    pub fn physics_hz(&self) -> u32 {
        1000 / self.physics_every.max(1)
    }

    /// `behaviour` on simulated robots: its own world with all its robots, seed 1, as fast as
    /// possible, [`Plan::DEFAULT_DURATION`], no parameters, faults or kicks.
    pub fn sim(behaviour: impl Into<String>) -> Plan {
        Plan {
            behaviour: behaviour.into(),
            world: None,
            robots: None,
            transport: Transport::Sim,
            seed: 1,
            realtime: false,
            duration: Self::DEFAULT_DURATION,
            params: std::collections::BTreeMap::new(),
            faults: Vec::new(),
            random_faults: Vec::new(),
            body_faults: Vec::new(),
            kicks: Vec::new(),
            random_kicks: Vec::new(),
            settings: Vec::new(),
            physics_every: 1,
            link: None,
            host_load: 0,
            resume: None,
        }
    }

    /// Simulated links follow `profile` (a name of [`world::LINK_PROFILES`]) instead of the
    /// world's `[link]`.
    ///
    /// # Panics
    /// If no profile has that name.
    pub fn link_profile(mut self, profile: &str) -> Plan {
        let model = world::RadioModel::profile(profile)
            .unwrap_or_else(|| panic!("no link profile {profile:?}"));
        self.link = Some(world::cli::LinkProfileArg {
            name: profile.to_string(),
            model,
        });
        self
    }

    /// Runs in this world preset or file instead of the behaviour's own.
    pub fn world(mut self, world: impl Into<String>) -> Plan {
        self.world = Some(world.into());
        self
    }

    /// Runs with the world's first `n` robots.
    pub fn robots(mut self, n: usize) -> Plan {
        self.robots = Some(n);
        self
    }

    /// Seeds the simulation's noise and the behaviour's choices.
    pub fn seed(mut self, seed: u64) -> Plan {
        self.seed = seed;
        self
    }

    /// Sets the time limit.
    pub fn duration(mut self, limit: Duration) -> Plan {
        self.duration = limit;
        self
    }

    /// Sets one behaviour parameter, replacing an earlier value for `key`.
    pub fn param(mut self, key: impl Into<String>, value: impl Into<String>) -> Plan {
        self.params.insert(key.into(), value.into());
        self
    }

    /// Sets several behaviour parameters.
    pub fn params<K: Into<String>, V: Into<String>>(
        mut self,
        params: impl IntoIterator<Item = (K, V)>,
    ) -> Plan {
        self.params
            .extend(params.into_iter().map(|(k, v)| (k.into(), v.into())));
        self
    }

    /// Adds a fault of a simulated robot's link or firmware.
    pub fn fault(mut self, fault: FaultSpec) -> Plan {
        self.faults.push(fault);
        self
    }

    /// Breaks simulated robot `robot` (by id) from the start.
    pub fn body_fault(mut self, robot: u16, fault: BodyFault) -> Plan {
        self.body_faults.push((robot, fault));
        self
    }

    /// Adds a kick of a simulated robot.
    pub fn kick(mut self, kick: Kick) -> Plan {
        self.kicks.push(kick);
        self
    }

    /// Takes the robots from `transport` instead of the simulator.
    pub fn transport(mut self, transport: Transport) -> Plan {
        self.transport = transport;
        self
    }

    /// Paces the simulation to the wall clock (or not).
    pub fn realtime(mut self, realtime: bool) -> Plan {
        self.realtime = realtime;
        self
    }

    /// Whether this plan runs on a paused clock (see [`crate::actor_system`]): everything but
    /// robots at addresses, unless paced to the wall clock.
    pub fn paused_clock(&self) -> bool {
        !self.realtime && matches!(self.transport, Transport::Sim | Transport::Replay(_))
    }
}

/// A kick: simulated robot `robot` (by id) is moved by (`dx_m`, `dy_m`) and turned by
/// `dtheta_rad` at `at`, as [`KickHow`] says: at once and unfelt (picked up and put down), or
/// by a shove its sensors feel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Kick {
    /// Robot id.
    pub robot: u16,
    /// When, after the robots are connected.
    pub at: Duration,
    /// Displacement along x, metres.
    pub dx_m: f64,
    /// Displacement along y, metres.
    pub dy_m: f64,
    /// Turn, radians counter-clockwise.
    pub dtheta_rad: f64,
    /// Further displacement to the robot's left (negative: right) at the moment of the kick,
    /// metres: a sideways shove whatever way the robot faces then.
    pub sideways_m: f64,
    /// Teleport or shove.
    pub how: KickHow,
    /// Drawn at random: the displacement is drawn at the kick's instant from this seed (a shift
    /// and a turn clear of every other body and wall), and the fields above are ignored.
    pub drawn: Option<u64>,
}

impl From<world::cli::KickArg> for Kick {
    /// The kick `--kick [HOW:]ID:SECONDS:DX,DY[,DEG]` gives (no sideways shove).
    fn from(k: world::cli::KickArg) -> Self {
        Self {
            robot: k.robot,
            at: k.at,
            dx_m: k.dx_m,
            dy_m: k.dy_m,
            dtheta_rad: k.dtheta_rad,
            sideways_m: 0.0,
            how: k.how,
            drawn: None,
        }
    }
}

impl Kick {
    /// The kick `random` draws for a run with `seed` among `robots` (ids): which robot and when;
    /// its displacement is drawn at that instant.
    pub fn random(r: RandomKick, seed: u64, robots: &[u16]) -> Option<Kick> {
        use rand::Rng;
        let (mut rng, robot, at) =
            draw_robot_and_time(seed ^ 0x4B1C_4B1C_4B1C_4B1C, robots, r.within)?;
        Some(Kick {
            robot,
            at,
            dx_m: 0.0,
            dy_m: 0.0,
            dtheta_rad: 0.0,
            sideways_m: 0.0,
            how: r.how,
            drawn: Some(rng.gen()),
        })
    }
}

/// The fault `random:KIND` draws for a run with `seed` among `robots` (ids): which robot and
/// when, from one second to the fault's window.
pub fn random_fault(r: RandomFault, seed: u64, robots: &[u16]) -> Option<FaultSpec> {
    let (_, robot, at) = draw_robot_and_time(seed ^ 0xFA17_FA17_FA17_FA17, robots, r.within)?;
    Some(FaultSpec {
        kind: r.kind,
        robot,
        at,
        lasting: r.lasting,
    })
}

/// One of `robots` and a time from one second to `within`, drawn from `seed`, with the stream for
/// any further draws; `None` when there are no robots.
fn draw_robot_and_time(
    seed: u64,
    robots: &[u16],
    within: Duration,
) -> Option<(rand_chacha::ChaCha8Rng, u16, Duration)> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let robot = *robots.get(rng.gen_range(0..robots.len().max(1)))?;
    let from = 1.0;
    let at = Duration::from_secs_f64(rng.gen_range(from..within.as_secs_f64().max(from + 1e-3)));
    Some((rng, robot, at))
}

/// Loads a preset by name or a world file by path.
pub fn load_world(name: &str) -> Result<World> {
    if let Some(w) = presets::preset(name) {
        return Ok(w);
    }
    if let Some(spec) = name.strip_prefix("grid:") {
        // `grid:COLSxROWS:ROBOTS`, a generated warehouse lattice.
        let parsed = spec.split_once(':').and_then(|(size, robots)| {
            let (c, r) = size.split_once('x')?;
            Some((c.parse().ok()?, r.parse().ok()?, robots.parse().ok()?))
        });
        let Some((cols, rows, robots)) = parsed else {
            bail!("world {name:?}: expected grid:COLSxROWS:ROBOTS, e.g. grid:12x8:50");
        };
        return presets::grid_exact(cols, rows, robots).map_err(|e| anyhow!("world {name:?}: {e}"));
    }
    if let Some(robots) = name.strip_prefix("serpentine:") {
        // `serpentine:ROBOTS`, one generated loop for line following at scale.
        return match robots.parse::<usize>() {
            Ok(n) if (1..=world::MAX_ROBOTS).contains(&n) => Ok(presets::serpentine(n)),
            _ => bail!(
                "world {name:?}: expected serpentine:ROBOTS with 1 to {} robots, e.g. \
                 serpentine:500",
                world::MAX_ROBOTS
            ),
        };
    }
    if name.ends_with(".toml") || std::path::Path::new(name).exists() {
        return file::load(name).map_err(|e| anyhow!("{e}"));
    }
    bail!(
        "unknown world {name:?}: not a preset ({}) nor a .toml file",
        presets::preset_names().join(", ")
    )
}
