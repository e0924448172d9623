//! `coordinator sweep`: a batch of independent, deterministic experiments over the cross product of
//! seeds, worlds, robot counts and behaviour parameters, each run a child process of this binary;
//! results are appended as JSON Lines as runs end, so a sweep resumes, shards and merges, and a
//! summary gives each combination's success rate (Wilson 95 % interval) and metric statistics.
//!
//! - `runner`: the worker pool of child runs, progress, resume and shards.
//! - `store`: the results and timing files (JSON Lines).
//! - `summary`: per-combination statistics, failure reasons, `summary.md` and `summary.csv`.
//! - `plots`: success rate against each swept coordinate, and metric histograms, as SVG.

pub mod plots;
pub mod runner;
pub mod store;
pub mod summary;

use std::collections::BTreeSet;
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};

pub use runner::{merge, sweep, Options};

/// `coordinator sweep`: the arguments of a sweep, or its `merge` subcommand.
#[derive(clap::Args, Debug)]
#[command(
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true,
    after_help = "Examples:\n  coordinator sweep --behaviour line_follow --seeds 1..100 --param laps=1,2,3 --out sweep-laps\n  coordinator sweep --behaviour traffic_control --seeds 1..50 --robots 4,8 --shard 2/4 --record-failures --out traffic\n  coordinator sweep merge traffic-1 traffic-2 --out traffic"
)]
pub struct SweepCommand {
    /// The sweep.
    #[command(flatten)]
    pub args: SweepArgs,
    /// `merge`, instead of running a sweep.
    #[command(subcommand)]
    pub command: Option<SweepSub>,
}

/// A sweep's arguments.
#[derive(clap::Args, Debug)]
pub struct SweepArgs {
    /// The behaviour every run runs.
    #[arg(long, required = true)]
    pub behaviour: Option<String>,
    /// Seeds: inclusive ranges and single seeds, comma-separated (`1..100`, `1,5,9`, `1..3,10`).
    #[arg(long, required = true)]
    pub seeds: Option<String>,
    /// A behaviour parameter and its values, `key=v1,v2,v3` (repeatable).
    #[arg(long = "param", value_name = "KEY=V1,V2")]
    pub params: Vec<String>,
    /// Worlds to run in, comma-separated or repeated (default: the behaviour's own).
    #[arg(long = "world", value_name = "W1,W2")]
    pub worlds: Vec<String>,
    /// Numbers of simulated robots, comma-separated or repeated (default: the world's own).
    #[arg(long = "robots", value_name = "N1,N2")]
    pub robots: Vec<String>,
    /// Physics rates of the simulated robots in Hz, comma-separated or repeated (1000, 500, 250,
    /// 200; default: the coordinator's).
    #[arg(long = "physics-hz", value_name = "HZ1,HZ2")]
    pub physics_hz: Vec<String>,
    /// A kick to try, as `coordinator --kick` takes it (several in one run joined by `+`, `none`
    /// for none); repeat the flag for more values.
    #[arg(long = "kick", value_name = "ID:SECONDS:DX,DY[,DEG]")]
    pub kicks: Vec<String>,
    /// A fault to try, as `coordinator --fault` takes it (several in one run joined by `+`,
    /// `none` for none); repeat the flag for more values.
    #[arg(long = "fault", value_name = "KIND:ID:SECONDS[:FOR[:AMOUNT]]")]
    pub faults: Vec<String>,
    /// Each run's time limit in simulated seconds (default: the coordinator's).
    #[arg(long, value_parser = world::cli::parse_seconds, allow_negative_numbers = true)]
    pub duration: Option<f64>,
    /// Runs at a time (default: the number of cores; with --realtime, 8 per core, since a run
    /// paced to the wall clock mostly waits).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Pace every run to the wall clock (`coordinator --realtime`) instead of lockstep.
    #[arg(long)]
    pub realtime: bool,
    /// Every run's simulated links follow this profile or file (`coordinator --link-profile`).
    #[arg(long = "link-profile", value_name = "NAME|FILE", value_parser = world::cli::parse_link_profile)]
    pub link_profile: Option<world::cli::LinkProfileArg>,
    /// Keep N threads busy beside the sweep's runs for its whole length, standing for other
    /// programs on a loaded host.
    #[arg(long = "host-load", value_name = "N", default_value_t = 0)]
    pub host_load: usize,
    /// Run only every N-th run, starting at the K-th (`K/N`), to split a sweep between machines.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<String>,
    /// Keep an MCAP recording of each failed run in DIR/failures (for `coordinator replay`).
    #[arg(long)]
    pub record_failures: bool,
    /// The sweep's directory: run reports, logs, results.jsonl and the summary.
    #[arg(long, value_name = "DIR", required = true)]
    pub out: Option<PathBuf>,
}

/// `coordinator sweep merge`.
#[derive(clap::Subcommand, Debug)]
pub enum SweepSub {
    /// Combine the results of sweep directories (shards of one sweep) and summarise them.
    Merge {
        /// The directories to merge.
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        /// Where the merged results and summary go.
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
    },
}

/// Runs `coordinator sweep …` over the built-in behaviours, each run a child process of this
/// binary; `Ok(true)` once every run of the sweep (or shard) has a result.
///
/// # Errors
/// Bad arguments, an unknown behaviour, a directory holding another sweep, or files that cannot
/// be written.
pub fn main(cmd: &SweepCommand) -> Result<bool> {
    if let Some(SweepSub::Merge { dirs, out }) = &cmd.command {
        merge(dirs, out)?;
        return Ok(true);
    }
    let a = &cmd.args;
    let definition = Definition::from_args(a)?;
    // Every run would fail the same way: say so once instead.
    let mut registry = behaviours::Registry::builtin();
    crate::instruments::panel::register_teleop(&mut registry);
    let Some(entry) = registry.get(&definition.behaviour) else {
        bail!(
            "unknown behaviour {:?}; known: {}",
            definition.behaviour,
            registry.names().join(", ")
        );
    };
    // Each parameter value alone against the behaviour's declaration: a key it does not take or
    // a value it refuses would fail every run of the sweep.
    for (key, values) in &definition.params {
        for value in values {
            entry
                .check_params(&[(key.clone(), value.clone())].into())
                .map_err(|e| anyhow::anyhow!("--param {key}={value}: {e}"))?;
        }
    }
    let shard = a.shard.as_deref().map(parse_shard).transpose()?;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let jobs = match a.jobs {
        Some(0) => bail!("--jobs must be at least 1"),
        Some(n) => n,
        None if a.realtime => 8 * cores,
        None => cores,
    };
    let options = Options {
        out: a.out.clone().context("--out is required")?,
        jobs,
        shard,
        record_failures: a.record_failures,
        exe: std::env::current_exe().context("finding this program to run each experiment")?,
    };
    let _load = crate::experiment::HostLoad::start(a.host_load);
    sweep(&definition, &options)?;
    Ok(true)
}

/// What a sweep is: the lists whose cross product is its set of runs. Stored as DIR/sweep.json.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Definition {
    /// The behaviour.
    pub behaviour: String,
    /// Worlds (empty: the behaviour's own).
    pub worlds: Vec<String>,
    /// Robot counts (empty: the world's own).
    pub robots: Vec<usize>,
    /// Physics rates, Hz (empty: the coordinator's default). Sweeps written before it read empty.
    #[serde(default)]
    pub physics_hz: Vec<u32>,
    /// Kicks, each as `coordinator --kick` takes it, several joined by `+`, or `none` (empty: no
    /// kick). Sweeps written before it read empty.
    #[serde(default)]
    pub kicks: Vec<String>,
    /// Faults, each as `coordinator --fault` takes it, several joined by `+`, or `none` (empty:
    /// no fault). Sweeps written before it read empty.
    #[serde(default)]
    pub faults: Vec<String>,
    /// Behaviour parameters and their values, in the order given.
    pub params: Vec<(String, Vec<String>)>,
    /// Seeds, in the order given.
    pub seeds: Vec<u64>,
    /// Each run's time limit, simulated seconds (none: the coordinator's default).
    pub duration_s: Option<f64>,
    /// Every run paced to the wall clock. Sweeps written before it read lockstep.
    #[serde(default)]
    pub realtime: bool,
    /// Every run's link profile, as given (none: the world's `[link]`).
    #[serde(default)]
    pub link_profile: Option<String>,
    /// Busy threads beside the sweep.
    #[serde(default)]
    pub host_load: usize,
}

/// One run of a sweep: its coordinates.
#[derive(Clone, Debug, PartialEq)]
pub struct RunSpec {
    /// Place in the sweep's fixed run order.
    pub index: usize,
    /// World, when the sweep lists worlds.
    pub world: Option<String>,
    /// Robot count, when the sweep lists them.
    pub robots: Option<usize>,
    /// Physics rate in Hz, when the sweep lists rates.
    pub physics_hz: Option<u32>,
    /// Kicks, when the sweep lists them.
    pub kick: Option<String>,
    /// Faults, when the sweep lists them.
    pub fault: Option<String>,
    /// Parameter values, in the sweep's parameter order.
    pub params: Vec<(String, String)>,
    /// Seed.
    pub seed: u64,
}

impl RunSpec {
    /// Every coordinate but the seed, as `key=value` pairs in the sweep's order.
    pub fn coordinates(&self) -> Vec<(String, String)> {
        let mut c = Vec::new();
        if let Some(w) = &self.world {
            c.push(("world".to_string(), w.clone()));
        }
        if let Some(n) = self.robots {
            c.push(("robots".to_string(), n.to_string()));
        }
        if let Some(hz) = self.physics_hz {
            c.push(("physics_hz".to_string(), hz.to_string()));
        }
        if let Some(k) = &self.kick {
            c.push(("kick".to_string(), k.clone()));
        }
        if let Some(f) = &self.fault {
            c.push(("fault".to_string(), f.clone()));
        }
        c.extend(self.params.iter().cloned());
        c
    }

    /// The combination this run belongs to: its coordinates but the seed (`all` when none).
    pub fn combination(&self) -> String {
        combination_key(&self.coordinates())
    }

    /// The run's stable, readable id, e.g. `world=junction,robots=8,laps=2,seed=7`.
    pub fn id(&self) -> String {
        let mut parts: Vec<String> = self
            .coordinates()
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect();
        parts.push(format!("seed={}", self.seed));
        parts.join(",")
    }

    /// The id made safe as a file name (a world given as a path keeps only harmless characters).
    pub fn file_stem(&self) -> String {
        file_stem(&self.id())
    }
}

/// A combination's key from its coordinates.
pub fn combination_key(coordinates: &[(String, String)]) -> String {
    if coordinates.is_empty() {
        return "all".to_string();
    }
    coordinates
        .iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect::<Vec<_>>()
        .join(",")
}

/// A run id as a file name.
pub fn file_stem(id: &str) -> String {
    id.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "=,.-_+".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}

impl Definition {
    /// The definition from the command line.
    ///
    /// # Errors
    /// An empty or malformed list or a duplicate, named.
    pub fn from_args(a: &SweepArgs) -> Result<Self> {
        let behaviour = a.behaviour.clone().context("--behaviour is required")?;
        let seeds = parse_seeds(a.seeds.as_deref().context("--seeds is required")?)?;
        let mut params: Vec<(String, Vec<String>)> = Vec::new();
        for p in &a.params {
            let (k, vs) = parse_param_list(p)?;
            if params.iter().any(|(q, _)| *q == k) {
                bail!("--param {k}: the parameter is given twice; list its values in one --param {k}=v1,v2");
            }
            params.push((k, vs));
        }
        let worlds = parse_list("--world", &a.worlds)?;
        let robots = parse_list("--robots", &a.robots)?
            .iter()
            .map(|s| match s.parse::<usize>() {
                Ok(n) if n > 0 => Ok(n),
                _ => bail!("--robots {s:?}: expected a number of simulated robots (1 or more)"),
            })
            .collect::<Result<Vec<_>>>()?;
        let physics_hz = parse_list("--physics-hz", &a.physics_hz)?
            .iter()
            .map(|s| {
                world::cli::parse_physics_hz(s)
                    .map(|every| 1000 / every)
                    .map_err(|e| anyhow::anyhow!("--physics-hz {s:?}: {e}"))
            })
            .collect::<Result<Vec<_>>>()?;
        let kicks = parse_joined("--kick", &a.kicks, |k| world::cli::parse_kick(k).map(drop))?;
        let faults = parse_joined("--fault", &a.faults, |f| {
            world::faults::parse_fault(f).map(drop)
        })?;
        Ok(Self {
            behaviour,
            worlds,
            robots,
            physics_hz,
            kicks,
            faults,
            params,
            seeds,
            duration_s: a.duration,
            realtime: a.realtime,
            link_profile: a.link_profile.as_ref().map(|l| l.name.clone()),
            host_load: a.host_load,
        })
    }

    /// How every run is paced and loaded, in words: `lockstep`, or `wall clock`, with the link
    /// profile and host load when given.
    pub fn conditions(&self) -> String {
        let mut c = vec![if self.realtime {
            "wall clock"
        } else {
            "lockstep"
        }
        .to_string()];
        c.extend(self.link_profile.as_ref().map(|l| format!("link {l}")));
        if self.host_load > 0 {
            c.push(format!("host load {}", self.host_load));
        }
        c.join(", ")
    }

    /// The coordinates swept (with more than one value), in order; the seed is not one.
    pub fn swept(&self) -> Vec<(String, Vec<String>)> {
        let mut s = Vec::new();
        if self.worlds.len() > 1 {
            s.push(("world".to_string(), self.worlds.clone()));
        }
        if self.robots.len() > 1 {
            s.push((
                "robots".to_string(),
                self.robots.iter().map(ToString::to_string).collect(),
            ));
        }
        if self.physics_hz.len() > 1 {
            s.push((
                "physics_hz".to_string(),
                self.physics_hz.iter().map(ToString::to_string).collect(),
            ));
        }
        if self.kicks.len() > 1 {
            s.push(("kick".to_string(), self.kicks.clone()));
        }
        if self.faults.len() > 1 {
            s.push(("fault".to_string(), self.faults.clone()));
        }
        s.extend(self.params.iter().filter(|(_, v)| v.len() > 1).cloned());
        s
    }

    /// Every run, in the sweep's fixed order: worlds, robot counts, physics rates, kicks, then
    /// parameters in the order given, the seed varying fastest.
    pub fn runs(&self) -> Vec<RunSpec> {
        let worlds: Vec<Option<String>> = if self.worlds.is_empty() {
            vec![None]
        } else {
            self.worlds.iter().cloned().map(Some).collect()
        };
        let robots: Vec<Option<usize>> = if self.robots.is_empty() {
            vec![None]
        } else {
            self.robots.iter().copied().map(Some).collect()
        };
        let rates: Vec<Option<u32>> = if self.physics_hz.is_empty() {
            vec![None]
        } else {
            self.physics_hz.iter().copied().map(Some).collect()
        };
        let kicks: Vec<Option<String>> = if self.kicks.is_empty() {
            vec![None]
        } else {
            self.kicks.iter().cloned().map(Some).collect()
        };
        let faults: Vec<Option<String>> = if self.faults.is_empty() {
            vec![None]
        } else {
            self.faults.iter().cloned().map(Some).collect()
        };
        let mut combos: Vec<Vec<(String, String)>> = vec![Vec::new()];
        for (k, vs) in &self.params {
            combos = combos
                .into_iter()
                .flat_map(|c| {
                    vs.iter().map(move |v| {
                        let mut c = c.clone();
                        c.push((k.clone(), v.clone()));
                        c
                    })
                })
                .collect();
        }
        let mut runs = Vec::new();
        for w in &worlds {
            for n in &robots {
                for hz in &rates {
                    for (kick, fault) in kicks
                        .iter()
                        .flat_map(|k| faults.iter().map(move |f| (k, f)))
                    {
                        for c in &combos {
                            for &seed in &self.seeds {
                                runs.push(RunSpec {
                                    index: runs.len(),
                                    world: w.clone(),
                                    robots: *n,
                                    physics_hz: *hz,
                                    kick: kick.clone(),
                                    fault: fault.clone(),
                                    params: c.clone(),
                                    seed,
                                });
                            }
                        }
                    }
                }
            }
        }
        runs
    }
}

/// Parses seeds: inclusive ranges `A..B` and single seeds, comma-separated.
///
/// # Errors
/// An empty list, an empty or reversed range, a bad number, or a seed listed twice.
pub fn parse_seeds(s: &str) -> Result<Vec<u64>> {
    let mut seeds = Vec::new();
    let mut seen = BTreeSet::new();
    for part in s.split(',').map(str::trim) {
        let num = |t: &str| {
            t.trim()
                .parse::<u64>()
                .with_context(|| format!("--seeds {s:?}: {t:?} is not a seed (a whole number)"))
        };
        let (a, b) = match part.split_once("..") {
            Some((a, b)) => (num(a)?, num(b.strip_prefix('=').unwrap_or(b))?),
            None => {
                let n = num(part)?;
                (n, n)
            }
        };
        if a > b {
            bail!("--seeds {s:?}: the range {part} is empty (ranges are A..B with A <= B, both included)");
        }
        if b - a >= 10_000_000 {
            bail!("--seeds {s:?}: the range {part} is too long for one sweep");
        }
        for seed in a..=b {
            if !seen.insert(seed) {
                bail!("--seeds {s:?}: seed {seed} is listed twice");
            }
            seeds.push(seed);
        }
    }
    Ok(seeds)
}

/// Checks the values of a repeated `flag` whose value is several of one thing joined by `+`
/// (or `none`), each part by `parse`.
///
/// # Errors
/// A part `parse` refuses, or a value given twice.
fn parse_joined(
    flag: &str,
    values: &[String],
    parse: impl Fn(&str) -> std::result::Result<(), String>,
) -> Result<Vec<String>> {
    let mut out: Vec<String> = Vec::new();
    for v in values {
        let v = v.trim();
        if v != "none" {
            for part in v.split('+') {
                parse(part.trim()).map_err(|e| anyhow::anyhow!("{flag} {v:?}: {e}"))?;
            }
        }
        if out.iter().any(|q| q == v) {
            bail!("{flag} {v:?} is given twice");
        }
        out.push(v.to_string());
    }
    Ok(out)
}

/// Parses `key=v1,v2,…`.
///
/// # Errors
/// No `=`, an empty key or value, a reserved key, or a value listed twice.
pub fn parse_param_list(s: &str) -> Result<(String, Vec<String>)> {
    let (k, vs) = s
        .split_once('=')
        .with_context(|| format!("--param {s:?}: expected key=v1,v2,…"))?;
    let k = k.trim();
    if k.is_empty() {
        bail!("--param {s:?}: the key is empty");
    }
    if ["seed", "world", "robots", "physics_hz", "kick", "fault"].contains(&k) {
        let flag = match k {
            "seed" => "seeds",
            "physics_hz" => "physics-hz",
            k => k,
        };
        bail!("--param {s:?}: {k} is not a behaviour parameter; use --{flag}");
    }
    let values = parse_list(&format!("--param {k}"), &[vs.to_string()])?;
    Ok((k.to_string(), values))
}

/// Splits repeated, comma-separated values.
fn parse_list(flag: &str, items: &[String]) -> Result<Vec<String>> {
    let mut out: Vec<String> = Vec::new();
    for item in items {
        for v in item.split(',').map(str::trim) {
            if v.is_empty() {
                bail!("{flag} {item:?}: an empty value");
            }
            if out.iter().any(|o| o == v) {
                bail!("{flag}: {v:?} is listed twice");
            }
            out.push(v.to_string());
        }
    }
    Ok(out)
}

/// Parses `K/N` (1 ≤ K ≤ N) into (K, N).
///
/// # Errors
/// Not two numbers, or K outside 1..=N.
pub fn parse_shard(s: &str) -> Result<(usize, usize)> {
    let (k, n) = s
        .split_once('/')
        .with_context(|| format!("--shard {s:?}: expected K/N, e.g. 2/4"))?;
    let (k, n) = match (k.trim().parse::<usize>(), n.trim().parse::<usize>()) {
        (Ok(k), Ok(n)) => (k, n),
        _ => bail!("--shard {s:?}: expected K/N with whole numbers, e.g. 2/4"),
    };
    if n == 0 || k == 0 || k > n {
        bail!("--shard {s:?}: K must be between 1 and N (shard K of N)");
    }
    Ok((k, n))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeds_take_ranges_and_lists() {
        assert_eq!(parse_seeds("1..3").unwrap(), vec![1, 2, 3]);
        assert_eq!(parse_seeds("1,5,9").unwrap(), vec![1, 5, 9]);
        assert_eq!(parse_seeds("1..3,10").unwrap(), vec![1, 2, 3, 10]);
        assert_eq!(parse_seeds("7").unwrap(), vec![7]);
        assert_eq!(parse_seeds("1..=2").unwrap(), vec![1, 2]);
        assert_eq!(parse_seeds("1..100").unwrap().len(), 100);
    }

    #[test]
    fn bad_seeds_are_named() {
        let e = parse_seeds("5..1").unwrap_err().to_string();
        assert!(e.contains("5..1") && e.contains("empty"), "{e}");
        let e = parse_seeds("1..3,2").unwrap_err().to_string();
        assert!(e.contains("seed 2 is listed twice"), "{e}");
        let e = parse_seeds("a").unwrap_err().to_string();
        assert!(e.contains("\"a\" is not a seed"), "{e}");
        assert!(parse_seeds("").is_err());
        assert!(parse_seeds("1,,2").is_err());
    }

    #[test]
    fn params_and_shards_parse_or_are_named() {
        assert_eq!(
            parse_param_list("laps=1,2, 3").unwrap(),
            ("laps".into(), vec!["1".into(), "2".into(), "3".into()])
        );
        assert!(parse_param_list("laps").is_err());
        assert!(parse_param_list("laps=1,1").is_err());
        assert!(parse_param_list("seed=1")
            .unwrap_err()
            .to_string()
            .contains("--seeds"));
        assert_eq!(parse_shard("2/4").unwrap(), (2, 4));
        assert!(parse_shard("3/2")
            .unwrap_err()
            .to_string()
            .contains("between 1 and N"));
        assert!(parse_shard("0/2").is_err());
        assert!(parse_shard("2").is_err());
    }

    #[test]
    fn runs_are_the_cross_product_with_stable_ids() {
        let d = Definition {
            behaviour: "line_follow".into(),
            worlds: vec!["oval".into(), "ring".into()],
            robots: vec![],
            physics_hz: vec![],
            kicks: vec![],
            faults: vec![],
            params: vec![("laps".into(), vec!["1".into(), "2".into()])],
            seeds: vec![3, 4, 5],
            duration_s: None,
            realtime: false,
            link_profile: None,
            host_load: 0,
        };
        let runs = d.runs();
        assert_eq!(runs.len(), 12);
        assert_eq!(runs[0].id(), "world=oval,laps=1,seed=3");
        assert_eq!(runs[4].id(), "world=oval,laps=2,seed=4");
        assert_eq!(runs[11].id(), "world=ring,laps=2,seed=5");
        assert_eq!(runs[11].combination(), "world=ring,laps=2");
        assert!(runs.iter().enumerate().all(|(i, r)| r.index == i));
        assert_eq!(d.swept().len(), 2);
        let w = RunSpec {
            world: Some("maps/a b.toml".into()),
            ..runs[0].clone()
        };
        assert_eq!(w.file_stem(), "world=maps_a_b.toml,laps=1,seed=3");
    }

    #[test]
    fn physics_rates_are_a_coordinate_between_robots_and_parameters() {
        let d = Definition {
            behaviour: "square_walk".into(),
            worlds: vec![],
            robots: vec![2],
            physics_hz: vec![1000, 500],
            kicks: vec![],
            faults: vec![],
            params: vec![("side".into(), vec!["0.1".into()])],
            seeds: vec![1, 2],
            duration_s: None,
            realtime: false,
            link_profile: None,
            host_load: 0,
        };
        let ids: Vec<String> = d.runs().iter().map(RunSpec::id).collect();
        assert_eq!(
            ids,
            [
                "robots=2,physics_hz=1000,side=0.1,seed=1",
                "robots=2,physics_hz=1000,side=0.1,seed=2",
                "robots=2,physics_hz=500,side=0.1,seed=1",
                "robots=2,physics_hz=500,side=0.1,seed=2",
            ]
        );
        assert_eq!(
            d.swept(),
            [("physics_hz".to_string(), vec!["1000".into(), "500".into()])]
        );
        assert!(parse_param_list("physics_hz=500")
            .unwrap_err()
            .to_string()
            .contains("--physics-hz"));
        // A sweep stored before rates could be swept reads as one at the default rate.
        let mut old = serde_json::to_value(&d).unwrap();
        old.as_object_mut().unwrap().remove("physics_hz");
        let old: Definition = serde_json::from_value(old).unwrap();
        assert!(old.physics_hz.is_empty());
        assert_eq!(old.runs().len(), 2);
    }

    /// A sweep of `behaviour` over `seeds` with these kicks and faults, everything else default.
    fn disturbed(behaviour: &str, seeds: &str, kicks: &[&str], faults: &[&str]) -> SweepArgs {
        let own = |v: &[&str]| v.iter().map(|k| k.to_string()).collect();
        SweepArgs {
            behaviour: Some(behaviour.into()),
            seeds: Some(seeds.into()),
            params: vec![],
            worlds: vec![],
            robots: vec![],
            physics_hz: vec![],
            kicks: own(kicks),
            faults: own(faults),
            duration: None,
            jobs: None,
            shard: None,
            record_failures: false,
            realtime: false,
            link_profile: None,
            host_load: 0,
            out: None,
        }
    }

    #[test]
    fn kicks_are_a_coordinate_checked_before_any_run() {
        let args = |kicks: &[&str]| disturbed("token_ring", "1..2", kicks, &[]);
        let d = Definition::from_args(&args(&["none", "2:5:0.05,0", "1:3:0,0.02+3:8:0.01,0,10"]))
            .unwrap();
        let ids: Vec<String> = d.runs().iter().map(RunSpec::id).collect();
        assert_eq!(
            ids,
            [
                "kick=none,seed=1",
                "kick=none,seed=2",
                "kick=2:5:0.05,0,seed=1",
                "kick=2:5:0.05,0,seed=2",
                "kick=1:3:0,0.02+3:8:0.01,0,10,seed=1",
                "kick=1:3:0,0.02+3:8:0.01,0,10,seed=2",
            ]
        );
        assert_eq!(d.swept()[0].0, "kick");
        let bad = Definition::from_args(&args(&["2:5:0.05"])).unwrap_err();
        assert!(bad.to_string().contains("--kick"), "{bad}");
        assert!(Definition::from_args(&args(&["none", "none"])).is_err());
        assert!(parse_param_list("kick=1").is_err());
    }

    #[test]
    fn faults_are_a_coordinate_after_kicks_checked_before_any_run() {
        let mut a = disturbed(
            "line_follow",
            "1",
            &["none", "random"],
            &["none", "random:cut:2+reboot:1:5"],
        );
        let d = Definition::from_args(&a).unwrap();
        let ids: Vec<String> = d.runs().iter().map(RunSpec::id).collect();
        assert_eq!(
            ids,
            [
                "kick=none,fault=none,seed=1",
                "kick=none,fault=random:cut:2+reboot:1:5,seed=1",
                "kick=random,fault=none,seed=1",
                "kick=random,fault=random:cut:2+reboot:1:5,seed=1",
            ]
        );
        a.faults = vec!["latency:1:2:3:5".into()];
        let bad = Definition::from_args(&a).unwrap_err().to_string();
        assert!(
            bad.contains("--fault") && bad.contains("at most 2"),
            "{bad}"
        );
        assert!(parse_param_list("fault=1").is_err());
    }
}
