//! MCAP recording: every packet in both directions, the world model's snapshots, the robots'
//! events and Foxglove scene messages, written by one thread so no actor ever waits on the disk.
//!
//! Chunks are built in memory and reach the file only whole: every [`FLUSH_EVERY`] (or every
//! [`CHUNK_BYTES`]) the open chunk is closed and written in one piece, followed by a provisional
//! end (a data end record, a footer without summary and the closing magic) that the next write
//! overwrites. The file on disk is therefore a complete MCAP file at every moment: a process
//! killed mid-run leaves one that any MCAP reader reads up to its last closed chunk, and
//! `coordinator recover` adds the summary and indexes a clean finish would have written.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, Cursor, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU16, AtomicU32, Ordering};
use std::sync::{mpsc as std_mpsc, Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context as _, Result};
use futures::future::BoxFuture;
use protocol::layout::TypeInfo;
use protocol::packets::AnyPacket;
use protocol::{Frame, PacketType};
use robot_actor::link::{Connector, Link, LinkError, LinkEvent, SEND_QUEUE};
use serde_json::{json, Value};
use tokio::sync::mpsc;

/// The longest a message waits in memory before its chunk is closed and flushed to the file.
pub const FLUSH_EVERY: Duration = Duration::from_millis(500);
/// Chunks are also closed once they hold this many bytes, which bounds the memory they take.
pub const CHUNK_BYTES: u64 = 256 * 1024;
/// Bytes a message record adds to its payload inside a chunk (opcode, length, header).
const MESSAGE_OVERHEAD: u64 = 1 + 8 + 2 + 4 + 8 + 8;
/// Name of the metadata record that describes the run.
pub const METADATA_NAME: &str = "pocketfleet.run";

/// The channels of a recording.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Topic {
    /// Every packet, both directions: `/packets`.
    Packets,
    /// World model snapshots: `/world`.
    World,
    /// Robot events as the behaviour receives them: `/events`.
    Events,
    /// `foxglove.SceneUpdate`: track, boxes, robots and trails for the 3D panel: `/scene`.
    Scene,
    /// `foxglove.PosesInFrame`: every robot's pose: `/poses`.
    Poses,
}

impl Topic {
    /// Every topic.
    pub const ALL: [Topic; 5] = [
        Topic::Packets,
        Topic::World,
        Topic::Events,
        Topic::Scene,
        Topic::Poses,
    ];

    /// The MCAP topic name.
    pub fn name(self) -> &'static str {
        match self {
            Topic::Packets => "/packets",
            Topic::World => "/world",
            Topic::Events => "/events",
            Topic::Scene => "/scene",
            Topic::Poses => "/poses",
        }
    }

    fn schema(self) -> (&'static str, Value) {
        let num = json!({"type": "number"});
        let time = json!({"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}});
        let vec3 = json!({"type": "object", "properties": {"x": num, "y": num, "z": num}});
        let quat =
            json!({"type": "object", "properties": {"x": num, "y": num, "z": num, "w": num}});
        let pose = json!({"type": "object", "properties": {"position": vec3, "orientation": quat}});
        let colour =
            json!({"type": "object", "properties": {"r": num, "g": num, "b": num, "a": num}});
        match self {
            Topic::Packets => (
                "pocketfleet.Packet",
                json!({"type": "object", "properties": {
                    "robot_index": {"type": "integer", "description": "robot's place in the run's robot list"},
                    "robot": {"type": "integer", "description": "robot id (0 until its hello)"},
                    "link": {"type": "integer", "description": "link number, counting reconnects"},
                    "dir": {"type": "string", "enum": ["rx", "tx", "closed"]},
                    "type": {"type": "string"},
                    "hex": {"type": "string", "description": "the whole packet, header included"}}}),
            ),
            Topic::World => (
                "pocketfleet.WorldSnapshot",
                json!({"type": "object", "properties": {
                    "t": num,
                    "robots": {"type": "array", "items": {"type": "object", "properties": {
                        "id": {"type": "integer"}, "connected": {"type": "boolean"},
                        "updates": {"type": "integer", "description": "state updates applied so far"},
                        "pose": {"type": "object", "properties": {"x": num, "y": num, "theta": num}},
                        "odometry": {"type": "object", "properties": {"x": num, "y": num, "theta": num}},
                        "pending_moves": {"type": "integer"},
                        "on_track": {"type": ["array", "null"]},
                        "uncertainty": {"type": "object", "description": "1σ of the pose estimate", "properties": {"position_m": num, "heading_rad": num}},
                        "localisation": {"type": "string", "enum": ["tracking", "lost"]},
                        "state": {"type": "object"}}}},
                    "encounters": {"type": "array"}}}),
            ),
            Topic::Events => (
                "pocketfleet.RobotEvent",
                json!({"type": "object", "properties": {
                    "t": num, "robot": {"type": "integer"}, "kind": {"type": "string"},
                    "detail": {"type": "string"}}}),
            ),
            Topic::Scene => {
                let entity = json!({"type": "object", "properties": {
                    "timestamp": time, "frame_id": {"type": "string"}, "id": {"type": "string"},
                    "lifetime": time, "frame_locked": {"type": "boolean"},
                    "metadata": {"type": "array"},
                    "cubes": {"type": "array", "items": {"type": "object", "properties": {"pose": pose, "size": vec3, "color": colour}}},
                    "arrows": {"type": "array", "items": {"type": "object", "properties": {"pose": pose, "shaft_length": num, "shaft_diameter": num, "head_length": num, "head_diameter": num, "color": colour}}},
                    "lines": {"type": "array", "items": {"type": "object", "properties": {"type": {"type": "integer"}, "pose": pose, "thickness": num, "scale_invariant": {"type": "boolean"}, "points": {"type": "array", "items": vec3}, "color": colour}}},
                    "texts": {"type": "array", "items": {"type": "object", "properties": {"pose": pose, "billboard": {"type": "boolean"}, "font_size": num, "scale_invariant": {"type": "boolean"}, "color": colour, "text": {"type": "string"}}}}}});
                (
                    "foxglove.SceneUpdate",
                    json!({"type": "object", "properties": {
                        "deletions": {"type": "array"},
                        "entities": {"type": "array", "items": entity}}}),
                )
            }
            Topic::Poses => (
                "foxglove.PosesInFrame",
                json!({"type": "object", "properties": {
                    "timestamp": time, "frame_id": {"type": "string"},
                    "poses": {"type": "array", "items": pose}}}),
            ),
        }
    }
}

/// What a recording says about the run it holds (its `pocketfleet.run` metadata record).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunInfo {
    /// Behaviour name.
    pub behaviour: String,
    /// World preset or file.
    pub world: String,
    /// Number of robots taken from the world.
    pub robots: usize,
    /// Seed.
    pub seed: u64,
    /// Behaviour parameters.
    pub params: BTreeMap<String, String>,
    /// Whether the robots were simulated (their odometry origins then come from the world).
    pub simulated: bool,
    /// Wall-clock time of the recording's zero, nanoseconds since the Unix epoch; every log time
    /// is this plus the run's own clock.
    pub start_unix_ns: u64,
}

impl RunInfo {
    fn to_map(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        m.insert("behaviour".into(), self.behaviour.clone());
        m.insert("world".into(), self.world.clone());
        m.insert("robots".into(), self.robots.to_string());
        m.insert("seed".into(), self.seed.to_string());
        m.insert(
            "params".into(),
            serde_json::to_string(&self.params).unwrap_or_default(),
        );
        m.insert("simulated".into(), self.simulated.to_string());
        m.insert("start_unix_ns".into(), self.start_unix_ns.to_string());
        m
    }

    /// Reads the metadata back.
    ///
    /// # Errors
    /// A missing or malformed key, by name.
    pub fn from_map(m: &BTreeMap<String, String>) -> Result<Self> {
        let get = |k: &str| {
            m.get(k)
                .ok_or_else(|| anyhow!("recording metadata lacks {k:?}"))
        };
        let parse_err = |k: &str| format!("recording metadata {k:?} is malformed");
        Ok(Self {
            behaviour: get("behaviour")?.clone(),
            world: get("world")?.clone(),
            robots: get("robots")?
                .parse()
                .with_context(|| parse_err("robots"))?,
            seed: get("seed")?.parse().with_context(|| parse_err("seed"))?,
            params: serde_json::from_str(get("params")?).with_context(|| parse_err("params"))?,
            simulated: get("simulated")?
                .parse()
                .with_context(|| parse_err("simulated"))?,
            start_unix_ns: get("start_unix_ns")?
                .parse()
                .with_context(|| parse_err("start_unix_ns"))?,
        })
    }
}

/// Which way a packet went.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dir {
    /// Robot to host.
    Rx,
    /// Host to robot.
    Tx,
    /// The link closed (no bytes).
    Closed,
}

impl Dir {
    /// As written in the recording.
    pub fn name(self) -> &'static str {
        match self {
            Dir::Rx => "rx",
            Dir::Tx => "tx",
            Dir::Closed => "closed",
        }
    }
}

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
            .spawn(move || -> Result<RecordStats> {
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
            })
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

/// The bytes that end a recording between two writes: a data end record (no CRC), a footer
/// that says there is no summary, and the closing magic. Readers take the file as complete.
const PROVISIONAL_END: [u8; 50] = {
    let mut end = [0u8; 50];
    end[0] = mcap::records::op::DATA_END;
    end[1] = 4; // record length, u64 little-endian; the CRC after it stays 0
    end[13] = mcap::records::op::FOOTER;
    end[14] = 20; // summary start, summary offset start (both 0: none), summary CRC
    let mut i = 0;
    while i < mcap::MAGIC.len() {
        end[42 + i] = mcap::MAGIC[i];
        i += 1;
    }
    end
};

/// The file under the MCAP writer: everything written stays in memory until the writer flushes
/// (it does so only between records: after closing a chunk, and at its finish), then goes to the
/// file in one write followed by [`PROVISIONAL_END`], which the next flush overwrites. A process
/// killed at any moment leaves whole records and a valid end.
struct WholeRecords {
    file: File,
    /// Bytes of the recording already in the file (the provisional end follows them).
    written: u64,
    pending: Cursor<Vec<u8>>,
}

impl WholeRecords {
    fn new(file: File) -> Self {
        Self {
            file,
            written: 0,
            pending: Cursor::new(Vec::new()),
        }
    }

    fn commit(&mut self, provisional: bool) -> io::Result<()> {
        let len = self.pending.get_ref().len();
        if self.pending.position() != len as u64 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "the MCAP writer flushed while rewriting an earlier record",
            ));
        }
        let mut bytes = std::mem::take(self.pending.get_mut());
        if provisional {
            bytes.extend_from_slice(&PROVISIONAL_END);
        }
        self.file.seek(SeekFrom::Start(self.written))?;
        self.file.write_all(&bytes)?;
        self.written += len as u64;
        bytes.clear();
        self.pending = Cursor::new(bytes);
        Ok(())
    }

    /// Writes what is left without a provisional end and cuts the file there; returns its length.
    fn finish(mut self) -> io::Result<u64> {
        self.commit(false)?;
        self.file.set_len(self.written)?;
        self.file.flush()?;
        Ok(self.written)
    }
}

impl Write for WholeRecords {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.pending.write(buf)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.commit(true)
    }
}

impl Seek for WholeRecords {
    fn seek(&mut self, pos: SeekFrom) -> io::Result<u64> {
        let here = self.written + self.pending.position();
        let end = self.written + self.pending.get_ref().len() as u64;
        let target = match pos {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::End(d) => end.checked_add_signed(d),
            SeekFrom::Current(d) => here.checked_add_signed(d),
        };
        match target {
            Some(t) if t >= self.written => {
                self.pending.set_position(t - self.written);
                Ok(t)
            }
            _ => Err(io::Error::new(
                io::ErrorKind::Unsupported,
                "the MCAP writer sought back into bytes already in the file",
            )),
        }
    }
}

/// Wraps a connector so every packet through its links, both ways, is recorded.
pub struct Tap {
    inner: Arc<dyn Connector>,
    index: usize,
    robot: Arc<AtomicU16>,
    links: AtomicU32,
    recorder: Arc<Recorder>,
}

impl Tap {
    /// Taps robot `index`'s connector; `robot` is its id if known already (0 otherwise: the tap
    /// learns it from the robot's hello).
    pub fn new(
        inner: Arc<dyn Connector>,
        index: usize,
        robot: u16,
        recorder: Arc<Recorder>,
    ) -> Self {
        Self {
            inner,
            index,
            robot: Arc::new(AtomicU16::new(robot)),
            links: AtomicU32::new(0),
            recorder,
        }
    }
}

impl Connector for Tap {
    fn peer(&self) -> String {
        self.inner.peer()
    }

    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let opening = self.inner.connect();
        let (index, robot, recorder) = (self.index, Arc::clone(&self.robot), self.recorder.clone());
        let link_no = self.links.fetch_add(1, Ordering::Relaxed);
        Box::pin(async move {
            let link = opening.await?;
            let (tx, mut from_actor) = mpsc::channel::<Vec<u8>>(SEND_QUEUE);
            let (to_actor, rx) = mpsc::unbounded_channel();
            let (inner_tx, mut inner_rx) = (link.tx, link.rx);
            let rec = recorder.clone();
            let id = Arc::clone(&robot);
            tokio::spawn(async move {
                while let Some(p) = from_actor.recv().await {
                    rec.packet(index, id.load(Ordering::Relaxed), link_no, Dir::Tx, &p);
                    if inner_tx.send(p).await.is_err() {
                        break;
                    }
                }
            });
            tokio::spawn(async move {
                while let Some(event) = inner_rx.recv().await {
                    match &event {
                        LinkEvent::Packet(p) => {
                            if let Ok(frame) = Frame::parse(p) {
                                if let AnyPacket::Hello(h) = frame.packet() {
                                    robot.store(h.robot_id, Ordering::Relaxed);
                                }
                            }
                            recorder.packet(
                                index,
                                robot.load(Ordering::Relaxed),
                                link_no,
                                Dir::Rx,
                                p,
                            );
                        }
                        LinkEvent::Closed(_) => recorder.packet(
                            index,
                            robot.load(Ordering::Relaxed),
                            link_no,
                            Dir::Closed,
                            &[],
                        ),
                    }
                    if to_actor.send(event).is_err() {
                        break;
                    }
                }
            });
            Ok(Link {
                peer: link.peer,
                tx,
                rx,
                counters: link.counters,
            })
        })
    }
}

/// A `Pod` wire struct as nested JSON, field by field, from its compile-time layout.
pub fn layout_json<T: protocol::Layout + bytemuck::Pod>(value: &T) -> Value {
    typed_json(&T::LAYOUT, bytemuck::bytes_of(value))
}

fn typed_json(ty: &TypeInfo, bytes: &[u8]) -> Value {
    if let Some((elem, len)) = ty.array {
        return Value::Array(
            (0..len)
                .map(|i| typed_json(elem, &bytes[i * elem.size..(i + 1) * elem.size]))
                .collect(),
        );
    }
    if !ty.fields.is_empty() {
        let mut m = serde_json::Map::new();
        for f in ty.fields {
            m.insert(
                f.name.to_string(),
                typed_json(f.ty, &bytes[f.offset..f.offset + f.ty.size]),
            );
        }
        return Value::Object(m);
    }
    primitive_json(ty.name, bytes).unwrap_or(Value::Null)
}

fn primitive_json(name: &str, b: &[u8]) -> Option<Value> {
    Some(match name {
        "u8" => json!(b[0]),
        "i8" => json!(b[0] as i8),
        "u16" => json!(u16::from_le_bytes(b.try_into().ok()?)),
        "i16" => json!(i16::from_le_bytes(b.try_into().ok()?)),
        "u32" => json!(u32::from_le_bytes(b.try_into().ok()?)),
        "i32" => json!(i32::from_le_bytes(b.try_into().ok()?)),
        "u64" => json!(u64::from_le_bytes(b.try_into().ok()?)),
        "i64" => json!(i64::from_le_bytes(b.try_into().ok()?)),
        // Through f64 so the JSON shows the f32 exactly.
        "f32" => json!(f64::from(f32::from_le_bytes(b.try_into().ok()?))),
        _ => return None,
    })
}

/// One leaf of a wire struct's layout: its path (`line_pid.kp`, `spots[3]`), offset and type.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Leaf {
    /// Dotted path with array indices.
    pub path: String,
    /// Byte offset.
    pub offset: usize,
    /// Primitive type name (`f32`, `u16`, …).
    pub ty: &'static str,
    /// Size in bytes.
    pub size: usize,
}

/// Every primitive leaf of a layout, arrays expanded.
pub fn leaves(ty: &'static TypeInfo) -> Vec<Leaf> {
    fn walk(ty: &'static TypeInfo, path: String, base: usize, out: &mut Vec<Leaf>) {
        if let Some((elem, len)) = ty.array {
            for i in 0..len {
                walk(elem, format!("{path}[{i}]"), base + i * elem.size, out);
            }
        } else if ty.fields.is_empty() {
            out.push(Leaf {
                path,
                offset: base,
                ty: ty.name,
                size: ty.size,
            });
        } else {
            for f in ty.fields {
                let p = if path.is_empty() {
                    f.name.to_string()
                } else {
                    format!("{path}.{}", f.name)
                };
                walk(f.ty, p, base + f.offset, out);
            }
        }
    }
    let mut out = Vec::new();
    walk(ty, String::new(), 0, &mut out);
    out
}

/// A leaf's value in `bytes` (the whole struct) as JSON.
pub fn leaf_value(leaf: &Leaf, bytes: &[u8]) -> Value {
    bytes
        .get(leaf.offset..leaf.offset + leaf.size)
        .and_then(|b| primitive_json(leaf.ty, b))
        .unwrap_or(Value::Null)
}

/// The little-endian bytes of `text` as a value of the leaf's type.
///
/// # Errors
/// Text that is not a number of that type, or out of its range.
pub fn leaf_bytes(leaf: &Leaf, text: &str) -> Result<Vec<u8>, String> {
    let text = text.trim();
    let bad = || format!("{}: {text:?} is not a valid {}", leaf.path, leaf.ty);
    if leaf.ty == "f32" {
        let v: f32 = text.parse().map_err(|_| bad())?;
        if !v.is_finite() {
            return Err(bad());
        }
        return Ok(v.to_le_bytes().to_vec());
    }
    let v: i128 = text.parse().map_err(|_| bad())?;
    let (lo, hi): (i128, i128) = match leaf.ty {
        "u8" => (0, u8::MAX.into()),
        "i8" => (i8::MIN.into(), i8::MAX.into()),
        "u16" => (0, u16::MAX.into()),
        "i16" => (i16::MIN.into(), i16::MAX.into()),
        "u32" => (0, u32::MAX.into()),
        "i32" => (i32::MIN.into(), i32::MAX.into()),
        "u64" => (0, u64::MAX.into()),
        "i64" => (i64::MIN.into(), i64::MAX.into()),
        _ => return Err(format!("{}: type {} cannot be edited", leaf.path, leaf.ty)),
    };
    if v < lo || v > hi {
        return Err(format!(
            "{}: {v} is out of range for {}",
            leaf.path, leaf.ty
        ));
    }
    Ok(v.to_le_bytes()[..leaf.size].to_vec())
}

/// Foxglove time from nanoseconds.
pub fn fox_time(ns: u64) -> Value {
    json!({"sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000})
}

/// A Foxglove pose in the plane.
pub fn fox_pose(x: f64, y: f64, theta: f64) -> Value {
    json!({"position": {"x": x, "y": y, "z": 0.0},
        "orientation": {"x": 0.0, "y": 0.0, "z": (theta / 2.0).sin(), "w": (theta / 2.0).cos()}})
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_file_on_disk_is_a_complete_mcap_between_any_two_writes() {
        let dir = std::env::temp_dir().join(format!("pocketfleet-whole-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("whole.mcap");
        let mut w = mcap::WriteOptions::new()
            .chunk_size(None)
            .create(WholeRecords::new(File::create(&path).unwrap()))
            .unwrap();
        let s = w.add_schema("S", "jsonschema", b"{}").unwrap();
        let c = w.add_channel(s, "/a", "json", &BTreeMap::new()).unwrap();
        let on_disk = || {
            let bytes = std::fs::read(&path).unwrap();
            let n = mcap::MessageStream::new(&bytes)
                .expect("a complete file")
                .collect::<Result<Vec<_>, _>>()
                .expect("every message reads")
                .len();
            (n, mcap::Summary::read(&bytes).unwrap().is_some())
        };
        w.flush().unwrap();
        assert_eq!(on_disk(), (0, false));
        for i in 0..20u32 {
            let header = mcap::records::MessageHeader {
                channel_id: c,
                sequence: i,
                log_time: u64::from(i),
                publish_time: u64::from(i),
            };
            w.write_to_known_channel(&header, b"{}").unwrap();
            // Until the chunk closes, nothing of it is in the file.
            assert_eq!(on_disk().0, (i / 5 * 5) as usize);
            if i % 5 == 4 {
                w.flush().unwrap();
                assert_eq!(on_disk(), (i as usize + 1, false));
            }
        }
        w.finish().unwrap();
        let len = w.into_inner().finish().unwrap();
        assert_eq!(len, std::fs::metadata(&path).unwrap().len());
        assert_eq!(on_disk(), (20, true));
    }

    #[test]
    fn settings_leaves_round_trip_through_text() {
        let leaves = leaves(&<protocol::Settings as protocol::Layout>::LAYOUT);
        let kp = leaves
            .iter()
            .find(|l| l.path == "line_pid.kp")
            .expect("line_pid.kp is a leaf");
        assert_eq!(kp.ty, "f32");
        let bytes = leaf_bytes(kp, "1.25").unwrap();
        assert_eq!(bytes, 1.25f32.to_le_bytes());
        assert!(leaf_bytes(kp, "fast").is_err());
        let small = leaves.iter().find(|l| l.ty == "u8").expect("a u8 setting");
        assert!(leaf_bytes(small, "256").is_err());
        assert_eq!(leaf_bytes(small, "255").unwrap(), vec![255]);
    }

    #[test]
    fn state_json_has_every_sub_struct() {
        let mut s = protocol::RobotState::default();
        s.wheels.left_mps = 0.25;
        s.line.darkness[3] = 700;
        let v = layout_json(&s);
        assert_eq!(v["wheels"]["left_mps"], json!(0.25));
        assert_eq!(v["line"]["darkness"][3], json!(700));
        assert!(v["power"]["battery_mv"].is_number());
    }
}
