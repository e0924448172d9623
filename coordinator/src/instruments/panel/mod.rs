//! The live control panel: one HTML page (shipped in the binary) over a WebSocket fed by the
//! observer's snapshots. Every motion command from the page goes through the supervisor's safety
//! check; settings go through the robot actor's typed settings reflection (written, then read
//! back).
//!
//! Every request must name the panel's own address in `Host` (no DNS rebinding), and an `Origin`,
//! required on the WebSocket, must be the panel's own page. The WebSocket also needs the run's
//! token (`?token=…` or `Authorization: Bearer …`), which the page served at `/` embeds. On
//! loopback the page itself needs no token; on any other address every request does.

use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;

use actix::Addr;
use anyhow::{Context as _, Result};
use axum::extract::connect_info::{ConnectInfo, Connected};
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use axum::serve::IncomingStream;
use axum::Router;
use behaviours::{Behaviour, Intent, MoveCommand, Registry, WorldSnapshot};
use protocol::packets::ReflectorMode;
use robot_actor::actor::{Command, ReflectorSetup, WriteSettings};
use robot_actor::Robot;
use serde_json::{json, Value};
use tokio::sync::broadcast;

use crate::instruments::record::{leaf_bytes, leaf_value, leaves, Leaf};
use crate::supervisor::{EStop, PanelIntent, Supervisor};

const INDEX: &str = include_str!("index.html");

/// Where the page carries the run's token; replaced when the page is served.
const TOKEN_SLOT: &str = "{{PANEL_TOKEN}}";

/// Reflector period while a robot's PID view is open (reduced state), milliseconds.
pub const PID_PERIOD_MS: u16 = 10;

/// How to serve the panel.
#[derive(Clone, Debug)]
pub struct PanelOptions {
    /// Listen address; port 0 picks a free one.
    pub addr: SocketAddr,
    /// Keep serving after the experiment's verdict, until Ctrl-C.
    pub linger: bool,
}

/// What the panel serves from.
#[derive(Clone)]
pub struct PanelContext {
    /// Commands go through it.
    pub supervisor: Addr<Supervisor>,
    /// The robots, for settings and the reflector.
    pub robots: Vec<(u16, Robot)>,
    /// Snapshot frames from the observer.
    pub feed: broadcast::Sender<Arc<str>>,
    /// What does not change: arena, track, boxes' sizes, robot ids.
    pub scene: Value,
}

/// A running panel.
#[derive(Debug)]
pub struct PanelServer {
    /// Where it listens.
    pub addr: SocketAddr,
    /// This run's token: the WebSocket always needs it, every request does off loopback.
    pub token: String,
    /// The page's address; it carries the token only when the panel is not on loopback.
    pub url: String,
    task: tokio::task::JoinHandle<()>,
}

impl Drop for PanelServer {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// A fresh 128-bit token from the standard library's randomly keyed hasher (keyed from the OS).
fn new_token() -> String {
    use std::hash::{BuildHasher, Hasher};
    let mut out = String::new();
    for salt in 0..2u64 {
        let mut h = std::collections::hash_map::RandomState::new().build_hasher();
        h.write_u64(salt);
        h.write_u128(
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_nanos())
                .unwrap_or(0),
        );
        out.push_str(&format!("{:016x}", h.finish()));
    }
    out
}

#[derive(Clone)]
struct AppState {
    ctx: PanelContext,
    token: Arc<str>,
    /// The page with the token in place.
    page: Arc<str>,
    /// Off loopback the page itself also needs the token.
    token_everywhere: bool,
    /// One permit per open WebSocket, [`MAX_SESSIONS`] in all.
    sessions: Arc<tokio::sync::Semaphore>,
}

/// The most panel WebSockets open at once: each holds a feed of snapshot frames, and 200 of
/// them raised the coordinator's resident memory from 21 to 75 MB, not all of it given back.
pub const MAX_SESSIONS: usize = 16;

/// The local address a connection reached: with a wildcard bind this is the interface's own
/// address, which is what a browser that really asked for this panel puts in `Host`.
#[derive(Clone, Copy, Debug)]
struct Reached(SocketAddr);

impl Connected<IncomingStream<'_, tokio::net::TcpListener>> for Reached {
    fn connect_info(stream: IncomingStream<'_, tokio::net::TcpListener>) -> Self {
        // An address that names nothing makes every Host wrong: refused rather than guessed.
        Reached(
            stream
                .io()
                .local_addr()
                .unwrap_or_else(|_| SocketAddr::from(([0, 0, 0, 0], 0))),
        )
    }
}

/// Binds the panel's address now, so that a busy or foreign address is a one-line error before
/// any robot moves.
///
/// # Errors
/// The address cannot be bound (in use, not this machine's, no permission).
pub fn bind(addr: SocketAddr) -> Result<std::net::TcpListener> {
    let listener = std::net::TcpListener::bind(addr)
        .with_context(|| format!("panel: cannot listen on {addr}"))?;
    listener
        .set_nonblocking(true)
        .with_context(|| format!("panel: cannot listen on {addr}"))?;
    Ok(listener)
}

/// Starts serving on the current tokio runtime from a listener made by [`bind`].
///
/// # Errors
/// The listener cannot be handed to tokio.
pub fn serve(listener: std::net::TcpListener, ctx: PanelContext) -> Result<PanelServer> {
    let local = listener.local_addr()?;
    // Tokio requires a non-blocking socket; `bind` made it so, a caller's own may not be.
    listener.set_nonblocking(true)?;
    let listener = tokio::net::TcpListener::from_std(listener)
        .with_context(|| format!("panel: cannot serve on {local}"))?;
    let token = new_token();
    let token_everywhere = !local.ip().is_loopback();
    let state = AppState {
        ctx,
        token: Arc::from(token.as_str()),
        page: Arc::from(INDEX.replace(TOKEN_SLOT, &token)),
        token_everywhere,
        sessions: Arc::new(tokio::sync::Semaphore::new(MAX_SESSIONS)),
    };
    let app = Router::new()
        .route("/", get(page))
        .route("/ws", get(ws))
        .layer(middleware::from_fn_with_state(state.clone(), guard))
        .with_state(state);
    let task = tokio::spawn(async move {
        let service = app.into_make_service_with_connect_info::<Reached>();
        if let Err(e) = axum::serve(listener, service).await {
            tracing::warn!(error = %e, "panel server stopped");
        }
    });
    let shown = if local.ip().is_unspecified() {
        SocketAddr::new(std::net::Ipv4Addr::LOCALHOST.into(), local.port())
    } else {
        local
    };
    let url = if token_everywhere {
        format!("http://{shown}/?token={token}")
    } else {
        format!("http://{shown}/")
    };
    Ok(PanelServer {
        addr: local,
        token,
        url,
        task,
    })
}

async fn page(State(state): State<AppState>) -> Response {
    let mut r = Html(state.page.to_string()).into_response();
    let h = r.headers_mut();
    // The page carries the token: not cached, not framed by another site, not sent on as a
    // referrer.
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static("frame-ancestors 'none'"),
    );
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    r
}

/// The `Host` values under which a connection that reached `local` is asking for this panel:
/// the address itself and, on loopback, `localhost`; without the port when it is HTTP's own.
fn allowed_hosts(local: SocketAddr) -> Vec<String> {
    let ip = match local.ip() {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(IpAddr::V6(v6), IpAddr::V4),
        v4 => v4,
    };
    let port = local.port();
    let mut names = vec![SocketAddr::new(ip, port).to_string()];
    if ip.is_loopback() {
        names.push(format!("localhost:{port}"));
    }
    if port == 80 {
        let bare: Vec<String> = names
            .iter()
            .filter_map(|n| n.strip_suffix(":80").map(str::to_string))
            .collect();
        names.extend(bare);
    }
    names
}

/// Why a request is refused, if it is: `Host`, then `Origin`, then the token.
fn refusal(
    allowed: &[String],
    host: Option<&str>,
    origin: Option<&str>,
    websocket: bool,
    token: Option<&str>,
    state: &AppState,
) -> Option<(StatusCode, String)> {
    let ours = allowed.first().map_or("", String::as_str);
    if !host.is_some_and(|h| allowed.iter().any(|a| a.eq_ignore_ascii_case(h))) {
        return Some((
            StatusCode::FORBIDDEN,
            format!("refused: the Host header does not name this panel (open http://{ours}/)\n"),
        ));
    }
    match origin {
        Some(o)
            if !allowed.iter().any(|a| {
                o.strip_prefix("http://")
                    .is_some_and(|h| h.eq_ignore_ascii_case(a))
            }) =>
        {
            return Some((
                StatusCode::FORBIDDEN,
                format!(
                    "refused: requests from another site's page (the panel is http://{ours})\n"
                ),
            ));
        }
        None if websocket => {
            return Some((
                StatusCode::FORBIDDEN,
                format!("refused: the WebSocket needs an Origin header naming http://{ours}\n"),
            ));
        }
        _ => {}
    }
    match token {
        Some(t) if same(t.as_bytes(), state.token.as_bytes()) => None,
        Some(_) => Some((
            StatusCode::UNAUTHORIZED,
            "refused: wrong token; open the URL the coordinator printed\n".to_string(),
        )),
        None if websocket || state.token_everywhere => Some((
            StatusCode::UNAUTHORIZED,
            "refused: this panel needs its token: open the URL the coordinator printed\n"
                .to_string(),
        )),
        None => None,
    }
}

/// Compares without stopping at the first difference, so timing does not reveal a prefix.
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// The token a request carries, in its query or as a bearer credential.
fn token_of(req: &Request) -> Option<&str> {
    let in_query = req
        .uri()
        .query()
        .into_iter()
        .flat_map(|q| q.split('&'))
        .find_map(|kv| kv.strip_prefix("token="));
    in_query.or_else(|| {
        req.headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
    })
}

async fn guard(
    State(state): State<AppState>,
    ConnectInfo(Reached(local)): ConnectInfo<Reached>,
    req: Request,
    next: Next,
) -> Response {
    // Decided in its own scope: a request body is not `Sync`, so no borrow of the request may
    // live across the await below.
    let refused = {
        let header_str = |name| {
            req.headers()
                .get(name)
                .and_then(|v: &HeaderValue| v.to_str().ok())
        };
        refusal(
            &allowed_hosts(local),
            header_str(header::HOST),
            header_str(header::ORIGIN),
            req.uri().path() == "/ws",
            token_of(&req),
            &state,
        )
    };
    match refused {
        Some(why) => why.into_response(),
        None => next.run(req).await,
    }
}

async fn ws(upgrade: WebSocketUpgrade, State(state): State<AppState>) -> Response {
    let Ok(permit) = Arc::clone(&state.sessions).try_acquire_owned() else {
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            format!("refused: {MAX_SESSIONS} panel sessions are open already\n"),
        )
            .into_response();
    };
    upgrade.on_upgrade(move |socket| async move {
        session(socket, state.ctx).await;
        drop(permit);
    })
}

fn settings_leaves() -> Vec<Leaf> {
    leaves(&<protocol::Settings as protocol::Layout>::LAYOUT)
}

async fn session(mut socket: WebSocket, ctx: PanelContext) {
    let fields: Vec<Value> = settings_leaves()
        .iter()
        .map(|l| json!({"path": l.path, "type": l.ty}))
        .collect();
    let hello = json!({"type": "hello", "scene": ctx.scene, "settings": fields});
    if socket
        .send(Message::Text(hello.to_string().into()))
        .await
        .is_err()
    {
        return;
    }
    let mut feed = ctx.feed.subscribe();
    loop {
        tokio::select! {
            frame = feed.recv() => match frame {
                Ok(f) => {
                    if socket.send(Message::Text(f.to_string().into())).await.is_err() {
                        return;
                    }
                }
                // A slow page skips frames rather than holding the observer up.
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => return,
            },
            msg = socket.recv() => {
                let text = match msg {
                    Some(Ok(Message::Text(t))) => t.to_string(),
                    Some(Ok(Message::Close(_))) | None | Some(Err(_)) => return,
                    Some(Ok(_)) => continue,
                };
                let reply = match serde_json::from_str::<Value>(&text) {
                    Ok(cmd) => {
                        let id = cmd["id"].clone();
                        let mut r = command(&ctx, &cmd).await;
                        r["id"] = id;
                        r
                    }
                    Err(e) => json!({"type": "reply", "ok": false, "message": format!("not JSON: {e}")}),
                };
                if socket.send(Message::Text(reply.to_string().into())).await.is_err() {
                    return;
                }
            }
        }
    }
}

fn ok(message: impl Into<String>) -> Value {
    json!({"type": "reply", "ok": true, "message": message.into()})
}

fn fail(message: impl Into<String>) -> Value {
    json!({"type": "reply", "ok": false, "message": message.into()})
}

fn num(cmd: &Value, key: &str) -> Result<f32, String> {
    cmd[key]
        .as_f64()
        .filter(|v| v.is_finite())
        .map(|v| v as f32)
        .ok_or_else(|| format!("{key} must be a number"))
}

/// Carries out one command from the page and says how it went.
pub async fn command(ctx: &PanelContext, cmd: &Value) -> Value {
    match run_command(ctx, cmd).await {
        Ok(v) => v,
        Err(e) => fail(e),
    }
}

async fn run_command(ctx: &PanelContext, cmd: &Value) -> Result<Value, String> {
    let name = cmd["cmd"].as_str().unwrap_or("");
    if name == "estop" {
        ctx.supervisor
            .send(EStop)
            .await
            .map_err(|e| format!("supervisor unreachable: {e}"))?;
        return Ok(ok("every robot stopped; the behaviour is over"));
    }
    let id = cmd["robot"]
        .as_u64()
        .and_then(|v| u16::try_from(v).ok())
        .ok_or("robot must be a robot id")?;
    let robot = ctx
        .robots
        .iter()
        .find(|(r, _)| *r == id)
        .map(|(_, r)| r)
        .ok_or_else(|| format!("no robot {id}"))?;
    let intent = match name {
        "wheels" => Intent::WheelSpeeds {
            robot: id,
            left: num(cmd, "left")?,
            right: num(cmd, "right")?,
        },
        "straight" => Intent::Move {
            robot: id,
            command: MoveCommand::Straight {
                distance_m: num(cmd, "distance")?,
                speed_mps: num(cmd, "speed")?,
            },
            tag: 0,
        },
        "rotate" => Intent::Move {
            robot: id,
            command: MoveCommand::Rotate {
                angle_deg: num(cmd, "angle")?,
                speed_mps: num(cmd, "speed")?,
            },
            tag: 0,
        },
        "stop" => Intent::Stop { robot: id },
        "settings" => return read_all_settings(robot, id).await,
        "set" => return write_setting(robot, id, cmd).await,
        "pid" => return pid_view(robot, id, cmd).await,
        other => return Err(format!("unknown command {other:?}")),
    };
    ctx.supervisor
        .send(PanelIntent(intent))
        .await
        .map_err(|e| format!("supervisor unreachable: {e}"))?
        .map_err(|why| format!("held by the safety check: {why}"))?;
    Ok(ok(format!("robot {id}: {name} sent")))
}

/// Every setting of robot `id`, read from the robot.
async fn read_all_settings(robot: &Robot, id: u16) -> Result<Value, String> {
    let s = robot
        .read_settings()
        .await
        .map_err(|e| format!("reading settings: {e}"))?;
    let bytes = bytemuck::bytes_of(&s);
    let values: serde_json::Map<String, Value> = settings_leaves()
        .iter()
        .map(|l| (l.path.clone(), leaf_value(l, bytes)))
        .collect();
    Ok(json!({"type": "settings", "ok": true, "robot": id, "values": values}))
}

/// Writes one setting through the robot actor and reads the whole block back from the robot,
/// not from the host's mirror.
async fn write_setting(robot: &Robot, id: u16, cmd: &Value) -> Result<Value, String> {
    let path = cmd["path"].as_str().ok_or("path must be a settings path")?;
    let leaf = settings_leaves()
        .into_iter()
        .find(|l| l.path == path)
        .ok_or_else(|| format!("no setting {path:?}"))?;
    let text = match &cmd["value"] {
        Value::String(s) => s.clone(),
        v => v.to_string(),
    };
    let bytes = leaf_bytes(&leaf, &text)?;
    robot
        .addr()
        .send(WriteSettings {
            offset: leaf.offset,
            bytes,
        })
        .await
        .map_err(|e| format!("robot unreachable: {e}"))?
        .map_err(|e| format!("writing {path}: {e}"))?;
    // Read the whole block back from the robot, not from the host's mirror.
    let s = robot
        .read_settings()
        .await
        .map_err(|e| format!("reading back: {e}"))?;
    let value = leaf_value(&leaf, bytemuck::bytes_of(&s));
    Ok(
        json!({"type": "reply", "ok": true, "robot": id, "path": path,
        "value": value, "message": format!("robot {id}: {path} read back {value}")}),
    )
}

/// Turns the PID view on (the reduced state at a high rate) or off (the full state again).
async fn pid_view(robot: &Robot, id: u16, cmd: &Value) -> Result<Value, String> {
    let on = cmd["on"].as_bool().unwrap_or(false);
    let setup = if on {
        ReflectorSetup {
            mode: ReflectorMode::Reduced,
            period_ms: PID_PERIOD_MS,
        }
    } else {
        robot_actor::RobotConfig::default().reflector
    };
    robot
        .addr()
        .send(Command::Reflector(setup))
        .await
        .map_err(|e| format!("robot unreachable: {e}"))?
        .map_err(|e| format!("reflector: {e}"))?;
    Ok(ok(if on {
        format!("robot {id}: reduced state every {PID_PERIOD_MS} ms")
    } else {
        format!("robot {id}: full state again")
    }))
}

/// A behaviour that does nothing and never ends: the robots wait for the control panel.
#[derive(Debug, Default)]
pub struct Teleop;

impl Behaviour for Teleop {
    fn start(&mut self, _: &WorldSnapshot, _: &mut behaviours::Team) -> Vec<Intent> {
        Vec::new()
    }
}

/// Adds `teleop` (robots driven from the panel only) to a registry.
pub fn register_teleop(registry: &mut Registry) {
    registry.register(
        "teleop",
        "robots wait for commands from the control panel (use with --panel); runs until the \
         time limit, the e-stop or Ctrl-C",
        "oval",
        |_| Ok(Box::new(Teleop)),
    );
}

#[cfg(test)]
mod tests {
    use super::allowed_hosts;

    #[test]
    fn the_allowed_hosts_are_the_reached_address_and_localhost_on_loopback() {
        assert_eq!(
            allowed_hosts("127.0.0.1:7878".parse().unwrap()),
            ["127.0.0.1:7878", "localhost:7878"]
        );
        assert_eq!(
            allowed_hosts("[::1]:7878".parse().unwrap()),
            ["[::1]:7878", "localhost:7878"]
        );
        // A dual-stack wildcard bind reports IPv4 clients' interface as a mapped address.
        assert_eq!(
            allowed_hosts("[::ffff:192.168.1.5]:7878".parse().unwrap()),
            ["192.168.1.5:7878"]
        );
        assert_eq!(
            allowed_hosts("10.0.0.2:80".parse().unwrap()),
            ["10.0.0.2:80", "10.0.0.2"]
        );
    }
}
