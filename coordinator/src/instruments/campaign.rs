//! `coordinator campaign`: every fault kind against every built-in behaviour over many seeds, one
//! sweep per behaviour (its fault the swept coordinate, a robot and a time drawn per seed), and a
//! table of what happened: verdicts, contacts, the longest a robot cut off from its host kept
//! driving, and whether every run ended with a verdict of its own before its time limit.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{bail, Context, Result};

use crate::instruments::sweep::store::{self, RunResult};
use crate::instruments::sweep::summary::{normalise, wilson};
use crate::instruments::sweep::{parse_seeds, Definition, Options};

/// The faults a campaign tries unless told otherwise, as `--fault` takes them: what the issue of
/// a lab's radio links and robots looks like, each drawn per seed onto one robot at a time from
/// 1 to 30 s.
pub const DEFAULT_FAULTS: [&str; 9] = [
    "random:cut:2",
    "random:cut:20",
    "random:loss:3",
    "random:loss:10:0.3",
    "random:latency:5:1.5",
    "random:corrupt:10:0.2",
    "random:duplicate:10:0.3",
    "random:reorder:10:0.3",
    "random:reboot",
];

/// The built-ins a campaign runs unless told otherwise.
pub const DEFAULT_BEHAVIOURS: [&str; 5] = [
    "cooperative_push",
    "line_follow",
    "square_walk",
    "token_ring",
    "traffic_control",
];

/// A robot cut off from its host must stand within its watchdog (500 ms by default) and the time
/// its wheels take to coast to a stop once the watchdog cuts their power (up to 240 ms measured
/// in the built-ins' runs): the bound the table checks, seconds.
pub const UNATTENDED_BOUND_S: f64 = 0.5 + 0.25;

/// `coordinator campaign`'s arguments.
#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example:\n  coordinator campaign --seeds 1..20 --out campaign --doc docs/faults.md"
)]
pub struct CampaignArgs {
    /// Seeds of every fault × behaviour (`1..20`, as `sweep --seeds` takes them).
    #[arg(long)]
    pub seeds: String,
    /// Behaviours, comma-separated (default: every built-in).
    #[arg(long, value_delimiter = ',')]
    pub behaviours: Vec<String>,
    /// Faults, as `--fault` takes them (repeatable; default: every kind, drawn per seed).
    #[arg(long = "fault")]
    pub faults: Vec<String>,
    /// Runs at a time (default: the number of cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Each run's time limit in simulated seconds (default: the coordinator's).
    #[arg(long, value_parser = world::cli::parse_seconds)]
    pub duration: Option<f64>,
    /// The campaign's directory: one sweep per behaviour, and `faults.md`.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Also write the table to this file (e.g. docs/faults.md).
    #[arg(long, value_name = "FILE")]
    pub doc: Option<PathBuf>,
}

/// Runs the campaign and writes its table; `Ok(true)` when every rule it checks held.
///
/// # Errors
/// Bad arguments, or a sweep that cannot run or be read.
pub fn main(a: &CampaignArgs) -> Result<bool> {
    let behaviours: Vec<String> = if a.behaviours.is_empty() {
        DEFAULT_BEHAVIOURS.iter().map(|b| b.to_string()).collect()
    } else {
        a.behaviours.clone()
    };
    let registry = behaviours::Registry::builtin();
    for b in &behaviours {
        if registry.get(b).is_none() {
            bail!(
                "--behaviours: unknown behaviour {b:?}; known: {}",
                registry.names().join(", ")
            );
        }
    }
    let faults: Vec<String> = if a.faults.is_empty() {
        DEFAULT_FAULTS.iter().map(|f| f.to_string()).collect()
    } else {
        a.faults.clone()
    };
    for f in &faults {
        world::faults::parse_fault(f).map_err(|e| anyhow::anyhow!("--fault {f:?}: {e}"))?;
    }
    let seeds = parse_seeds(&a.seeds)?;
    let jobs = match a.jobs {
        Some(0) => bail!("--jobs must be at least 1"),
        Some(n) => n,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    let exe = std::env::current_exe().context("finding this program to run each experiment")?;
    let mut rows = Vec::new();
    for b in &behaviours {
        let definition = Definition {
            behaviour: b.clone(),
            worlds: Vec::new(),
            robots: Vec::new(),
            physics_hz: Vec::new(),
            kicks: Vec::new(),
            faults: faults.clone(),
            params: Vec::new(),
            seeds: seeds.clone(),
            duration_s: a.duration,
            realtime: false,
            link_profile: None,
            host_load: 0,
        };
        let dir = a.out.join(b);
        let options = Options {
            out: dir.clone(),
            jobs,
            shard: None,
            record_failures: false,
            exe: exe.clone(),
        };
        crate::instruments::sweep::sweep(&definition, &options)?;
        let ids: std::collections::BTreeSet<String> =
            definition.runs().iter().map(|r| r.id()).collect();
        let results: Vec<RunResult> = store::read_lines(&dir.join("results.jsonl"))?
            .into_iter()
            .filter(|r: &RunResult| ids.contains(&r.id))
            .collect();
        for f in &faults {
            let of: Vec<&RunResult> = results
                .iter()
                .filter(|r| r.fault.as_deref() == Some(f.as_str()))
                .collect();
            rows.push(Row::of(b, f, &of));
        }
    }
    let table = render(&rows, &seeds, &a.seeds);
    let path = a.out.join("faults.md");
    std::fs::write(&path, &table).with_context(|| format!("writing {}", path.display()))?;
    if let Some(doc) = &a.doc {
        std::fs::write(doc, &table).with_context(|| format!("writing {}", doc.display()))?;
    }
    println!("{table}");
    Ok(rows.iter().all(Row::rules_hold))
}

/// One fault × behaviour.
struct Row {
    behaviour: String,
    fault: String,
    runs: usize,
    successes: usize,
    /// Runs whose fault landed before the run ended.
    landed: usize,
    contact_runs: usize,
    /// Runs that ended on the time limit, or came to no verdict at all.
    no_verdict: usize,
    longest_unattended_s: f64,
    /// The commonest failure verdicts, with how many runs gave each.
    verdicts: Vec<(String, usize)>,
}

impl Row {
    fn of(behaviour: &str, fault: &str, runs: &[&RunResult]) -> Row {
        let mut verdicts: BTreeMap<String, usize> = BTreeMap::new();
        for r in runs.iter().filter(|r| !r.success()) {
            *verdicts.entry(normalise(&r.summary)).or_default() += 1;
        }
        let mut verdicts: Vec<(String, usize)> = verdicts.into_iter().collect();
        verdicts.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        verdicts.truncate(2);
        Row {
            behaviour: behaviour.to_string(),
            fault: fault.to_string(),
            runs: runs.len(),
            successes: runs.iter().filter(|r| r.success()).count(),
            landed: runs.iter().filter(|r| !r.faults_landed.is_empty()).count(),
            contact_runs: runs.iter().filter(|r| r.contacts() > 0).count(),
            no_verdict: runs
                .iter()
                .filter(|r| {
                    r.outcome == store::Outcome::Error
                        || r.summary.contains("did not finish within")
                })
                .count(),
            longest_unattended_s: runs
                .iter()
                .filter_map(|r| r.longest_unattended_s)
                .fold(0.0, f64::max),
            verdicts,
        }
    }

    /// No contact, every cut-off robot stopped within its watchdog, every run a verdict of its
    /// own.
    fn rules_hold(&self) -> bool {
        self.contact_runs == 0
            && self.longest_unattended_s <= UNATTENDED_BOUND_S
            && self.no_verdict == 0
    }
}

fn render(rows: &[Row], seeds: &[u64], given: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Fault campaign\n");
    let _ = writeln!(
        s,
        "Produced by `coordinator campaign --seeds {given}` ({} seeds per row; release build, \
         lockstep, each behaviour's own world and defaults). Each run injects one fault into one \
         robot, the robot and the time (1–30 s) drawn per seed. Faults are written as `--fault` \
         takes them: `random:KIND[:FOR_SECONDS[:AMOUNT]]`, AMOUNT the share of packets hit \
         (default all) or a latency spike's seconds.\n",
        seeds.len()
    );
    let _ = writeln!(
        s,
        "Rules checked per row: no run has a robot–robot or wall contact; no robot's wheels \
         turned longer than {:.0} ms with its host silent (its 500 ms watchdog, then the wheels \
         coast to a stop with their power cut); every run ends with its behaviour's own verdict before the time limit.\n",
        UNATTENDED_BOUND_S * 1e3
    );
    let _ = writeln!(
        s,
        "| fault | behaviour | runs | fault landed | success [Wilson 95 %] | contact runs | longest unattended [ms] | no verdict | rules | commonest failures |"
    );
    let _ = writeln!(s, "|---|---|---:|---:|---|---:|---:|---:|---|---|");
    let mut sorted: Vec<&Row> = rows.iter().collect();
    sorted.sort_by(|a, b| {
        let place = |r: &Row| DEFAULT_FAULTS.iter().position(|f| *f == r.fault);
        place(a)
            .cmp(&place(b))
            .then(a.fault.cmp(&b.fault))
            .then(a.behaviour.cmp(&b.behaviour))
    });
    for r in sorted {
        let (lo, hi) = wilson(r.successes, r.runs);
        let failures = r
            .verdicts
            .iter()
            .map(|(v, n)| format!("{n}× {}", v.replace('|', "/")))
            .collect::<Vec<_>>()
            .join("; ");
        let _ = writeln!(
            s,
            "| `{}` | {} | {} | {} | {}/{} [{:.0}, {:.0}] % | {} | {:.0} | {} | {} | {} |",
            r.fault,
            r.behaviour,
            r.runs,
            r.landed,
            r.successes,
            r.runs,
            lo * 100.0,
            hi * 100.0,
            r.contact_runs,
            r.longest_unattended_s * 1e3,
            r.no_verdict,
            if r.rules_hold() { "hold" } else { "**broken**" },
            failures
        );
    }
    s
}
