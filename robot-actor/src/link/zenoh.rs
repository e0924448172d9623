//! Robots behind `pocketfleet-gateway`s, reached over zenoh (feature `zenoh`).
//!
//! A gateway owns some robots' links (Bluetooth, serial, TCP, simulated) and bridges their
//! packets, unchanged, onto zenoh. The key space, under `pocketfleet/<fleet>/`:
//!
//! | key | what |
//! |---|---|
//! | `robot/<id>/up` | packets from robot `<id>`: one or more per sample, each after its length ([`UpBatch`]) |
//! | `robot/<id>/down` | one sample per packet to robot `<id>` |
//! | `alive/robot/<id>` | liveliness token, held by the gateway while the robot's link is up |
//! | `alive/gateway/<name>` | liveliness token of each gateway |
//! | `gateway/<name>/stats` | queryable: the gateway's link statistics as JSON |
//!
//! A robot is named by its id, not by its gateway, so a robot that reconnects through another
//! gateway is the same robot. A [`ZenohConnector`] opens a [`Link`] to one robot id; the link is
//! lost when the robot's token goes. Sessions are peers that meet only through the endpoints
//! given: multicast scouting is off unless a zenoh configuration file turns it on.
//!
//! zenoh refuses to run on a current-thread tokio runtime, which is what actix gives every
//! actor, so every zenoh call here runs on a small multi-thread runtime of its own
//! ([`on_zenoh`]); packets cross between the two by channels.

use std::future::Future;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use futures::future::BoxFuture;
use futures::FutureExt;
use tokio::sync::mpsc;
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;
use zenoh::Session;

use super::{
    Connector, Discovered, Discoverer, Link, LinkCounters, LinkError, LinkEvent, SEND_QUEUE,
};

/// Where and how to join a fleet's zenoh network.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ZenohOptions {
    /// Endpoints to listen on, e.g. `tcp/127.0.0.1:7447`.
    pub listen: Vec<String>,
    /// Endpoints of peers to connect to.
    pub connect: Vec<String>,
    /// A zenoh JSON5 configuration file (TLS, authentication, …) applied before the above.
    pub config_file: Option<std::path::PathBuf>,
}

/// A connect attempt not finished by then is given up, and the robot actor tries again later: a
/// liveliness query or a declaration can wait on a peer that has just died.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);

/// How long a liveliness query waits for the gateways' answers.
const QUERY_TIMEOUT: Duration = Duration::from_secs(1);

fn unavailable(what: impl std::fmt::Display) -> LinkError {
    LinkError::Unavailable("zenoh", what.to_string())
}

/// A zenoh session shared by clones, closed on the zenoh runtime when the last clone goes:
/// closing a session blocks, which zenoh forbids on a current-thread runtime.
#[derive(Clone)]
pub struct FleetSession(Arc<SessionCell>);

struct SessionCell(Option<Session>);

impl Drop for SessionCell {
    fn drop(&mut self) {
        if let Some(session) = self.0.take() {
            zenoh_runtime().spawn(async move { drop(session) });
        }
    }
}

impl FleetSession {
    /// The zenoh session, for calls made inside [`on_zenoh`].
    pub fn session(&self) -> &Session {
        self.0 .0.as_ref().expect("present until dropped")
    }
}

fn zenoh_runtime() -> &'static tokio::runtime::Runtime {
    static RUNTIME: OnceLock<tokio::runtime::Runtime> = OnceLock::new();
    RUNTIME.get_or_init(|| {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("zenoh-io")
            .enable_all()
            .build()
            .expect("a one-thread tokio runtime builds")
    })
}

/// Runs `work` on the zenoh runtime (one worker thread, started on first use) and awaits it
/// from any runtime, current-thread ones included.
///
/// # Panics
/// When `work` panicked.
pub async fn on_zenoh<T: Send + 'static>(work: impl Future<Output = T> + Send + 'static) -> T {
    match zenoh_runtime().spawn(work).await {
        Ok(value) => value,
        Err(e) => std::panic::resume_unwind(e.into_panic()),
    }
}

/// Opens a peer session: the configuration file if any, then peer mode, multicast scouting off
/// (unless the file turned it on) and the endpoints given.
///
/// # Errors
/// A configuration that zenoh refuses, or a session that does not open (an endpoint in use).
pub async fn open_session(options: &ZenohOptions) -> Result<FleetSession, LinkError> {
    let config = session_config(options)?;
    let session = on_zenoh(async move { zenoh::open(config).await.map_err(unavailable) }).await?;
    Ok(FleetSession(Arc::new(SessionCell(Some(session)))))
}

fn session_config(options: &ZenohOptions) -> Result<zenoh::Config, LinkError> {
    let (mut config, chose_multicast) = match &options.config_file {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| unavailable(format!("{}: {e}", path.display())))?;
            let config = zenoh::Config::from_json5(&text)
                .map_err(|e| unavailable(format!("{}: {e}", path.display())))?;
            let tree: serde_json::Value = json5::from_str(&text)
                .map_err(|e| unavailable(format!("{}: {e}", path.display())))?;
            let chose = !tree["scouting"]["multicast"]["enabled"].is_null();
            (config, chose)
        }
        None => (zenoh::Config::default(), false),
    };
    let set = |config: &mut zenoh::Config, key: &str, value: String| {
        config
            .insert_json5(key, &value)
            .map_err(|e| unavailable(format!("{key} = {value}: {e}")))
    };
    set(&mut config, "mode", "\"peer\"".into())?;
    // zenoh's own default is to scout by multicast on every interface; ours is to meet only
    // the peers named, unless the user's file says otherwise in so many words.
    if !chose_multicast {
        set(&mut config, "scouting/multicast/enabled", "false".into())?;
    }
    let json = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
    if !options.listen.is_empty() {
        set(&mut config, "listen/endpoints", json(&options.listen))?;
    }
    if !options.connect.is_empty() {
        set(&mut config, "connect/endpoints", json(&options.connect))?;
    }
    Ok(config)
}

/// The fleet's keys.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Keys {
    fleet: String,
}

impl Keys {
    /// The keys of fleet `fleet` (a single key chunk: no `/`, `*`, `$`, `?` or `#`).
    ///
    /// # Errors
    /// A name that is not one key chunk.
    pub fn new(fleet: &str) -> Result<Self, LinkError> {
        let bad = fleet.is_empty() || fleet.contains(['/', '*', '$', '?', '#']);
        if bad {
            return Err(LinkError::BadAddress {
                address: fleet.into(),
                reason: "a fleet name is one word without / * $ ? #".into(),
            });
        }
        Ok(Self {
            fleet: fleet.into(),
        })
    }

    /// Robot `id`'s packets to the host.
    pub fn up(&self, id: u16) -> String {
        format!("pocketfleet/{}/robot/{id}/up", self.fleet)
    }

    /// Robot `id`'s packets from the host.
    pub fn down(&self, id: u16) -> String {
        format!("pocketfleet/{}/robot/{id}/down", self.fleet)
    }

    /// Robot `id`'s liveliness token.
    pub fn robot_alive(&self, id: u16) -> String {
        format!("pocketfleet/{}/alive/robot/{id}", self.fleet)
    }

    /// Every robot's liveliness token.
    pub fn robots_alive(&self) -> String {
        format!("pocketfleet/{}/alive/robot/*", self.fleet)
    }

    /// Gateway `name`'s liveliness token.
    pub fn gateway_alive(&self, name: &str) -> String {
        format!("pocketfleet/{}/alive/gateway/{name}", self.fleet)
    }

    /// Gateway `name`'s statistics queryable.
    pub fn gateway_stats(&self, name: &str) -> String {
        format!("pocketfleet/{}/gateway/{name}/stats", self.fleet)
    }
}

/// The packets of one `up` sample: each is preceded by its length as a little-endian `u16`.
///
/// A gateway puts every packet its robot's link has already delivered into one sample, so under
/// load the per-sample cost of zenoh is shared, and a lone packet waits for nothing.
#[derive(Clone, Debug, Default)]
pub struct UpBatch {
    bytes: Vec<u8>,
    packets: usize,
}

impl UpBatch {
    /// Samples stop growing past this many bytes.
    pub const FULL: usize = 16 * 1024;

    /// Appends one packet (packets are far shorter than 64 KiB; a longer one is cut short,
    /// which the host then counts as a corrupt packet).
    pub fn push(&mut self, packet: &[u8]) {
        let len = packet.len().min(usize::from(u16::MAX));
        self.bytes.extend_from_slice(&(len as u16).to_le_bytes());
        self.bytes.extend_from_slice(&packet[..len]);
        self.packets += 1;
    }

    /// Packets in it.
    pub fn packets(&self) -> usize {
        self.packets
    }

    /// Whether another packet should go in a sample of its own.
    pub fn is_full(&self) -> bool {
        self.bytes.len() >= Self::FULL
    }

    /// The sample's payload, leaving the batch empty.
    pub fn take(&mut self) -> Vec<u8> {
        self.packets = 0;
        std::mem::take(&mut self.bytes)
    }

    /// The packets of a sample, in order; `Err` with the packets read when its end is cut short.
    pub fn split(mut sample: &[u8]) -> Result<Vec<&[u8]>, Vec<&[u8]>> {
        let mut packets = Vec::new();
        while !sample.is_empty() {
            let Some((len, rest)) = sample.split_first_chunk::<2>() else {
                return Err(packets);
            };
            let len = usize::from(u16::from_le_bytes(*len));
            if rest.len() < len {
                return Err(packets);
            }
            let (packet, rest) = rest.split_at(len);
            packets.push(packet);
            sample = rest;
        }
        Ok(packets)
    }
}

/// Robot ids whose tokens are alive now.
///
/// # Errors
/// The liveliness query failed.
pub async fn alive_robots(session: &FleetSession, keys: &Keys) -> Result<Vec<u16>, LinkError> {
    let (session, keys) = (session.clone(), keys.clone());
    on_zenoh(async move { query_alive(session.session(), &keys).await }).await
}

async fn query_alive(session: &Session, keys: &Keys) -> Result<Vec<u16>, LinkError> {
    let replies = session
        .liveliness()
        .get(keys.robots_alive())
        .timeout(QUERY_TIMEOUT)
        .await
        .map_err(unavailable)?;
    let mut ids = Vec::new();
    while let Ok(reply) = replies.recv_async().await {
        if let Ok(sample) = reply.result() {
            let key = sample.key_expr().as_str();
            if let Some(id) = key.rsplit('/').next().and_then(|s| s.parse().ok()) {
                ids.push(id);
            }
        }
    }
    ids.sort_unstable();
    ids.dedup();
    Ok(ids)
}

/// Reaches robot `id` of a fleet through whichever gateway holds it.
#[derive(Clone)]
pub struct ZenohConnector {
    session: FleetSession,
    keys: Keys,
    id: u16,
}

impl ZenohConnector {
    /// Robot `id` of the fleet whose keys are `keys`, over `session`.
    pub fn new(session: FleetSession, keys: Keys, id: u16) -> Self {
        Self { session, keys, id }
    }
}

impl Connector for ZenohConnector {
    fn peer(&self) -> String {
        format!("zenoh:{}", self.keys.up(self.id).trim_end_matches("/up"))
    }

    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let this = self.clone();
        let peer = self.peer();
        // Timed on the caller's runtime, so a stalled zenoh runtime cannot hold the actor.
        async move {
            tokio::time::timeout(CONNECT_TIMEOUT, on_zenoh(this.open()))
                .await
                .unwrap_or_else(|_| {
                    Err(LinkError::Connect {
                        peer,
                        source: std::io::Error::new(
                            std::io::ErrorKind::TimedOut,
                            format!("no answer from the fleet within {CONNECT_TIMEOUT:?}"),
                        ),
                    })
                })
        }
        .boxed()
    }
}

impl ZenohConnector {
    async fn open(self) -> Result<Link, LinkError> {
        let peer = self.peer();
        if !query_alive(self.session.session(), &self.keys)
            .await?
            .contains(&self.id)
        {
            return Err(LinkError::Connect {
                peer,
                source: std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "no gateway holds this robot",
                ),
            });
        }
        let counters = Arc::new(LinkCounters::default());
        let (tx, mut outgoing) = mpsc::channel::<Vec<u8>>(SEND_QUEUE);
        let (events, rx) = mpsc::unbounded_channel();
        let up = {
            let events = events.clone();
            let counters = Arc::clone(&counters);
            self.session
                .session()
                .declare_subscriber(self.keys.up(self.id))
                .callback(move |sample| {
                    let payload = sample.payload().to_bytes();
                    let packets = UpBatch::split(&payload).unwrap_or_else(|read| {
                        // A sample cut short: the whole packets before the cut still count.
                        LinkCounters::bump(&counters.framing_errors);
                        read
                    });
                    for packet in packets {
                        LinkCounters::bump(&counters.packets_in);
                        let _ = events.send(LinkEvent::Packet(packet.to_vec()));
                    }
                })
                .await
                .map_err(unavailable)?
        };
        let gone = {
            let events = events.clone();
            let peer = peer.clone();
            self.session
                .session()
                .liveliness()
                .declare_subscriber(self.keys.robot_alive(self.id))
                .callback(move |sample| {
                    if sample.kind() == SampleKind::Delete {
                        let source = std::io::Error::new(
                            std::io::ErrorKind::ConnectionAborted,
                            "its gateway lost it, or the gateway is gone",
                        );
                        let lost = LinkError::Lost {
                            peer: peer.clone(),
                            source,
                        };
                        let _ = events.send(LinkEvent::Closed(Some(lost)));
                    }
                })
                .await
                .map_err(unavailable)?
        };
        let down = self
            .session
            .session()
            .declare_publisher(self.keys.down(self.id))
            .congestion_control(CongestionControl::Block)
            .await
            .map_err(unavailable)?;
        let sent = Arc::clone(&counters);
        tokio::spawn(async move {
            while let Some(packet) = outgoing.recv().await {
                if down.put(packet).await.is_err() {
                    break;
                }
                LinkCounters::bump(&sent.packets_out);
            }
            // The robot actor dropped the link: stop listening for this robot.
            drop((up, gone));
            let _ = events.send(LinkEvent::Closed(None));
        });
        Ok(Link {
            peer,
            tx,
            rx,
            counters,
        })
    }
}

/// Finds a fleet's robots by their liveliness tokens, waiting until `expect` are there (or any,
/// when `expect` is 0) or `wait` has passed.
pub struct ZenohDiscoverer {
    session: FleetSession,
    keys: Keys,
    expect: usize,
    wait: Duration,
}

impl ZenohDiscoverer {
    /// Discovers robots of the fleet whose keys are `keys` over `session`.
    pub fn new(session: FleetSession, keys: Keys, expect: usize, wait: Duration) -> Self {
        Self {
            session,
            keys,
            expect,
            wait,
        }
    }
}

impl Discoverer for ZenohDiscoverer {
    fn discover(&self) -> BoxFuture<'_, Result<Vec<Discovered>, LinkError>> {
        let (session, keys, expect, wait) = (
            self.session.clone(),
            self.keys.clone(),
            self.expect,
            self.wait,
        );
        on_zenoh(discover(session, keys, expect, wait)).boxed()
    }
}

async fn discover(
    fleet: FleetSession,
    keys: Keys,
    expect: usize,
    wait: Duration,
) -> Result<Vec<Discovered>, LinkError> {
    let deadline = tokio::time::Instant::now() + wait;
    // Tokens already declared come first (history), then changes as they happen.
    let tokens = fleet
        .session()
        .liveliness()
        .declare_subscriber(keys.robots_alive())
        .history(true)
        .await
        .map_err(unavailable)?;
    let mut ids = std::collections::BTreeSet::new();
    while ids.len() < expect.max(1) {
        let Ok(Ok(sample)) = tokio::time::timeout_at(deadline, tokens.recv_async()).await else {
            break;
        };
        let id = sample.key_expr().as_str().rsplit('/').next();
        if let Some(id) = id.and_then(|s| s.parse::<u16>().ok()) {
            if sample.kind() == SampleKind::Put {
                ids.insert(id);
            } else {
                ids.remove(&id);
            }
        }
    }
    Ok(ids
        .into_iter()
        .map(|id| Discovered {
            name: format!("robot {id}"),
            connector: Arc::new(ZenohConnector::new(fleet.clone(), keys.clone(), id)),
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sessions_are_peers_that_meet_only_through_the_endpoints_given() {
        let options = ZenohOptions {
            listen: vec!["tcp/127.0.0.1:7447".into()],
            connect: vec!["tcp/127.0.0.1:7448".into()],
            config_file: None,
        };
        let config = session_config(&options).expect("a configuration");
        let get = |key: &str| config.get_json(key).expect(key);
        assert_eq!(get("mode"), "\"peer\"");
        assert_eq!(get("scouting/multicast/enabled"), "false");
        assert!(get("listen/endpoints").contains("tcp/127.0.0.1:7447"));
        assert!(get("connect/endpoints").contains("tcp/127.0.0.1:7448"));
    }

    #[test]
    fn a_users_file_keeps_multicast_off_unless_it_turns_it_on() {
        let dir = std::env::temp_dir().join(format!("pf-zenoh-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a temporary directory");
        let with = |name: &str, text: &str| {
            let path = dir.join(name);
            std::fs::write(&path, text).expect("written");
            let options = ZenohOptions {
                config_file: Some(path),
                ..Default::default()
            };
            let config = session_config(&options).expect("a configuration");
            config.get_json("scouting/multicast/enabled").expect("set")
        };
        // JSON5, as zenoh's own files are: comments and unquoted keys.
        let silent = "{ // nothing about scouting\n  transport: { unicast: { max_links: 2 } } }";
        assert_eq!(with("silent.json5", silent), "false");
        let on = "{ scouting: { multicast: { enabled: true } } }";
        assert_eq!(with("on.json5", on), "true");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn an_up_sample_carries_packets_in_order_and_a_cut_one_keeps_the_whole_ones() {
        let mut batch = UpBatch::default();
        for packet in [&[1u8, 2, 3][..], &[], &[9; 300]] {
            batch.push(packet);
        }
        assert_eq!(batch.packets(), 3);
        let sample = batch.take();
        assert_eq!(batch.packets(), 0);
        let packets = UpBatch::split(&sample).expect("whole");
        assert_eq!(packets, vec![&[1u8, 2, 3][..], &[], &[9; 300]]);
        assert_eq!(
            UpBatch::split(&sample[..sample.len() - 1]),
            Err(packets[..2].to_vec())
        );
        assert_eq!(UpBatch::split(&[7]), Err(vec![]));
    }

    #[test]
    fn a_fleet_is_one_key_chunk() {
        assert!(Keys::new("lab").is_ok());
        for bad in ["", "a/b", "lab*", "$x", "q?", "#"] {
            assert!(Keys::new(bad).is_err(), "{bad:?}");
        }
        let keys = Keys::new("lab").unwrap();
        assert_eq!(keys.up(3), "pocketfleet/lab/robot/3/up");
        assert_eq!(keys.robot_alive(3), "pocketfleet/lab/alive/robot/3");
    }
}
