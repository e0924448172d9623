//! Robot addresses as text (`tcp://`, `unix://`, `seqpacket://`, `serial://`, `bt://`) and static lists.
//!
//! An address names a transport and where the robot is on it; [`parse_address`] turns it into a
//! [`Connector`]. Every connector's `peer()` is an address this module parses back.

use std::sync::Arc;

use futures::future::BoxFuture;

use crate::link::stream::{SerialConnector, TcpConnector};
use crate::link::{Connector, Discovered, Discoverer, LinkError};

#[cfg(feature = "bluetooth")]
pub use crate::link::bluetooth::{BluezDiscoverer, L2capConnector};

/// Baud rate of a `serial://` address without `?baud=`.
pub const DEFAULT_BAUD: u32 = 115_200;

/// The L2CAP PSM PocketBot2 firmware listens on: the first dynamic BR/EDR PSM.
///
/// The default of `bt://` addresses and of Bluetooth discovery. A BR/EDR PSM is odd with bit 8
/// clear; LE PSMs are at most 0xff, so an LE robot's PSM is always given explicitly.
pub const DEFAULT_PSM: u16 = 0x1001;

/// Parses a robot address into a connector.
///
/// Accepted forms:
/// - `tcp://HOST:PORT` (an IPv6 host in brackets: `tcp://[::1]:7000`);
/// - `unix:///path/to/socket` (stream socket, SLIP framing);
/// - `seqpacket:///path/to/socket` (`SOCK_SEQPACKET`, one message per packet);
/// - `serial:///dev/ttyUSB0` with an optional `?baud=N` (default [`DEFAULT_BAUD`]);
/// - `bt://AA:BB:CC:DD:EE:FF` with optional `?psm=N` (decimal or `0x` hex, default [`DEFAULT_PSM`]) and
///   `&type=bredr|le-public|le-random` (default `bredr`); needs the `bluetooth` feature, without
///   which a well-formed `bt://` address is [`LinkError::Unavailable`].
///
/// Anything else is [`LinkError::BadAddress`] saying what is wrong.
pub fn parse_address(s: &str) -> Result<Arc<dyn Connector>, LinkError> {
    let bad = |reason: String| LinkError::BadAddress {
        address: s.to_owned(),
        reason,
    };
    let text = s.trim();
    let Some((scheme, rest)) = text.split_once("://") else {
        return Err(bad(
            "expected SCHEME://..., with SCHEME one of tcp, unix, seqpacket, serial, bt".into(),
        ));
    };
    match scheme.to_ascii_lowercase().as_str() {
        "tcp" => parse_tcp(rest).map_err(bad),
        "unix" => unix_path(rest).map_err(bad).and_then(unix_stream),
        "seqpacket" => unix_path(rest).map_err(bad).and_then(unix_seqpacket),
        "serial" => parse_serial(rest).map_err(bad),
        "bt" => parse_bt(rest).map_err(bad).and_then(bt_connector),
        other => Err(bad(format!(
            "unknown scheme {other:?}: expected tcp, unix, seqpacket, serial or bt"
        ))),
    }
}

fn parse_tcp(rest: &str) -> Result<Arc<dyn Connector>, String> {
    let Some((host, port)) = rest.rsplit_once(':') else {
        return Err("missing port: expected tcp://HOST:PORT".into());
    };
    if host.is_empty() || host == "[]" {
        return Err("missing host: expected tcp://HOST:PORT".into());
    }
    if host.contains(':') && !(host.starts_with('[') && host.ends_with(']')) {
        return Err(format!(
            "IPv6 host {host:?} must be in brackets: tcp://[{host}]:PORT"
        ));
    }
    if port.is_empty() {
        return Err("missing port: expected tcp://HOST:PORT".into());
    }
    match port.parse::<u16>() {
        Ok(0) | Err(_) => Err(format!("bad port {port:?}: expected 1 to 65535")),
        Ok(_) => Ok(Arc::new(TcpConnector {
            addr: rest.to_owned(),
        })),
    }
}

fn unix_path(rest: &str) -> Result<&str, String> {
    if rest.is_empty() {
        return Err("missing socket path: expected unix:///path or seqpacket:///path".into());
    }
    Ok(rest)
}

#[cfg(unix)]
fn unix_stream(path: &str) -> Result<Arc<dyn Connector>, LinkError> {
    Ok(Arc::new(crate::link::stream::UnixConnector {
        path: path.into(),
    }))
}

#[cfg(unix)]
fn unix_seqpacket(path: &str) -> Result<Arc<dyn Connector>, LinkError> {
    Ok(Arc::new(crate::link::seqpacket::UnixSeqpacketConnector {
        path: path.into(),
    }))
}

#[cfg(not(unix))]
fn unix_stream(_: &str) -> Result<Arc<dyn Connector>, LinkError> {
    Err(LinkError::Unavailable(
        "unix sockets",
        "not supported on this system".into(),
    ))
}

#[cfg(not(unix))]
fn unix_seqpacket(path: &str) -> Result<Arc<dyn Connector>, LinkError> {
    unix_stream(path)
}

fn parse_serial(rest: &str) -> Result<Arc<dyn Connector>, String> {
    let (path, options) = split_options(rest, &["baud"])?;
    if path.is_empty() {
        return Err("missing device: expected serial:///dev/ttyUSB0[?baud=N]".into());
    }
    let baud = match options.first() {
        Some((_, value)) => match value.parse::<u32>() {
            Ok(baud) if baud > 0 => baud,
            _ => {
                return Err(format!(
                    "bad baud rate {value:?}: expected a positive integer"
                ))
            }
        },
        None => DEFAULT_BAUD,
    };
    Ok(Arc::new(SerialConnector {
        path: path.to_owned(),
        baud,
    }))
}

/// `key=value` options of an address, in the order given.
type Options<'a> = Vec<(&'a str, &'a str)>;

/// Splits `rest` at `?` into the part before and its `key=value` options, checking the keys.
fn split_options<'a>(rest: &'a str, known: &[&str]) -> Result<(&'a str, Options<'a>), String> {
    let Some((head, query)) = rest.split_once('?') else {
        return Ok((rest, Vec::new()));
    };
    let mut options = Options::new();
    for option in query.split('&').filter(|o| !o.is_empty()) {
        let Some((key, value)) = option.split_once('=') else {
            return Err(format!(
                "option {option:?} has no value: expected KEY=VALUE"
            ));
        };
        if !known.contains(&key) {
            return Err(format!(
                "unknown option {key:?}: expected {}",
                known.join(" or ")
            ));
        }
        if options.iter().any(|(k, _)| *k == key) {
            return Err(format!("option {key:?} given twice"));
        }
        options.push((key, value));
    }
    Ok((head, options))
}

/// How a Bluetooth robot is reached, before bluer types exist (they need the feature).
#[cfg_attr(not(feature = "bluetooth"), allow(dead_code))]
struct BtTarget {
    mac: [u8; 6],
    le: Option<LeKind>,
    psm: u16,
}

#[cfg_attr(not(feature = "bluetooth"), allow(dead_code))]
#[derive(Clone, Copy)]
enum LeKind {
    Public,
    Random,
}

fn parse_bt(rest: &str) -> Result<BtTarget, String> {
    let (mac, options) = split_options(rest, &["psm", "type"])?;
    let mac = parse_mac(mac)?;
    let option = |key: &str| options.iter().find(|(k, _)| *k == key).map(|(_, v)| *v);
    let le = match option("type") {
        None | Some("bredr") => None,
        Some("le-public") | Some("le") => Some(LeKind::Public),
        Some("le-random") => Some(LeKind::Random),
        Some(other) => {
            return Err(format!(
                "bad address type {other:?}: expected bredr, le-public or le-random"
            ))
        }
    };
    let psm = match option("psm") {
        Some(text) => parse_psm(text)?,
        None if le.is_some() => return Err("an LE address needs ?psm=N (1 to 0xff)".into()),
        None => DEFAULT_PSM,
    };
    // The kernel rejects these too, but only with a bare EINVAL at connect time.
    if le.is_some() && !(1..=0xff).contains(&psm) {
        return Err(format!("bad LE psm {psm:#x}: expected 1 to 0xff"));
    }
    if le.is_none() && (psm & 0x0001 == 0 || psm & 0x0100 != 0) {
        return Err(format!(
            "bad BR/EDR psm {psm:#x}: must be odd with bit 8 clear, e.g. 0x1001"
        ));
    }
    Ok(BtTarget { mac, le, psm })
}

fn parse_mac(text: &str) -> Result<[u8; 6], String> {
    let bad = || format!("bad MAC address {text:?}: expected six hex pairs like AA:BB:CC:DD:EE:FF");
    let mut mac = [0u8; 6];
    let mut parts = text.split(':');
    for byte in &mut mac {
        let part = parts.next().ok_or_else(bad)?;
        if part.len() != 2 || !part.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(bad());
        }
        *byte = u8::from_str_radix(part, 16).map_err(|_| bad())?;
    }
    match parts.next() {
        Some(_) => Err(bad()),
        None => Ok(mac),
    }
}

fn parse_psm(text: &str) -> Result<u16, String> {
    let parsed = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u16::from_str_radix(hex, 16),
        None => text.parse::<u16>(),
    };
    match parsed {
        Ok(psm) if psm > 0 => Ok(psm),
        _ => Err(format!(
            "bad psm {text:?}: expected 1 to 0xffff, decimal or 0x hex"
        )),
    }
}

#[cfg(feature = "bluetooth")]
fn bt_connector(target: BtTarget) -> Result<Arc<dyn Connector>, LinkError> {
    use bluer::AddressType;
    let addr_type = match target.le {
        None => AddressType::BrEdr,
        Some(LeKind::Public) => AddressType::LePublic,
        Some(LeKind::Random) => AddressType::LeRandom,
    };
    Ok(Arc::new(L2capConnector {
        addr: bluer::Address::new(target.mac),
        addr_type,
        psm: target.psm,
    }))
}

#[cfg(not(feature = "bluetooth"))]
fn bt_connector(_: BtTarget) -> Result<Arc<dyn Connector>, LinkError> {
    Err(LinkError::Unavailable(
        "bluetooth",
        "built without the `bluetooth` feature".into(),
    ))
}

/// A fixed list of robot addresses, e.g. from the command line or a fleet file.
#[derive(Clone, Debug, Default)]
pub struct StaticList {
    /// Addresses in [`parse_address`] form; each robot is named by its address.
    pub addresses: Vec<String>,
}

impl StaticList {
    fn robots(&self) -> Result<Vec<Discovered>, LinkError> {
        self.addresses
            .iter()
            .map(|address| {
                let connector = parse_address(address).map_err(|e| match e {
                    // BadAddress names the address already; say which entry is unusable here.
                    LinkError::Unavailable(what, why) => {
                        LinkError::Unavailable(what, format!("{why} (address {address:?})"))
                    }
                    other => other,
                })?;
                Ok(Discovered {
                    name: address.trim().to_owned(),
                    connector,
                })
            })
            .collect()
    }
}

impl Discoverer for StaticList {
    fn discover(&self) -> BoxFuture<'_, Result<Vec<Discovered>, LinkError>> {
        Box::pin(futures::future::ready(self.robots()))
    }
}
