//! Whole-system test support: builds the STM32F405 firmware, boots it in QEMU's `netduinoplus2`
//! and talks to it over the emulated USART1 as a host would (SLIP-framed packets on TCP).
//!
//! The test owns the TCP port: it binds port 0, hands the port to QEMU's `-serial tcp:` client and
//! accepts, so there is no window in which another process could take the port. QEMU is killed
//! when the [`QemuRobot`] is dropped, also when a test panics.

use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{mpsc, OnceLock};
use std::time::{Duration, Instant};

use protocol::slip::{self, SlipDecoder};
use protocol::{AnyPacket, MAX_PACKET};

/// The Cortex-M4F target the board crate builds for.
pub const TARGET: &str = "thumbv7em-none-eabihf";
/// Environment variable that turns missing QEMU tools from a skip into a failure (CI sets it).
pub const REQUIRE_ENV: &str = "POCKETFLEET_REQUIRE_QEMU";
/// The emulator binary.
pub const QEMU: &str = "qemu-system-arm";

/// The board crate's folder.
pub fn board_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/board-stm32f405")
}

/// The release ELF the board crate's own build produces.
pub fn firmware_elf() -> PathBuf {
    board_dir()
        .join("target")
        .join(TARGET)
        .join("release")
        .join("board-stm32f405")
}

/// Whether CI demands the QEMU tests run.
pub fn qemu_required() -> bool {
    std::env::var(REQUIRE_ENV).is_ok_and(|v| !v.is_empty() && v != "0")
}

fn on_path(program: &str) -> bool {
    std::env::var_os("PATH")
        .is_some_and(|paths| std::env::split_paths(&paths).any(|dir| dir.join(program).is_file()))
}

fn target_installed() -> bool {
    let rustc = std::env::var_os("RUSTC").unwrap_or_else(|| "rustc".into());
    Command::new(rustc)
        .args(["--print", "sysroot"])
        .current_dir(board_dir())
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
        .is_some_and(|sysroot| {
            Path::new(&sysroot)
                .join("lib/rustlib")
                .join(TARGET)
                .is_dir()
        })
}

/// What is missing to run the QEMU tests, if anything.
pub fn missing_tools() -> Option<String> {
    let mut missing = Vec::new();
    if !on_path(QEMU) {
        missing.push(format!(
            "{QEMU} (apt-get install -y --no-install-recommends qemu-system-arm)"
        ));
    }
    if !target_installed() {
        missing.push(format!("the {TARGET} target (rustup target add {TARGET})"));
    }
    (!missing.is_empty()).then(|| missing.join(" and "))
}

/// Skips (returns true after saying why) when the tools are missing and CI does not require them;
/// panics when they are missing and required.
pub fn skip_without_qemu(test: &str) -> bool {
    let Some(missing) = missing_tools() else {
        return false;
    };
    assert!(
        !qemu_required(),
        "{REQUIRE_ENV} is set but {missing} is missing"
    );
    // Written to the process's stderr directly, so the test harness does not capture it.
    let _ = writeln!(
        std::io::stderr(),
        "skipped: {test}: missing {missing}; set {REQUIRE_ENV}=1 to make this a failure"
    );
    true
}

/// Builds the firmware in release with the board crate's own configuration, once per process.
pub fn build_firmware() -> Result<PathBuf, String> {
    static BUILT: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    BUILT
        .get_or_init(|| {
            let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
            // The outer build's target dir and host flags must not leak into the board's build.
            let status = Command::new(cargo)
                .args(["build", "--release", "--quiet"])
                .current_dir(board_dir())
                .env_remove("CARGO_TARGET_DIR")
                .env_remove("CARGO_BUILD_TARGET_DIR")
                .env_remove("RUSTFLAGS")
                .env_remove("CARGO_ENCODED_RUSTFLAGS")
                .status()
                .map_err(|e| format!("cannot run cargo: {e}"))?;
            if !status.success() {
                return Err(format!("firmware build failed: {status}"));
            }
            let elf = firmware_elf();
            if elf.is_file() {
                Ok(elf)
            } else {
                Err(format!("build succeeded but {} is missing", elf.display()))
            }
        })
        .clone()
}

/// Flash and RAM taken by an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageSize {
    /// Bytes stored in flash: code, constants, vector table, initial values of `.data`.
    pub flash: u64,
    /// Bytes of RAM reserved statically: `.data`, `.bss`, `.uninit` (the stack takes the rest).
    pub ram: u64,
}

/// Flash and RAM use of a 32-bit little-endian ARM ELF, from its section headers.
pub fn image_size(elf: &[u8], ram_start: u32, ram_len: u32) -> Result<ImageSize, String> {
    const SHF_ALLOC: u32 = 0x2;
    const SHT_NOBITS: u32 = 8;
    let u16_at = |o: usize| -> Result<u16, String> {
        elf.get(o..o + 2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .ok_or_else(|| "truncated ELF".to_owned())
    };
    let u32_at = |o: usize| -> Result<u32, String> {
        elf.get(o..o + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| "truncated ELF".to_owned())
    };
    if elf.get(..6) != Some(&[0x7F, b'E', b'L', b'F', 1, 1][..]) {
        return Err("not a 32-bit little-endian ELF".into());
    }
    let shoff = u32_at(0x20)? as usize;
    let shentsize = usize::from(u16_at(0x2E)?);
    let shnum = usize::from(u16_at(0x30)?);
    let mut size = ImageSize { flash: 0, ram: 0 };
    for i in 0..shnum {
        let h = shoff + i * shentsize;
        let (kind, flags, addr, len) = (
            u32_at(h + 4)?,
            u32_at(h + 8)?,
            u32_at(h + 12)?,
            u32_at(h + 20)?,
        );
        if flags & SHF_ALLOC == 0 {
            continue;
        }
        if kind != SHT_NOBITS {
            size.flash += u64::from(len);
        }
        if addr >= ram_start && addr - ram_start < ram_len {
            size.ram += u64::from(len);
        }
    }
    Ok(size)
}

/// The firmware running in QEMU, with the host end of its UART.
pub struct QemuRobot {
    child: Child,
    /// The host end of USART1.
    pub link: UartLink,
}

impl QemuRobot {
    /// Boots `elf` and accepts QEMU's serial connection within `timeout`.
    pub fn start(elf: &Path, timeout: Duration) -> Result<Self, String> {
        let listener = TcpListener::bind("127.0.0.1:0").map_err(|e| format!("bind: {e}"))?;
        let port = listener
            .local_addr()
            .map_err(|e| format!("local_addr: {e}"))?
            .port();
        let mut child = Command::new(QEMU)
            .args(["-machine", "netduinoplus2", "-nographic"])
            .args(["-semihosting-config", "enable=on,target=native"])
            // 8 ns per instruction and idle time skipped: deterministic, and usually faster than
            // the wall clock, so tests measure with the robot's own timestamps.
            .args(["-icount", "shift=3,sleep=off"])
            .arg("-serial")
            .arg(format!("tcp:127.0.0.1:{port},nodelay=on"))
            // With -nographic the monitor would otherwise take stdio.
            .args(["-monitor", "none"])
            .arg("-kernel")
            .arg(elf)
            .stdin(Stdio::null())
            .spawn()
            .map_err(|e| format!("cannot start {QEMU}: {e}"))?;
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(listener.accept());
        });
        let deadline = Instant::now() + timeout;
        let stream = loop {
            match rx.recv_timeout(Duration::from_millis(100)) {
                Ok(Ok((stream, _))) => break stream,
                Ok(Err(e)) => {
                    let _ = child.kill();
                    return Err(format!("accept: {e}"));
                }
                Err(_) => {
                    if let Ok(Some(status)) = child.try_wait() {
                        return Err(format!("{QEMU} exited before connecting: {status}"));
                    }
                    if Instant::now() >= deadline {
                        let _ = child.kill();
                        let _ = child.wait();
                        return Err(format!("{QEMU} did not connect within {timeout:?}"));
                    }
                }
            }
        };
        stream
            .set_nodelay(true)
            .map_err(|e| format!("nodelay: {e}"))?;
        Ok(Self {
            child,
            link: UartLink::new(stream),
        })
    }

    /// QEMU's exit status if it has ended.
    pub fn exit_status(&mut self) -> Option<std::process::ExitStatus> {
        self.child.try_wait().ok().flatten()
    }
}

impl Drop for QemuRobot {
    fn drop(&mut self) {
        let _ = self.link.stream.shutdown(Shutdown::Both);
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The host end of the robot's USART1, a SLIP stream: typed packets out, decoded packets in.
pub struct UartLink {
    stream: TcpStream,
    decoder: SlipDecoder,
    received: VecDeque<AnyPacket>,
    /// Frames that did not decode (should stay zero).
    pub bad_frames: u32,
}

impl UartLink {
    fn new(stream: TcpStream) -> Self {
        Self {
            stream,
            decoder: SlipDecoder::new(),
            received: VecDeque::new(),
            bad_frames: 0,
        }
    }

    /// Sends one packet, SLIP-framed.
    pub fn send(&mut self, packet: impl Into<AnyPacket>) -> Result<(), String> {
        let mut buf = [0u8; MAX_PACKET];
        let n = packet
            .into()
            .encode(&mut buf)
            .map_err(|e| format!("encode: {e}"))?;
        let framed: Vec<u8> = slip::encode_iter(&buf[..n]).collect();
        self.send_raw(&framed)
    }

    /// Sends bytes as they are, for corrupt-input tests.
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<(), String> {
        self.stream
            .write_all(bytes)
            .map_err(|e| format!("send: {e}"))
    }

    /// The next packet from the robot, waiting until `deadline` at most.
    pub fn recv(&mut self, deadline: Instant) -> Result<AnyPacket, String> {
        let mut buf = [0u8; 4096];
        loop {
            if let Some(p) = self.received.pop_front() {
                return Ok(p);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err("timed out waiting for a packet".into());
            }
            self.stream
                .set_read_timeout(Some(left))
                .map_err(|e| format!("set_read_timeout: {e}"))?;
            let n = match self.stream.read(&mut buf) {
                Ok(0) => return Err("the robot closed the link (QEMU ended?)".into()),
                Ok(n) => n,
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    continue
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(format!("recv: {e}")),
            };
            for &b in &buf[..n] {
                match self.decoder.push(b) {
                    Ok(Some(frame)) => match protocol::decode(frame) {
                        Ok(p) => {
                            if let AnyPacket::Log(l) = &p {
                                // Fault and panic reports arrive this way; show them with the failure.
                                eprintln!("robot log [{}] {}", l.module(), l.text());
                            }
                            self.received.push_back(p)
                        }
                        Err(_) => self.bad_frames += 1,
                    },
                    Ok(None) => {}
                    Err(_) => self.bad_frames += 1,
                }
            }
        }
    }

    /// Receives until `pick` returns a value, handing it every packet; fails after `timeout` with
    /// `what` in the message. `pick` may send (through the link it is given) to keep the robot fed.
    pub fn wait_for<T>(
        &mut self,
        what: &str,
        timeout: Duration,
        mut pick: impl FnMut(&mut Sender<'_>, AnyPacket) -> Option<T>,
    ) -> Result<T, String> {
        let deadline = Instant::now() + timeout;
        loop {
            let p = self
                .recv(deadline)
                .map_err(|e| format!("waiting for {what}: {e}"))?;
            let mut sender = Sender {
                stream: &mut self.stream,
                error: None,
            };
            let picked = pick(&mut sender, p);
            if let Some(e) = sender.error {
                return Err(format!("while waiting for {what}: {e}"));
            }
            if let Some(v) = picked {
                return Ok(v);
            }
        }
    }
}

/// Lets a [`UartLink::wait_for`] callback answer packets as they arrive.
pub struct Sender<'a> {
    stream: &'a mut TcpStream,
    error: Option<String>,
}

impl Sender<'_> {
    /// Sends one packet; an error ends the wait.
    pub fn send(&mut self, packet: impl Into<AnyPacket>) {
        let mut buf = [0u8; MAX_PACKET];
        let framed: Vec<u8> = match packet.into().encode(&mut buf) {
            Ok(n) => slip::encode_iter(&buf[..n]).collect(),
            Err(e) => {
                self.error = Some(format!("encode: {e}"));
                return;
            }
        };
        if let Err(e) = self.stream.write_all(&framed) {
            self.error = Some(format!("send: {e}"));
        }
    }
}
