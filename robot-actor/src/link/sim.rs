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
            // Only one link at a time reads this robot's packets: the previous one's task lets go
            // of the receiver when its owner drops the sender.
            let mut incoming = from_robot.lock_owned().await;
            while incoming.try_recv().is_ok() {}
            sender.connect();
            tokio::spawn(async move {
                loop {
                    tokio::select! {
                        out = to_robot.recv() => match out {
                            Some(p) => {
                                LinkCounters::bump(&c.packets_out);
                                if !sender.send(p) {
                                    let _ = events.send(LinkEvent::Closed(None));
                                    break;
                                }
                            }
                            None => break,
                        },
                        inc = incoming.recv() => match inc {
                            Some(p) => {
                                LinkCounters::bump(&c.packets_in);
                                if events.send(LinkEvent::Packet(p)).is_err() {
                                    break;
                                }
                            }
                            None => {
                                let _ = events.send(LinkEvent::Closed(None));
                                break;
                            }
                        },
                    }
                }
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
