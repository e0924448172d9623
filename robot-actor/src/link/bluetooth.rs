//! Bluetooth links (L2CAP sequenced packets) and BlueZ discovery, via bluer (feature `bluetooth`).
//!
//! L2CAP `SOCK_SEQPACKET` keeps message boundaries, so framing is [`spawn_datagram_link`]'s: one
//! message per packet. Connecting needs only the kernel's `AF_BLUETOOTH`; discovery talks to
//! `bluetoothd` over D-Bus. Where either is missing the errors are [`LinkError::Unavailable`].

use std::future::Future;
use std::io;
use std::sync::Arc;
use std::time::Duration;

use bluer::l2cap::{SeqPacket, SocketAddr};
use bluer::{Adapter, AdapterEvent, Address, AddressType, Session, Uuid};
use futures::future::BoxFuture;
use futures::{FutureExt, StreamExt};

use super::seqpacket::{spawn_datagram_link, Datagram};
use super::{Connector, Discovered, Discoverer, Link, LinkError};
use crate::discover::DEFAULT_PSM;

/// Linux errno values meaning the kernel has no Bluetooth at all (bluer is Linux-only).
const NO_BLUETOOTH_ERRNOS: [i32; 3] = [
    97, // EAFNOSUPPORT: no AF_BLUETOOTH in this kernel
    93, // EPROTONOSUPPORT: no L2CAP protocol module
    19, // ENODEV: no adapter
];

/// The name [`LinkError::Unavailable`] gives this transport.
const BLUETOOTH: &str = "bluetooth";

/// Reaches a robot over an L2CAP sequenced-packet channel.
#[derive(Clone, Debug)]
pub struct L2capConnector {
    /// The robot's Bluetooth address.
    pub addr: Address,
    /// Classic (`BrEdr`) or Low Energy (`LePublic`, `LeRandom`).
    pub addr_type: AddressType,
    /// The protocol service multiplexor the robot listens on.
    pub psm: u16,
}

impl L2capConnector {
    /// A classic (BR/EDR) robot on [`DEFAULT_PSM`].
    pub fn new(addr: Address) -> Self {
        Self {
            addr,
            addr_type: AddressType::BrEdr,
            psm: DEFAULT_PSM,
        }
    }
}

impl Connector for L2capConnector {
    /// A `bt://` address that `parse_address` turns back into this connector.
    fn peer(&self) -> String {
        let kind = match self.addr_type {
            AddressType::BrEdr => "",
            AddressType::LePublic => "&type=le-public",
            AddressType::LeRandom => "&type=le-random",
        };
        format!("bt://{}?psm={:#06x}{kind}", self.addr, self.psm)
    }

    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let target = SocketAddr::new(self.addr, self.addr_type, self.psm);
        let peer = self.peer();
        async move {
            match SeqPacket::connect(target).await {
                Ok(sock) => Ok(spawn_datagram_link(sock, peer)),
                Err(e) => Err(connect_error(peer, e)),
            }
        }
        .boxed()
    }
}

/// A missing Bluetooth stack is `Unavailable` (nothing to retry); anything else is `Connect`.
fn connect_error(peer: String, source: io::Error) -> LinkError {
    match source.raw_os_error() {
        Some(errno) if NO_BLUETOOTH_ERRNOS.contains(&errno) => {
            LinkError::Unavailable(BLUETOOTH, format!("cannot reach {peer}: {source}"))
        }
        _ => LinkError::Connect { peer, source },
    }
}

impl Datagram for SeqPacket {
    fn send(&self, message: &[u8]) -> impl Future<Output = io::Result<usize>> + Send {
        SeqPacket::send(self, message)
    }

    /// The kernel truncates a message longer than `buf` to `buf.len()` bytes, which the link
    /// detects because its buffer is one byte longer than any packet.
    fn recv(&self, buf: &mut [u8]) -> impl Future<Output = io::Result<usize>> + Send {
        SeqPacket::recv(self, buf)
    }
}

/// Finds robots with BlueZ: scans on the default adapter and keeps the devices that match.
#[derive(Clone, Debug)]
pub struct BluezDiscoverer {
    /// Keep devices whose name starts with this.
    pub name_prefix: Option<String>,
    /// Keep devices that advertise this service.
    pub service_uuid: Option<Uuid>,
    /// How long to scan.
    pub scan_for: Duration,
    /// The PSM to connect found robots on.
    pub psm: u16,
    /// How to connect devices BlueZ reports with a public address.
    ///
    /// BlueZ calls classic devices' addresses "public" too, so it cannot tell BR/EDR from LE
    /// here; devices with a random address are always connected over LE.
    pub public_addr_type: AddressType,
}

impl Default for BluezDiscoverer {
    /// Every device found in five seconds, as classic robots on [`DEFAULT_PSM`].
    fn default() -> Self {
        Self {
            name_prefix: None,
            service_uuid: None,
            scan_for: Duration::from_secs(5),
            psm: DEFAULT_PSM,
            public_addr_type: AddressType::BrEdr,
        }
    }
}

impl BluezDiscoverer {
    /// Whether a device is wanted: no filter keeps every device, otherwise either filter may match.
    fn wanted(&self, name: Option<&str>, uuids: &[Uuid]) -> bool {
        if self.name_prefix.is_none() && self.service_uuid.is_none() {
            return true;
        }
        let by_name =
            matches!((&self.name_prefix, name), (Some(p), Some(n)) if n.starts_with(p.as_str()));
        let by_service = self.service_uuid.is_some_and(|u| uuids.contains(&u));
        by_name || by_service
    }

    async fn scan(&self) -> Result<Vec<Discovered>, LinkError> {
        let bluez = |e: bluer::Error| LinkError::Unavailable(BLUETOOTH, format!("BlueZ: {e}"));
        let session = Session::new().await.map_err(bluez)?;
        let adapter = session.default_adapter().await.map_err(bluez)?;
        adapter.set_powered(true).await.map_err(bluez)?;
        let seen = self.collect_addresses(&adapter).await.map_err(bluez)?;

        let mut found = Vec::new();
        for addr in seen {
            // Names and services often arrive after the device does, so they are read after the
            // scan; a device BlueZ has forgotten by then is skipped rather than failing the scan.
            let Ok(device) = adapter.device(addr) else {
                continue;
            };
            let name = device.name().await.ok().flatten();
            let uuids: Vec<Uuid> = device
                .uuids()
                .await
                .ok()
                .flatten()
                .map(|set| set.into_iter().collect())
                .unwrap_or_default();
            if !self.wanted(name.as_deref(), &uuids) {
                continue;
            }
            let addr_type = match device.address_type().await {
                Ok(AddressType::LeRandom) => AddressType::LeRandom,
                _ => self.public_addr_type,
            };
            found.push(Discovered {
                name: name.unwrap_or_else(|| addr.to_string()),
                connector: Arc::new(L2capConnector {
                    addr,
                    addr_type,
                    psm: self.psm,
                }),
            });
        }
        Ok(found)
    }

    /// Addresses of the devices seen during the scan, in order of appearance.
    async fn collect_addresses(&self, adapter: &Adapter) -> bluer::Result<Vec<Address>> {
        let events = adapter.discover_devices().await?;
        let deadline = tokio::time::sleep(self.scan_for);
        tokio::pin!(events, deadline);
        let mut seen = Vec::new();
        loop {
            tokio::select! {
                _ = &mut deadline => break,
                event = events.next() => match event {
                    Some(AdapterEvent::DeviceAdded(addr)) if !seen.contains(&addr) => seen.push(addr),
                    Some(AdapterEvent::DeviceRemoved(addr)) => seen.retain(|a| *a != addr),
                    Some(_) => {}
                    None => break,
                },
            }
        }
        // Dropping the event stream (at return) ends BlueZ's discovery session.
        Ok(seen)
    }
}

impl Discoverer for BluezDiscoverer {
    fn discover(&self) -> BoxFuture<'_, Result<Vec<Discovered>, LinkError>> {
        self.scan().boxed()
    }
}
