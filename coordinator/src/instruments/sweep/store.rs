//! The sweep's files of record: `results.jsonl` (one line per finished run, nothing wall-clock in
//! it) and `timing.jsonl` (run id and wall seconds). Each line is written whole with one
//! `write_all` and flushed, so a killed sweep leaves at most a partial last line, which the next
//! start cuts away.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::Path;

use anyhow::{bail, Context, Result};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// How a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Outcome {
    /// The run succeeded (exit status 0): the behaviour did and the ground truth saw no contact.
    Success,
    /// The run failed (exit status 1): the behaviour did, or the ground truth overruled it.
    Failure,
    /// The run did not come to a verdict: another exit status, a signal, or no report.
    Error,
}

/// One line of `results.jsonl`: a run's coordinates and what its report says. Keys keep this
/// order; nothing in it depends on the wall clock, so the same run always gives the same line.
/// Lines written before a field existed read with it empty, so old results still merge.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunResult {
    /// The run's id.
    pub id: String,
    /// Its place in the sweep's run order.
    pub index: usize,
    /// Its combination (every coordinate but the seed).
    pub combination: String,
    /// World, when swept.
    pub world: Option<String>,
    /// Robot count, when swept.
    pub robots: Option<usize>,
    /// Physics rate in Hz, when swept.
    #[serde(default)]
    pub physics_hz: Option<u32>,
    /// Kicks, when swept.
    #[serde(default)]
    pub kick: Option<String>,
    /// The run's faults coordinate, when the sweep lists faults.
    #[serde(default)]
    pub fault: Option<String>,
    /// Parameter values.
    pub params: BTreeMap<String, String>,
    /// Seed.
    pub seed: u64,
    /// How it ended.
    pub outcome: Outcome,
    /// The process's exit status (none when a signal ended it).
    pub exit_code: Option<i32>,
    /// The verdict's summary, or why the run came to no verdict.
    pub summary: String,
    /// The verdict's metrics.
    pub metrics: BTreeMap<String, f64>,
    /// Robot–robot contacts.
    pub robot_collisions: Option<u64>,
    /// Robot–wall contacts.
    pub wall_contacts: Option<u64>,
    /// Experiment time, simulated seconds.
    pub experiment_time_s: Option<f64>,
    /// Whether the behaviour itself called the run a success (`Some(true)` with a failed outcome:
    /// the ground truth overruled it).
    #[serde(default)]
    pub behaviour_success: Option<bool>,
    /// The world model's worst position error against ground truth over every robot and every
    /// 100 ms sample of the run, mm.
    #[serde(default)]
    pub worst_model_error_mm: Option<f64>,
    /// Lost episodes summed over the robots.
    #[serde(default)]
    pub lost_episodes: Option<u64>,
    /// Time lost summed over the robots, seconds.
    #[serde(default)]
    pub lost_s: Option<f64>,
    /// The kicks as they landed, one line each (random ones as drawn).
    #[serde(default)]
    pub kicks_landed: Vec<String>,
    /// Each fault as it began, in words.
    #[serde(default)]
    pub faults_landed: Vec<String>,
    /// The longest any robot's wheels turned while its host was silent, seconds (simulated).
    #[serde(default)]
    pub longest_unattended_s: Option<f64>,
    /// Contacts that began while a kick landed (the kick's own).
    #[serde(default)]
    pub contacts_at_kick: Option<u64>,
    /// Contacts that began at any other time (the supervision's).
    #[serde(default)]
    pub contacts_other: Option<u64>,
    /// The slowest link's one-way latency p99, ms (half the ping round trip).
    #[serde(default)]
    pub latency_p99_ms: Option<f64>,
    /// The latest link's event lateness p99, ms.
    #[serde(default)]
    pub event_late_p99_ms: Option<f64>,
}

impl RunResult {
    /// Whether the run succeeded (the behaviour did and the ground truth agreed).
    pub fn success(&self) -> bool {
        self.outcome == Outcome::Success
    }

    /// Whether the behaviour called the run a success but the ground truth failed it.
    pub fn overruled(&self) -> bool {
        self.outcome == Outcome::Failure && self.behaviour_success == Some(true)
    }

    /// Whether the run ended with a robot lost and not found.
    pub fn lost_not_found(&self) -> bool {
        self.summary.contains("lost and not found")
    }

    /// Robot–robot and wall contacts together (0 when the report had none to give).
    pub fn contacts(&self) -> u64 {
        self.robot_collisions.unwrap_or(0) + self.wall_contacts.unwrap_or(0)
    }
}

/// One line of `timing.jsonl`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    /// The run's id.
    pub id: String,
    /// Wall-clock seconds the run took.
    pub wall_s: f64,
}

/// Cuts a partial last line (a write the kill interrupted) off the file, if there is one.
///
/// # Errors
/// The file cannot be read or truncated.
pub fn repair(path: &Path) -> Result<()> {
    let Ok(bytes) = std::fs::read(path) else {
        return Ok(());
    };
    if bytes.is_empty() || bytes.ends_with(b"\n") {
        return Ok(());
    }
    let keep = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
    let f = OpenOptions::new()
        .write(true)
        .open(path)
        .with_context(|| format!("opening {} to cut its partial last line", path.display()))?;
    f.set_len(keep as u64)
        .with_context(|| format!("cutting the partial last line of {}", path.display()))?;
    Ok(())
}

/// Reads every complete line of a JSON Lines file (none when it does not exist); a partial last
/// line is left out.
///
/// # Errors
/// The file cannot be read, or a complete line is not a record of this kind (named by its number).
pub fn read_lines<T: DeserializeOwned>(path: &Path) -> Result<Vec<T>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
    };
    let complete = match text.rfind('\n') {
        Some(i) => &text[..=i],
        None => "",
    };
    complete
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            serde_json::from_str(l)
                .with_context(|| format!("{} line {}: not a sweep record", path.display(), i + 1))
        })
        .collect()
}

/// Appends whole lines to a JSON Lines file.
#[derive(Debug)]
pub struct Appender {
    file: File,
}

impl Appender {
    /// Opens (creating) the file for appending, after cutting a partial last line.
    ///
    /// # Errors
    /// The file cannot be opened.
    pub fn open(path: &Path) -> Result<Self> {
        repair(path)?;
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .with_context(|| format!("opening {}", path.display()))?;
        Ok(Self { file })
    }

    /// Appends one record as one line, in one write, and flushes it.
    ///
    /// # Errors
    /// The write failed.
    pub fn append(&mut self, record: &impl Serialize) -> Result<()> {
        let mut line = serde_json::to_string(record).context("encoding a sweep record")?;
        if line.contains('\n') {
            bail!("a sweep record encoded over more than one line");
        }
        line.push('\n');
        self.file
            .write_all(line.as_bytes())
            .and_then(|()| self.file.flush())
            .context("appending a sweep record")
    }
}

/// Writes JSON Lines to a file at once (merge).
///
/// # Errors
/// The write failed.
pub fn write_lines<T: Serialize>(path: &Path, records: &[T]) -> Result<()> {
    let mut text = String::new();
    for r in records {
        text.push_str(&serde_json::to_string(r).context("encoding a sweep record")?);
        text.push('\n');
    }
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scratch directory removed when the test is done with it.
    fn temp() -> tempfile::TempDir {
        tempfile::Builder::new()
            .prefix("pf-sweep-store-")
            .tempdir()
            .unwrap()
    }

    #[test]
    fn a_partial_last_line_is_cut_before_appending() {
        let dir = temp();
        let path = dir.path().join("t.jsonl");
        std::fs::write(&path, "{\"id\":\"a\",\"wall_s\":1.0}\n{\"id\":\"b\",\"wal").unwrap();
        let read: Vec<Timing> = read_lines(&path).unwrap();
        assert_eq!(read.len(), 1);
        let mut a = Appender::open(&path).unwrap();
        a.append(&Timing {
            id: "c".into(),
            wall_s: 2.5,
        })
        .unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "{\"id\":\"a\",\"wall_s\":1.0}\n{\"id\":\"c\",\"wall_s\":2.5}\n"
        );
        std::fs::write(&path, "{\"id\":\"a\"").unwrap();
        repair(&path).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"");
    }

    #[test]
    fn a_bad_complete_line_is_named() {
        let dir = temp();
        let path = dir.path().join("t.jsonl");
        std::fs::write(&path, "{\"id\":\"a\",\"wall_s\":1.0}\nnonsense\n").unwrap();
        let e = read_lines::<Timing>(&path).unwrap_err().to_string();
        assert!(e.contains("line 2"), "{e}");
    }
}
