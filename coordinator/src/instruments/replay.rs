//! Replay: a recording's robot-to-host packets fed back, at their recorded times, through fresh
//! robot actors, the supervisor and the behaviour, and the world snapshots checked against the
//! recorded ones.
//!
//! Each robot's link is a [`ReplayConnector`] that plays back what that robot sent on that link
//! and swallows what the host sends: the robots answer as they did, whatever the behaviour asks.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{anyhow, bail, Context as _, Result};
use futures::future::BoxFuture;
use robot_actor::link::{Connector, Discovered, Link, LinkCounters, LinkError, LinkEvent};
use serde_json::Value;
use tokio::sync::mpsc;
use tokio::time::Instant;

use crate::instruments::record::{Dir, RunInfo, Topic, METADATA_NAME};

/// One recorded link: (time since the recording's zero, direction, bytes).
pub type RecordedLink = Vec<(Duration, Dir, Vec<u8>)>;

/// A recording read back.
#[derive(Clone, Debug, Default)]
pub struct Recording {
    /// The run it holds.
    pub info: RunInfo,
    /// Per robot (in run order), per link, what went over it.
    pub links: Vec<Vec<RecordedLink>>,
    /// The world snapshots: (time, JSON).
    pub snapshots: Vec<(Duration, Value)>,
    /// Messages per topic.
    pub counts: BTreeMap<String, u64>,
    /// Why reading stopped early, if it did (a file cut off by a crash).
    pub truncated: Option<String>,
    /// Time of the last message.
    pub end: Duration,
}

/// Reads a recording. A killed recorder leaves a complete file without summary, read whole; a
/// file whose tail is torn (killed during a write, or cut off) is read up to its last whole chunk
/// and says so in [`Recording::truncated`].
///
/// # Errors
/// A file that is not MCAP, lacks the run's metadata, or holds malformed messages.
pub fn load(path: &Path) -> Result<Recording> {
    let buf = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    read(&buf)
        .with_context(|| format!("{} is not a readable PocketFleet recording", path.display()))
}

/// Reads a recording from its bytes, as [`load`] does from a file (fuzzing feeds it directly).
///
/// # Errors
/// As [`load`].
pub fn read(buf: &[u8]) -> Result<Recording> {
    // The mcap crate's readers trust a chunk's inner record lengths (a record longer than its
    // chunk panics on an overflow in 0.26), so a file is first rewritten from whole, checked
    // chunks only; what that cuts away is what the file's tail had torn.
    let mut clean = std::io::Cursor::new(Vec::new());
    let kept = crate::instruments::recover::recover(buf, &mut clean)?;
    // A replay that passed over damaged chunks could not say the run came out the same.
    if let Some((offset, why)) = kept.skipped.first() {
        bail!(
            "the recording is damaged: the chunk at byte {offset} is unreadable ({why}){}; \
             `coordinator recover` keeps the intact chunks",
            match kept.skipped.len() {
                1 => String::new(),
                n => format!(", and {} more", n - 1),
            }
        );
    }
    let buf = clean.get_ref().as_slice();
    let lenient = || mcap::read::Options::IgnoreEndMagic.into();
    let mut info = None;
    for record in mcap::read::LinearReader::new_with_options(buf, lenient())? {
        match record {
            Ok(mcap::records::Record::Metadata(m)) if m.name == METADATA_NAME => {
                info = Some(RunInfo::from_map(&m.metadata)?);
                break;
            }
            Ok(mcap::records::Record::Chunk { .. }) => {}
            Ok(_) => {}
            Err(e) => bail!("before the run's metadata: {e}"),
        }
    }
    let info = info.ok_or_else(|| anyhow!("no {METADATA_NAME:?} metadata record"))?;
    let mut rec = Recording {
        links: vec![Vec::new(); info.robots],
        info,
        ..Recording::default()
    };
    for message in mcap::MessageStream::new_with_options(buf, lenient())? {
        let m = match message {
            Ok(m) => m,
            Err(e) => {
                rec.truncated = Some(e.to_string());
                break;
            }
        };
        let t = Duration::from_nanos(m.log_time.saturating_sub(rec.info.start_unix_ns));
        rec.end = rec.end.max(t);
        *rec.counts.entry(m.channel.topic.clone()).or_default() += 1;
        if m.channel.topic == Topic::Packets.name() {
            let v: Value = serde_json::from_slice(&m.data).context("a packet message")?;
            let index = v["robot_index"]
                .as_u64()
                .context("packet without robot_index")? as usize;
            let link = v["link"].as_u64().context("packet without link")? as usize;
            let dir = match v["dir"].as_str() {
                Some("rx") => Dir::Rx,
                Some("tx") => Dir::Tx,
                Some("closed") => Dir::Closed,
                other => bail!("packet with direction {other:?}"),
            };
            let bytes = unhex(v["hex"].as_str().context("packet without hex")?)?;
            let robot = rec
                .links
                .get_mut(index)
                .with_context(|| format!("packet for robot {index} of {}", rec.info.robots))?;
            if robot.len() <= link {
                robot.resize(link + 1, Vec::new());
            }
            robot[link].push((t, dir, bytes));
        } else if m.channel.topic == Topic::World.name() {
            rec.snapshots.push((
                t,
                serde_json::from_slice(&m.data).context("a world snapshot")?,
            ));
        }
    }
    if let crate::instruments::recover::Ending::Cut { why, .. } = kept.ending {
        rec.truncated.get_or_insert(why);
    }
    if rec.counts.is_empty() && rec.truncated.is_some() {
        bail!(
            "no message could be read: {}",
            rec.truncated.unwrap_or_default()
        );
    }
    Ok(rec)
}

fn unhex(s: &str) -> Result<Vec<u8>> {
    // By bytes, not by string slices: a recording is outside input, and a multi-byte character
    // in the hex would split inside a char.
    let digit = |b: u8| char::from(b).to_digit(16);
    let bytes = s.as_bytes();
    if bytes.len() % 2 != 0 {
        bail!("odd-length hex");
    }
    bytes
        .chunks_exact(2)
        .map(|pair| match (digit(pair[0]), digit(pair[1])) {
            (Some(hi), Some(lo)) => Ok((hi * 16 + lo) as u8),
            _ => Err(anyhow!("bad hex {s:?}")),
        })
        .collect()
}

impl Recording {
    /// Every (robot, update count) a snapshot holds a view at.
    pub fn wanted(&self) -> Vec<(u16, u64)> {
        let mut out = Vec::new();
        for (_, s) in &self.snapshots {
            for r in s["robots"].as_array().into_iter().flatten() {
                if let (Some(id), Some(n)) = (r["id"].as_u64(), r["updates"].as_u64()) {
                    if n > 0 {
                        out.push((id as u16, n));
                    }
                }
            }
        }
        out
    }

    /// One connector per recorded robot, playing back from `t0`.
    pub fn connectors(self: &Arc<Self>, t0: Instant) -> Vec<Discovered> {
        (0..self.links.len())
            .map(|index| Discovered {
                name: format!("replay robot {index}"),
                connector: Arc::new(ReplayConnector {
                    recording: Arc::clone(self),
                    index,
                    t0,
                    next: AtomicUsize::new(0),
                }),
            })
            .collect()
    }
}

/// Plays back one robot's recorded links.
pub struct ReplayConnector {
    recording: Arc<Recording>,
    index: usize,
    t0: Instant,
    next: AtomicUsize,
}

impl Connector for ReplayConnector {
    fn peer(&self) -> String {
        format!("replay:{}", self.index)
    }

    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let n = self.next.fetch_add(1, Ordering::Relaxed);
        let recording = Arc::clone(&self.recording);
        let (index, t0) = (self.index, self.t0);
        Box::pin(async move {
            if recording.links[index].len() <= n {
                return Err(LinkError::Unavailable(
                    "replay",
                    format!("robot {index} has no link {n} in the recording"),
                ));
            }
            let (tx, mut from_host) = mpsc::channel::<Vec<u8>>(robot_actor::link::SEND_QUEUE);
            let (to_host, rx) = mpsc::unbounded_channel();
            // What the host sends is not needed: the robot's answers are in the recording.
            tokio::spawn(async move { while from_host.recv().await.is_some() {} });
            tokio::spawn(async move {
                for (t, dir, bytes) in &recording.links[index][n] {
                    let event = match dir {
                        Dir::Tx => continue,
                        Dir::Rx => LinkEvent::Packet(bytes.clone()),
                        Dir::Closed => LinkEvent::Closed(None),
                    };
                    tokio::time::sleep_until(t0 + *t).await;
                    if to_host.send(event).is_err() {
                        break;
                    }
                }
            });
            Ok(Link {
                peer: format!("replay:{index}"),
                tx,
                rx,
                counters: Arc::new(LinkCounters::default()),
            })
        })
    }
}

/// How a replay compared with its recording.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReplayCheck {
    /// World snapshots in the recording.
    pub snapshots: usize,
    /// Robot views compared.
    pub views: usize,
    /// Views that differ or never came, with the first few described.
    pub mismatches: usize,
    /// The first differences.
    pub examples: Vec<String>,
}

impl ReplayCheck {
    /// Whether every recorded snapshot was reproduced exactly.
    pub fn exact(&self) -> bool {
        self.mismatches == 0 && self.views > 0
    }
}

impl std::fmt::Display for ReplayCheck {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "replay: {} world snapshots, {} robot views compared, {} differ",
            self.snapshots, self.views, self.mismatches
        )?;
        for e in &self.examples {
            write!(f, "\n  {e}")?;
        }
        Ok(())
    }
}

/// Compares the recorded snapshots with the views the replay produced.
pub fn check(recording: &Recording, captured: &HashMap<(u16, u64), Value>) -> ReplayCheck {
    let mut out = ReplayCheck {
        snapshots: recording.snapshots.len(),
        ..ReplayCheck::default()
    };
    for (t, s) in &recording.snapshots {
        for r in s["robots"].as_array().into_iter().flatten() {
            let (Some(id), Some(n)) = (r["id"].as_u64(), r["updates"].as_u64()) else {
                continue;
            };
            if n == 0 {
                continue;
            }
            out.views += 1;
            let why = match captured.get(&(id as u16, n)) {
                Some(v) if v == r => continue,
                Some(v) => format!(
                    "t={:.3}s robot {id} after {n} updates: recorded {r}, replayed {v}",
                    t.as_secs_f64()
                ),
                None => format!(
                    "t={:.3}s robot {id}: replay never reached update {n}",
                    t.as_secs_f64()
                ),
            };
            out.mismatches += 1;
            if out.examples.len() < 3 {
                out.examples.push(why);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn garbage_is_a_clear_error_not_a_panic() {
        let e = read(b"not an mcap file at all").unwrap_err();
        assert!(!format!("{e:#}").is_empty());
        assert!(unhex("abc").is_err());
        assert!(unhex("zz").is_err());
        assert_eq!(unhex("00ff").unwrap(), vec![0, 255]);
        assert_eq!(unhex("A0b1").unwrap(), vec![0xa0, 0xb1]);
        // A two-byte character at an even offset used to split inside the char and panic.
        assert!(unhex("0\u{699}a").is_err());
        assert!(unhex("\u{699}").is_err());
    }
}
