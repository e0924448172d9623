//! Runs a sweep: each run is a child process of this binary writing its own JSON report, a pool of
//! worker threads keeps `--jobs` of them going, and the calling thread alone appends results as
//! they come in, so a killed sweep loses only the runs in flight.

use std::collections::{BTreeMap, BTreeSet};
use std::fs::File;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;
use std::time::Instant;

use anyhow::{bail, Context, Result};

use super::store::{self, Appender, Outcome, RunResult, Timing};
use super::summary::summarise;
use super::{plots, Definition, RunSpec};

/// How to run a sweep (nothing here changes its results).
#[derive(Clone, Debug)]
pub struct Options {
    /// The sweep's directory.
    pub out: PathBuf,
    /// Runs at a time.
    pub jobs: usize,
    /// `(K, N)`: run only the runs whose index i has i % N == K − 1.
    pub shard: Option<(usize, usize)>,
    /// Keep an MCAP recording of each failed run.
    pub record_failures: bool,
    /// The coordinator binary each run executes.
    pub exe: PathBuf,
}

const RESULTS: &str = "results.jsonl";
const TIMING: &str = "timing.jsonl";
const DEFINITION: &str = "sweep.json";

/// Runs the sweep's runs that `out` has no result for yet, then writes and prints the summary.
///
/// # Errors
/// `out` holds a different sweep, or its files cannot be read or written.
pub fn sweep(definition: &Definition, options: &Options) -> Result<()> {
    let out = &options.out;
    for sub in ["runs", "logs"] {
        std::fs::create_dir_all(out.join(sub))
            .with_context(|| format!("creating {}", out.join(sub).display()))?;
    }
    if options.record_failures {
        std::fs::create_dir_all(out.join("failures"))
            .with_context(|| format!("creating {}", out.join("failures").display()))?;
    }
    claim(out, definition)?;
    let mut results = Appender::open(&out.join(RESULTS))?;
    let mut timing = Appender::open(&out.join(TIMING))?;
    let done: BTreeSet<String> = store::read_lines::<RunResult>(&out.join(RESULTS))?
        .into_iter()
        .map(|r| r.id)
        .collect();
    let all = definition.runs();
    let total_all = all.len();
    let shard: Vec<RunSpec> = all
        .into_iter()
        .filter(|r| options.shard.is_none_or(|(k, n)| r.index % n == k - 1))
        .collect();
    let total = shard.len();
    let todo: Vec<RunSpec> = shard
        .into_iter()
        .filter(|r| !done.contains(&r.id()))
        .collect();
    let skipped = total - todo.len();
    let shard_note = options
        .shard
        .map(|(k, n)| format!(" (shard {k}/{n} of {total_all})"))
        .unwrap_or_default();
    eprintln!(
        "sweep: {total} runs{shard_note}; {skipped} already done, skipped; running {} with {} jobs",
        todo.len(),
        options.jobs.min(todo.len()).max(1)
    );
    let progress = Progress::new(total, skipped, todo.len());
    let began = Instant::now();
    let (tx, rx) = mpsc::channel::<(RunResult, f64)>();
    let next = AtomicUsize::new(0);
    let written: Result<()> = std::thread::scope(|scope| {
        for _ in 0..options.jobs.min(todo.len()) {
            let tx = tx.clone();
            let (todo, next) = (&todo, &next);
            scope.spawn(move || loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(spec) = todo.get(i) else { break };
                let started = Instant::now();
                let result = execute(definition, options, spec);
                if tx.send((result, started.elapsed().as_secs_f64())).is_err() {
                    break;
                }
            });
        }
        drop(tx);
        for (result, wall_s) in rx {
            results.append(&result)?;
            timing.append(&Timing {
                id: result.id.clone(),
                wall_s,
            })?;
            progress.finished(&result);
        }
        Ok(())
    });
    progress.done();
    written?;
    eprintln!(
        "sweep: {} runs ({}) took {:.0} s of wall time",
        todo.len(),
        definition.conditions(),
        began.elapsed().as_secs_f64()
    );
    let all = own_results(definition, store::read_lines(&out.join(RESULTS))?);
    report(out, definition, &all)
}

/// Of the lines in `results.jsonl`, those of `definition`'s runs, one per run (the last written
/// wins): a line copied in twice, or one of another sweep's runs, is not counted, and a warning
/// says how many were left out.
fn own_results(definition: &Definition, lines: Vec<RunResult>) -> Vec<RunResult> {
    let ids: BTreeSet<String> = definition.runs().iter().map(RunSpec::id).collect();
    let read = lines.len();
    let mut by_id: BTreeMap<String, RunResult> = BTreeMap::new();
    let mut foreign = 0;
    for r in lines {
        if ids.contains(&r.id) {
            by_id.insert(r.id.clone(), r);
        } else {
            foreign += 1;
        }
    }
    let repeated = read - foreign - by_id.len();
    if foreign > 0 || repeated > 0 {
        eprintln!(
            "sweep: {RESULTS} holds {foreign} line(s) of runs this sweep does not have and \
             {repeated} repeated line(s): left out of the summary"
        );
    }
    let mut own: Vec<RunResult> = by_id.into_values().collect();
    own.sort_by_key(|r| r.index);
    own
}

/// Writes `sweep.json`, or checks that the one there is this sweep's.
fn claim(out: &Path, definition: &Definition) -> Result<()> {
    let path = out.join(DEFINITION);
    match std::fs::read_to_string(&path) {
        Ok(text) => {
            let there: Definition = serde_json::from_str(&text)
                .with_context(|| format!("{} is not a sweep definition", path.display()))?;
            if there != *definition {
                bail!(
                    "{} holds a different sweep ({}); resume it with the same arguments or give another --out",
                    out.display(),
                    differences(&there, definition)
                );
            }
            Ok(())
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            // Results with no definition beside them may be any sweep's: counting them as this
            // one's would mix another behaviour's runs into its rates.
            let results = out.join(RESULTS);
            if std::fs::metadata(&results).is_ok_and(|m| m.len() > 0) {
                bail!(
                    "{} holds results but no {DEFINITION}: nothing shows they are this sweep's; \
                     give another --out",
                    out.display()
                );
            }
            let json = serde_json::to_string_pretty(definition).context("encoding the sweep")?;
            std::fs::write(&path, json + "\n")
                .with_context(|| format!("writing {}", path.display()))
        }
        Err(e) => Err(e).with_context(|| format!("reading {}", path.display())),
    }
}

/// Which fields two definitions differ in, for an error message.
fn differences(a: &Definition, b: &Definition) -> String {
    let (Ok(serde_json::Value::Object(a)), Ok(serde_json::Value::Object(b))) =
        (serde_json::to_value(a), serde_json::to_value(b))
    else {
        return "it cannot be compared".to_string();
    };
    a.iter()
        .filter(|(k, v)| b.get(*k) != Some(*v))
        .map(|(k, v)| {
            format!(
                "{k} there {v}, here {}",
                b.get(k).cloned().unwrap_or_default()
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// Runs one experiment as a child process and reads its report.
fn execute(definition: &Definition, options: &Options, spec: &RunSpec) -> RunResult {
    let stem = spec.file_stem();
    let report = options.out.join("runs").join(format!("{stem}.json"));
    let log = options.out.join("logs").join(format!("{stem}.log"));
    let recording = options
        .record_failures
        .then(|| options.out.join("failures").join(format!("{stem}.mcap")));
    // A report or recording left by a run the last sweep was killed in must not pass for this one.
    let _ = std::fs::remove_file(&report);
    if let Some(r) = &recording {
        let _ = std::fs::remove_file(r);
    }
    let mut cmd = command(definition, options, spec, &report, recording.as_deref());
    guard_child(&mut cmd, RUN_FILE_LIMIT);
    let status: std::io::Result<ExitStatus> = File::create(&log).and_then(|f| {
        cmd.stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(f)
            .status()
    });
    let mut result = unfinished(spec);
    let status = match status {
        Ok(s) => s,
        Err(e) => {
            result.summary = format!("could not start {}: {e}", options.exe.display());
            return result;
        }
    };
    result.exit_code = status.code();
    match status.code() {
        Some(0 | 1) => match read_report(&report, &mut result) {
            Ok(()) => {}
            Err(e) => {
                result.outcome = Outcome::Error;
                result.summary = format!(
                    "exit status {} but no report: {e:#}",
                    status.code().unwrap_or(-1)
                );
            }
        },
        Some(code) => {
            result.summary = format!("exit status {code}: {}", stderr_reason(&log));
        }
        None => result.summary = signal_reason(status, &log),
    }
    if let Some(r) = &recording {
        if result.success() {
            let _ = std::fs::remove_file(r);
        }
    }
    result
}

/// The coordinator command line of one run: its coordinates, the report's and the recording's
/// paths.
fn command(
    definition: &Definition,
    options: &Options,
    spec: &RunSpec,
    report: &Path,
    recording: Option<&Path>,
) -> Command {
    let mut cmd = Command::new(&options.exe);
    cmd.arg("--behaviour")
        .arg(&definition.behaviour)
        .arg("--seed")
        .arg(spec.seed.to_string());
    if let Some(w) = &spec.world {
        cmd.arg("--world").arg(w);
    }
    if let Some(n) = spec.robots {
        cmd.arg("--robots").arg(n.to_string());
    }
    if let Some(hz) = spec.physics_hz {
        cmd.arg("--physics-hz").arg(hz.to_string());
    }
    for kick in spec.kick.iter().filter(|k| *k != "none") {
        for part in kick.split('+') {
            cmd.arg("--kick").arg(part.trim());
        }
    }
    for fault in spec.fault.iter().filter(|f| *f != "none") {
        for part in fault.split('+') {
            cmd.arg("--fault").arg(part.trim());
        }
    }
    for (k, v) in &spec.params {
        cmd.arg("--param").arg(format!("{k}={v}"));
    }
    if let Some(d) = definition.duration_s {
        cmd.arg("--duration").arg(d.to_string());
    }
    if definition.realtime {
        cmd.arg("--realtime");
    }
    if let Some(l) = &definition.link_profile {
        cmd.arg("--link-profile").arg(l);
    }
    cmd.arg("--json-report").arg(report);
    if let Some(r) = recording {
        cmd.arg("--record").arg(r);
    }
    cmd
}

/// A run's result before its process ends: its coordinates, and an error until it says more.
fn unfinished(spec: &RunSpec) -> RunResult {
    RunResult {
        id: spec.id(),
        index: spec.index,
        combination: spec.combination(),
        world: spec.world.clone(),
        robots: spec.robots,
        physics_hz: spec.physics_hz,
        kick: spec.kick.clone(),
        fault: spec.fault.clone(),
        params: spec.params.iter().cloned().collect(),
        seed: spec.seed,
        outcome: Outcome::Error,
        exit_code: None,
        summary: String::new(),
        metrics: BTreeMap::new(),
        robot_collisions: None,
        wall_contacts: None,
        experiment_time_s: None,
        behaviour_success: None,
        worst_model_error_mm: None,
        lost_episodes: None,
        lost_s: None,
        kicks_landed: Vec::new(),
        faults_landed: Vec::new(),
        longest_unattended_s: None,
        contacts_at_kick: None,
        contacts_other: None,
        latency_p99_ms: None,
        event_late_p99_ms: None,
    }
}

/// Fills a result from a run's JSON report.
fn read_report(path: &Path, result: &mut RunResult) -> Result<()> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    let success = v["success"]
        .as_bool()
        .with_context(|| format!("{} has no verdict", path.display()))?;
    result.outcome = if success {
        Outcome::Success
    } else {
        Outcome::Failure
    };
    result.summary = v["summary"].as_str().unwrap_or_default().to_string();
    result.metrics = v["metrics"]
        .as_object()
        .map(|m| {
            m.iter()
                .filter_map(|(k, x)| x.as_f64().map(|x| (k.clone(), x)))
                .collect()
        })
        .unwrap_or_default();
    result.robot_collisions = v["robot_collisions"].as_u64();
    result.wall_contacts = v["wall_contacts"].as_u64();
    result.experiment_time_s = v["experiment_time_s"].as_f64();
    result.behaviour_success = v["behaviour_success"].as_bool();
    result.worst_model_error_mm = v["worst_model_error_mm"].as_f64();
    result.lost_episodes = v["lost_episodes"].as_u64();
    result.lost_s = v["lost_s"].as_f64();
    result.kicks_landed = v["kicks"]
        .as_array()
        .map(|ks| {
            ks.iter()
                .filter_map(|k| k["text"].as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default();
    result.faults_landed = v["faults"]
        .as_array()
        .map(|fs| {
            fs.iter()
                .filter_map(|f| f["text"].as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default();
    result.longest_unattended_s = v["longest_unattended_s"].as_f64();
    let worst = |key: &str| {
        v["links"]
            .as_array()?
            .iter()
            .filter_map(|l| l[key].as_f64())
            .reduce(f64::max)
    };
    result.latency_p99_ms = worst("latency_p99_ms");
    result.event_late_p99_ms = worst("event_late_p99_ms");
    if !result.kicks_landed.is_empty() {
        result.contacts_at_kick = v["contacts_at_kick"].as_u64();
        result.contacts_other = v["contacts_other"].as_u64();
    }
    Ok(())
}

/// Why a run came to no verdict, from the end of its stderr: a panic's message, or the last line.
fn stderr_reason(log: &Path) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect();
    let reason = match lines.iter().rposition(|l| l.contains("panicked at")) {
        Some(i) => format!("panic: {}", lines.get(i + 1).copied().unwrap_or(lines[i])),
        None => lines.last().copied().unwrap_or("no output").to_string(),
    };
    reason.chars().take(300).collect()
}

/// The most a run may write to any one file (its log, report or recording). A run that never
/// ended once logged the same held move for ever and filled a 250 GB disk in minutes; past this
/// the kernel ends it with `SIGXFSZ`, and the sweep goes on.
const RUN_FILE_LIMIT: u64 = 2 << 30;

/// Ends the child when the sweep dies, so a killed sweep leaves no run writing into its directory
/// behind the next one, and when one of its files grows past `file_limit` bytes.
#[cfg(target_os = "linux")]
fn guard_child(cmd: &mut Command, file_limit: u64) {
    use std::os::unix::process::CommandExt;
    // SAFETY: prctl and setrlimit are async-signal-safe and touch no memory of the parent.
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) == -1 {
                return Err(std::io::Error::last_os_error());
            }
            // Only the soft limit, and never above the hard one: raising a limit the shell set
            // lower is refused, and the run would not start.
            let mut limit = libc::rlimit {
                rlim_cur: 0,
                rlim_max: 0,
            };
            if libc::getrlimit(libc::RLIMIT_FSIZE, &mut limit) == -1 {
                return Err(std::io::Error::last_os_error());
            }
            limit.rlim_cur = limit.rlim_max.min(file_limit);
            if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) == -1 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

#[cfg(not(target_os = "linux"))]
fn guard_child(_cmd: &mut Command, _file_limit: u64) {}

/// Why a run ended by a signal, in words.
fn signal_reason(status: ExitStatus, log: &Path) -> String {
    #[cfg(unix)]
    {
        use std::os::unix::process::ExitStatusExt;
        if status.signal() == Some(libc::SIGXFSZ) {
            return format!(
                "its log or report grew past the sweep's {} GiB limit and it was stopped (a run \
                 that never ends logs without bound): {}",
                RUN_FILE_LIMIT >> 30,
                stderr_tail(log)
            );
        }
    }
    format!("ended by a signal ({status}): {}", stderr_reason(log))
}

/// The last line of a log too large to read whole.
fn stderr_tail(log: &Path) -> String {
    use std::io::{Read, Seek, SeekFrom};
    let mut tail = String::new();
    if let Ok(mut f) = File::open(log) {
        let _ = f.seek(SeekFrom::End(-4096));
        let mut bytes = Vec::new();
        let _ = f.read_to_end(&mut bytes);
        tail = String::from_utf8_lossy(&bytes).into_owned();
    }
    let line = tail
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .unwrap_or("no output");
    line.trim().chars().take(300).collect()
}

/// Progress: a bar on a terminal, else one line per finished run.
struct Progress {
    bar: Option<indicatif::ProgressBar>,
    total: usize,
    done: AtomicUsize,
    failures: AtomicUsize,
}

impl Progress {
    fn new(total: usize, skipped: usize, todo: usize) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar = indicatif::ProgressBar::new(todo as u64);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "[{bar:40}] {pos}/{len} runs, {msg}, ETA {eta}",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            bar.set_message(format!("0 failures ({skipped} done before)"));
            bar
        });
        Self {
            bar,
            total,
            done: AtomicUsize::new(skipped),
            failures: AtomicUsize::new(0),
        }
    }

    fn finished(&self, r: &RunResult) {
        let done = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        let failures = self.failures.load(Ordering::Relaxed) + usize::from(!r.success());
        self.failures.store(failures, Ordering::Relaxed);
        let word = match r.outcome {
            Outcome::Success => "ok",
            Outcome::Failure => "FAIL",
            Outcome::Error => "ERROR",
        };
        match &self.bar {
            Some(bar) => {
                bar.inc(1);
                bar.set_message(format!("{failures} failures"));
                if !r.success() {
                    bar.println(format!("{} {word}: {}", r.id, r.summary));
                }
            }
            None => eprintln!("[{done}/{}] {} {word}", self.total, r.id),
        }
    }

    fn done(&self) {
        if let Some(bar) = &self.bar {
            bar.finish();
        }
    }
}

/// Writes the summary files and plots for `results` into `out`, and prints the summary.
fn report(out: &Path, definition: &Definition, results: &[RunResult]) -> Result<()> {
    let summary = summarise(definition, results);
    let md = summary.to_markdown();
    std::fs::write(out.join("summary.md"), &md)
        .with_context(|| format!("writing {}", out.join("summary.md").display()))?;
    std::fs::write(out.join("summary.csv"), summary.to_csv())
        .with_context(|| format!("writing {}", out.join("summary.csv").display()))?;
    plots::write_all(out, definition, results)?;
    println!("{md}");
    println!("summary: {}", out.join("summary.md").display());
    Ok(())
}

/// Merges the results of sweep directories (shards of one sweep) into `out`, with its summary.
///
/// # Errors
/// A directory without a sweep, directories of different sweeps, or unreadable or unwritable files.
pub fn merge(dirs: &[PathBuf], out: &Path) -> Result<()> {
    let mut definition: Option<(Definition, &Path)> = None;
    let mut results: BTreeMap<String, RunResult> = BTreeMap::new();
    let mut timing: BTreeMap<String, Timing> = BTreeMap::new();
    for dir in dirs {
        let path = dir.join(DEFINITION);
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("{} holds no sweep (no {DEFINITION})", dir.display()))?;
        let d: Definition = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a sweep definition", path.display()))?;
        match &definition {
            Some((first, from)) if *first != d => bail!(
                "{} and {} hold different sweeps ({}); only shards of one sweep merge",
                from.display(),
                dir.display(),
                differences(first, &d)
            ),
            Some(_) => {}
            None => definition = Some((d, dir)),
        }
        for r in store::read_lines::<RunResult>(&dir.join(RESULTS))? {
            match results.get(&r.id) {
                Some(seen) if *seen != r => eprintln!(
                    "sweep merge: run {} differs between directories; keeping the first",
                    r.id
                ),
                Some(_) => {}
                None => {
                    results.insert(r.id.clone(), r);
                }
            }
        }
        for t in store::read_lines::<Timing>(&dir.join(TIMING))? {
            timing.entry(t.id.clone()).or_insert(t);
        }
    }
    let Some((definition, _)) = definition else {
        bail!("sweep merge: no directories given");
    };
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    claim(out, &definition)?;
    let mut results: Vec<RunResult> = results.into_values().collect();
    results.sort_by_key(|r| r.index);
    let timing: Vec<Timing> = results
        .iter()
        .filter_map(|r| timing.get(&r.id).cloned())
        .collect();
    store::write_lines(&out.join(RESULTS), &results)?;
    store::write_lines(&out.join(TIMING), &timing)?;
    eprintln!(
        "sweep merge: {} runs of {} from {} directories",
        results.len(),
        definition.runs().len(),
        dirs.len()
    );
    report(out, &definition, &results)
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    /// A run that writes past the limit is stopped there, and the sweep says why.
    #[test]
    fn a_run_writing_past_the_file_limit_is_stopped_and_the_reason_named() {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("run.log");
        let mut cmd = Command::new("head");
        cmd.args(["-c", "100000", "/dev/zero"]);
        guard_child(&mut cmd, 4096);
        let status = cmd.stdout(File::create(&log).unwrap()).status().unwrap();
        assert!(std::fs::metadata(&log).unwrap().len() <= 4096);
        assert_eq!(status.code(), None, "{status}");
        let why = signal_reason(status, &log);
        assert!(why.contains("limit"), "{why}");
    }
}
