//! A link to a robot that is only a script: it says hello, then sends the frames its caller
//! pushes and ignores what the host sends. For tests and benchmarks of the host side at scale,
//! without a simulator behind the links.

use std::sync::{Arc, Mutex, PoisonError};

use futures::future::BoxFuture;
use futures::FutureExt;
use tokio::sync::mpsc;

use super::{Connector, Link, LinkCounters, LinkError, LinkEvent};

/// The packet queue of every scripted link that has connected, in connection order, with its
/// robot id: push `LinkEvent::Packet(frame)` to make that robot send `frame`.
pub type Feed = Arc<Mutex<Vec<(u16, mpsc::UnboundedSender<LinkEvent>)>>>;

/// A robot that says hello as `id`, then sends whatever is pushed into its queue in `feed`.
pub struct Scripted {
    /// The robot id its hello gives.
    pub id: u16,
    /// Where its queue is published when it connects.
    pub feed: Feed,
}

impl Connector for Scripted {
    fn peer(&self) -> String {
        format!("scripted://{}", self.id)
    }

    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let (tx, mut from_host) = mpsc::channel::<Vec<u8>>(1024);
        let (events, rx) = mpsc::unbounded_channel();
        let mut settings = protocol::Settings::default();
        settings.identity.robot_id = self.id;
        let hello = protocol::packets::Hello::new(&settings, [0, 1, 0]);
        let (buf, n) = protocol::frame::encode_to_array(&hello);
        let _ = events.send(LinkEvent::Packet(buf[..n].to_vec()));
        self.feed
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push((self.id, events));
        // Host packets (pings, settings reads) are drained and ignored.
        tokio::spawn(async move { while from_host.recv().await.is_some() {} });
        let peer = self.peer();
        async move {
            Ok(Link {
                peer,
                tx,
                rx,
                counters: Arc::new(LinkCounters::default()),
            })
        }
        .boxed()
    }
}
