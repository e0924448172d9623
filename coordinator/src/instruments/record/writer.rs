//! The recorder: one writer thread owns the MCAP writer and closes a chunk every
//! [`FLUSH_EVERY`] or [`CHUNK_BYTES`], so no actor ever waits on the disk.

use std::collections::BTreeMap;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::{mpsc as std_mpsc, Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context as _, Result};
use protocol::PacketType;
use serde_json::{json, Value};

use super::format::{Dir, RunInfo, Topic, METADATA_NAME};
use super::whole_records::WholeRecords;

/// The longest a message waits in memory before its chunk is closed and flushed to the file.
pub const FLUSH_EVERY: Duration = Duration::from_millis(500);
/// Chunks are also closed once they hold this many bytes, which bounds the memory they take.
pub const CHUNK_BYTES: u64 = 256 * 1024;
/// Bytes a message record adds to its payload inside a chunk (opcode, length, header).
const MESSAGE_OVERHEAD: u64 = 1 + 8 + 2 + 4 + 8 + 8;

enum Msg {
    Write {
        topic: Topic,
        t_ns: u64,
        data: Vec<u8>,
    },
    Finish,
}

/// Totals of a finished recording.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RecordStats {
    /// Messages written.
    pub messages: u64,
    /// Packets among them.
    pub packets: u64,
    /// Bytes in the file.
    pub bytes: u64,
}

/// Writes one MCAP file from any thread or task; cheap to share behind an `Arc`.
pub struct Recorder {
    tx: Mutex<Option<std_mpsc::Sender<Msg>>>,
    t0: tokio::time::Instant,
    thread: Mutex<Option<JoinHandle<Result<RecordStats>>>>,
    path: PathBuf,
}

impl Recorder {
    /// Creates `path` and starts the writer thread. The recording's zero is now on the tokio
    /// clock (simulated time under a paused clock).
    ///
    /// # Errors
    /// The file cannot be created or the MCAP header written.
    pub fn create(path: &Path, info: &RunInfo) -> Result<Arc<Self>> {
        let file =
            File::create(path).with_context(|| format!("creating recording {}", path.display()))?;
        let mut writer = mcap::WriteOptions::new()
            .profile("")
            .library("pocketfleet-coordinator")
            // The writer thread closes chunks itself, on time and on size, so that every close is
            // also a write to the file.
            .chunk_size(None)
            .create(WholeRecords::new(file))
            .with_context(|| format!("writing MCAP header to {}", path.display()))?;
        writer.write_metadata(&mcap::records::Metadata {
            name: METADATA_NAME.into(),
            metadata: info.to_map(),
        })?;
        let mut channels = BTreeMap::new();
        for topic in Topic::ALL {
            let (name, schema) = topic.schema();
            let schema_id = writer.add_schema(name, "jsonschema", schema.to_string().as_bytes())?;
            let channel = writer.add_channel(schema_id, topic.name(), "json", &BTreeMap::new())?;
            channels.insert(topic, channel);
        }
        writer
            .flush()
            .with_context(|| format!("writing {}", path.display()))?;
        let (tx, rx) = std_mpsc::channel::<Msg>();
        let base = info.start_unix_ns;
        let shown = path.display().to_string();
        let thread = std::thread::Builder::new()
            .name("mcap-writer".into())
            .spawn(move || write_loop(writer, &rx, &channels, base, &shown))
            .context("starting the MCAP writer thread")?;
        Ok(Arc::new(Self {
            tx: Mutex::new(Some(tx)),
            t0: tokio::time::Instant::now(),
            thread: Mutex::new(Some(thread)),
            path: path.to_path_buf(),
        }))
    }

    /// The recording's zero on the tokio clock.
    pub fn t0(&self) -> tokio::time::Instant {
        self.t0
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn now_ns(&self) -> u64 {
        (tokio::time::Instant::now() - self.t0).as_nanos() as u64
    }

    fn send(&self, topic: Topic, data: Vec<u8>) {
        let t_ns = self.now_ns();
        if let Ok(guard) = self.tx.lock() {
            if let Some(tx) = guard.as_ref() {
                // A writer that failed has said why through `finish`; the run goes on.
                let _ = tx.send(Msg::Write { topic, t_ns, data });
            }
        }
    }

    /// Records one JSON message on `topic`, stamped now.
    pub fn json(&self, topic: Topic, value: &Value) {
        self.send(topic, value.to_string().into_bytes());
    }

    /// Records one packet (or a link's close, with no bytes).
    pub fn packet(&self, robot_index: usize, robot: u16, link: u32, dir: Dir, bytes: &[u8]) {
        let kind = bytes
            .get(1)
            .and_then(|c| PacketType::from_code(*c))
            .map_or("unknown", PacketType::name);
        let mut hex = String::with_capacity(bytes.len() * 2);
        for b in bytes {
            hex.push_str(&format!("{b:02x}"));
        }
        let v = json!({"robot_index": robot_index, "robot": robot, "link": link,
            "dir": dir.name(), "type": if dir == Dir::Closed { "" } else { kind }, "hex": hex});
        self.send(Topic::Packets, v.to_string().into_bytes());
    }

    /// Writes the summary and closes the file; later messages are dropped.
    ///
    /// # Errors
    /// Any write error the writer thread met.
    pub fn finish(&self) -> Result<RecordStats> {
        if let Ok(mut guard) = self.tx.lock() {
            if let Some(tx) = guard.take() {
                let _ = tx.send(Msg::Finish);
            }
        }
        let thread = self.thread.lock().ok().and_then(|mut t| t.take());
        match thread {
            Some(t) => t
                .join()
                .map_err(|_| anyhow!("the MCAP writer thread panicked"))?,
            None => Err(anyhow!("recording already finished")),
        }
    }
}

/// The writer thread: each message into the open chunk, which is closed on time
/// (`FLUSH_EVERY`) and on size (`CHUNK_BYTES`), until the finish or every sender is gone.
fn write_loop(
    mut writer: mcap::Writer<WholeRecords>,
    rx: &std_mpsc::Receiver<Msg>,
    channels: &BTreeMap<Topic, u16>,
    base: u64,
    shown: &str,
) -> Result<RecordStats> {
    let mut stats = RecordStats::default();
    let mut sequence = 0u32;
    // When the open chunk must be on disk, and how big it is so far.
    let mut due: Option<Instant> = None;
    let mut chunk_bytes = 0u64;
    loop {
        let msg = match due {
            Some(at) => {
                match rx.recv_timeout(at.saturating_duration_since(Instant::now())) {
                    Ok(m) => Some(m),
                    Err(std_mpsc::RecvTimeoutError::Timeout) => None,
                    // Every sender gone without a finish (a panic unwinding): close the file.
                    Err(std_mpsc::RecvTimeoutError::Disconnected) => Some(Msg::Finish),
                }
            }
            None => Some(rx.recv().unwrap_or(Msg::Finish)),
        };
        match msg {
            Some(Msg::Write { topic, t_ns, data }) => {
                sequence = sequence.wrapping_add(1);
                let header = mcap::records::MessageHeader {
                    channel_id: channels[&topic],
                    sequence,
                    log_time: base + t_ns,
                    publish_time: base + t_ns,
                };
                writer.write_to_known_channel(&header, &data)?;
                stats.messages += 1;
                if topic == Topic::Packets {
                    stats.packets += 1;
                }
                chunk_bytes += data.len() as u64 + MESSAGE_OVERHEAD;
                due.get_or_insert_with(|| Instant::now() + FLUSH_EVERY);
            }
            Some(Msg::Finish) => {
                writer
                    .finish()
                    .with_context(|| format!("finishing {shown}"))?;
                stats.bytes = writer
                    .into_inner()
                    .finish()
                    .with_context(|| format!("finishing {shown}"))?;
                return Ok(stats);
            }
            None => {}
        }
        if chunk_bytes >= CHUNK_BYTES || due.is_some_and(|at| Instant::now() >= at) {
            writer.flush().with_context(|| format!("writing {shown}"))?;
            chunk_bytes = 0;
            due = None;
        }
    }
}
