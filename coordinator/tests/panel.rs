//! The control panel: its own Host and Origin only, the run's token on the WebSocket (and on
//! every request off loopback), a busy address refused before the run, and the page itself driven
//! in headless Chromium over the DevTools protocol (robots shown, joystick drive, settings write
//! with read-back, e-stop, phone-sized layout, screenshot).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use serde_json::{json, Value};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::Message;

/// A coordinator child process, killed when dropped.
struct Coordinator {
    child: Child,
    url: String,
}

impl Drop for Coordinator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `coordinator ARGS` and waits for the panel's address on its stderr.
/// A teleop run (robots wait for the panel) serving its panel on a free loopback port.
fn teleop_panel_on_loopback() -> Coordinator {
    coordinator(&[
        "--behaviour",
        "teleop",
        "--panel",
        "127.0.0.1:0",
        "--duration",
        "120",
    ])
}

fn coordinator(args: &[&str]) -> Coordinator {
    let mut child = Command::new(env!("CARGO_BIN_EXE_coordinator"))
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("coordinator starts");
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            eprintln!("coordinator: {line}");
            if let Some(url) = line.split("control panel at ").nth(1) {
                let _ = tx.send(url.trim().to_string());
            }
        }
    });
    let url = rx
        .recv_timeout(Duration::from_secs(120))
        .expect("the coordinator printed the panel's address");
    Coordinator { child, url }
}

fn addr_of(url: &str) -> SocketAddr {
    let host = url.trim_start_matches("http://").split('/').next().unwrap();
    host.parse().unwrap()
}

/// One HTTP/1.1 GET (`Host: ADDR` unless `headers` name one); returns the status code and body.
fn http(addr: SocketAddr, path: &str, headers: &[&str]) -> (u16, String) {
    let mut s = TcpStream::connect(addr).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let mut req = format!("GET {path} HTTP/1.1\r\n");
    if !headers.iter().any(|h| h.starts_with("Host:")) {
        req.push_str(&format!("Host: {addr}\r\n"));
    }
    if !headers.iter().any(|h| h.starts_with("Connection:")) {
        req.push_str("Connection: close\r\n");
    }
    for h in headers {
        req.push_str(h);
        req.push_str("\r\n");
    }
    req.push_str("\r\n");
    s.write_all(req.as_bytes()).unwrap();
    let mut out = String::new();
    // A switched protocol keeps the connection open: its status line is all that is needed.
    let mut buf = [0u8; 4096];
    while let Ok(n) = s.read(&mut buf) {
        if n == 0 {
            break;
        }
        out.push_str(&String::from_utf8_lossy(&buf[..n]));
        if complete(&out) {
            break;
        }
    }
    let status = out
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let body = out.split("\r\n\r\n").nth(1).unwrap_or("").to_string();
    (status, body)
}

/// Whether a response is all there: an upgrade keeps the connection open, and so does a refused
/// upgrade (it asked for `Connection: Upgrade`, not `close`), so the length is what tells.
fn complete(response: &str) -> bool {
    let Some((head, body)) = response.split_once("\r\n\r\n") else {
        return false;
    };
    if head.starts_with("HTTP/1.1 101") {
        return true;
    }
    head.lines()
        .filter_map(|l| l.split_once(':'))
        .find(|(k, _)| k.eq_ignore_ascii_case("content-length"))
        .and_then(|(_, v)| v.trim().parse::<usize>().ok())
        .is_some_and(|len| body.len() >= len)
}

/// This machine's address on its default route, if it has one; loopback otherwise.
fn outward_ip() -> std::net::IpAddr {
    std::net::UdpSocket::bind("0.0.0.0:0")
        .and_then(|s| {
            s.connect("192.0.2.1:9")?;
            s.local_addr()
        })
        .map(|a| a.ip())
        .ok()
        .filter(|ip| !ip.is_unspecified())
        .unwrap_or(std::net::Ipv4Addr::LOCALHOST.into())
}

/// The headers of a WebSocket upgrade.
const WS: [&str; 4] = [
    "Upgrade: websocket",
    "Connection: Upgrade",
    "Sec-WebSocket-Version: 13",
    "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==",
];

/// A WebSocket upgrade carrying `extra` headers too.
fn ws_with<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    WS.iter().copied().chain(extra.iter().copied()).collect()
}

/// The token the panel's page embeds for its WebSocket.
fn token_in(page: &str) -> String {
    let tag = "<meta name=\"pocketfleet-token\" content=\"";
    let rest = page
        .split(tag)
        .nth(1)
        .unwrap_or_else(|| panic!("the page embeds its token: {page}"));
    rest.split('"').next().unwrap().to_string()
}

#[test]
fn off_loopback_every_request_needs_the_token() {
    let c = coordinator(&[
        "--behaviour",
        "teleop",
        "--panel",
        "0.0.0.0:0",
        "--duration",
        "120",
    ]);
    let token = c
        .url
        .split("token=")
        .nth(1)
        .expect("a token is printed for a non-loopback panel")
        .to_string();
    assert!(token.len() >= 32, "{token}");
    let port = addr_of(&c.url).port();
    let addr = SocketAddr::new(outward_ip(), port);
    eprintln!("asking {addr}");
    let origin = format!("Origin: http://{addr}");
    let ws = ws_with(&[&origin]);

    let (status, body) = http(addr, "/", &[]);
    assert_eq!(status, 401, "{body}");
    assert!(body.contains("token"), "{body}");
    assert_eq!(http(addr, "/?token=wrong", &[]).0, 401);
    assert_eq!(http(addr, "/ws", &ws).0, 401);
    assert_eq!(http(addr, "/ws?token=nope", &ws).0, 401);

    let (status, body) = http(addr, &format!("/?token={token}"), &[]);
    assert_eq!(status, 200);
    assert!(body.contains("PocketFleet"));
    assert_eq!(token_in(&body), token);
    let bearer = format!("Authorization: Bearer {token}");
    assert_eq!(http(addr, "/", &[&bearer]).0, 200);
    assert_eq!(http(addr, &format!("/ws?token={token}"), &ws).0, 101);
    // The token does not stand in for the panel's own Host and Origin.
    let foreign = ws_with(&["Origin: http://evil.example"]);
    assert_eq!(http(addr, &format!("/ws?token={token}"), &foreign).0, 403);
    let rebound = format!("Host: evil.example:{port}");
    assert_eq!(http(addr, &format!("/?token={token}"), &[&rebound]).0, 403);
}

#[test]
fn loopback_page_needs_no_token_and_embeds_it() {
    let c = teleop_panel_on_loopback();
    assert!(!c.url.contains("token"), "{}", c.url);
    let (status, body) = http(addr_of(&c.url), "/", &[]);
    assert_eq!(status, 200);
    assert!(body.contains("<svg id=\"arena\""));
    let token = token_in(&body);
    assert!(
        token.len() >= 32 && token.bytes().all(|b| b.is_ascii_hexdigit()),
        "{token}"
    );
}

#[test]
fn only_the_panels_own_page_may_command_it() {
    let c = teleop_panel_on_loopback();
    let addr = addr_of(&c.url);
    let port = addr.port();
    let (status, page) = http(addr, "/", &[]);
    assert_eq!(status, 200, "{page}");
    let token = token_in(&page);
    let with_token = format!("/ws?token={token}");
    let ours = format!("Origin: http://{addr}");

    // A page from another site: its Origin gives it away, on the page and the WebSocket.
    let foreign = "Origin: http://evil.example";
    let (status, body) = http(addr, "/", &[foreign]);
    assert_eq!(status, 403, "{body}");
    assert!(body.contains("refused"), "{body}");
    assert_eq!(http(addr, &with_token, &ws_with(&[foreign])).0, 403);
    let null = "Origin: null";
    assert_eq!(http(addr, &with_token, &ws_with(&[null])).0, 403);

    // DNS rebinding: another site's name resolving to 127.0.0.1 still says so in Host.
    let rebound = format!("Host: evil.example:{port}");
    let (status, body) = http(addr, "/", &[&rebound]);
    assert_eq!(status, 403, "{body}");
    assert!(body.contains("Host"), "{body}");
    let rebound_origin = format!("Origin: http://evil.example:{port}");
    assert_eq!(
        http(addr, &with_token, &ws_with(&[&rebound, &rebound_origin])).0,
        403
    );

    // The panel's own Origin without the token, or with a wrong one, or the token without an
    // Origin: refused.
    let (status, body) = http(addr, "/ws", &ws_with(&[&ours]));
    assert_eq!(status, 401, "{body}");
    assert!(body.contains("token"), "{body}");
    assert_eq!(http(addr, "/ws?token=0123", &ws_with(&[&ours])).0, 401);
    assert_eq!(http(addr, &with_token, &WS).0, 403);

    // Host, Origin and token all the panel's own: the WebSocket opens, also under `localhost`.
    assert_eq!(http(addr, &with_token, &ws_with(&[&ours])).0, 101);
    let local_host = format!("Host: localhost:{port}");
    let local_origin = format!("Origin: http://localhost:{port}");
    assert_eq!(
        http(addr, &with_token, &ws_with(&[&local_host, &local_origin])).0,
        101
    );
    let bearer = format!("Authorization: Bearer {token}");
    assert_eq!(http(addr, "/ws", &ws_with(&[&ours, &bearer])).0, 101);
}

#[test]
fn a_busy_panel_address_is_refused_before_the_run() {
    let held = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = held.local_addr().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_coordinator"))
        .args(["--behaviour", "square_walk", "--duration", "20", "--panel"])
        .arg(addr.to_string())
        .output()
        .expect("coordinator runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains(&addr.to_string()), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "one line: {stderr}");
    // Refused before the run: no report was printed.
    assert!(
        out.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    drop(held);
}

// ---- headless Chromium over the DevTools protocol ----

struct Browser {
    child: Child,
    /// Its profile directory, removed after `drop` has stopped the browser.
    _dir: tempfile::TempDir,
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn chromium() -> Option<PathBuf> {
    std::env::var_os("CHROMIUM").map(PathBuf::from).or_else(|| {
        ["/usr/bin/chromium", "/usr/bin/chromium-browser"]
            .iter()
            .map(PathBuf::from)
            .find(|p| p.exists())
    })
}

/// Starts headless Chromium and returns it with its first page's DevTools WebSocket address.
fn launch(exe: &Path) -> (Browser, String) {
    let profile = tempfile::Builder::new()
        .prefix("pocketfleet-chromium-")
        .tempdir()
        .unwrap();
    let dir = profile.path().to_path_buf();
    let child = Command::new(exe)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--remote-debugging-port=0",
            "--window-size=1280,1000",
        ])
        .arg(format!("--user-data-dir={}", dir.display()))
        .arg("about:blank")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("chromium starts");
    let browser = Browser {
        child,
        _dir: profile,
    };
    let port_file = dir.join("DevToolsActivePort");
    let deadline = Instant::now() + Duration::from_secs(60);
    let port: u16 = loop {
        if let Some(p) = std::fs::read_to_string(&port_file)
            .ok()
            .and_then(|s| s.lines().next().and_then(|l| l.trim().parse().ok()))
        {
            break p;
        }
        assert!(
            Instant::now() < deadline,
            "chromium wrote no DevToolsActivePort"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let addr: SocketAddr = ([127, 0, 0, 1], port).into();
    let page = loop {
        let (_, body) = http(addr, "/json/list", &[]);
        let list: Value = serde_json::from_str(&body).unwrap_or(Value::Null);
        if let Some(url) = list
            .as_array()
            .into_iter()
            .flatten()
            .find(|t| t["type"] == "page")
            .and_then(|t| t["webSocketDebuggerUrl"].as_str())
        {
            break url.to_string();
        }
        assert!(Instant::now() < deadline, "chromium lists no page");
        std::thread::sleep(Duration::from_millis(100));
    };
    (browser, page)
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

struct Cdp {
    ws: Ws,
    next: u64,
}

impl Cdp {
    async fn call(&mut self, method: &str, params: Value) -> Value {
        self.next += 1;
        let id = self.next;
        let msg = json!({"id": id, "method": method, "params": params}).to_string();
        self.ws.send(Message::Text(msg.into())).await.unwrap();
        loop {
            let m = self.ws.next().await.expect("DevTools open").unwrap();
            let Message::Text(t) = m else { continue };
            let v: Value = serde_json::from_str(&t).unwrap();
            if v["id"] == json!(id) {
                assert!(v["error"].is_null(), "{method}: {}", v["error"]);
                return v["result"].clone();
            }
        }
    }

    async fn eval(&mut self, expression: &str) -> Value {
        let r = self
            .call(
                "Runtime.evaluate",
                json!({"expression": expression, "returnByValue": true}),
            )
            .await;
        assert!(
            r["exceptionDetails"].is_null(),
            "{expression}: {}",
            r["exceptionDetails"]
        );
        r["result"]["value"].clone()
    }

    /// Polls a page expression until `ok` holds, failing with `what` after `secs`.
    async fn until(
        &mut self,
        expression: &str,
        secs: u64,
        what: &str,
        ok: impl Fn(&Value) -> bool,
    ) -> Value {
        let deadline = Instant::now() + Duration::from_secs(secs);
        loop {
            let v = self.eval(expression).await;
            if ok(&v) {
                return v;
            }
            assert!(Instant::now() < deadline, "{what}: last {v}");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }

    async fn mouse(&mut self, kind: &str, x: f64, y: f64) {
        self.call(
            "Input.dispatchMouseEvent",
            json!({"type": kind, "x": x, "y": y, "button": "left", "buttons": 1, "clickCount": 1}),
        )
        .await;
    }

    async fn screenshot(&mut self, path: &Path) {
        let r = self
            .call("Page.captureScreenshot", json!({"format": "png"}))
            .await;
        let png = base64(r["data"].as_str().unwrap());
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        std::fs::write(path, png).unwrap();
    }
}

fn base64(s: &str) -> Vec<u8> {
    let val = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        _ => 63,
    };
    let clean: Vec<u8> = s.bytes().filter(|c| *c != b'=' && *c != b'\n').collect();
    let mut out = Vec::with_capacity(clean.len() * 3 / 4);
    for chunk in clean.chunks(4) {
        let mut n = 0u32;
        for (i, c) in chunk.iter().enumerate() {
            n |= u32::from(val(*c)) << (18 - 6 * i);
        }
        let bytes = n.to_be_bytes();
        out.extend_from_slice(&bytes[1..chunk.len()]);
    }
    out
}

fn pose_of(v: &Value, id: u64) -> Option<(f64, f64)> {
    v.as_array()?
        .iter()
        .find(|r| r["id"] == json!(id))
        .map(|r| (r["x"].as_f64().unwrap(), r["y"].as_f64().unwrap()))
}

#[test]
fn panel_drives_robots_in_headless_chromium() {
    let Some(exe) = chromium() else {
        assert!(
            std::env::var_os("POCKETFLEET_REQUIRE_CHROMIUM").is_none(),
            "POCKETFLEET_REQUIRE_CHROMIUM is set but chromium is not installed"
        );
        println!("skipped: chromium is not installed (apt-get install chromium)");
        return;
    };
    let c = coordinator(&[
        "--behaviour",
        "teleop",
        "--world",
        "oval",
        "--panel",
        "127.0.0.1:0",
        "--duration",
        "300",
    ]);
    let (_browser, page) = launch(&exe);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async move {
        let (ws, _) = tokio_tungstenite::connect_async(page.as_str()).await.unwrap();
        let mut cdp = Cdp { ws, next: 0 };
        cdp.call("Page.enable", json!({})).await;
        cdp.call("Page.navigate", json!({"url": c.url})).await;

        // Every robot is drawn, and live frames arrive.
        cdp.until(
            "document.querySelectorAll('#arena [data-robot]').length * 1000 + Math.min(window.pf ? pf.frames : 0, 999)",
            60,
            "two robots drawn and frames flowing",
            |v| v.as_f64().is_some_and(|n| n >= 2005.0),
        )
        .await;
        cdp.until("pf.truth ? pf.truth.robots : null", 30, "ground truth shown", |v| {
            v.as_array().is_some_and(|a| a.len() == 2)
        })
        .await;

        // A joystick drag (mouse pressed on the stick and pulled up) drives robot 1 forward.
        cdp.eval("document.querySelector('[data-select=\"1\"]').click(); document.getElementById('joystick').scrollIntoView(); 0").await;
        let rect = cdp
            .eval("(() => { const r = document.getElementById('joystick').getBoundingClientRect(); return [r.left + r.width / 2, r.top + r.height / 2, r.height]; })()")
            .await;
        let (cx, cy, h) = (rect[0].as_f64().unwrap(), rect[1].as_f64().unwrap(), rect[2].as_f64().unwrap());
        let before = pose_of(&cdp.eval("pf.truth.robots").await, 1).unwrap();
        cdp.mouse("mousePressed", cx, cy).await;
        for k in 1..=5 {
            cdp.mouse("mouseMoved", cx, cy - h * 0.08 * f64::from(k)).await;
        }
        let moved = cdp
            .until("pf.truth.robots", 30, "robot 1 drives while the stick is held", |v| {
                pose_of(v, 1).is_some_and(|p| (p.0 - before.0).hypot(p.1 - before.1) > 0.03)
            })
            .await;
        cdp.mouse("mouseReleased", cx, cy - h * 0.4).await;
        let after = pose_of(&moved, 1).unwrap();
        assert!(after.0 > before.0 + 0.02, "forward is +x for robot 1: {before:?} -> {after:?}");
        cdp.until(
            "pf.robots[1].state.wheels.left_target_mps",
            10,
            "releasing the stick stops the wheels",
            |v| v.as_f64().is_some_and(|s| s.abs() < 1e-6),
        )
        .await;

        // A settings change goes to the robot and is read back from it.
        let original = cdp.eval("pf.send({cmd:'settings', robot:1}); 0").await;
        assert_eq!(original, json!(0));
        cdp.until("pf.settings['line_pid.kp']", 20, "settings read", Value::is_number).await;
        cdp.eval("document.getElementById('set-path').value = 'line_pid.kp'; document.getElementById('set-value').value = '1.7'; document.getElementById('set-apply').click(); 0").await;
        let status = cdp
            .until(
                "document.getElementById('settings-status').textContent",
                20,
                "the write is read back",
                |v| v.as_str().is_some_and(|s| s.contains("read back")),
            )
            .await;
        let kp = cdp.eval("pf.settings['line_pid.kp']").await.as_f64().unwrap();
        assert!((kp - 1.7).abs() < 1e-6, "{status}: {kp}");

        // The PID view switches the robot to reduced state at a high rate: over 50 samples a
        // second reach the chart (the full state comes at 20 a second).
        cdp.eval("document.getElementById('pid-toggle').click(); pf.send({cmd:'wheels', robot:1, left:0.05, right:0.05}); 0").await;
        cdp.until(
            "(() => { const s = pf.samples; if (s.length < 2) return 0; const t1 = s[s.length - 1][0]; return s.filter(x => x[0] > t1 - 1).length; })()",
            20,
            "reduced state at a high rate in the PID chart",
            |v| v.as_f64().is_some_and(|n| n > 50.0),
        )
        .await;
        cdp.eval("pf.send({cmd:'wheels', robot:1, left:0, right:0}); document.getElementById('pid-toggle').click(); 0").await;

        // A move that would leave the arena is held by the supervisor's safety check.
        cdp.eval("window.heldId = pf.send({cmd:'straight', robot:1, distance:2.0, speed:0.1}); 0")
            .await;
        let held = cdp
            .until(
                "(() => { const r = pf.replies.find(r => r.id === window.heldId); return r ? [r.ok, r.message] : null; })()",
                10,
                "the safety check's answer",
                |v| v.is_array(),
            )
            .await;
        assert_eq!(held[0], json!(false), "{held}");
        assert!(
            held[1].as_str().unwrap().contains("held by the safety check"),
            "{held}"
        );
        // The host's link statistics reach the page.
        cdp.until("pf.links['1'] ? pf.links['1'].in : 0", 10, "host link statistics", |v| {
            v.as_f64().is_some_and(|n| n > 10.0)
        })
        .await;

        // Both robots on a long move, then the e-stop stops them all.
        cdp.eval("pf.send({cmd:'straight', robot:1, distance:0.3, speed:0.1}); pf.send({cmd:'straight', robot:2, distance:0.3, speed:0.1}); 0").await;
        cdp.until(
            "Object.values(pf.robots).map(r => Math.abs(r.state.wheels.left_mps))",
            20,
            "both robots moving",
            |v| v.as_array().is_some_and(|a| a.len() == 2 && a.iter().all(|s| s.as_f64().unwrap() > 0.03)),
        )
        .await;
        let shot = std::env::var_os("POCKETFLEET_SCREENSHOT")
            .map_or_else(|| std::env::temp_dir().join("pocketfleet-panel.png"), PathBuf::from);
        cdp.eval("window.scrollTo(0, 0); 0").await;
        cdp.screenshot(&shot).await;
        cdp.eval("document.getElementById('estop').click(); 0").await;
        cdp.until(
            "pf.lastReply ? pf.lastReply.message : ''",
            10,
            "e-stop confirmed",
            |v| v.as_str().is_some_and(|s| s.contains("every robot stopped")),
        )
        .await;
        cdp.until(
            "Object.values(pf.robots).map(r => [r.state.wheels.left_mps, r.state.wheels.right_mps, r.state.locomotion.queue_len])",
            10,
            "every robot stopped",
            |v| {
                v.as_array().is_some_and(|a| {
                    a.len() == 2
                        && a.iter().all(|r| {
                            r[0].as_f64().unwrap().abs() < 0.005
                                && r[1].as_f64().unwrap().abs() < 0.005
                                && r[2] == json!(0)
                        })
                })
            },
        )
        .await;

        // On a phone-sized screen nothing runs off the side.
        cdp.call(
            "Emulation.setDeviceMetricsOverride",
            json!({"width": 390, "height": 844, "deviceScaleFactor": 2, "mobile": true}),
        )
        .await;
        let width = cdp
            .until("document.documentElement.scrollWidth", 10, "phone layout", |v| {
                v.is_number()
            })
            .await;
        let widest = cdp
            .eval("[...document.querySelectorAll('body *')].filter(e => e.getBoundingClientRect().right > 391).map(e => e.tagName + '#' + e.id + '.' + e.className).slice(0, 8).join(' ')")
            .await;
        assert!(
            width.as_f64().unwrap() <= 390.0,
            "page is {width} px wide on a 390 px phone: {widest}"
        );
        if let Some(path) = std::env::var_os("POCKETFLEET_PHONE_SCREENSHOT") {
            cdp.screenshot(Path::new(&path)).await;
        }
    });
}

#[test]
fn the_panel_follows_a_replay() {
    // Declared before the replaying coordinator, so it is removed after that has stopped.
    let dir = tempfile::Builder::new()
        .prefix("pocketfleet-panel-")
        .tempdir()
        .unwrap();
    let path = dir.path().join("replay.mcap");
    let status = Command::new(env!("CARGO_BIN_EXE_coordinator"))
        .args(["--behaviour", "square_walk", "--robots", "2", "--record"])
        .arg(&path)
        .stdout(Stdio::null())
        .status()
        .expect("coordinator runs");
    assert!(status.success());
    let c = coordinator(&["replay", path.to_str().unwrap(), "--panel", "127.0.0.1:0"]);
    let addr = addr_of(&c.url);
    let token = token_in(&http(addr, "/", &[]).1);
    let mut request = format!("ws://{addr}/ws?token={token}")
        .into_client_request()
        .unwrap();
    request
        .headers_mut()
        .insert("Origin", format!("http://{addr}").parse().unwrap());
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async move {
        let (mut ws, _) = tokio_tungstenite::connect_async(request).await.unwrap();
        let mut hello = None;
        let mut poses = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(60);
        while poses.len() < 20 {
            assert!(Instant::now() < deadline, "too few replayed frames");
            let Some(Ok(Message::Text(t))) = ws.next().await else {
                panic!("panel closed")
            };
            let v: Value = serde_json::from_str(&t).unwrap();
            match v["type"].as_str() {
                Some("hello") => hello = Some(v),
                Some("world") => poses.push(v["robots"][0]["pose"].clone()),
                _ => {}
            }
        }
        let hello = hello.expect("hello first");
        assert_eq!(hello["scene"]["replay"], json!(true));
        assert_eq!(hello["scene"]["robots"], json!([1, 2]));
        assert!(
            poses.windows(2).any(|w| w[0] != w[1]),
            "the replayed robot moves"
        );
    });
}

/// At most `MAX_SESSIONS` WebSockets are open at once; one more is refused with 503 and a reason
/// (200 of them once raised the coordinator's memory from 21 to 75 MB).
#[test]
fn panel_sessions_are_capped() {
    let c = teleop_panel_on_loopback();
    let addr = addr_of(&c.url);
    let (_, page) = http(addr, "/", &[]);
    let token = token_in(&page);
    let path = format!("/ws?token={token}");
    let ours = format!("Origin: http://{addr}");
    let mut open = Vec::new();
    for i in 0..coordinator::instruments::panel::MAX_SESSIONS {
        let mut s = TcpStream::connect(addr).expect("connect");
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let mut req = format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\n{ours}\r\n");
        for h in WS {
            req.push_str(h);
            req.push_str("\r\n");
        }
        req.push_str("\r\n");
        s.write_all(req.as_bytes()).unwrap();
        let mut buf = [0u8; 64];
        let n = s.read(&mut buf).unwrap();
        let head = String::from_utf8_lossy(&buf[..n]).to_string();
        assert!(head.starts_with("HTTP/1.1 101"), "session {i}: {head}");
        open.push(s);
    }
    let (status, body) = http(addr, &path, &ws_with(&[&ours]));
    assert_eq!(status, 503, "{body}");
    assert!(body.contains("sessions are open already"), "{body}");
}
