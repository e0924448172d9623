//! What a recording holds: its channels with their JSON schemas, the run's metadata record and
//! the direction of a recorded packet; shared by the writer and by replay.

use std::collections::BTreeMap;

use anyhow::{anyhow, Context as _, Result};
use serde_json::{json, Value};

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

    /// The schema's name and its JSON schema.
    pub(super) fn schema(self) -> (&'static str, Value) {
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
                    "encounters": {"type": "array"},
                    "truth": {"type": ["object", "null"], "description": "simulation only: the latest ground truth, [id, x, y, theta] per robot at its own time t", "properties": {
                        "t": num, "robots": {"type": "array", "items": {"type": "array"}}}}}}),
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
    /// The robots' addresses when they were reached by address (`--transport tcp` and the
    /// like), in run order: what `coordinator --resume` connects to again. Empty otherwise.
    pub addresses: Vec<String>,
    /// The run's time limit, seconds (absent from older recordings).
    pub duration_s: Option<f64>,
    /// Wall-clock time of the recording's zero, nanoseconds since the Unix epoch; every log time
    /// is this plus the run's own clock.
    pub start_unix_ns: u64,
}

impl RunInfo {
    /// As the metadata record's key-value map.
    pub(super) fn to_map(&self) -> BTreeMap<String, String> {
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
        if !self.addresses.is_empty() {
            m.insert("addresses".into(), self.addresses.join(","));
        }
        if let Some(d) = self.duration_s {
            m.insert("duration_s".into(), d.to_string());
        }
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
            addresses: m
                .get("addresses")
                .map(|a| a.split(',').map(str::to_string).collect())
                .unwrap_or_default(),
            duration_s: m
                .get("duration_s")
                .map(|d| d.parse().with_context(|| parse_err("duration_s")))
                .transpose()?,
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
