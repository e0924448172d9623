//! The in-process simulator as a transport: a [`simulator::runtime::LinkEnd`] behind a
//! [`Connector`], plus a [`Discoverer`] that lists every simulated robot.

use std::sync::Arc;

use futures::future::BoxFuture;
use futures::FutureExt;
use simulator::runtime::{LinkEnd, LinkSender};
use tokio::sync::{mpsc, Mutex};

use super::{
    Connector, Discovered, Discoverer, Link, LinkCounters, LinkError, LinkEvent, SEND_QUEUE,
};

/// Connects to one simulated robot.
pub struct SimConnector {
    robot_id: u16,
    sender: LinkSender,
    from_robot: Arc<Mutex<mpsc::UnboundedReceiver<Vec<u8>>>>,
}

impl SimConnector {
    /// Wraps a link end handed out by `simulator::runtime::spawn`.
    pub fn new(end: LinkEnd) -> Self {
        let robot_id = end.robot_id;
        let (sender, from_robot) = end.split();
        Self {
            robot_id,
            sender,
            from_robot: Arc::new(Mutex::new(from_robot)),
        }
    }

    /// The simulated robot's id.
    pub fn robot_id(&self) -> u16 {
        self.robot_id
    }
}

impl Connector for SimConnector {
    fn peer(&self) -> String {
        format!("sim://{}", self.robot_id)
    }

    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let sender = self.sender.clone();
        let from_robot = Arc::clone(&self.from_robot);
        let peer = self.peer();
        async move {
            let (tx, mut to_robot) = mpsc::channel::<Vec<u8>>(SEND_QUEUE);
            let (events, rx) = mpsc::unbounded_channel();
            let counters = Arc::new(LinkCounters::default());
            let c = Arc::clone(&counters);
            // Only one link at a time reads this robot's packets: the previous one lets go of the
            // receiver when its owner drops the sender.
            let mut incoming = from_robot.lock_owned().await;
            while incoming.try_recv().is_ok() {}
            // The stepping task hands packets straight to the actor's channel: no task of ours
            // to wake in between.
            let to_actor = events.clone();
            let key = sender.set_sink(Box::new(move |p| match p {
                Some(p) => {
                    LinkCounters::bump(&c.packets_in);
                    to_actor.send(LinkEvent::Packet(p)).is_ok()
                }
                None => {
                    let _ = to_actor.send(LinkEvent::Closed(None));
                    false
                }
            }));
            sender.connect();
            let c = Arc::clone(&counters);
            tokio::spawn(async move {
                let _reading = incoming;
                while let Some(p) = to_robot.recv().await {
                    LinkCounters::bump(&c.packets_out);
                    if !sender.send(p) {
                        let _ = events.send(LinkEvent::Closed(None));
                        break;
                    }
                }
                sender.clear_sink(key);
                sender.disconnect();
            });
            Ok(Link {
                peer,
                tx,
                rx,
                counters,
            })
        }
        .boxed()
    }
}

/// Lists the robots of a running simulation.
pub struct SimDiscoverer {
    robots: Vec<Arc<SimConnector>>,
}

impl SimDiscoverer {
    /// Takes the link ends of a simulation started with `simulator::runtime::spawn`.
    pub fn new(ends: Vec<LinkEnd>) -> Self {
        Self {
            robots: ends
                .into_iter()
                .map(|e| Arc::new(SimConnector::new(e)))
                .collect(),
        }
    }
}

impl Discoverer for SimDiscoverer {
    fn discover(&self) -> BoxFuture<'_, Result<Vec<Discovered>, LinkError>> {
        let found = self
            .robots
            .iter()
            .map(|c| Discovered {
                name: format!("PocketBot2-{}", c.robot_id()),
                connector: Arc::clone(c) as Arc<dyn Connector>,
            })
            .collect();
        async move { Ok(found) }.boxed()
    }
}
